"""Training the GAN-DDPM: a real fit on tiny synthetic data, exact resume, the NaN guard, and DDP."""

from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys
from pathlib import Path

import lightning as L
import probes
import pytest
import synthetic
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.data.datamodule import MotionDataModule
from walkdiff.models.body_terms import BodyTerms
from walkdiff.models.styled_ddpm import StyledMotionDiffusion, TrainingDiverged

TINY = dict(
    d_model=32, layers=1, heads=2, dropout=0.1, lambda_adv=0.05, adv_warmup_batches=2, lr_warmup_batches=2
)


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("tiny")
    synthetic.xia_like_folder(root, walk_clips=8, frames=240)
    return root


def datamodule(root: Path) -> MotionDataModule:
    return MotionDataModule(
        root=str(root), cache_dir=str(root / "cache"), batch_size=8, window=24, preprocess_workers=1
    )


class LossRecorder(L.Callback):
    def __init__(self):
        self.losses: list[tuple[int, float, float]] = []

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        metrics = trainer.callback_metrics
        self.losses.append(
            (pl_module.batches_done, float(metrics["total/train"]), float(metrics["discriminator/train"]))
        )


class Interrupted(Exception):
    pass


class InterruptAt(L.Callback):
    """Stands for a killed process: stops the run when the given epoch starts."""

    def __init__(self, epoch: int):
        self.epoch = epoch

    def on_train_epoch_start(self, trainer, pl_module):
        if trainer.current_epoch == self.epoch:
            raise Interrupted


def fit(
    root: Path, ckpt_dir: Path, ckpt_path: str | None = None, interrupt_at: int | None = None
) -> LossRecorder:
    L.seed_everything(7)
    dm = datamodule(root)
    model = StyledMotionDiffusion(dm.spec, **TINY)
    recorder = LossRecorder()
    extra = [InterruptAt(interrupt_at)] if interrupt_at is not None else []
    trainer = L.Trainer(
        accelerator="cpu",
        max_epochs=3,
        limit_train_batches=3,
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        num_sanity_val_steps=0,
        callbacks=[recorder, L.pytorch.callbacks.ModelCheckpoint(dirpath=ckpt_dir, save_last=True), *extra],
    )
    trainer.fit(model, dm, ckpt_path=ckpt_path)
    return recorder


def test_training_reduces_the_loss_and_checkpoints_carry_what_sampling_needs(tiny_root, tmp_path):
    L.seed_everything(0)
    dm = datamodule(tiny_root)
    model = StyledMotionDiffusion(dm.spec, **TINY)
    recorder = LossRecorder()
    trainer = L.Trainer(
        accelerator="cpu", max_epochs=8, logger=False, enable_progress_bar=False, enable_model_summary=False,
        callbacks=[recorder], default_root_dir=tmp_path,
    )  # fmt: skip
    trainer.fit(model, dm)
    first, last = recorder.losses[0][1], recorder.losses[-1][1]
    assert last < first
    path = tmp_path / "model.ckpt"
    trainer.save_checkpoint(path)
    loaded = StyledMotionDiffusion.load_from_checkpoint(path, map_location="cpu")
    assert loaded.skeleton.names == dm.skeleton.names
    torch.testing.assert_close(loaded.normalizer.mean, dm.normalizer.mean)
    ids = loaded.label_ids(["angry", "old"], "style")
    content = loaded.label_ids(["walk", "walk"], "content")
    x = loaded.generate(ids, content, sampler="ddim", steps=3, generator=torch.Generator().manual_seed(0))
    assert x.shape == (2, 24, dm.spec.feature_dim) and torch.isfinite(x).all()
    # EMA weights (not the raw ones) are what sampling uses; they differ after training.
    raw = dict(loaded.denoiser.named_parameters())
    ema = dict(loaded.ema.module.named_parameters())
    assert any(not torch.equal(raw[k], ema[k]) for k in raw)


def test_resumed_run_logs_the_same_next_losses(tiny_root, tmp_path):
    straight = fit(tiny_root, ckpt_dir=tmp_path / "a")
    with pytest.raises(Interrupted):
        fit(tiny_root, ckpt_dir=tmp_path / "b", interrupt_at=2)
    with pytest.warns(UserWarning, match="exists and is not empty"):  # the same run, continued
        resumed = fit(tiny_root, ckpt_dir=tmp_path / "b", ckpt_path=str(tmp_path / "b" / "last.ckpt"))
    # Epoch 3 of both: same batches-done counter and the same generator and discriminator losses.
    assert [r[0] for r in resumed.losses] == [r[0] for r in straight.losses[-3:]] == [7, 8, 9]
    for a, b in zip(straight.losses[-3:], resumed.losses):
        assert a[1] == pytest.approx(b[1], rel=1e-5) and a[2] == pytest.approx(b[2], rel=1e-5)


def test_non_finite_loss_stops_with_the_term_and_batch_named(tiny_root, monkeypatch, tmp_path):
    dm = datamodule(tiny_root)
    model = StyledMotionDiffusion(dm.spec, **TINY)
    original = model.generator_losses

    def poisoned(*args, **kwargs):
        losses = original(*args, **kwargs)
        losses["root"] = losses["root"] * float("nan")
        return losses

    monkeypatch.setattr(model, "generator_losses", poisoned)
    trainer = L.Trainer(
        accelerator="cpu", fast_dev_run=1, logger=False, enable_progress_bar=False, default_root_dir=tmp_path
    )
    with pytest.raises(TrainingDiverged, match=r"'root' is nan at batch 0"):
        trainer.fit(model, dm)


def test_ddp_two_processes_through_the_cli(tiny_root, tmp_path):
    env = dict(os.environ, WALKDIFF_DATA=str(tiny_root), PYTHONWARNINGS="ignore")
    config = Path(__file__).parents[1] / "conf" / "xia_cpu.yaml"
    command = [
        sys.executable, "-m", "walkdiff.cli.main", "fit", "--config", str(config),
        "--trainer.strategy", "ddp", "--trainer.devices", "2", "--trainer.accelerator", "cpu",
        "--trainer.max_epochs", "1", "--trainer.limit_train_batches", "2", "--trainer.limit_val_batches", "1",
        "--trainer.check_val_every_n_epoch", "1", "--trainer.val_check_interval", "2",
        "--trainer.enable_progress_bar", "false", "--trainer.log_every_n_steps", "1",
        "--model.d_model", "32", "--model.layers", "1", "--model.heads", "2",
        "--model.adv_warmup_batches", "0", "--data.batch_size", "4",
        # No metrics callback here (it needs a trained evaluator): just the latest checkpoint.
        "--trainer.callbacks", '[{"class_path": "lightning.pytorch.callbacks.ModelCheckpoint", '
        '"init_args": {"dirpath": "checkpoints/xia_cpu", "filename": "last"}}]',
        "--data.cache_dir", str(tmp_path / "cache"), "--data.preprocess_workers", "1",
    ]  # fmt: skip
    # Run in tmp_path: the config's relative mlruns/ and checkpoints/ land there.
    result = subprocess.run(command, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path}/mlruns/mlflow.db")
    runs = client.search_runs([e.experiment_id for e in client.search_experiments()])
    assert len(runs) == 1, "both ranks log into one run"
    metrics = runs[0].data.metrics
    assert "total/train" in metrics and "diffusion/val" in metrics and "total/val" in metrics
    assert (tmp_path / "checkpoints" / "xia_cpu" / "last.ckpt").exists()


def test_velocity_and_foot_losses_see_sliding_feet(tiny_root):
    """The FK terms are zero for the real motion itself and measure feet sliding while planted."""
    dm = datamodule(tiny_root)
    dm.setup("fit")
    model = StyledMotionDiffusion(dm.spec, **TINY, lambda_velocity=1.0, lambda_foot=1.0, lambda_position=1.0)
    model.normalizer.load_state_dict(dm.normalizer.state_dict())
    model.profile = dm.profile
    batch = next(iter(dm.train_dataloader()))
    # Standing still on planted feet: every frame the first pose, no root motion, all contacts on.
    raw = model.normalizer.denormalize(batch["features"])[:, :1].repeat(1, 24, 1)
    raw[..., model.layout.root_vel] = 0
    raw[..., model.layout.heading_vel] = 0
    raw[..., model.layout.contacts] = 1
    batch = batch | {"features": model.normalizer.normalize(raw)}
    t = torch.zeros(len(raw), dtype=torch.long)  # weight abar_0 = 0.999

    def losses(x0_hat):
        return model.generator_losses(batch, x0_hat, x0_hat, x0_hat, t, adversarial=False)

    exact = losses(batch["features"])
    assert exact["velocity"] == 0 and exact["foot"] == 0 and exact["position"] == 0
    # Sliding 1 unit sideways every frame: planted feet move at 30 units/s, 30 / threshold thresholds.
    slid_raw = raw.clone()
    slid_raw[..., 0] += 1.0
    slid = model.normalizer.normalize(slid_raw).requires_grad_(True)
    moved = losses(slid)
    abar = float(model.diffusion.alphas_cumprod[0])
    thresholds = (30.0 / model.contact_spec.speed_threshold) ** 2
    assert moved["foot"].item() == pytest.approx(abar * thresholds, rel=1e-4)
    # Every joint moves, in x of (x, y, z).
    assert moved["velocity"].item() == pytest.approx(abar * thresholds / 3, rel=1e-4)
    assert moved["position"].item() == pytest.approx(0, abs=1e-8)  # the pose itself did not change
    moved["foot"].backward()
    assert slid.grad[..., 0].abs().sum() > 0
    # Lowering the root by one contact height moves no joint relative to the root...
    low = raw.clone()
    low[..., model.layout.root_height] -= model.contact_spec.height_threshold
    assert losses(model.normalizer.normalize(low))["position"].item() == pytest.approx(0, abs=1e-8)
    # ...bending the pose does: every joint below the first rotated one moves.
    bent = raw.clone()
    bent[..., model.layout.rotations.start + 6 : model.layout.rotations.start + 12] = torch.tensor(
        [0.0, 1.0, 0.0, -1.0, 0.0, 0.0]
    )
    assert losses(model.normalizer.normalize(bent))["position"].item() > 0.1
    # Under bf16 autocast (trainer.precision bf16-mixed) the forward kinematics stay float32, exactly.
    with torch.autocast("cpu", dtype=torch.bfloat16):
        under_autocast = model.body_terms.positions(bent)
    assert under_autocast.dtype == torch.float32 and torch.equal(
        under_autocast, model.body_terms.positions(bent)
    )


def test_the_foot_height_loss_measures_the_feet_in_the_world_in_contact_heights(tiny_root):
    """Feet one contact height too high cost 1 (times abar_t) whatever the skeleton's units, though the
    pose relative to the root, which the position term sees, has not changed."""
    dm = datamodule(tiny_root)
    dm.setup("fit")
    model = StyledMotionDiffusion(dm.spec, **TINY, lambda_foot_height=2.0, lambda_position=1.0)
    model.normalizer.load_state_dict(dm.normalizer.state_dict())
    model.profile = dm.profile
    batch = next(iter(dm.train_dataloader()))
    raw = model.normalizer.denormalize(batch["features"])
    t = torch.zeros(len(raw), dtype=torch.long)
    abar = float(model.diffusion.alphas_cumprod[0])

    def losses(x0_hat):
        return model.generator_losses(batch, x0_hat, x0_hat, x0_hat, t, adversarial=False)

    assert losses(batch["features"])["foot_height"] == 0
    high = raw.clone()
    high[..., model.layout.root_height] += model.contact_spec.height_threshold
    x0_hat = model.normalizer.normalize(high).requires_grad_(True)
    raised = losses(x0_hat)
    assert raised["foot_height"].item() == pytest.approx(abar, rel=1e-3)
    assert raised["position"].item() == pytest.approx(0, abs=1e-6)
    raised["foot_height"].backward()
    assert x0_hat.grad[..., model.layout.root_height].abs().sum() > 0
    assert model.total_loss({"foot_height": raised["foot_height"]}) == 2 * raised["foot_height"]
    # Off (the default) it is not computed at all.
    plain = StyledMotionDiffusion(dm.spec, **TINY, lambda_position=1.0)
    plain.normalizer.load_state_dict(dm.normalizer.state_dict())
    plain.profile = dm.profile
    assert "foot_height" not in plain.generator_losses(batch, x0_hat, x0_hat, x0_hat, t, adversarial=False)


def test_the_low_foot_term_stops_a_foot_the_sample_itself_puts_on_the_ground(tiny_root):
    """The low-foot term judges the prediction by its own geometry, as the skating metric does: a foot
    near the floor that slides beyond the contact speed costs how far beyond, a foot as fast in the air
    or still on the floor costs nothing, and the gradient both slows the low foot and lifts it."""
    dm = datamodule(tiny_root)
    dm.setup("fit")
    body = BodyTerms(dm.profile, fps=30.0)
    spec = dm.profile.contacts
    joints, frames = len(body.skeleton.parents), 4
    floor = torch.zeros(4)
    step = 3 * spec.speed_threshold / 30.0  # three contact speed thresholds per frame

    def cost(height_in_contact_heights: float, moving: bool) -> torch.Tensor:
        positions = torch.zeros(1, frames, joints, 3)
        positions[..., 1] = height_in_contact_heights * spec.height_threshold
        if moving:
            positions[:, :, :, 0] = torch.arange(frames, dtype=torch.float32)[:, None] * step
        positions.requires_grad_(True)
        velocity = body.velocities(positions)
        return body.low_foot_slide(positions, velocity, floor), positions

    sliding, positions = cost(0.0, moving=True)
    assert sliding.shape == (1, frames - 1, 4)
    assert sliding.mean().item() == pytest.approx(2.0, rel=1e-3)  # 3 thresholds: 2 beyond the first
    sliding.sum().backward()
    feet = positions.grad[:, :, body.feet]
    assert (feet[:, -1, :, 0] > 0).all()  # slowed: the last frame pulled back along the slide
    assert cost(3.0, moving=True)[0].max().item() < 1e-6  # the same speed in the air
    assert cost(0.0, moving=False)[0].max().item() == 0  # planted
    # Just at the contact height the foot is half "near the ground", and the term lifts it.
    edge, positions = cost(1.0, moving=True)
    assert edge.mean().item() == pytest.approx(0.5, rel=1e-3)
    edge.sum().backward()
    assert (positions.grad[:, :, body.feet, 1] < 0).all()
    # A joint never planted in the training data (NaN floor) is never near it.
    assert (
        body.low_foot_slide(positions, body.velocities(positions), torch.full((4,), float("nan"))).max() == 0
    )
    # In the model: measured from the floor real planted feet stand on, weighted by its lambda.
    model = StyledMotionDiffusion(dm.spec, **TINY, lambda_low_foot=2.0)
    model.normalizer.load_state_dict(dm.normalizer.state_dict())
    model.profile = dm.profile
    batch = next(iter(dm.train_dataloader()))
    t = torch.zeros(len(batch["features"]), dtype=torch.long)
    x0 = batch["features"]
    low_foot = model.generator_losses(batch, x0, x0, x0, t, adversarial=False)["low_foot"]
    assert torch.isfinite(low_foot) and model.total_loss({"low_foot": low_foot}) == 2 * low_foot


def test_a_slowed_rerun_trains_the_same_and_keeps_both_runs_checkpoints(tiny_root, tmp_path, monkeypatch):
    """Bounded by steps (max_time only a safety net), the same command and seed train the same number
    of steps, to the same validation losses, on a fast and a slow machine. The rerun's
    checkpoints go to a folder of their own and last.ckpt follows them."""
    from walkdiff.cli.main import main

    monkeypatch.chdir(tmp_path)  # the config's mlruns/ and checkpoints/ land here
    monkeypatch.setattr("sys.argv", ["walkdiff"])  # LightningCLI warns about pytest's own arguments
    records = {}
    for name, slow in (
        ("normal", []),
        ("slowed", [{"class_path": "probes.SleepEachBatch", "init_args": {"seconds": 0.3}}]),
    ):
        steps = {"class_path": "probes.RecordSteps", "init_args": {"path": f"{name}.json"}}
        config = tmp_path / f"{name}.yaml"
        config.write_text(
            probes.tiny_fit_config(tiny_root, "same", epochs=3, batches=3, callbacks=[steps, *slow])
        )
        assert main(["fit", "--config", str(config)]) == 0
        records[name] = json.loads((tmp_path / f"{name}.json").read_text())
        runs = sorted(p for p in (tmp_path / "checkpoints" / "same").iterdir() if p.is_dir())
        newest = max(runs, key=lambda p: p.stat().st_mtime)
        assert (tmp_path / "checkpoints" / "same" / "last.ckpt").resolve() == newest / "last.ckpt"
    normal, slowed = records["normal"], records["slowed"]
    assert normal["epochs"] == slowed["epochs"] == 3
    assert (
        normal["last_step"] == slowed["last_step"] == 3 * 3
    )  # batches: the discriminator's step is not counted
    assert len(normal["val_loss"]) == 3
    assert slowed["val_loss"] == pytest.approx(normal["val_loss"], abs=1e-4)
    # The learning-rate cosine spans the planned steps: it ends at its floor, 0.1 of the peak.
    assert (
        normal["lr"]
        == slowed["lr"]
        == pytest.approx(0.1 * inspect.signature(StyledMotionDiffusion).parameters["lr"].default)
    )
    # Two runs, two folders, each with its own last.ckpt; nothing written beside another run's file.
    assert len(runs) == 2 and all((run / "last.ckpt").is_file() for run in runs)
    assert not list((tmp_path / "checkpoints").rglob("*-v1.ckpt"))


def test_a_best_checkpoint_skips_validations_that_do_not_log_its_metric(
    tiny_root, tmp_path, monkeypatch, capsys
):
    """Issue 33: xia_cpu.yaml with --trainer.check_val_every_n_epoch 1 failed after the first epoch, its
    best checkpoint monitoring metrics/fmd, which MotionMetrics logs every 5th epoch only."""
    from walkdiff.cli.main import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("sys.argv", ["walkdiff"])
    best = {"dirpath": "checkpoints/every", "filename": "best-{epoch:04d}", "link": "best"}
    callbacks = [
        {"class_path": "probes.LogEveryOtherEpoch", "init_args": {"key": "probe/score"}},
        {"class_path": "walkdiff.callbacks.checkpoints.RunCheckpoint",
         "init_args": best | {"monitor": "probe/score", "mode": "min", "save_top_k": -1}},
        {"class_path": "walkdiff.callbacks.checkpoints.RunCheckpoint",
         "init_args": best | {"dirpath": "checkpoints/typo", "monitor": "probe/scor"}},
    ]  # fmt: skip
    config = tmp_path / "every.yaml"
    config.write_text(probes.tiny_fit_config(tiny_root, "every", epochs=4, batches=1, callbacks=callbacks))
    assert main(["fit", "--config", str(config), "--trainer.check_val_every_n_epoch", "1"]) == 0
    # Saved at the validations that logged the metric (epochs 1 and 3), never on a stale value between.
    run = (tmp_path / "checkpoints" / "every" / "best.ckpt").resolve().parent
    assert sorted(p.name for p in run.glob("best-*.ckpt")) == ["best-epoch=0001.ckpt", "best-epoch=0003.ckpt"]
    assert (tmp_path / "checkpoints" / "every" / "best.ckpt").resolve() == run / "best-epoch=0003.ckpt"
    # A monitor that no validation logs (a typo) saves nothing, and says so rather than failing the run.
    assert not list((tmp_path / "checkpoints" / "typo").rglob("*.ckpt"))
    err = capsys.readouterr().err
    assert "no best checkpoint saved: its monitor 'probe/scor' was never logged in this run" in err
    assert "probe/score" in err


def test_checkpoints_without_a_folder_follow_the_trainers_default_root_dir(tiny_root, tmp_path, monkeypatch):
    """A RunCheckpoint without dirpath (as conf/*.yaml and `data scan` write them) saves and links under
    trainer.default_root_dir, so `--trainer.default_root_dir` moves a variant's checkpoints away from the
    config's own links (the quality suite trains Xia's contents from conf/xia_cpu.yaml so)."""
    from walkdiff.cli.main import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("sys.argv", ["walkdiff"])
    best = {"filename": "best-{epoch:04d}", "monitor": "diffusion/val", "mode": "min", "save_top_k": 1}
    callbacks = [{"class_path": "walkdiff.callbacks.checkpoints.RunCheckpoint", "init_args": best}]
    config = tmp_path / "moved.yaml"
    config.write_text(probes.tiny_fit_config(tiny_root, "moved", epochs=1, batches=1, callbacks=callbacks))
    text = config.read_text().replace("  max_time:", "  default_root_dir: checkpoints/mine\n  max_time:")
    config.write_text(text)
    assert main(["fit", "--config", str(config), "--trainer.default_root_dir", "checkpoints/variant"]) == 0
    link = tmp_path / "checkpoints" / "variant" / "best.ckpt"
    assert link.is_symlink() and link.resolve().parent.parent == link.parent
    assert not (tmp_path / "checkpoints" / "mine").exists()


def test_a_checkpoint_saved_before_run_folders_is_moved_aside_not_replaced(tmp_path, capsys):
    from walkdiff.callbacks.checkpoints import _point

    old = tmp_path / "last.ckpt"
    old.write_bytes(b"the earlier run")
    target = tmp_path / "run1" / "last.ckpt"
    target.parent.mkdir()
    target.write_bytes(b"this run")
    _point(old, str(target))
    assert old.is_symlink() and old.read_bytes() == b"this run" and os.readlink(old) == "run1/last.ckpt"
    [kept] = tmp_path.glob("earlier-*/last.ckpt")
    assert kept.read_bytes() == b"the earlier run"
    assert f"moved the earlier {old}" in capsys.readouterr().err
    _point(old, str(target))  # a link is simply replaced
    assert len(list(tmp_path.glob("earlier-*"))) == 1


def test_bar_rows_find_the_first_measurement_at_bar_and_the_one_from_which_it_stays():
    from walkdiff.bench.time_to_bar import _bar_rows, _first

    bar = {"style_acc": 0.8, "fmd": 10.0, "skate_ratio": 0.2}
    values = [(0.5, 50.0, 0.1), (0.9, 9.0, 0.1), (0.9, 11.0, 0.1), (0.9, 8.0, 0.2), (1.0, 7.0, 0.15)]
    history = [
        {
            "batches": 10 * (i + 1),
            "seconds": 1.0,
            "style_acc": s,
            "fmd": f,
            "skate_ratio": k,
        }
        for i, (s, f, k) in enumerate(values)
    ]
    times = {10 * (i + 1): {"wall_s": 5.0 * (i + 1), "train_loop_s": 3.0 * (i + 1)} for i in range(5)}
    rows = _bar_rows(history, times, bar)
    assert [r["at_bar"] for r in rows] == [False, True, False, True, True]  # 11 > 10; 0.2 <= 0.2 holds
    assert [r["training_s"] for r in rows] == [4.0, 8.0, 12.0, 16.0, 20.0]  # wall minus the measurements
    found = _first(rows, "at_bar")
    assert found["first"]["batches"] == 20 and found["from_then_on"]["batches"] == 40
    assert _first(rows, "fmd_ok")["from_then_on"]["batches"] == 40
    assert _first(rows[:1], "at_bar") == {"first": None, "from_then_on": None}


def tiny_evaluator(root: Path, path: Path) -> Path:
    """An evaluator trained one epoch on the tiny folder (its accuracy does not matter), saved at `path`."""
    from walkdiff.models.evaluator import MotionEvaluator

    L.seed_everything(0)
    dm = MotionDataModule(
        root=str(root), cache_dir=str(root / "cache"), contents="all", batch_size=8, window=24,
        preprocess_workers=1,
    )  # fmt: skip
    trainer = L.Trainer(
        accelerator="cpu", max_epochs=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
        enable_model_summary=False, limit_val_batches=1, num_sanity_val_steps=0,
    )  # fmt: skip
    trainer.fit(MotionEvaluator(dm.spec, hidden=16, embed_dim=8, blocks=1), dm)
    trainer.save_checkpoint(path)
    return path


def test_a_label_turns_only_when_its_held_out_and_training_windows_turn_alike():
    from walkdiff.bench.ablate import turning

    def turn(mean, ci=3.0):
        return {"mean": mean, "low": mean - ci, "high": mean + ci}

    assert turning(turn(58.9), turn(68.5)) and turning(turn(-44.5), turn(-63.4))  # walk-turn-left, -right
    assert not turning(turn(-17.9), turn(5.7))  # held-out runs that curve, training runs that do not
    assert (
        not turning(turn(16.0), turn(-23.3))
        and not turning(turn(9.9), turn(12.4))
        and not turning(None, turn(50))
    )
    assert not turning(turn(18.5, ci=19.2), turn(12.4))  # held-out punches whose turn is not clear of zero


def test_bench_ablate_trains_each_variant_once_and_tables_them(tiny_root, tmp_path, monkeypatch):
    """`walkdiff bench ablate`: a variant trained at the grid's budget and one scored otherwise from its
    model; every figure a ratio to real with its interval; a second call resumes without training; a
    suite (`bench train --to-bar --suite`) of folders, each with its config and overrides."""
    from walkdiff.bench.ablate import BAR
    from walkdiff.cli.main import main

    evaluator = tiny_evaluator(tiny_root, tmp_path / "evaluator.ckpt")
    monkeypatch.chdir(tmp_path)
    metrics = {
        "class_path": "walkdiff.callbacks.metrics.MotionMetrics",
        "init_args": {"evaluator_ckpt": str(evaluator), "every_n_steps": 2, "num_samples": 16,
                      "sampler": "ddim", "steps": 2, "batch_size": 16},
    }  # fmt: skip
    config = tmp_path / "abl.yaml"
    config.write_text(probes.tiny_fit_config(tiny_root, "abl", epochs=3, batches=2, callbacks=[metrics]))
    grid = tmp_path / "grid.yaml"
    grid.write_text(
        "budget: 4\n"
        "evaluate: {num: 16, repeats: 2, sampler: ddim, steps: 2}\n"
        "variants:\n"
        "  - {name: baseline, factor: baseline}\n"
        "  - {name: guided, factor: guidance, from: baseline, evaluate: {guidance: 2.0}}\n"
        "  - {name: fixed, factor: feet fixed, from: baseline, evaluate: {fix_feet: true}}\n"
    )
    args = ["bench", "ablate", "--config", str(config), "--grid", str(grid), "--out", "abl"]
    assert main(args) == 0
    result = json.loads((tmp_path / "abl" / "ablation.json").read_text())
    rows = {v["name"]: v for v in result["variants"]}
    assert list(rows) == ["baseline", "guided", "fixed"]
    # Scored with fix_feet, the bar judges the windows as `generate --fix-feet` writes them.
    fixed = json.loads(Path("abl/fixed/eval/report.json").read_text())["rows"]["generated, feet fixed"]
    assert rows["fixed"]["finish"] == "generated, feet fixed" and rows["baseline"]["finish"] == "generated"
    assert rows["fixed"]["fmd"]["mean"] == round(fixed["fmd"]["mean"], 4)
    assert rows["baseline"]["batches"] == 4  # the grid's budget, not the config's 6
    assert json.loads(Path("abl/guided/eval/report.json").read_text())["settings"]["guidance"] == 2.0
    assert not Path("abl/guided/train.json").exists()  # scored from the baseline's model
    for row in rows.values():
        for name in BAR:
            ratio = row[name]  # None where real has no reference value (tiny data: no real skating)
            assert ratio is None or ratio["low"] <= ratio["value"] <= ratio["high"]
        assert row["fmd_floor"]["value"] > 0
        assert row["at_bar"]["all"] == all(ok for k, ok in row["at_bar"].items() if k != "all")
        assert [m["batches"] for m in row["curve"]] == [2, 4]
    table = (tmp_path / "abl" / "ablation.md").read_text()
    assert "| guidance | guided | 4 |" in table and "| feet fixed | fixed, feet fixed | 4 |" in table
    # Resumed: nothing is trained again; the table is the same.
    stamp = Path("abl/baseline/train.json").stat().st_mtime_ns
    assert main(args) == 0
    assert Path("abl/baseline/train.json").stat().st_mtime_ns == stamp
    # A suite: each entry names its folder's config; finished entries of the same folder are kept.
    other = tmp_path / "other.yaml"
    other.write_text(config.read_text())
    suite = tmp_path / "suite.yaml"
    suite.write_text(
        "budget: 4\nevaluate: {num: 16, repeats: 2, sampler: ddim, steps: 2}\nvariants:\n"
        f"  - {{name: baseline, factor: tiny, config: {config}}}\n"
        f"  - {{name: other, factor: other folder, config: {other}, fit: [--model.lambda_adv, '0']}}\n"
    )
    args_suite = ["bench", "train", "--to-bar", "--suite", str(suite), "--out", "abl"]
    assert main(args_suite) == 0
    assert Path("abl/baseline/train.json").stat().st_mtime_ns == stamp
    table = (tmp_path / "abl" / "ablation.md").read_text()
    assert f"| `{other}` | other folder | other | 4 |" in table
    # A suite's table names each row's config, even while one entry is done (entries run one at a time).
    from walkdiff.bench.ablate import format_table

    done = json.loads(Path("abl/ablation.json").read_text())
    alone = format_table(done | {"variants": done["variants"][:1]})
    assert "None" not in alone and f"| `{config}` | tiny | baseline | 4 |" in alone
    fit_args = json.loads(Path("abl/other/train.json").read_text())["fit_args"]
    assert fit_args[:2] == ["--model.lambda_adv", "0"]
    assert fit_args[fit_args.index("--trainer.max_time") + 1] == "null"  # the budget, never the clock
    assert json.loads(Path("abl/other/train.json").read_text())["fit_args"][:2] == ["--model.lambda_adv", "0"]
    # A grid naming a variant that does not exist, or a `from` that is not trained before it.
    grid.write_text("variants:\n  - {name: a, from: b}\n")
    assert main(args) == 1


def test_bench_time_to_bar_times_a_run_and_reads_its_metrics(tiny_root, tmp_path, monkeypatch):
    """`walkdiff bench train --to-bar` on a tiny config: its measurements, their times and the bar."""
    from mlflow import MlflowClient

    from walkdiff.bench.time_to_bar import BAR
    from walkdiff.cli.main import main

    evaluator = tiny_evaluator(tiny_root, tmp_path / "evaluator.ckpt")
    monkeypatch.chdir(tmp_path)  # the config's mlruns/ and checkpoints/ land here
    metrics = {
        "class_path": "walkdiff.callbacks.metrics.MotionMetrics",
        # --evaluator replaces the config's evaluator: this one does not exist
        "init_args": {"evaluator_ckpt": "missing.ckpt", "every_n_steps": 3, "num_samples": 16,
                      "sampler": "ddim", "steps": 2, "batch_size": 16},
    }  # fmt: skip
    config = tmp_path / "bar.yaml"
    # What the report said while the run was still training (after the first measurement).
    copy = {
        "class_path": "probes.CopyAtEpochStart",
        "init_args": {"source": "bar.json", "target": "early.json", "epoch": 1},
    }
    config.write_text(
        probes.tiny_fit_config(tiny_root, "bar", epochs=5, batches=3, callbacks=[metrics, copy])
    )
    out = Path("bar.json")
    args = ["bench", "train", "--to-bar", "--config", str(config), "--evaluator", str(evaluator)]
    assert main(args + ["--repeats", "2", "--out", str(out), "--", "--trainer.max_steps", "6"]) == 0
    early = json.loads((tmp_path / "early.json").read_text())
    assert not early["finished"] and [r["batches"] for r in early["measurements"]] == [3]

    result = json.loads(out.read_text())
    assert result["finished"] and result["fit_args"] == ["--trainer.max_steps", "6"]
    rows = result["measurements"]
    assert [r["batches"] for r in rows] == [3, 6]
    assert result["max_steps"] == result["batches"] == 6
    assert all(r["metrics_s"] > 0 and 0 < r["train_loop_s"] <= r["training_s"] < r["wall_s"] for r in rows)
    assert rows[0]["training_s"] < rows[1]["training_s"]
    assert result["training_s"] + result["metrics_s"] >= rows[-1]["wall_s"] - 0.1
    assert 0 < result["train_loop_s"] <= result["training_s"]
    for name, (kind, factor) in BAR.items():
        bar = result["bar"][name]["value"]
        assert bar == pytest.approx(factor * result["real_held_out"][name], abs=1e-3)
        for r in rows:
            assert r[f"{name}_ok"] == (r[name] >= bar if kind == "min" else r[name] <= bar)
    assert [r["at_bar"] for r in rows] == [all(r[f"{n}_ok"] for n in BAR) for r in rows]
    first = next((r["batches"] for r in rows if r["at_bar"]), None)
    assert (result["time_to_bar"]["first"] or {}).get("batches") == first
    run = MlflowClient(tracking_uri=f"sqlite:///{tmp_path}/mlruns/mlflow.db").get_run(result["mlflow_run_id"])
    assert run.info.status == "FINISHED" and "metrics/fmd" in run.data.metrics


def test_bench_train_times_a_config_in_its_own_precision(tiny_root, tmp_path):
    from walkdiff.bench.train import bench_train

    config = tmp_path / "bf16.yaml"
    text = probes.tiny_fit_config(tiny_root, "bf16", epochs=1, batches=4, callbacks=[])
    config.write_text(text.replace("  devices: 1\n", "  devices: 1\n  precision: bf16-mixed\n"))
    result = bench_train(str(tmp_path / "train.json"), str(config), batches=2, warmup=1, repeats=1)
    assert result["precision"] == "bf16-mixed" and result["batch_size"] == 8
    assert result["lightning_windows_per_s_median"] > 0 and result["plain_windows_per_s_median"] > 0
    assert result["cpu_seconds_per_batch_median"] > 0
    assert json.loads((tmp_path / "train.json").read_text())["precision"] == "bf16-mixed"
    config.write_text(text.replace("  devices: 1\n", "  devices: 1\n  precision: 16-mixed\n"))
    with pytest.raises(WalkdiffError, match="trainer.precision"):
        bench_train(str(tmp_path / "other.json"), str(config), batches=2, warmup=1, repeats=1)


def test_bench_train_times_a_recipe_beside_its_config_in_one_run(tiny_root, tmp_path):
    """`bench train -- FIT_OPTIONS`: both timed, interleaved; the overrides reach the model and data; a
    trainer option is ignored and anything else named."""
    from walkdiff.bench.train import _config_model_and_data, bench_train_recipe

    config = tmp_path / "tiny.yaml"
    config.write_text(probes.tiny_fit_config(tiny_root, "recipe", epochs=1, batches=4, callbacks=[]))
    args = ["--model.min_snr_gamma", "5", "--data.stride=3", "--trainer.max_steps", "9"]
    model, dm = _config_model_and_data(str(config), args)
    assert model.hparams.min_snr_gamma == 5 and dm.hparams.stride == 3
    result = bench_train_recipe(
        str(tmp_path / "recipe.json"), str(config), args, batches=2, warmup=1, repeats=2
    )
    assert [len(v) for v in result["seconds_per_batch"].values()] == [2, 2]
    medians = result["seconds_per_batch_median"]
    assert result["recipe_over_config"] == pytest.approx(medians["recipe"] / medians["config"], rel=0.01)
    assert json.loads((tmp_path / "recipe.json").read_text())["fit_args"] == args
    for bad in (["--model.min_snr_gamma"], ["--optimizer.lr", "1"], ["model.lr", "1"]):
        with pytest.raises(WalkdiffError, match="fit option"):
            _config_model_and_data(str(config), bad)


def test_the_foot_velocity_loss_costs_feet_moving_unlike_real_ones_on_every_frame(tiny_root):
    """A foot velocity of one contact speed threshold more than the real one costs 1 (times abar_t) on
    every frame, planted or swinging, whatever the skeleton's units; the real motion costs 0."""
    dm = datamodule(tiny_root)
    dm.setup("fit")
    model = StyledMotionDiffusion(dm.spec, **TINY, lambda_foot_velocity=1.0)
    model.normalizer.load_state_dict(dm.normalizer.state_dict())
    model.profile = dm.profile
    batch = next(iter(dm.train_dataloader()))
    raw = model.normalizer.denormalize(batch["features"])
    t = torch.zeros(len(raw), dtype=torch.long)
    abar = float(model.diffusion.alphas_cumprod[0])

    def losses(x0_hat):
        return model.generator_losses(batch, x0_hat, x0_hat, x0_hat, t, adversarial=False)

    assert losses(batch["features"])["foot_velocity"] == 0
    # The whole body rising at the threshold speed: every foot's vertical speed is off by 1 threshold.
    rising = raw.clone()
    frames = torch.arange(raw.shape[1], dtype=raw.dtype)
    step = model.contact_spec.speed_threshold / model.spec["fps"]
    rising[..., model.layout.root_height] += (frames * step)[None, :, None]
    x0_hat = model.normalizer.normalize(rising).requires_grad_(True)
    moved = losses(x0_hat)
    assert moved["foot_velocity"].item() == pytest.approx(abar, rel=1e-3)
    moved["foot_velocity"].backward()
    assert x0_hat.grad[..., model.layout.root_height].abs().sum() > 0


def test_adaln_conditioning_starts_blind_to_the_labels_then_learns_them_and_reloads(tiny_root, tmp_path):
    L.seed_everything(0)
    dm = datamodule(tiny_root)
    model = StyledMotionDiffusion(dm.spec, **{**TINY, "conditioning": "adaln"})
    net = model.denoiser
    assert not hasattr(net, "encoder") and len(net.layers) == TINY.get("layers", 4)
    x, t = torch.randn(2, 24, dm.spec.feature_dim), torch.tensor([50, 50])
    style, content = model.label_ids(["angry", "old"], "style"), model.label_ids(["walk", "walk"], "content")
    # adaLN-Zero: every modulation starts at zero, so each layer starts as the identity whatever the labels
    same = net(x[:1].expand(2, -1, -1), t, style, content)
    torch.testing.assert_close(same[0], same[1])
    trainer = L.Trainer(
        accelerator="cpu", max_epochs=4, logger=False, enable_progress_bar=False, enable_model_summary=False,
        default_root_dir=tmp_path,
    )  # fmt: skip
    trainer.fit(model, dm)
    after = net(x[:1].expand(2, -1, -1), t, style, content)
    assert not torch.allclose(after[0], after[1])  # the style now sets the layers' statistics
    path = tmp_path / "model.ckpt"
    trainer.save_checkpoint(path)
    loaded = StyledMotionDiffusion.load_from_checkpoint(path, map_location="cpu")
    assert loaded.hparams.conditioning == "adaln"
    loaded.eval(), model.eval()  # no dropout in the comparison
    torch.testing.assert_close(loaded.denoiser(x, t, style, content), net(x, t, style, content))


def test_an_unknown_conditioning_is_named_with_the_choices(tiny_root):
    with pytest.raises(WalkdiffError, match=r"model.conditioning: expected one of prefix, adaln, got 'film'"):
        StyledMotionDiffusion(datamodule(tiny_root).spec, **{**TINY, "conditioning": "film"})


def test_the_discriminator_judges_only_its_share_of_the_windows(tiny_root):
    """With discriminator_windows N, its step and the generator's adversarial term see N of the batch's
    windows (the part that costs the same at any batch size); the denoiser's terms see them all."""
    L.seed_everything(0)
    dm = datamodule(tiny_root)
    model = StyledMotionDiffusion(dm.spec, **{**TINY, "discriminator_windows": 3})
    seen = []
    model.discriminator.register_forward_hook(lambda module, args, out: seen.append(args[0].shape[0]))
    dm.setup("fit")
    model.profile = dm.profile
    batch = next(iter(dm.train_dataloader()))
    assert batch["features"].shape[0] == 8
    out, target, x0_hat, t = model.denoise(batch, cond_drop=0.0)
    assert out.shape[0] == x0_hat.shape[0] == 8  # the denoiser's terms see the whole batch
    assert model.discriminator_loss(batch, x0_hat, t)["d"].isfinite()
    losses = model.generator_losses(batch, out, target, x0_hat, t, adversarial=True)
    assert seen == [3, 3, 3] and losses["adv"].isfinite() and losses["diffusion"].isfinite()
    # The whole batch is judged by default, and a count below one is refused by name.
    full = StyledMotionDiffusion(dm.spec, **TINY)
    full.discriminator.register_forward_hook(lambda module, args, out: seen.append(args[0].shape[0]))
    full.discriminator_loss(batch, x0_hat, t)
    assert seen[3:] == [8, 8]
    with pytest.raises(WalkdiffError, match=r"model.discriminator_windows: expected >= 1 or null, got 0"):
        StyledMotionDiffusion(dm.spec, **{**TINY, "discriminator_windows": 0})
