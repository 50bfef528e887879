"""`walkdiff evaluate` end to end on real windows, and the metrics callback on a tiny generator."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from lightning.pytorch.loggers import MLFlowLogger
from mlflow import MlflowClient
from test_evaluator import make_xia_subset, tiny_datamodule, tiny_trainer

from walkdiff.callbacks.metrics import MotionMetrics
from walkdiff.cli.main import main
from walkdiff.evaluation.evaluate import METRICS
from walkdiff.evaluation.scorer import WindowSet, drawn_labels, halves_fmd, matching_windows, window_set
from walkdiff.models.evaluator import MotionEvaluator
from walkdiff.models.styled_ddpm import StyledMotionDiffusion


@pytest.fixture(scope="module")
def setup(xia_dir, tmp_path_factory):
    """A data subset and an evaluator checkpoint trained one epoch on it (its accuracy does not matter)."""
    tmp = tmp_path_factory.mktemp("evaluation")
    root, cache = make_xia_subset(xia_dir, tmp / "data"), tmp / "cache"
    torch.manual_seed(0)
    dm = tiny_datamodule(root, cache)
    trainer = tiny_trainer(max_epochs=1, limit_val_batches=1)
    trainer.fit(MotionEvaluator(dm.spec, hidden=16, embed_dim=8, blocks=1), dm)
    ckpt = tmp / "evaluator.ckpt"
    trainer.save_checkpoint(ckpt)
    return {"root": root, "cache": cache, "ckpt": ckpt, "tmp": tmp}


def tiny_generator(setup, tmp_path, timesteps: int = 10) -> Path:
    """A generator fitted on two batches of the subset (its quality does not matter)."""
    torch.manual_seed(0)
    dm = tiny_datamodule(setup["root"], setup["cache"], contents="walk")
    model = StyledMotionDiffusion(dm.spec, d_model=32, layers=1, heads=2, lambda_adv=0.0, timesteps=timesteps)
    tiny_trainer(max_epochs=1, limit_train_batches=2, limit_val_batches=1).fit(model, dm)
    ckpt = tmp_path / "generator.ckpt"
    model.trainer.save_checkpoint(ckpt)
    return ckpt


def test_generated_labels_are_drawn_as_often_as_the_reference_holds_them():
    # A reference of 90% content 0 (style 1) and 10% content 3 (style 2): generated windows are asked for
    # that mixture, pairs and all, not for every label alike.
    style = torch.tensor([1] * 90 + [2] * 10)
    reference = WindowSet(None, style, torch.where(style == 1, 0, 3), torch.arange(100))
    style, content = drawn_labels(reference, 2000, torch.Generator().manual_seed(0))
    assert set(zip(style.tolist(), content.tolist(), strict=True)) == {(1, 0), (2, 3)}
    assert (content == 3).float().mean() == pytest.approx(0.1, abs=0.02)
    again = drawn_labels(reference, 2000, torch.Generator().manual_seed(0))
    assert torch.equal(again[0], style) and torch.equal(again[1], content)


def test_floor_windows_are_drawn_with_the_asked_labels_and_a_missing_pair_is_counted():
    # A pool (say the training split) of 3 styles x 2 contents, but no window of style 2 with content 1.
    style = torch.tensor([0, 0, 1, 1, 2, 0, 1, 0, 1, 2])
    content = torch.tensor([0, 1, 0, 1, 0, 0, 0, 1, 1, 0])
    pool = WindowSet(None, style, content, torch.arange(10))
    asked = torch.tensor([0, 1, 2, 2, 1, 0]), torch.tensor([1, 0, 0, 1, 1, 0])
    windows, unmatched = matching_windows(pool, asked, torch.Generator().manual_seed(0))
    assert torch.equal(windows.content, asked[1])  # every window of the asked content
    assert windows.style.tolist()[:3] == [0, 1, 2] and windows.style.tolist()[4:] == [1, 0]
    assert unmatched == 1 and windows.style[3] != 2  # the missing pair: another style of content 1


def test_window_set_never_crosses_clips():
    class Info:
        style, content = 2, 1

    clips = [
        (Info, "a", torch.arange(10.0)[:, None].repeat(1, 3).numpy()),
        (Info, "b", torch.zeros(3, 3).numpy()),
    ]
    windows = window_set(clips, window=4, stride=2)
    assert windows.raw.shape == (4, 4, 3)  # starts 0, 2, 4, 6 in the first clip; the second is too short
    assert windows.raw[:, :, 0].tolist()[-1] == [6.0, 7.0, 8.0, 9.0]
    assert windows.clip.tolist() == [0] * 4 and windows.style.tolist() == [2] * 4


def test_halves_fmd_is_zero_for_identical_halves():
    # Two clips per style with the same features: whichever halves, the two sets are identical.
    features = torch.randn(6, 4, generator=torch.Generator().manual_seed(0)).repeat(2, 1)
    style, clip = torch.arange(6).repeat(2) % 3, torch.arange(12) // 6 * 3 + torch.arange(12) % 3
    windows = WindowSet(torch.zeros(12, 2, 3), style, style, clip, features=features)
    assert halves_fmd(windows, torch.Generator().manual_seed(0)) == pytest.approx(0.0, abs=1e-3)


def test_evaluate_real_only_writes_both_reports(setup, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the MLflow database lands in tmp_path/mlruns
    out = tmp_path / "report"
    args = ["evaluate", "--evaluator", str(setup["ckpt"]), "--real-only", "--num", "200", "--repeats", "3"]
    args += ["--seed", "3", "--contents", "walk", "--root", str(setup["root"])]
    assert main(args + ["--out", str(out), "--mlflow-experiment", "eval-test"]) == 0

    report = json.loads((out / "report.json").read_text())
    assert list(report["rows"]) == ["real test", "real train vs test"]
    for row in report["rows"].values():
        assert set(row) == set(METRICS)
        assert row["fmd"]["n"] == 3 and row["fmd"]["ci95"] >= 0
        assert 0 <= row["style_acc"]["mean"] <= 1 and 0 <= row["content_acc"]["mean"] <= 1
    # The real test windows are drawn from the very set FMD is measured against: closer than training data.
    assert report["rows"]["real test"]["fmd"]["mean"] < report["rows"]["real train vs test"]["fmd"]["mean"]
    assert report["fmd_test_halves"]["mean"] > 0
    assert report["data"]["contents"] == ["walk"] and 0 < report["data"]["clips"]["test"] <= 24  # 3 per style
    markdown = (out / "report.md").read_text()
    assert "| real test |" in markdown and "| real train vs test |" in markdown
    assert "FMD(test half A, test half B)" in markdown

    # --seed makes the run repeatable.
    again = tmp_path / "again"
    assert main(args + ["--out", str(again)]) == 0
    assert json.loads((again / "report.json").read_text())["rows"] == report["rows"]

    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path}/mlruns/mlflow.db")
    (run,) = client.search_runs([client.get_experiment_by_name("eval-test").experiment_id])
    assert run.data.metrics["real_test/fmd"] == pytest.approx(report["rows"]["real test"]["fmd"]["mean"])
    assert {a.path for a in client.list_artifacts(run.info.run_id, "evaluation")} == {
        "evaluation/report.json",
        "evaluation/report.md",
    }


def test_evaluate_scores_a_generator_beside_the_real_rows(setup, tmp_path, capsys):
    torch.manual_seed(0)
    dm = tiny_datamodule(setup["root"], setup["cache"], contents="walk")
    model = StyledMotionDiffusion(dm.spec, d_model=32, layers=1, heads=2, lambda_adv=0.0, timesteps=10)
    trainer = tiny_trainer(max_epochs=1, limit_train_batches=2, limit_val_batches=1, log_every_n_steps=1)
    trainer.fit(model, dm)
    ckpt = tmp_path / "generator.ckpt"
    trainer.save_checkpoint(ckpt)

    out = tmp_path / "report"
    args = ["evaluate", "--ckpt", str(ckpt), "--evaluator", str(setup["ckpt"]), "--out", str(out)]
    assert main(args + ["--num", "16", "--repeats", "2", "--sampler", "ddim", "--steps", "2"]) == 0
    report = json.loads((out / "report.json").read_text())
    # The same generated windows grounded and as sampled, then the real references.
    assert list(report["rows"]) == ["generated", "generated, not grounded", "real test", "real train vs test"]
    assert report["data"]["contents"] == ["walk"]  # the generator's data selection
    generated = report["rows"]["generated"]
    assert set(generated) == set(METRICS) and generated["fmd"]["n"] == 2
    # An untrained generator is far from the real data.
    assert generated["fmd"]["mean"] > report["rows"]["real test"]["fmd"]["mean"]
    assert "| generated |" in (out / "report.md").read_text()
    # Per content label, generated beside real: signed turn rate, multimodality and skating.
    walk = report["per_content"]["walk"]
    assert set(walk) == {"generated", "real test", "real train vs test"}
    assert {"turn_deg_s", "multimodality"} <= set(walk["generated"]) and walk["generated"]["windows"] == 16
    assert "| walk | generated | 16 |" in (out / "report.md").read_text()
    # --fix-feet: the same windows once more with their feet pinned (as `generate --fix-feet`), beside.
    fixed = tmp_path / "fixed"
    args_fixed = ["evaluate", "--ckpt", str(ckpt), "--evaluator", str(setup["ckpt"]), "--out", str(fixed)]
    assert (
        main(
            args_fixed + ["--num", "16", "--repeats", "1", "--sampler", "ddim", "--steps", "2", "--fix-feet"]
        )
        == 0
    )
    report = json.loads((fixed / "report.json").read_text())
    assert list(report["rows"])[:3] == ["generated", "generated, not grounded", "generated, feet fixed"]
    assert report["settings"]["fix_feet"] and "generated, feet fixed" in report["per_content"]["walk"]
    assert main(["evaluate", "--ckpt", str(ckpt), "--out", str(out)]) == 1
    assert "report.json" in capsys.readouterr().err  # an earlier report is not replaced unasked
    assert main(["evaluate", "--ckpt", str(ckpt), "--out", str(tmp_path / "other")]) == 1
    assert "--evaluator is required" in capsys.readouterr().err


def test_per_content_reads_each_labels_signed_turn_rate(setup):
    """Windows of one label turning left at 30 degrees/s and another turning right at 60 are told apart:
    a pooled turn rate would average them to a left turn of -15."""
    from walkdiff.evaluation.scorer import MotionScorer, load_evaluator
    from walkdiff.motion.representation import FeatureLayout

    dm = tiny_datamodule(setup["root"], setup["cache"])
    windows = window_set(dm.split_features("train"), dm.spec.window, stride=8)
    raw = windows.raw.clone()
    left = torch.arange(len(raw)) % 2 == 0
    rate = torch.where(left, torch.tensor(30.0), torch.tensor(-60.0))  # degrees per second
    raw[:, :, FeatureLayout.heading_vel.start] = torch.deg2rad(rate)[:, None] / dm.spec.fps
    windows = WindowSet(raw, windows.style, left.long(), windows.clip)
    evaluator = load_evaluator(setup["ckpt"])
    scorer = MotionScorer(evaluator, dm.skeleton, dm.spec.fps)
    embedded = scorer.embed(windows)
    scorer.set_reference(embedded)
    rows = scorer.per_content(embedded)
    assert rows[1]["turn_deg_s"] == pytest.approx(30.0, abs=1e-3)
    assert rows[0]["turn_deg_s"] == pytest.approx(-60.0, abs=1e-3)
    assert rows[0]["windows"] + rows[1]["windows"] == len(windows) and rows[1]["multimodality"] > 0


def test_evaluate_refuses_a_num_too_small_before_any_window_is_made(setup, tmp_path, capsys, monkeypatch):
    """Issue 33: --num 4 failed after a minute of generating, in multimodality. It is checked first."""

    def no_work(*args, **kwargs):
        raise AssertionError("windows were made before --num was checked")

    monkeypatch.setattr("walkdiff.evaluation.evaluate.MotionScorer.embed", no_work)
    monkeypatch.setattr("walkdiff.evaluation.evaluate.generate_windows", no_work)
    args = ["evaluate", "--evaluator", str(setup["ckpt"]), "--real-only", "--root", str(setup["root"])]
    assert main(args + ["--num", "15", "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == (
        "walkdiff: error: --num 15 is too small: multimodality pairs windows of one style, and 15 windows "
        "give some of the 8 styles fewer than 2; the smallest --num that works is 16"
    )
    assert not (tmp_path / "o").exists()


def test_evaluate_needs_a_generator_unless_real_only(setup, tmp_path, capsys):
    assert main(["evaluate", "--evaluator", str(setup["ckpt"]), "--out", str(tmp_path)]) == 1
    assert "--ckpt" in capsys.readouterr().err
    assert main(["evaluate", "--evaluator", str(tmp_path / "missing.ckpt"), "--real-only", "--out", "x"]) == 1


def test_callback_logs_metrics_and_images(setup, tmp_path):
    torch.manual_seed(0)
    dm = tiny_datamodule(setup["root"], setup["cache"], contents="walk")
    model = StyledMotionDiffusion(dm.spec, d_model=32, layers=1, heads=2, lambda_adv=0.0, timesteps=10)
    logger = MLFlowLogger(
        experiment_name="callback-test",
        tracking_uri=f"sqlite:///{tmp_path}/mlflow.db",
        artifact_location=str(tmp_path / "artifacts"),
    )
    callback = MotionMetrics(str(setup["ckpt"]), every_n_steps=2, num_samples=24, sampler="ddim", steps=2)
    trainer = tiny_trainer(
        max_epochs=1,
        limit_train_batches=2,
        limit_val_batches=1,
        log_every_n_steps=1,
        logger=logger,
        callbacks=[callback],
    )
    trainer.fit(model, dm)

    logged = {k for k in trainer.callback_metrics if k.startswith("metrics/")}
    assert {f"metrics/{name}" for name in METRICS} <= logged
    assert 0 <= float(trainer.callback_metrics["metrics/style_acc"]) <= 1
    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path}/mlflow.db")
    run = client.get_run(logger.run_id)
    assert "metrics/fmd" in run.data.metrics
    images = {a.path for a in client.list_artifacts(logger.run_id, "metrics/step_000002")}
    assert images == {"metrics/step_000002/style_confusion.png", "metrics/step_000002/feature_pca.png"}
    for name in images:
        path = client.download_artifacts(logger.run_id, name, str(tmp_path))
        assert Path(path).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_sample_reports_quality_speed_seams_and_transfer(setup, tmp_path):
    from walkdiff.bench.sample import bench_sample

    torch.manual_seed(0)
    dm = tiny_datamodule(setup["root"], setup["cache"], contents="walk")
    model = StyledMotionDiffusion(dm.spec, d_model=32, layers=1, heads=2, lambda_adv=0.0, timesteps=10)
    trainer = tiny_trainer(max_epochs=1, limit_train_batches=2, limit_val_batches=1)
    trainer.fit(model, dm)
    ckpt = tmp_path / "generator.ckpt"
    trainer.save_checkpoint(ckpt)

    out = tmp_path / "bench"
    result = bench_sample(
        str(out), str(ckpt), str(setup["ckpt"]), num=16, ddim_steps=(5,), dpm_steps=(5,), seeds=2,
        batch_size=4, repeats=1,
    )  # fmt: skip
    settings = [(row["sampler"], row["steps"], row["eta"]) for row in result["quality"]]
    assert settings == [
        ("ddpm", 10, 1.0), ("ddim", 5, 0.0), ("ddim", 10, 0.5), ("ddim", 10, 1.0), ("dpmpp", 5, 0.0)
    ]  # fmt: skip
    for row in result["quality"]:
        assert row["fmd"] > 0 and 0 <= row["style_acc"] <= 1 and len(row["fmd_per_seed"]) == 2
        assert row["fmd"] == pytest.approx(sum(row["fmd_per_seed"]) / 2, abs=1e-3)
        assert row["fmd_over_ddpm"] == pytest.approx(row["fmd"] / result["quality"][0]["fmd"], abs=1e-3)
    assert result["quality"][0]["fmd_per_seed"][0] != result["quality"][0]["fmd_per_seed"][1]
    speed = result["speed"]
    assert result["grounded"] and speed["step_s"] > 0 and speed["dpmpp_step_s"] > 0 and speed["forward_s"] > 0
    seams = result["seams_300_frames"]
    assert len(seams) == 9 and all(isinstance(row["within_spread"], bool) for row in seams.values())
    assert all(row["seam_mean"] > 0 and row["inside_mean"] > 0 for row in seams.values())
    kept = result["transfer"]["keep_trajectory"]
    assert kept["windows"] > 0 and kept["root_path_error_relative_max"] < 1e-6
    assert json.loads((out / "sample.json").read_text())["quality"] == result["quality"]
    assert (out / "sample.png").stat().st_size > 0

    # A distilled student against its teacher: the teacher's DDPM is the reference of every ratio.
    from walkdiff.bench.distill import bench_distill
    from walkdiff.common.errors import WalkdiffError
    from walkdiff.styled.distill import distill

    evaluator, report_path = str(setup["ckpt"]), str(tmp_path / "d.json")
    with pytest.raises(WalkdiffError, match="not a distilled checkpoint"):
        bench_distill(report_path, str(ckpt), str(ckpt), evaluator, num=8, seeds=1)
    student = tmp_path / "student.ckpt"
    distill(str(ckpt), str(student), steps=[1, 2], iterations=2, teacher_steps=5)
    with pytest.raises(WalkdiffError, match="the student was distilled from another teacher"):
        bench_distill(report_path, str(student), str(student), evaluator, num=8, seeds=1)
    report = bench_distill(report_path, str(ckpt), str(student), evaluator, num=16, seeds=1)
    rows = [(r["model"], r["sampler"], r["steps"]) for r in report["quality"]]
    assert rows == [("teacher", "ddpm", 10), ("teacher", "ddim", 1), ("teacher", "dpmpp", 1),
                    ("teacher", "ddim", 2), ("teacher", "dpmpp", 2),
                    ("student", "ddim", 1), ("student", "ddim", 2)]  # fmt: skip
    assert report["quality"][0]["fmd_over_ddpm"] == 1.0 and report["distilled"]["steps"] == [1, 2]
    quality = report["quality"]
    fixed = report["student_ddim_fix_feet"]
    assert fixed["before"]["fmd"] == quality[5]["fmd_per_seed"][0] and fixed["after"]["fmd"] > 0
    assert json.loads((tmp_path / "d.json").read_text())["quality"] == report["quality"]

    # `bench sample` on the student: its step counts join the DDIM rows, the speed and the seams.
    result = bench_sample(
        str(tmp_path / "bench_student"), str(student), evaluator, num=16, ddim_steps=(5,), dpm_steps=(5,),
        seeds=1, batch_size=4, repeats=1,
    )  # fmt: skip
    ddim = [row["steps"] for row in result["quality"] if row["sampler"] == "ddim" and row["eta"] == 0]
    assert ddim == [5, 2, 1]
    assert result["speed"]["student_ddim1_window_frames_per_s"] > 0
    assert result["speed"]["student_ddim2_window_frames_per_s"] > 0
    seams = result["seams_300_frames"]
    assert [sum(key.startswith(f"student_ddim{k}_") for key in seams) for k in (1, 2)] == [3, 3]


def test_bench_protocol_scores_walkdiff_beside_the_baselines(setup, tmp_path):
    from walkdiff.bench.protocol import bench_protocol

    ckpt = tiny_generator(setup, tmp_path)

    result = bench_protocol(
        tmp_path / "protocol", ckpt, setup["ckpt"], strengths=(0.5,), samples=16, bootstrap=10
    )
    assert list(result["sampling"]) == ["walkdiff, DDPM 100", "walkdiff, DDIM 10", "real train (floor)"]
    assert list(result["transfer"]) == [
        "transfer 0.5", "transfer 0.5, keep trajectory",
        "baseline: source unchanged", "baseline: real target-style clips",
    ]  # fmt: skip
    # Every test clip went to every other style; the unchanged sources are their own distance 0.
    assert result["transfer_pairs"] == result["sources"] * 7
    assert result["transfer"]["baseline: source unchanged"]["content_distance"]["value"] == pytest.approx(
        0, abs=1e-6
    )
    for row in result["transfer"].values():
        assert 0 <= row["target_style_acc"]["value"] <= 1 and row["fmd"]["value"] >= 0
    assert set(result["verdicts"]) == {"transfer 0.5", "transfer 0.5, keep trajectory"}
    for verdict in result["verdicts"].values():  # at least 5 sources per target style, or no verdict
        few = min(verdict["sources_per_style"].values()) < 5
        assert (verdict["verdict"] == "inconclusive") if few else verdict["verdict"] in ("yes", "no")
    # Which real test clip stood in for each source and target style.
    stand_ins = result["baseline_real_clips"]
    assert len(stand_ins) == result["transfer_pairs"]
    assert {s["real"].split("_")[0] for s in stand_ins} == {s["style"] for s in stand_ins}
    table = (tmp_path / "protocol" / "protocol.md").read_text()
    assert "## Style transfer" in table and "| baseline: real target-style clips |" in table


def test_evaluate_says_its_plan_and_estimate_first_and_quick_changes_the_protocol(setup, tmp_path, capsys):
    """Issue 46: the default protocol ran for hours and said nothing of it. Its plan comes before any
    window, the estimate after the first batch (with what --quick would take); --quick is the quick
    protocol, its settings replaceable, the same table with intervals."""
    from walkdiff.evaluation.plan import FULL, QUICK, protocol

    assert protocol(False, None, None, None, None) == FULL
    assert protocol(True, None, None, None, None) == QUICK
    assert protocol(True, 32, None, "ddpm", None) == replace(QUICK, num=32, sampler="ddpm", steps=None)
    assert protocol(True, None, 2, None, 3) == replace(QUICK, repeats=2, steps=3)

    ckpt = tiny_generator(setup, tmp_path, timesteps=20)
    args = [
        "evaluate",
        "--ckpt",
        str(ckpt),
        "--evaluator",
        str(setup["ckpt"]),
        "--batch-size",
        "16",
        "--stride",
        "8",
    ]
    assert main([*args, "--quick", "--num", "32", "--repeats", "2", "--out", str(tmp_path / "q")]) == 0
    printed = capsys.readouterr().err
    err = [line for line in printed.splitlines() if line.startswith("walkdiff: evaluate:")]
    assert err[0] == (
        "walkdiff: evaluate: quick protocol: 2 repeats x 32 generated windows (dpmpp-10, 10 network passes "
        "each, batches of 16), each repeat scored beside as many real windows; the time it needs follows "
        "the first batch"
    )
    assert re.fullmatch(
        r"walkdiff: evaluate: the first 16 windows took [\d.]+ s: generating all 64 needs about [\d.]+ s "
        r"on this machine",
        err[1],
    ), printed
    report = json.loads((tmp_path / "q" / "report.json").read_text())
    assert report["settings"]["protocol"] == "quick" and report["settings"]["sampler"] == "dpmpp"
    assert report["settings"]["steps"] == 10 and report["estimated_generation_s"] > 0
    assert report["rows"]["generated"]["fmd"]["n"] == 2 and report["rows"]["generated"]["fmd"]["ci95"] >= 0
    assert "quick protocol: 32 windows per repeat, 2 repeats" in (tmp_path / "q" / "report.md").read_text()
    # The full protocol's estimate points at --quick with what it would take.
    assert main([*args, "--num", "16", "--repeats", "1", "--out", str(tmp_path / "full")]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("walkdiff: evaluate:")]
    assert err[0].startswith("walkdiff: evaluate: protocol: 1 repeats x 16 generated windows (ddpm-20, 20 ")
    assert re.search(r"; --quick \(10 x 256, dpmpp-10\) would need about [\d.]+ (s|min)$", err[1]), err
