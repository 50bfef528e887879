"""`MotionDataModule`: any dataset module -> normalised feature windows for Lightning."""

from __future__ import annotations

import inspect
import logging
import os
import warnings
from collections import Counter
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler

from walkdiff.common.errors import WalkdiffError
from walkdiff.data import laterality
from walkdiff.data.clips import ClipInfo, ContentSelection
from walkdiff.data.datasets import open_source
from walkdiff.data.folder import SPLITS
from walkdiff.data.preprocess import ProcessedClips, detect_profile, preprocess
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import FeatureLayout, Normalizer
from walkdiff.motion.skeleton import Skeleton
from walkdiff.spec import DataSpec

log = logging.getLogger(__name__)

# data.balance: how often training windows are drawn (`MotionDataModule.training_weights`).
BALANCE = ("none", "content", "cell")


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

    def __init__(self, size: int, seed: int = 0, weights: torch.Tensor | None = None):
        self.size, self.seed, self.epoch, self.weights = size, seed, 0, weights

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __iter__(self):
        generator = torch.Generator().manual_seed(self.seed * 100_003 + self.epoch)
        if self.weights is not None:  # an epoch's worth of windows drawn in proportion to their weights
            return iter(
                torch.multinomial(self.weights, self.size, replacement=True, generator=generator).tolist()
            )
        return iter(torch.randperm(self.size, generator=generator).tolist())

    def __len__(self) -> int:
        return self.size


def window_loader(
    data: Dataset, batch_size: int, shuffle: bool, num_workers: int, weights: torch.Tensor | None = None
) -> DataLoader:
    """The DataLoader every walkdiff data module uses: epoch-seeded shuffling for training (windows drawn
    in proportion to `weights` when given)."""
    seed = int(os.environ.get("PL_GLOBAL_SEED", 0))
    return DataLoader(
        data,
        batch_size=batch_size,
        sampler=EpochShuffle(len(data), seed, weights) if shuffle else None,
        drop_last=shuffle and len(data) >= batch_size,  # never an empty training loader
        num_workers=num_workers,
        persistent_workers=num_workers > 0,
    )


class WindowLoaders(L.LightningDataModule):
    """train/val/test loaders over `self.datasets[split]`, for data modules with batch_size/num_workers."""

    datasets: dict[str, Dataset]

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        self.setup()
        h = self.hparams
        weights = self.training_weights() if split == "train" else None
        return window_loader(self.datasets[split], h.batch_size, shuffle, h.num_workers, weights)

    def training_weights(self) -> torch.Tensor | None:
        """How often each training window is drawn, relative to the others (None: each once an epoch)."""
        return None

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
        balance: `none` (every window once an epoch), `content` (every content label drawn alike) or
            `cell` (every style x content pair alike), drawn with replacement, an epoch's worth.
        mirror: add left/right mirrored copies of the training clips (refused for a skeleton without
            left/right pairs). A copy of a clip whose style or content names a side (`walk-turn-left`,
            `punch_l`, `lturn`, ...) takes the label with the side swapped; one whose swapped label no
            clip has is left out, with a warning (`walkdiff.data.laterality`).
        mirror_labels: {label: mirrored label} overriding what the names say: a partner of the same
            kind, the label itself (not lateral) or null (no partner: the copies are left out).
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
        mirror_labels: dict[str, str | None] | None = None,
        batch_size: int = 32,
        num_workers: int = 0,
        cache_dir: str = ".cache/walkdiff",
        on_error: str = "fail",
        preprocess_workers: int = 2,
        leave_out_styles: list[str] | None = None,
        balance: str = "none",
    ):
        super().__init__()
        self.save_hyperparameters(logger=False)  # the run logs its config (run_params)
        if window < 2 or stride < 1:
            raise WalkdiffError(f"data.window must be >= 2 and data.stride >= 1, got {window} and {stride}")
        if balance not in BALANCE:
            raise WalkdiffError(f"data.balance: expected one of {', '.join(BALANCE)}, got {balance!r}")
        self.source = open_source(
            dataset, root, profile, labels=labels, pattern=pattern, default_style=default_style,
            default_content=default_content, val_fraction=val_fraction, test_fraction=test_fraction,
        )  # fmt: skip
        self.folder = self.source.folder
        self.clips = self.source.list_clips()
        self.selection = ContentSelection.parse(contents, self.source.groups)
        self.splits = self.source.split_clips(self.clips, self.selection)
        self._leave_out(leave_out_styles or [])
        # What mirrored copies are labelled: checked now, before any preprocessing.
        styles, groups = self.source.styles, self.source.groups
        self.mirror_map = (
            laterality.mirror_labels(styles, groups, mirror_labels, selected=self.selection.names)
            if mirror
            else laterality.MirrorLabels.unchanged(len(styles), len(groups))
        )
        self._profile: SkeletonProfile | None = None
        self.processed: ProcessedClips | None = None
        self.normalizer: Normalizer | None = None
        self.datasets: dict[str, WindowDataset] = {}

    def _leave_out(self, styles: list[str]) -> None:
        """Styles kept out of training and validation (to test styles never seen, from example clips):
        their clips stay in the test split, their labels in the vocabulary, so evaluators still name them."""
        unknown = [s for s in styles if s not in self.source.styles]
        if unknown:
            valid = ", ".join(self.source.styles)
            raise WalkdiffError(f"data.leave_out_styles: unknown style {', '.join(unknown)}; valid: {valid}")
        left = {self.source.styles.index(s) for s in styles}
        for split in ("train", "val"):
            self.splits[split] = [c for c in self.splits[split] if c.style not in left]

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
        """(clip, name, features) of every readable clip of a split; mirrored copies when asked, with
        their lateral labels swapped (`self.mirror_map`): a copy whose label has no partner is left out."""
        processed = self._ensure_processed()
        position = {name: i for i, name in enumerate(processed.names)}
        out = []
        for clip in self.splits[split]:
            if clip.name not in position:  # left out by on_error=skip, which warned already
                continue
            i = position[clip.name]
            out.append((clip, clip.name, processed.features[i]))
            copy = self.mirror_map.mirrored(clip) if mirrored and processed.mirrored is not None else None
            if copy is not None:
                out.append((copy, clip.name + "#mirror", processed.mirrored[i]))
        return out

    def setup(self, stage: str | None = None) -> None:
        if self.datasets:
            return
        self._check_splits()
        h = self.hparams
        if h.mirror:
            self._report_mirror_labels()
        parts = {
            split: self.split_features(split, mirrored=h.mirror and split == "train") for split in SPLITS
        }
        needed = self._needed_splits()
        skipped = [s for s in needed if not parts[s]]
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
            if len(self.datasets[split]) == 0 and split in needed:
                raise WalkdiffError(
                    f"the {split} split has no {h.window}-frame windows; use a shorter data.window"
                )

    def training_weights(self) -> torch.Tensor | None:
        """With data.balance `content`, every content label is drawn as often as the others (a rare kind
        of motion learned as well as a common one); with `cell`, every style x content pair. Mirrored
        copies count under the labels they carry. None with `none`: each window once an epoch."""
        if self.hparams.balance == "none":
            return None
        data = self.datasets["train"]
        keys = [
            data.labels[clip][1] if self.hparams.balance == "content" else data.labels[clip][:2]
            for clip, _ in data.index
        ]
        counts = Counter(keys)
        return torch.tensor([1.0 / counts[key] for key in keys], dtype=torch.float64)

    def _report_mirror_labels(self) -> None:
        """Log the lateral labels that mirrored copies swap; warn about those whose copies are left out."""
        for line in self.mirror_map.describe():
            log.info(f"mirrored copies: {line}")
        warning = self.mirror_map.warning()
        left_out = [c for c in self.splits["train"] if self.mirror_map.mirrored(c) is None]
        if warning and left_out:
            total = len(self.splits["train"])
            warnings.warn(f"{warning} ({len(left_out)} of {total} training clips)", stacklevel=3)

    def _validates(self) -> bool:
        """Whether the trainer this module is attached to runs validation: `fit` with
        trainer.limit_val_batches above 0, or `validate`. Outside a trainer (evaluate, score), no."""
        trainer = self.trainer
        if trainer is None:
            return False
        state = getattr(trainer, "state", None)
        if getattr(state, "fn", None) in ("test", "predict"):
            return False
        return trainer.limit_val_batches != 0

    def _needed_splits(self) -> tuple[str, ...]:
        """The splits that must have clips: all three, val only when validation runs."""
        return SPLITS if self._validates() else tuple(s for s in SPLITS if s != "val")

    def _check_splits(self) -> None:
        """A WalkdiffError naming the splits without a clip, how the dataset split and how to fix it
        (a one-clip folder has only training clips: no window length gives it a validation window).
        An empty val split is fine when nothing validates (trainer.limit_val_batches 0)."""
        empty = [s for s in self._needed_splits() if not self.splits[s]]
        if empty:
            chosen = sum(len(clips) for clips in self.splits.values())
            selected = (
                "" if chosen == len(self.clips) else f" ({chosen} of the contents data.contents selects)"
            )
            counts = ", ".join(f"{len(self.splits[s])} {s}" for s in SPLITS)
            without = (
                "; or train without validation: trainer.limit_val_batches 0 (what `walkdiff data scan` "
                "writes for a folder without val clips)"
                if "val" in empty
                else ""
            )
            raise WalkdiffError(
                f"no {' and no '.join(empty)} clip: the dataset has {len(self.clips)} clip"
                f"{'s' * (len(self.clips) != 1)}{selected}, "
                f"split {counts}; {self.source.empty_split_advice(empty)}{without}",
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
