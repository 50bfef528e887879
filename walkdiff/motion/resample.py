"""Change a clip's frame rate: rotations by slerp, translations linearly."""

from __future__ import annotations

from dataclasses import replace
from fractions import Fraction

import numpy as np
import roma
import torch

from walkdiff.motion.skeleton import Motion

# Frame times are written with few digits (Xia: 0.008333 s for 120 fps, 4e-5 off), so a ratio of rates
# this close (relatively) to a simple fraction is taken as that fraction: then 120 -> 30 fps picks
# every 4th frame exactly, and 120 -> 240 keeps every original frame.
_RATIO_TOLERANCE = 1e-4
_MAX_DENOMINATOR = 100


def resample(motion: Motion, fps: float) -> Motion:
    """The clip sampled at `fps` over the same time span.

    New frame k lies at time k / fps; frames run from the first original frame up to the last one
    (no extrapolation), so the clip keeps its span from first to last frame. An integer ratio of
    rates picks every n-th frame; up-sampling by an integer factor keeps every original frame.
    """
    if not fps > 0:
        raise ValueError(f"expected a positive frame rate, got {fps}")
    before, weight = _source_frames(motion.num_frames, motion.fps / fps)
    after = np.minimum(before + 1, motion.num_frames - 1)
    positions = motion.positions[before] + weight[:, None, None] * (
        motion.positions[after] - motion.positions[before]
    )
    rotations = _slerp(motion.rotations[before], motion.rotations[after], weight)
    return replace(motion, rotations=rotations, positions=positions, frame_time=1.0 / fps)


def _source_frames(num_frames: int, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """For each new frame: the original frame before it and the weight of the one after."""
    last = num_frames - 1
    simple = Fraction(ratio).limit_denominator(_MAX_DENOMINATOR)
    if abs(float(simple) - ratio) <= _RATIO_TOLERANCE * ratio:
        # Exact integer arithmetic: a new frame on an original frame gets a weight of exactly 0.
        p, q = simple.numerator, simple.denominator
        ticks = np.arange(last * q // p + 1) * p
        return ticks // q, (ticks % q) / q
    source = np.arange(int(np.floor(last / ratio + 1e-9)) + 1) * ratio
    before = np.minimum(np.floor(source).astype(np.int64), last)
    return before, source - before


def _slerp(r0: np.ndarray, r1: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Frame-wise slerp of (F, J, 3, 3) rotations with one weight per frame.

    roma's slerp functions interpolate every pair at every given step (steps x pairs); one step per
    frame is the same geodesic written through roma's rotation vectors: r0 exp(w log(r0^T r1)).
    """
    start = torch.from_numpy(r0)
    relative = roma.rotmat_to_rotvec(start.transpose(-1, -2) @ torch.from_numpy(r1))
    step = roma.rotvec_to_rotmat(torch.from_numpy(weight)[:, None, None] * relative)
    exact = weight == 0  # keep picked frames bit-exact
    out = (start @ step).numpy()
    out[exact] = r0[exact]
    return out
