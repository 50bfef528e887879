"""`MotionDataModule`: any dataset module -> normalised feature windows for Lightning."""

from __future__ import annotations

import inspect
import logging
import os
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler

from walkdiff.common.errors import WalkdiffError
from walkdiff.data.clips import ClipInfo, ContentSelection
from walkdiff.data.datasets import open_source
from walkdiff.data.folder import SPLITS
from walkdiff.data.preprocess import ProcessedClips, detect_profile, preprocess
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import FeatureLayout, Normalizer
from walkdiff.motion.skeleton import Skeleton
from walkdiff.spec import DataSpec

log = logging.getLogger(__name__)


class WindowDataset(Dataset):
    """Fixed-length windows cut inside clips (never across them), normalised on the fly."""

    def __init__(
        self, clips: list[tuple[ClipInfo, str, np.ndarray]], window: int, stride: int, norm: Normalizer
    ):
        self.features = [torch.from_numpy(norm.normalize(f)) for _, _, f in clips]
        self.labels = [(c.style, c.content, name) for c, name, _ in clips]
        self.index = [
            (i, start)
            for i, f in enumerate(self.features)
            for start in range(0, f.shape[0] - window + 1, stride)
        ]
        self.window = window

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, i: int) -> dict:
        clip, start = self.index[i]
        style, content, name = self.labels[clip]
        return {
            "features": self.features[clip][start : start + self.window],
            "style": style,
            "content": content,
            "clip": name,
        }


class EpochShuffle(Sampler[int]):
    """A fresh permutation per epoch, a function of (seed, epoch) only.

    Lightning calls `set_epoch` before each epoch, so a resumed run sees the same order as an
    uninterrupted one (a plain shuffling DataLoader draws from torch's global generator instead).
    """

    def __init__(self, size: int, seed: int = 0):
        self.size, self.seed, self.epoch = size, seed, 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __iter__(self):
        generator = torch.Generator().manual_seed(self.seed * 100_003 + self.epoch)
        return iter(torch.randperm(self.size, generator=generator).tolist())

    def __len__(self) -> int:
        return self.size


def window_loader(data: Dataset, batch_size: int, shuffle: bool, num_workers: int) -> DataLoader:
    """The DataLoader every walkdiff data module uses: epoch-seeded shuffling for training."""
    seed = int(os.environ.get("PL_GLOBAL_SEED", 0))
    return DataLoader(
        data,
        batch_size=batch_size,
        sampler=EpochShuffle(len(data), seed) if shuffle else None,
        drop_last=shuffle and len(data) >= batch_size,  # never an empty training loader
        num_workers=num_workers,
        persistent_workers=num_workers > 0,
    )


class WindowLoaders(L.LightningDataModule):
    """train/val/test loaders over `self.datasets[split]`, for data modules with batch_size/num_workers."""

    datasets: dict[str, Dataset]

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        self.setup()
        return window_loader(self.datasets[split], self.hparams.batch_size, shuffle, self.hparams.num_workers)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)


class MotionDataModule(WindowLoaders):
    """Windows of motion features with style and content labels.

    Args:
        dataset: `folder` (any folder of BVH files), `xia` or `humanact12`.
        root: the folder of BVH files (folder); else the data root, default $WALKDIFF_DATA, else ./data.
        labels: folder: a CSV/JSON manifest (file, style, content, split); default labels.csv/.json in
            the folder.
        pattern: folder: a regular expression with named groups style/content over the file path.
        default_style, default_content: folder: the label of clips that have none.
        val_fraction, test_fraction: folder: per label, the clips held out (without a split column).
        profile: skeleton profile overrides (root, left_heel, ..., up, forward, units, body_height,
            contact_speed, contact_height, mirror_pairs); the rest is found from the clips.
        contents: content groups to use: 'walk' (the paper), 'all', or a comma-separated list.
        fps: frame rate the clips are resampled to.
        window: frames per training window. Xia's clips are short (walking: median 40 frames at
            30 fps), so 24 keeps 99% of the walking; longer motion is generated window by window.
        stride: frames between window starts.
        mirror: add left/right mirrored copies of the training clips (refused for a skeleton without
            left/right pairs).
        cache_dir: where preprocessed features are kept.
        on_error: 'fail' on an unreadable clip, or 'skip' it with a warning that lists it.
        preprocess_workers: processes for the first (cold) preprocessing.
    """

    def __init__(
        self,
        dataset: str = "xia",
        root: str | None = None,
        labels: str | None = None,
        pattern: str | None = None,
        default_style: str | None = None,
        default_content: str | None = None,
        val_fraction: float | None = None,
        test_fraction: float | None = None,
        profile: dict | None = None,
        contents: str = "walk",
        fps: float = 30.0,
        window: int = 24,
        stride: int = 4,
        mirror: bool = True,
        batch_size: int = 32,
        num_workers: int = 0,
        cache_dir: str = ".cache/walkdiff",
        on_error: str = "fail",
        preprocess_workers: int = 2,
    ):
        super().__init__()
        self.save_hyperparameters(logger=False)  # the run logs its config (run_params)
        if window < 2 or stride < 1:
            raise WalkdiffError(f"data.window must be >= 2 and data.stride >= 1, got {window} and {stride}")
        self.source = open_source(
            dataset, root, profile, labels=labels, pattern=pattern, default_style=default_style,
            default_content=default_content, val_fraction=val_fraction, test_fraction=test_fraction,
        )  # fmt: skip
        self.folder = self.source.folder
        self.clips = self.source.list_clips()
        self.selection = ContentSelection.parse(contents, self.source.groups)
        self.splits = self.source.split_clips(self.clips, self.selection)
        self._profile: SkeletonProfile | None = None
        self.processed: ProcessedClips | None = None
        self.normalizer: Normalizer | None = None
        self.datasets: dict[str, WindowDataset] = {}

    @property
    def profile(self) -> SkeletonProfile:
        """The skeleton profile, found from the first clip (cheap: before any preprocessing)."""
        if self.processed is not None:
            return self.processed.profile
        if self._profile is None:
            self._profile = detect_profile(self.source, self.clips)
        return self._profile

    @property
    def spec(self) -> DataSpec:
        """Known before any preprocessing: the joint count comes from the profile's body."""
        num_joints = len(self.profile.body)
        return DataSpec(
            dataset=self.hparams.dataset,
            feature_dim=FeatureLayout(num_joints).dim,
            num_joints=num_joints,
            window=self.hparams.window,
            fps=self.hparams.fps,
            styles=tuple(self.source.styles),
            contents=tuple(self.source.groups),
        )

    @property
    def skeleton(self) -> Skeleton:
        """The canonical skeleton the features are on."""
        return self.profile.canonical_skeleton

    def _ensure_processed(self, progress: bool = True) -> ProcessedClips:
        if self.processed is None:
            h = self.hparams
            self.processed = preprocess(
                self.source,
                self.clips,
                self.profile,  # found once, from the first clip: the spec linked into the model has it
                fps=h.fps,
                mirror=h.mirror,
                cache_dir=Path(h.cache_dir),
                on_error=h.on_error,
                workers=h.preprocess_workers,
                progress=progress,
            )
        return self.processed

    def prepare_data(self) -> None:
        self._check_splits()  # before preprocessing every clip
        self._ensure_processed()

    def split_features(self, split: str, mirrored: bool = False) -> list[tuple[ClipInfo, str, np.ndarray]]:
        """(clip, name, features) of every readable clip of a split; mirrored copies when asked."""
        processed = self._ensure_processed()
        position = {name: i for i, name in enumerate(processed.names)}
        out = []
        for clip in self.splits[split]:
            if clip.name not in position:  # left out by on_error=skip, which warned already
                continue
            i = position[clip.name]
            out.append((clip, clip.name, processed.features[i]))
            if mirrored and processed.mirrored is not None:
                out.append((clip, clip.name + "#mirror", processed.mirrored[i]))
        return out

    def setup(self, stage: str | None = None) -> None:
        if self.datasets:
            return
        self._check_splits()
        h = self.hparams
        parts = {
            split: self.split_features(split, mirrored=h.mirror and split == "train") for split in SPLITS
        }
        skipped = [s for s in SPLITS if not parts[s]]
        if skipped:
            raise WalkdiffError(
                f"the {skipped[0]} split has no readable clip: data.on_error skip left out all its "
                f"{len(self.splits[skipped[0]])} (see the warning above)",
                path=self.folder,
            )
        self.normalizer = Normalizer.fit(np.concatenate([f for _, _, f in parts["train"]]))
        for split, clips in parts.items():
            self.datasets[split] = WindowDataset(clips, h.window, h.stride, self.normalizer)
            short = [name for _, name, f in clips if f.shape[0] < h.window]
            if short:
                log.warning(
                    f"{split}: {len(short)} of {len(clips)} clips are shorter than the {h.window}-frame "
                    f"window and give no windows: {', '.join(short[:10])}{' ...' if len(short) > 10 else ''}"
                )
            if len(self.datasets[split]) == 0:
                raise WalkdiffError(
                    f"the {split} split has no {h.window}-frame windows; use a shorter data.window"
                )

    def _check_splits(self) -> None:
        """A WalkdiffError naming the splits without a clip, how the dataset split and how to fix it
        (a one-clip folder has only training clips: no window length gives it a validation window)."""
        empty = [s for s in SPLITS if not self.splits[s]]
        if empty:
            chosen = sum(len(clips) for clips in self.splits.values())
            selected = (
                "" if chosen == len(self.clips) else f" ({chosen} of the contents data.contents selects)"
            )
            counts = ", ".join(f"{len(self.splits[s])} {s}" for s in SPLITS)
            raise WalkdiffError(
                f"no {' and no '.join(empty)} clip: the dataset has {len(self.clips)} clip"
                f"{'s' * (len(self.clips) != 1)}{selected}, "
                f"split {counts}; {self.source.empty_split_advice(empty)}",
                path=self.folder,
            )


def data_settings(checkpoint: dict, **overrides) -> dict:
    """MotionDataModule arguments as stored by the run that wrote `checkpoint`, with overrides applied."""
    spec = checkpoint.get("hyper_parameters", {}).get("data_spec", {})
    settings = {k: spec[k] for k in ("dataset", "fps", "window") if k in spec}
    settings |= checkpoint.get("datamodule_hyper_parameters", {}) or {}
    settings |= {k: v for k, v in overrides.items() if v is not None}
    accepted = inspect.signature(MotionDataModule).parameters
    return {k: v for k, v in settings.items() if k in accepted}
