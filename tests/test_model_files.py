"""Model files that are safe to open: every command reads checkpoints weights-only and refuses a pickled
payload before it runs; `export` writes safetensors and a card every `--ckpt` takes; `checkpoint upgrade`
is the one full unpickling, and only on --trust."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import probes
import pytest
import synthetic
import tiny
import torch
from test_speech import write_take

import walkdiff
from walkdiff.cli.main import main
from walkdiff.common.checkpoints import read_checkpoint
from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.bvh import write_bvh
from walkdiff.spec import DataSpec

PACKAGE = Path(__file__).resolve().parents[1] / "walkdiff"


class Payload:
    """Unpickling this creates `marker`: what a malicious checkpoint would do, made visible."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


@pytest.fixture
def payload(tmp_path) -> tuple[Path, Path]:
    """A checkpoint that is valid but for one pickled object; (its path, the marker unpickling makes)."""
    marker = tmp_path / "payload-ran"
    checkpoint = {
        "state_dict": {"w": torch.zeros(2)},
        "model_class": "walkdiff.models.styled_ddpm.StyledMotionDiffusion",
        "extra": Payload(marker),
    }
    path = tmp_path / "shared.ckpt"
    torch.save(checkpoint, path)
    return path, marker


@pytest.fixture(autouse=True)
def plain_argv(monkeypatch):
    monkeypatch.setattr("sys.argv", ["walkdiff"])


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """A BVH, a WAV, a path file and a BVH folder for the commands to be given beside the checkpoint."""
    root = tmp_path_factory.mktemp("inputs")
    write_take(root / "take", "a", 2.0)
    bvh = root / "walk.bvh"
    write_bvh(bvh, synthetic.walking(120, fps=30.0))
    path = root / "path.json"
    path.write_text(json.dumps([[0, 0], [1, 0]]))
    return {"bvh": bvh, "wav": root / "take" / "a.wav", "path": path, "folder": root / "take"}


def loading_commands(ckpt: Path, inputs: dict[str, Path], out: Path) -> dict[str, list[str]]:
    """Every command that opens a model file, given `ckpt` where it takes one."""
    c, o = str(ckpt), str(out)
    return {
        "sample": ["sample", "--ckpt", c, "--style", "old", "--out", o],
        "transfer": ["transfer", "--ckpt", c, "--input", str(inputs["bvh"]), "--style", "old", "--out", o],
        "walk": ["walk", "--ckpt", c, "--style", "old", "--path", str(inputs["path"]), "--out", o],
        "gesture": ["gesture", "--ckpt", c, "--audio", str(inputs["wav"]), "--out", o],
        "gesture --stream": ["gesture", "--stream", "--ckpt", c, "--audio", str(inputs["wav"]), "--out", o],
        "evaluate --ckpt": ["evaluate", "--ckpt", c, "--evaluator", c, "--out", o],
        "evaluate --evaluator": ["evaluate", "--evaluator", c, "--real-only", "--out", o],
        "score --evaluator": ["score", str(inputs["folder"]), "--evaluator", c, "--out", o],
        "distill": ["distill", "--ckpt", c, "--out", str(out / "student.ckpt")],
        "evaluate-gesture": ["evaluate-gesture", "--ckpt", c, "--out", o],
        "bench gesture": ["bench", "gesture", "--ckpt", c, "--out", str(out / "bench.json")],
        "bench walk": ["bench", "walk", "--ckpt", c, "--evaluator", c, "--out", str(out / "walk.json")],
        "export": ["export", "--ckpt", c, "--out", o],
    }


def test_a_pickled_payload_runs_in_no_command_and_is_refused_in_one_line(payload, inputs, tmp_path, capsys):
    ckpt, marker = payload
    for name, argv in loading_commands(ckpt, inputs, tmp_path / "out").items():
        assert main(argv) == 1, name
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, (name, err)
        assert str(ckpt) in err and "pickled Python objects" in err and "--trust" in err, (name, err)
        assert not marker.exists(), f"{name} ran the payload"
    with pytest.raises(WalkdiffError, match="pickled Python objects"):
        walkdiff.load(ckpt)
    assert not marker.exists()


def test_fit_refuses_a_payload_as_the_metrics_evaluator_before_training(
    payload, tmp_path, monkeypatch, capsys
):
    ckpt, marker = payload
    root = tmp_path / "data"
    synthetic.xia_like_folder(root, walk_clips=6, frames=240)
    metrics = {
        "class_path": "walkdiff.callbacks.metrics.MotionMetrics",
        "init_args": {"evaluator_ckpt": str(ckpt)},
    }
    monkeypatch.chdir(tmp_path)
    Path("fit.yaml").write_text(
        probes.tiny_fit_config(root, "unsafe", epochs=1, batches=1, callbacks=[metrics])
    )
    assert main(["fit", "--config", "fit.yaml"]) == 1
    err = capsys.readouterr().err
    assert "pickled Python objects" in err and not marker.exists()
    assert not list(Path("checkpoints").rglob("*.ckpt")), "it trained before refusing"


def test_no_module_but_the_upgrade_unpickles_in_full():
    """`weights_only=False` (or a torch.load without it) anywhere else would open a door again."""
    found = []
    for path in PACKAGE.rglob("*.py"):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if "weights_only=False" in line or re.search(r"torch\.load\((?![^)]*weights_only=True)", line):
                found.append(f"{path.relative_to(PACKAGE.parent)}:{number}")
    assert found == ["walkdiff/common/model_files.py:" + str(_upgrade_line())], found


def _upgrade_line() -> int:
    lines = (PACKAGE / "common" / "model_files.py").read_text().splitlines()
    return next(i for i, line in enumerate(lines, 1) if "weights_only=False" in line)


@pytest.fixture(scope="module")
def generator(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("generator")
    synthetic.xia_like_folder(root, walk_clips=6, frames=240)
    return tiny.generator(root, epochs=5)


def test_an_exported_model_samples_bit_identically_and_every_command_takes_it(generator, tmp_path, capsys):
    folder = tmp_path / "export"
    assert main(["export", "--ckpt", str(generator), "--out", str(folder)]) == 0
    assert sorted(p.name for p in folder.iterdir()) == ["model.json", "model.safetensors"]
    card = json.loads((folder / "model.json").read_text())
    assert card["model_class"] == "walkdiff.models.styled_ddpm.StyledMotionDiffusion"
    spec = read_checkpoint(generator)["hyper_parameters"]["data_spec"]
    assert card["summary"]["styles"] == list(spec["styles"]) and card["summary"]["fps"] == spec["fps"]
    assert "skeleton_profile" in card["checkpoint"] and "optimizer_states" not in card["checkpoint"]
    assert len(card["summary"]["normalisers"]["normalizer.mean"]) == spec["feature_dim"]

    options = dict(style="angry:0.5,old:0.5", num=2, frames=40, seed=3, sampler="ddim", steps=4)
    from_ckpt = walkdiff.load(generator).sample(**options)
    from_export = walkdiff.load(folder).sample(**options)
    for a, b in zip(from_ckpt, from_export, strict=True):
        assert np.array_equal(a.positions, b.positions)
        assert np.array_equal(a.motion.rotations, b.motion.rotations)

    out = tmp_path / "sampled"
    argv = ["sample", "--ckpt", str(folder), "--style", "old", "--num", "1", "--frames", "30", "--no-gif"]
    assert main([*argv, "--sampler", "ddim", "--steps", "2", "--out", str(out)]) == 0
    assert (out / "old_walk_000.bvh").is_file()
    assert main(["export", "--ckpt", str(generator), "--out", str(folder)]) == 1  # no overwrite unasked
    assert "--overwrite" in capsys.readouterr().err


def test_an_export_folder_missing_its_files_is_named(tmp_path):
    (tmp_path / "model.json").write_text(json.dumps({"format": "walkdiff-model/1", "checkpoint": {}}))
    with pytest.raises(WalkdiffError, match="must hold model.safetensors and model.json"):
        read_checkpoint(tmp_path, "generator")


def test_upgrade_needs_trust_and_rewrites_objects_as_plain_data(generator, tmp_path, capsys):
    checkpoint = read_checkpoint(generator, mmap=False)
    spec = checkpoint["hyper_parameters"]["data_spec"]
    checkpoint["hyper_parameters"]["data_spec"] = DataSpec(**{**spec, "styles": tuple(spec["styles"])})
    checkpoint["planted"] = np.array([0.5, 0.25])
    old, new = tmp_path / "old.ckpt", tmp_path / "new.ckpt"
    torch.save(checkpoint, old)
    assert main(["sample", "--ckpt", str(old), "--style", "old", "--out", str(tmp_path / "o")]) == 1
    assert "walkdiff.spec.DataSpec" in capsys.readouterr().err

    assert main(["checkpoint", "upgrade", str(old), "--out", str(new)]) == 1
    assert "--trust" in capsys.readouterr().err and not new.exists()
    assert main(["checkpoint", "upgrade", str(old), "--out", str(new), "--trust"]) == 0
    assert "unpickling" in capsys.readouterr().err  # said, every time
    upgraded = read_checkpoint(new)
    assert upgraded["hyper_parameters"]["data_spec"]["styles"] == tuple(spec["styles"])
    assert upgraded["planted"] == [0.5, 0.25]
    options = dict(style="old", num=1, frames=30, seed=0, sampler="ddim", steps=2)
    a, b = walkdiff.load(generator).sample(**options)[0], walkdiff.load(new).sample(**options)[0]
    assert np.array_equal(a.positions, b.positions)


def test_upgrade_refuses_what_has_no_plain_form_and_writes_nothing(generator, tmp_path, capsys):
    checkpoint = read_checkpoint(generator, mmap=False)
    checkpoint["hook"] = os.getcwd  # a function: no data in it to keep
    old, new = tmp_path / "old.ckpt", tmp_path / "new.ckpt"
    torch.save(checkpoint, old)
    assert main(["checkpoint", "upgrade", str(old), "--out", str(new), "--trust"]) == 1
    assert "checkpoint.hook" in capsys.readouterr().err and not new.exists()


def test_exported_walkers_and_gesture_models_make_what_their_checkpoints_make(tmp_path_factory, tmp_path):
    root = tmp_path_factory.mktemp("walker")
    synthetic.xia_like_folder(root, walk_clips=8, frames=240)
    walker = tiny.walker(root)[1]
    gestures, takes = tiny.gestures(tmp_path_factory.mktemp("gestures"))
    for ckpt, name in ((walker, "walker"), (gestures, "gestures")):
        assert main(["export", "--ckpt", str(ckpt), "--out", str(tmp_path / name)]) == 0
    path = dict(path=[[0.0, 0.0], [1.0, 0.0], [1.5, 0.5]], style=walkdiff.load(walker).styles[0], seed=1)
    a, b = (walkdiff.load(p).follow(**path, sampler="ddim", steps=2) for p in (walker, tmp_path / "walker"))
    assert np.array_equal(a.positions, b.positions)
    audio = dict(audio=str(takes / "a.wav"), seed=1, sampler="ddim", steps=2)
    a, b = (walkdiff.load(p).gesture(**audio)[0] for p in (gestures, tmp_path / "gestures"))
    assert np.array_equal(a.positions, b.positions)


def test_the_kind_check_of_an_export_reads_its_card_alone(generator, tmp_path):
    """`checkpoint_class` runs before every load: for a folder it must not read the weights twice."""
    from walkdiff.common import checkpoints

    folder = tmp_path / "export"
    assert main(["export", "--ckpt", str(generator), "--out", str(folder)]) == 0
    (folder / "model.safetensors").write_bytes(b"damaged")  # reading the weights would now fail
    assert checkpoints.checkpoint_class(folder) == "walkdiff.models.styled_ddpm.StyledMotionDiffusion"
    with pytest.raises(WalkdiffError, match="not readable safetensors"):
        read_checkpoint(folder)
