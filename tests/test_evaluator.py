"""The motion evaluator: shapes, position contract, training on real Xia windows, checkpoint round trip."""

from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path

import lightning as L
import pytest
import torch
from synthetic import xia_profile

from walkdiff.common.errors import WalkdiffError
from walkdiff.data.datamodule import MotionDataModule
from walkdiff.models.evaluator import MotionEvaluator
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.representation import FeatureLayout
from walkdiff.spec import DataSpec

SPEC = DataSpec(
    dataset="xia",
    feature_dim=FeatureLayout(3).dim,
    num_joints=3,
    window=16,
    fps=30.0,
    styles=("a", "b", "c"),
    contents=("walk", "run"),
)
TINY = dict(hidden=16, embed_dim=8, blocks=1)


def make_xia_subset(xia_dir: Path, root: Path, walk: int = 6, run: int = 3) -> Path:
    """`root/xia` with links to the first `walk` walking and `run` running clips of every style.

    Enough for every split of both groups (3 + 1 walking and 1 + 1 running clips are held out per style),
    and preprocessed in seconds, unlike the 572 clips of the full set.
    """
    folder = root / "xia"
    folder.mkdir(parents=True)
    for style in ("angry", "childlike", "depressed", "neutral", "old", "proud", "sexy", "strutting"):
        files = sorted(xia_dir.glob(f"{style}_*.bvh"))
        walking = [f for f in files if int(f.stem.split("_")[1]) <= 12][:walk]
        running = [f for f in files if 13 <= int(f.stem.split("_")[1]) <= 15][:run]
        for f in walking + running:
            (folder / f.name).symlink_to(f.resolve())
    return root


def tiny_datamodule(root: Path, cache_dir: Path, contents: str = "walk,run") -> MotionDataModule:
    return MotionDataModule(
        root=str(root),
        contents=contents,
        window=16,
        stride=4,
        batch_size=16,
        cache_dir=str(cache_dir),
        preprocess_workers=1,  # starting worker processes costs more than 72 clips take
    )


def tiny_trainer(**kwargs) -> L.Trainer:
    defaults = dict(
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        num_sanity_val_steps=0,
    )
    return L.Trainer(**(defaults | kwargs))


@pytest.fixture(scope="module")
def model(xia_dir):
    """An untrained evaluator on Xia's skeleton (31 joints), as a checkpoint would hold it."""
    profile = xia_profile(read_bvh(sorted(xia_dir.glob("*.bvh"))[0]))
    spec = replace(SPEC, num_joints=31, feature_dim=FeatureLayout(31).dim)
    evaluator = MotionEvaluator(asdict(spec), **TINY)  # the dict form, as stored in checkpoints
    evaluator.profile = profile
    return evaluator


def test_shapes_for_any_window_length(model):
    for frames in (16, 40, 3):
        positions = 20 * torch.randn(5, frames, 31, 3)
        assert model.features(positions).shape == (5, 8)
        style, content = model.classify(positions)
        assert style.shape == (5, 3) and content.shape == (5, 2)


def test_inputs_are_body_features_normalised_by_the_evaluator(model):
    positions = 20 * torch.randn(4, 16, 31, 3)
    model.feature_normalizer.mean.fill_(3.0)
    model.feature_normalizer.std.fill_(2.0)
    try:
        normalised = (model.body.features(positions, SPEC.fps) - 3.0) / 2.0
        expected, _, _ = model.eval()(normalised.float())
        torch.testing.assert_close(model.features(positions), expected)
    finally:
        model.feature_normalizer.mean.fill_(0.0)
        model.feature_normalizer.std.fill_(1.0)


def test_bad_input_and_missing_spec_raise(model):
    with pytest.raises(WalkdiffError, match=r"\(B, frames, 31, 3\)"):
        model.features(torch.randn(2, 16, 30, 3))
    with pytest.raises(WalkdiffError, match="data_spec"):
        MotionEvaluator(None)
    with pytest.raises(WalkdiffError, match="no skeleton profile"):
        MotionEvaluator(SPEC, **TINY).features(torch.randn(2, 16, 3, 3))


def test_trains_on_real_windows_and_round_trips(xia_dir, tmp_path):
    torch.manual_seed(0)
    dm = tiny_datamodule(make_xia_subset(xia_dir, tmp_path / "data"), tmp_path / "cache")
    model = MotionEvaluator(dm.spec, hidden=32, embed_dim=16, blocks=1, dropout=0.0, input_noise=0.0, lr=3e-3)
    trainer = tiny_trainer(max_epochs=4, limit_val_batches=2)
    first = None

    class FirstLoss(L.Callback):
        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
            nonlocal first
            first = first if first is not None else float(outputs["loss"])

    trainer.callbacks.append(FirstLoss())
    trainer.fit(model, dm)
    metrics = trainer.callback_metrics
    assert {"style_acc/train", "content_acc/train", "style_acc/val", "content_acc/val"} <= set(metrics)
    assert float(metrics["loss/train"]) < 0.8 * first
    # The evaluator took the data's normaliser and skeleton, fitted its own to the body features of the
    # training clips, and recognises its training windows.
    torch.testing.assert_close(model.normalizer.std, dm.normalizer.std)
    assert model.feature_normalizer.std.shape == (6 * 31 + 1,) and (model.feature_normalizer.std != 1).any()
    assert model.skeleton.same_hierarchy(dm.skeleton)
    assert float(metrics["content_acc/train"]) > 0.6

    raw = torch.from_numpy(dm.split_features("test")[0][2][:16]).unsqueeze(0)
    positions = model.raw_positions(raw.double()).float()
    before = model.features(positions)
    path = tmp_path / "evaluator.ckpt"
    trainer.save_checkpoint(path)
    loaded = MotionEvaluator.load_from_checkpoint(path, weights_only=False)
    torch.testing.assert_close(loaded.normalizer.mean, dm.normalizer.mean, rtol=0, atol=0)
    torch.testing.assert_close(loaded.feature_normalizer.std, model.feature_normalizer.std, rtol=0, atol=0)
    assert loaded.skeleton.names == dm.skeleton.names
    assert loaded.spec == model.spec
    torch.testing.assert_close(loaded.features(positions), before, rtol=0, atol=0)

    result = tiny_trainer().test(loaded, dm, verbose=False)[0]
    assert 0.0 <= result["style_acc/test"] <= 1.0 and 0.0 <= result["content_acc/test"] <= 1.0
