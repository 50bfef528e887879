"""Clips scored through a trained evaluator, as `walkdiff score` and `bench protocol` score them.

Files are read as world joint positions (`SkeletonProfile.body_positions`), so motion from any pipeline
scores alike: any frame rate (resampled to the evaluator's), any rotation convention or channel order, any
root layout, as long as the body is the evaluator's skeleton. A `ClipScorer` cuts clips into windows of
the evaluator's length, embeds them, and turns them into per-clip statistics (`metrics.bootstrap`).

The real windows every call needs (the test split at stride 1, the reference of FMD and KID, and the
training split's row) are embedded once per evaluator and data: they are kept in the feature cache's
folder, in a file keyed by the evaluator file's content hash and everything that makes the windows (the
feature cache, which hashes the data files and their settings, the split's clips, window and stride).
"""

from __future__ import annotations

import hashlib
import json
import logging
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import clean_temporaries, write_atomic
from walkdiff.evaluation.scorer import MotionScorer, WindowSet, load_evaluator, window_set
from walkdiff.metrics import Diversity
from walkdiff.metrics.bootstrap import ClipStatistics, Reference
from walkdiff.metrics.physics import jerk_sums, skating_sums
from walkdiff.motion.body_features import resample_positions
from walkdiff.motion.bvh import read_bvh

log = logging.getLogger(__name__)

# Bump when what an embedded window holds changes: older cached windows are then made again.
EMBEDDINGS_VERSION = 1
CACHED_FIELDS = ("style", "content", "clip", "positions", "features", "style_logits", "content_logits")


@dataclass
class Clip:
    """One scored file: its positions at the evaluator's frame rate and labels (None: unlabelled)."""

    name: str
    positions: np.ndarray  # (F, J, 3)
    style: str | None = None
    content: str | None = None


class ClipScorer:
    """An evaluator with its real reference windows: turns lists of clips into bootstrapped metrics."""

    def __init__(self, evaluator_path, root=None, cache_dir=None, contents=None, stride=None, batch_size=512):
        from walkdiff.common.checkpoints import read_checkpoint
        from walkdiff.data.datamodule import MotionDataModule, data_settings
        from walkdiff.data.datasets import protocol_contents

        self.evaluator = load_evaluator(evaluator_path)
        spec = self.evaluator.spec
        self.fps, self.window = float(spec["fps"]), int(spec["window"])
        if stride is not None and stride < 1:
            raise WalkdiffError(f"--stride: expected a whole number of frames >= 1, got {stride}")
        self.stride = stride or max(1, self.window // 2)
        self.styles, self.contents = list(spec["styles"]), list(spec["contents"])
        overrides = {"root": root, "cache_dir": cache_dir}
        checkpoint = read_checkpoint(evaluator_path, "evaluator", mmap=False)
        contents = contents or protocol_contents(spec["dataset"])
        self.data = MotionDataModule(**data_settings(checkpoint, contents=contents, **overrides))
        self.scorer = MotionScorer(self.evaluator, self.data.skeleton, self.fps, batch_size=batch_size)
        self.evaluator_hash = content_hash(Path(evaluator_path))
        # FMD and KID are measured against every real test window (stride 1), as `evaluate` does.
        test = self.data.split_features
        reference = self.cached(
            "test", {"stride": 1}, lambda: self.scorer.embed(window_set(test("test"), self.window))
        )
        self.scorer.set_reference(reference)
        self.reference_windows = reference  # whose labels generated windows are asked for
        self.reference = Reference.of(reference.features)
        spread = Diversity(num_pairs=1000, seed=0)
        spread.update(reference.features)
        self.real_spread = float(spread.compute())  # mean feature distance of two real windows

    # ------------------------------------------------------------ reading

    def read(self, path: Path, name: str) -> Clip:
        motion = read_bvh(path)
        positions = self.evaluator.profile.body_positions(motion, path)
        return Clip(name, resample_positions(positions, motion.fps, self.fps))

    def real_clips(self, split: str) -> list[Clip]:
        """The evaluator data's clips of a split, as positions, with their labels."""
        out = []
        groups = self.data.source.groups  # a clip's content indexes the dataset's groups, not the selection
        for info, name, features in self.data.split_features(split):
            raw = torch.from_numpy(features)[None]
            positions = self.scorer.positions(raw)[0].numpy()
            out.append(Clip(name, positions, self.styles[info.style], groups[info.content]))
        return out

    def real_windows(self, split: str) -> WindowSet:
        """The embedded windows of a split's real clips, every stride, as `windows` cuts any clips."""
        return self.cached(split, {"stride": self.stride}, lambda: self.windows(self.real_clips(split)))

    def cached(self, split: str, settings: dict, embed: Callable[[], WindowSet]) -> WindowSet:
        """`embed()`, or the windows it gave before for this evaluator, data, split and `settings`."""
        clips = [name for _, name, _ in self.data.split_features(split)]
        cache_file = self.data.processed.cache_file  # its name hashes the data files and feature settings
        key = {
            "version": EMBEDDINGS_VERSION,
            "evaluator": self.evaluator_hash,
            "features": cache_file.name,
            "split": split,
            "clips": clips,
            "window": self.window,
            "fps": self.fps,
            **settings,
        }
        digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:20]
        path = cache_file.parent / f"{self.data.source.name}-embedded-{split}-{digest}.npz"
        windows = _read_windows(path)
        if windows is None:
            windows = embed()
            clean_temporaries(path.parent)  # of scores killed while writing a cache
            arrays = {name: getattr(windows, name).numpy() for name in CACHED_FIELDS}
            write_atomic(path, lambda f: np.savez(f, **arrays))
        return windows

    def label_id(self, kind: str, value: str, where: str) -> int:
        known = self.styles if kind == "style" else self.contents
        if value not in known:
            raise WalkdiffError(
                f"{kind} {value!r} of {where} is not one of the evaluator's ({', '.join(known)})"
            )
        return known.index(value)

    # ------------------------------------------------------------ scoring

    def starts(self, frames: int) -> list[int]:
        return list(range(0, frames - self.window + 1, self.stride))

    def windows(self, clips: list[Clip], starts: list[list[int]] | None = None) -> WindowSet:
        """Embedded windows of the clips (at `starts` per clip, default every stride)."""
        cut, style, content, index = [], [], [], []
        root = self.evaluator.body.root
        for i, clip in enumerate(clips):
            begin = starts[i] if starts is not None else self.starts(len(clip.positions))
            for s in begin:
                w = clip.positions[s : s + self.window].astype(np.float64)
                cut.append(w - w[:1, root : root + 1] * np.array([1.0, 0.0, 1.0]))
            style += [-1 if clip.style is None else self.label_id("style", clip.style, clip.name)] * len(
                begin
            )
            content += [
                -1 if clip.content is None else self.label_id("content", clip.content, clip.name)
            ] * len(begin)
            index += [i] * len(begin)
        windows = WindowSet(
            None,
            torch.tensor(style),
            torch.tensor(content),
            torch.tensor(index),
            positions=torch.from_numpy(np.stack(cut)).float(),
        )
        return self.scorer.embed(windows)

    def statistics(self, windows: WindowSet, per_window: dict[str, torch.Tensor]) -> ClipStatistics:
        positions = windows.positions
        s = self.scorer
        skating = skating_sums(
            positions, s.ground_contacts(positions), s.foot_joints, self.fps, s.speed_threshold
        )
        return ClipStatistics.of(
            windows.features,
            windows.clip,
            self.reference,
            per_window,
            skating,
            jerk_sums(positions, self.fps),
        )

    def recognition(self, windows: WindowSet) -> dict[str, torch.Tensor]:
        """Per-window correctness against the labels the windows carry (none for unlabelled sets)."""
        out = {}
        for kind, labels, logits in (
            ("style", windows.style, windows.style_logits),
            ("content", windows.content, windows.content_logits),
        ):
            if len(getattr(self, f"{kind}s")) > 1 and (labels >= 0).all():
                out[f"{kind}_acc"] = logits.argmax(-1) == labels
        return out

    def clip_table(self, clips: list[Clip], windows: WindowSet) -> list[dict]:
        """Per clip: frames, windows and the majority recognised style and content."""
        out = []
        for i, clip in enumerate(clips):
            mine = windows.clip == i
            row = {"file": clip.name, "frames": len(clip.positions), "windows": int(mine.sum())}
            for kind, logits in (("style", windows.style_logits), ("content", windows.content_logits)):
                votes = torch.bincount(logits[mine].argmax(-1), minlength=len(getattr(self, f"{kind}s")))
                row[kind] = getattr(clip, kind)
                row[f"recognised_{kind}"] = getattr(self, f"{kind}s")[int(votes.argmax())]
            out.append(row)
        return out


def content_hash(path: Path) -> str:
    """sha256 of a model file's bytes (of every file of an exported model's folder)."""
    digest = hashlib.sha256()
    for file in sorted(p for p in path.iterdir() if p.is_file()) if path.is_dir() else [path]:
        digest.update(file.name.encode() + b"\0" if path.is_dir() else b"")
        with file.open("rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


def _read_windows(path: Path) -> WindowSet | None:
    """Embedded windows cached at `path`; None when there are none, or none readable (removed, with a
    warning, to be made again)."""
    if not path.is_file():
        return None
    try:
        # Opened here: np.load given a path leaks the file when the archive is corrupt.
        with path.open("rb") as f, np.load(f) as data:
            arrays = {name: torch.from_numpy(data[name]) for name in CACHED_FIELDS}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as error:
        log.warning(f"{path}: unreadable cache of embedded windows ({error}); making it again")
        path.unlink(missing_ok=True)
        return None
    return WindowSet(None, **arrays)
