"""Clips -> per-frame feature arrays, computed once and cached on disk.

The cache key hashes every source file's bytes and every setting that changes the features, so an
edited file, a new clip or a different frame rate rebuilds the cache, and nothing else does.
"""

from __future__ import annotations

import hashlib
import json
import warnings
import zipfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import clean_temporaries, write_atomic
from walkdiff.common.progress import progress as progress_bar
from walkdiff.data.clips import ClipInfo
from walkdiff.data.datasets import MotionSource
from walkdiff.motion.mirror import mirror as mirror_motion
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import encode
from walkdiff.motion.resample import resample
from walkdiff.motion.skeleton import Skeleton

# Bump when encode() or the loaders change what they produce: old caches then rebuild.
# 3: profiles from the posed body (a split root/hips translation, a rest pose that is no pose) and
# clips of another layout refused.
FEATURES_VERSION = 3


@dataclass
class ProcessedClips:
    names: list[str]
    features: list[np.ndarray]  # per clip (F, D) float32, at the configured rate
    mirrored: list[np.ndarray] | None  # the same clips mirrored left/right, when asked for
    profile: SkeletonProfile
    cache_file: Path
    from_cache: bool

    @property
    def skeleton(self) -> Skeleton:
        """The canonical skeleton the features are on."""
        return self.profile.canonical_skeleton


def cache_key(dataset: str, clips: list[ClipInfo], settings: dict) -> str:
    digest = hashlib.sha256()
    digest.update(
        json.dumps({"dataset": dataset, "version": FEATURES_VERSION, **settings}, sort_keys=True).encode()
    )
    file_hashes: dict[Path, str] = {}
    for clip in clips:
        if clip.path not in file_hashes:
            file_hashes[clip.path] = hashlib.sha256(clip.path.read_bytes()).hexdigest()
        digest.update(f"{clip.name}|{clip.item}|{file_hashes[clip.path]}\n".encode())
    return digest.hexdigest()[:20]


def detect_profile(source: MotionSource, clips: list[ClipInfo]) -> SkeletonProfile:
    """The dataset's skeleton profile, from its first clip and the source's overrides."""
    if not clips:
        raise WalkdiffError("no clips to find the skeleton profile from", path=source.folder)
    return SkeletonProfile.detect(source.load(clips[0]), source.profile, clips[0].path)


def _process_clip(source: MotionSource, profile: dict, clip: ClipInfo, fps: float, mirror: bool):
    """Runs in a worker process: returns (features, mirrored features) or an error text."""
    import torch

    torch.set_num_threads(1)
    profile = SkeletonProfile.from_dict(profile)
    try:
        file_motion = source.load(clip)
        # Another skeleton, up axis, unit or root layout than the clip the profile came from: refused,
        # naming the difference (joints above the root that move are folded in, per frame, instead).
        profile.check_layout(file_motion, clip.path)
        motion = resample(profile.to_canonical(file_motion), fps)
        features = encode(motion, profile)
        mirrored = encode(mirror_motion(motion, profile.body_pairs), profile) if mirror else None
    except WalkdiffError as error:
        return None, None, str(error)
    return features, mirrored, None


def preprocess(
    source: MotionSource,
    clips: list[ClipInfo],
    profile: SkeletonProfile,
    *,
    fps: float,
    mirror: bool,
    cache_dir: Path,
    on_error: str = "fail",
    workers: int = 2,
    progress: bool = True,
) -> ProcessedClips:
    if on_error not in ("fail", "skip"):
        raise WalkdiffError(f"data.on_error: expected 'fail' or 'skip', got {on_error!r}")
    if mirror and not profile.can_mirror:
        raise WalkdiffError(
            "data.mirror: this skeleton cannot be mirrored (no left/right joint pairs found by name); "
            "set data.mirror false, or name the pairs in data.profile.mirror_pairs"
        )
    # 20 and 20.0: one key. The profile settings are part of the key: an override rebuilds.
    settings = {"fps": float(fps), "mirror": bool(mirror), "on_error": on_error, "profile": source.profile}
    cache_file = Path(cache_dir) / f"{source.name}-{cache_key(source.name, clips, settings)}.npz"
    if cache_file.exists():
        try:
            return _load(cache_file, mirror)
        except _StaleCache:
            pass

    results = _run(source, profile, clips, fps, mirror, workers, progress)
    failed = [(clip, err) for clip, (*_, err) in zip(clips, results) if err is not None]
    if failed:
        listing = "\n  ".join(err for _, err in failed)
        if on_error == "fail":
            raise WalkdiffError(
                f"{len(failed)} clip(s) could not be read "
                f"(set data.on_error=skip to leave them out):\n  {listing}"
            )
        warnings.warn(f"skipping {len(failed)} unreadable clip(s):\n  {listing}", stacklevel=2)
    kept = [(clip, r) for clip, r in zip(clips, results) if r[2] is None]
    if not kept:
        raise WalkdiffError("no clip could be read", path=clips[0].path.parent if clips else None)
    _save(cache_file, kept, profile, mirror)
    return _load(cache_file, mirror, from_cache=False)


def _run(
    source, profile, clips: list[ClipInfo], fps: float, mirror: bool, workers: int, progress: bool
) -> list:
    bar = progress_bar(total=len(clips), desc=f"preprocessing {source.name}", unit="clip", show=progress)
    args = [(source, profile.to_dict(), clip, fps, mirror) for clip in clips]
    if workers <= 1:
        results = []
        for a in args:
            results.append(_process_clip(*a))
            bar.update()
    else:
        # spawn, not fork: forking a process that already runs torch threads can deadlock.
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
            futures = [pool.submit(_process_clip, *a) for a in args]
            results = []
            for future in futures:
                results.append(future.result())
                bar.update()
    bar.close()
    return results


def _save(cache_file: Path, kept: list, profile: SkeletonProfile, mirror: bool) -> None:
    cache_file.parent.mkdir(parents=True, exist_ok=True)
    arrays = {
        "names": np.array([clip.name for clip, _ in kept]),
        "lengths": np.array([r[0].shape[0] for _, r in kept]),
        "features": np.concatenate([r[0] for _, r in kept]),
        "profile": np.array(json.dumps(profile.to_dict())),
    }
    if mirror:
        arrays["mirrored"] = np.concatenate([r[1] for _, r in kept])
    clean_temporaries(cache_file.parent)  # of fits killed while writing a cache
    write_atomic(cache_file, lambda f: np.savez(f, **arrays))


def _load(cache_file: Path, mirror: bool, from_cache: bool = True) -> ProcessedClips:
    try:
        return _read_cache(cache_file, mirror, from_cache)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as error:
        if not from_cache:
            raise
        warnings.warn(f"{cache_file}: unreadable feature cache ({error}); rebuilding it", stacklevel=3)
        cache_file.unlink(missing_ok=True)
        raise _StaleCache from None


class _StaleCache(Exception):
    """A cache file that could not be read was removed; the caller builds it again."""


def _read_cache(cache_file: Path, mirror: bool, from_cache: bool) -> ProcessedClips:
    # Opened here: np.load given a path leaks the file when the archive is corrupt.
    with open(cache_file, "rb") as f, np.load(f) as data:
        bounds = np.cumsum(data["lengths"])[:-1]
        features = np.split(data["features"], bounds)
        mirrored = np.split(data["mirrored"], bounds) if mirror else None
        return ProcessedClips(
            names=data["names"].tolist(),
            features=features,
            mirrored=mirrored,
            profile=SkeletonProfile.from_dict(json.loads(str(data["profile"]))),
            cache_file=cache_file,
            from_cache=from_cache,
        )
