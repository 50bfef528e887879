"""The Xia data module: labels, splits, windows, cache and errors (real data and synthetic folders)."""

from __future__ import annotations

import collections
import logging
import os
from pathlib import Path

import numpy as np
import pytest
import synthetic

from walkdiff.common.errors import WalkdiffError
from walkdiff.data import xia
from walkdiff.data.clips import ContentSelection
from walkdiff.data.datamodule import MotionDataModule
from walkdiff.motion.representation import FeatureLayout

# Clips per style and group (walk/run/jump/punch/kick/trans), from ../shared/data/README.md.
README_COUNTS = {
    "angry": (37, 8, 6, 12, 8, 3),
    "childlike": (30, 9, 6, 12, 8, 3),
    "depressed": (37, 7, 5, 12, 8, 5),
    "neutral": (32, 12, 6, 16, 8, 6),
    "old": (35, 10, 6, 6, 8, 5),
    "proud": (33, 7, 5, 8, 5, 3),
    "sexy": (30, 9, 6, 8, 8, 3),
    "strutting": (43, 10, 3, 12, 8, 5),
}


@pytest.fixture(scope="module")
def xia_module(xia_dir: Path, tmp_path_factory) -> MotionDataModule:
    """All contents of the real set, preprocessed once for this module's tests."""
    cache = tmp_path_factory.mktemp("cache")
    dm = MotionDataModule(root=str(xia_dir.parent), contents="all", cache_dir=str(cache))
    dm.setup("fit")
    return dm


def test_label_counts_equal_the_readme_table(xia_dir):
    clips = xia.list_clips(xia_dir)
    assert len(clips) == 572
    counts = collections.Counter((xia.STYLES[c.style], c.content) for c in clips)
    for style, row in README_COUNTS.items():
        assert tuple(counts[(style, g)] for g in range(6)) == row, style


def test_split_follows_the_published_protocol(xia_dir):
    clips = xia.list_clips(xia_dir)
    splits = xia.split_clips(clips, ContentSelection.parse("all", xia.GROUPS))
    names = {k: {c.name for c in v} for k, v in splits.items()}
    assert (
        not names["train"] & names["test"]
        and not names["train"] & names["val"]
        and not names["val"] & names["test"]
    )
    assert sum(len(v) for v in names.values()) == 572
    for style in range(8):
        per_group = collections.Counter(xia.GROUPS[c.content] for c in splits["test"] if c.style == style)
        assert per_group == {"walk": 3, "run": 1, "jump": 1, "kick": 1, "punch": 1}
    # Deterministic and independent of the content selection: walk-only test clips are the same clips.
    walk = xia.split_clips(list(reversed(clips)), ContentSelection.parse("walk", xia.GROUPS))
    assert {c.name for c in walk["test"]} == {c.name for c in splits["test"] if c.content == 0}
    assert len(walk["test"]) == 24


def test_windows_stay_inside_one_clip_and_carry_labels(xia_module):
    data = xia_module.datasets["train"]
    for clip, start in data.index[::50]:
        assert start + data.window <= data.features[clip].shape[0]
    item = data[7]
    assert item["features"].shape == (24, FeatureLayout(31).dim)
    assert xia_module.spec.feature_dim == 194
    names = {name for _, _, name in data.labels}
    assert any(n.endswith("#mirror") for n in names), "mirrored copies are in training"
    assert not any(n.endswith("#mirror") for _, _, n in xia_module.datasets["test"].labels)


def test_normaliser_uses_training_clips_only(xia_module):
    train = np.concatenate([f for _, _, f in xia_module.split_features("train", mirrored=True)])
    test = np.concatenate([f for _, _, f in xia_module.split_features("test")])
    mean = xia_module.normalizer.mean.numpy()
    np.testing.assert_allclose(mean, train.mean(0, dtype=np.float64), atol=1e-4)
    assert np.abs(mean - np.concatenate([train, test]).mean(0)).max() > 1e-4


def test_batches_have_features_and_labels(xia_module):
    batch = next(iter(xia_module.train_dataloader()))
    assert batch["features"].shape == (32, 24, 194)
    assert batch["style"].max() < 8 and batch["content"].max() < 6
    assert len(batch["clip"]) == 32


def test_cache_is_reused_and_rebuilt_when_a_file_or_setting_changes(tmp_path):
    synthetic.xia_like_folder(tmp_path)
    cache = tmp_path / "cache"

    def module(**kw):
        dm = MotionDataModule(
            root=str(tmp_path), contents="all", cache_dir=str(cache), preprocess_workers=1, **kw
        )
        return dm._ensure_processed(progress=False)

    first = module()
    assert not first.from_cache
    again = module()
    assert again.from_cache and again.cache_file == first.cache_file
    np.testing.assert_array_equal(again.features[0], first.features[0])

    other_rate = module(fps=20.0)
    assert not other_rate.from_cache and other_rate.cache_file != first.cache_file

    clip = tmp_path / "xia" / "angry_01_000.bvh"
    synthetic.write_bvh(clip, synthetic.walking(200, seed=99))
    changed = module()
    assert not changed.from_cache and changed.cache_file != first.cache_file


def test_resampling_to_the_configured_rate(tmp_path):
    synthetic.xia_like_folder(tmp_path, walk_clips=3, frames=240)
    dm = MotionDataModule(root=str(tmp_path), cache_dir=str(tmp_path / "c"), fps=30, preprocess_workers=1)
    processed = dm._ensure_processed(progress=False)
    assert {f.shape[0] for f in processed.features} == {60}  # 2 s at 120 fps -> 60 frames at 30 fps


def test_balanced_batches_draw_a_rare_content_as_often_as_a_common_one(tmp_path):
    """data.balance content: 8 training walks and 2 training runs per style, drawn about half and half;
    `none` keeps each window once an epoch (the run's share as in the data); the same draw for the same
    seed and epoch."""
    folder = synthetic.xia_like_folder(tmp_path, walk_clips=12, frames=240)
    for style in ("angry", "old"):  # 4 runs: one held out for test, one for val, two to train on
        for take in range(1, 4):
            synthetic.write_bvh(folder / f"{style}_13_{take:03d}.bvh", synthetic.walking(240, seed=50 + take))
    shares = {}
    for balance in ("none", "content", "cell"):
        dm = MotionDataModule(
            root=str(tmp_path), cache_dir=str(tmp_path / "c"), contents="all", stride=2, batch_size=8,
            preprocess_workers=1, balance=balance,
        )  # fmt: skip
        dm.setup()
        loader = dm.train_dataloader()
        drawn = list(loader.sampler)
        assert len(drawn) == len(dm.datasets["train"]) and drawn == list(loader.sampler)  # seeded
        contents = collections.Counter(
            dm.datasets["train"].labels[dm.datasets["train"].index[i][0]][1] for i in drawn
        )
        shares[balance] = contents[1] / len(drawn)  # the run (content group 1)
    assert shares["none"] < 0.25 and 0.35 < shares["content"] < 0.65 and 0.35 < shares["cell"] < 0.65
    with pytest.raises(WalkdiffError, match="data.balance: expected one of none, content, cell"):
        MotionDataModule(root=str(tmp_path), cache_dir=str(tmp_path / "c"), balance="styles")


def test_missing_root_names_the_path_and_how_to_get_data(tmp_path):
    with pytest.raises(WalkdiffError) as error:
        MotionDataModule(root=str(tmp_path / "nowhere"))
    assert str(tmp_path / "nowhere" / "xia") in str(error.value)
    assert "WALKDIFF_DATA" in str(error.value)


def test_data_root_comes_from_the_environment(tmp_path, monkeypatch):
    synthetic.xia_like_folder(tmp_path, walk_clips=3)
    monkeypatch.setenv("WALKDIFF_DATA", str(tmp_path))
    dm = MotionDataModule(cache_dir=str(tmp_path / "c"))
    assert dm.folder == tmp_path / "xia"


def test_unreadable_clip_fails_or_is_skipped_with_its_name(tmp_path, caplog):
    folder = synthetic.xia_like_folder(tmp_path, walk_clips=6)
    bad = folder / "old_02_000.bvh"
    bad.write_text(bad.read_text().replace("Frames:", "Frames: 3\nFrames:", 1))

    def module(on_error):
        return MotionDataModule(
            root=str(tmp_path), cache_dir=str(tmp_path / on_error), on_error=on_error, preprocess_workers=1
        )

    with pytest.raises(WalkdiffError, match="old_02_000.bvh"):
        module("fail")._ensure_processed(progress=False)
    dm = module("skip")
    with pytest.warns(UserWarning, match="old_02_000.bvh"):
        processed = dm._ensure_processed(progress=False)
    assert "old_02_000" not in processed.names and len(processed.names) == 13


def test_short_clips_are_reported_not_silently_dropped(tmp_path, caplog):
    synthetic.xia_like_folder(tmp_path, walk_clips=6, frames=80)  # 20 frames at 30 fps < 24
    dm = MotionDataModule(root=str(tmp_path), cache_dir=str(tmp_path / "c"), window=24, preprocess_workers=1)
    with caplog.at_level(logging.WARNING), pytest.raises(WalkdiffError, match="no 24-frame windows"):
        dm.setup("fit")
    assert "shorter than the 24-frame window" in caplog.text


def test_bad_names_and_options_are_explained(tmp_path):
    with pytest.raises(WalkdiffError, match="STYLE_CC_NNN"):
        xia.parse_name(Path("walking_fast.bvh"))
    with pytest.raises(WalkdiffError, match="unknown content swim"):
        ContentSelection.parse("walk,swim", xia.GROUPS)
    synthetic.xia_like_folder(tmp_path, walk_clips=3)
    with pytest.raises(WalkdiffError, match="data.dataset"):
        MotionDataModule(dataset="nope", root=str(tmp_path))
    assert os.path.isdir(tmp_path / "xia")
