"""`walkdiff bench style` end to end on tiny models of real Xia walks (neutral and old): every section,
row and criterion is written with finite numbers, the unseen styles come from the checkpoint, and an
earlier run is kept unless --overwrite. Mechanics only: tiny models say nothing of quality."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import tiny
import torch
from test_evaluator import tiny_datamodule, tiny_trainer

from walkdiff.bench.style import CEILING, CODE_ALONE, EXAMPLES, FLOOR, LABEL, NEAREST, left_out_styles
from walkdiff.bench.style_time import _ramp_seams
from walkdiff.cli.main import main
from walkdiff.common.errors import WalkdiffError
from walkdiff.models.evaluator import MotionEvaluator


@pytest.fixture(scope="module")
def models(xia_tiny, xia_dir, tmp_path_factory) -> dict:
    """conftest's code and label models; a code model trained with `old` left out and an 8-style evaluator
    (one epoch), on the same twelve walks."""
    root = tmp_path_factory.mktemp("bench_style")
    (root / "xia").mkdir()
    for style in ("neutral", "old"):
        for content in (1, 2, 3, 5, 6, 7):
            name = f"{style}_{content:02d}_000.bvh"
            (root / "xia" / name).symlink_to(xia_dir / name)
    unseen = tiny.generator(
        root,
        epochs=2,
        timesteps=20,
        style_code_dim=16,
        name="unseen",
        data_options={"leave_out_styles": ["old"]},
    )
    torch.manual_seed(0)
    dm = tiny_datamodule(root, root / "cache", contents="walk")
    trainer = tiny_trainer(max_epochs=1, limit_val_batches=1)
    trainer.fit(MotionEvaluator(dm.spec, hidden=16, embed_dim=8, blocks=1), dm)
    evaluator = root / "evaluator.ckpt"
    trainer.save_checkpoint(evaluator)
    return {
        "codes": xia_tiny["style_codes"],
        "labels": xia_tiny["generator"],
        "unseen": unseen,
        "evaluator": evaluator,
    }


def numbers(tree) -> list[float]:
    if isinstance(tree, dict):
        return [x for v in tree.values() for x in numbers(v)]
    if isinstance(tree, list):
        return [x for v in tree for x in numbers(v)]
    return [tree] if isinstance(tree, float | int) and not isinstance(tree, bool) else []


def test_bench_style_writes_every_section_and_keeps_an_earlier_run(models, tmp_path, capsys):
    out = tmp_path / "style"
    fast = [
        "--per-example",
        "1",
        "--bootstrap",
        "10",
        "--sampler",
        "ddim",
        "--steps",
        "2",
        "--timeline-clips",
        "2",
    ]
    argv = ["bench", "style", "--ckpt", str(models["codes"]), "--evaluator", str(models["evaluator"]),
            "--out", str(out), *fast]  # fmt: skip
    everything = argv + ["--unseen-ckpt", str(models["unseen"]), "--labels-ckpt", str(models["labels"])]
    assert main(everything) == 0
    result = json.loads((out / "style.json").read_text())
    printed = capsys.readouterr().out
    assert (out / "style.md").read_text() in printed

    seen = result["seen"]
    assert seen["styles"] == ["neutral", "old"]  # the styles the code model holds codes for
    assert list(seen["rows"]) == [EXAMPLES, CODE_ALONE, LABEL] and seen["windows"] == sum(
        map(len, seen["example_clips"].values())
    )
    assert list(result["seen_vs_labels"]["rows"]) == [
        "style-code model, by label",
        "label-only model, by label",
    ]
    unseen = result["unseen"]
    assert unseen["left_out_styles"] == ["old"] == left_out_styles(models["unseen"])  # from the checkpoint
    assert unseen["training_styles"] == ["neutral"] and set(unseen["example_clips"]) == {"old"}
    assert list(unseen["sampling"]["rows"]) == [EXAMPLES, CODE_ALONE, CEILING, NEAREST, FLOOR]
    baselines = ["baseline: source unchanged", "baseline: real target-style clips"]
    expected = [f"{EXAMPLES} (mean code)", CODE_ALONE, CEILING, NEAREST, *baselines]
    assert list(unseen["transfer"]["rows"]) == expected
    assert set(unseen["sampling"]["nearest_training_style"].values()) == {"neutral"}
    assert unseen["transfer"]["pairs"] == unseen["transfer"]["sources"] > 0

    criteria = {"seen": {"accuracy", "fmd"}, "seen_vs_labels": {"accuracy", "fmd"}}
    criteria["unseen"] = {"target_style", "content_kept", "fmd"}
    criteria |= {"transitions": {"inside", "seams"}, "encoding": {"speed"}}
    timeline = result["transitions"]
    assert timeline["transitions"] == 2 * timeline["clips"] and timeline["inside_windows"] > 0
    assert 0 <= timeline["inside_style_acc"] <= 1 and 0 <= timeline["seams_within_p95"] <= 1
    assert result["encoding"]["median_ms"] > 0 and "## Style over time" in printed
    for section, names in criteria.items():
        assert set(result[section]["criteria"]) == names
        for name, criterion in result[section]["criteria"].items():
            assert math.isfinite(criterion["value"]) and math.isfinite(criterion["bar"])
            assert result["passed"][f"{section}/{name}"] is criterion["pass"]
    rows = [
        seen["rows"],
        result["seen_vs_labels"]["rows"],
        unseen["sampling"]["rows"],
        unseen["transfer"]["rows"],
    ]
    for table in rows:
        for row in table.values():
            for metric in ("fmd", "kid", "skate_ratio"):
                assert all(math.isfinite(x) for x in numbers(row[metric])), (metric, row[metric])
            accuracy = row.get("style_acc", row.get("target_style_acc"))
            assert 0 <= accuracy["low"] <= accuracy["value"] <= accuracy["high"] <= 1
    assert all(math.isfinite(x) for x in numbers(unseen["sampling"]["per_style_acc"]))
    assert "## Unseen styles: old" in printed and "## Seen styles against the label-only model" in printed

    assert main(argv) == 1  # an earlier run is kept
    assert "pass --overwrite" in capsys.readouterr().err
    assert main(argv + ["--overwrite"]) == 0  # without the optional models: their sections are left out
    again = json.loads((out / "style.json").read_text())
    assert again["unseen"] is None and again["seen_vs_labels"] is None
    assert again["seen"]["rows"] == seen["rows"]  # the same seed: the same windows


def test_a_model_trained_on_every_style_has_no_unseen_style(models):
    with pytest.raises(WalkdiffError, match="no style is unseen"):
        left_out_styles(models["codes"])


def test_a_ramp_is_judged_against_stretches_that_hold_as_many_window_joins():
    """Joins every 12 frames jolt the speed; a ramp that holds the same joins as the stretches it is
    compared with passes, a ramp with a jump of its own does not."""
    fps, segment, transition, hop = 30.0, 4.0, 1.0, 12
    frames = int(3 * segment * fps)
    speeds = np.ones((8, frames))
    speeds[:, ::hop] += 0.5  # a jolt at every join
    assert all(_ramp_seams(speeds, fps, segment, transition, hop))
    jumped = speeds.copy()
    middle = int(segment * fps)
    jumped[0, middle - 10 : middle + 10 : 2] += 0.3  # the first clip jolts at its first ramp
    seams = _ramp_seams(jumped, fps, segment, transition, hop)
    assert seams[0] is False and all(seams[2:])
