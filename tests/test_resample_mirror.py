"""Frame-rate changes against analytic motion (the mirroring tests are in test_mirror.py)."""

from __future__ import annotations

import numpy as np
import pytest
import roma
import torch

from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.resample import resample
from walkdiff.motion.skeleton import Motion, Skeleton

AXIS = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
C, D = (
    roma.rotvec_to_rotmat(torch.tensor(v, dtype=torch.float64)).numpy() for v in ([0.3, 0, 0.1], [0, 0.4, 0])
)


def _analytic(times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Root moving at constant velocity; joint 1 turning at 3 rad/s about AXIS: R(t) = C exp(3t AXIS) D."""
    turning = roma.rotvec_to_rotmat(torch.from_numpy(3.0 * times[:, None] * AXIS)).numpy()
    rotations = np.stack([np.repeat(np.eye(3)[None], len(times), axis=0), C @ turning @ D], axis=1)
    positions = np.zeros((len(times), 2, 3))
    positions[:, 0] = [1.0, 10.0, 0.0] + times[:, None] * [2.0, 0.0, -3.0]
    positions[:, 1] = [0.0, 1.0, 0.0]
    return rotations, positions


def _analytic_motion(fps: float, frames: int) -> Motion:
    skeleton = Skeleton(["Hips", "Spine"], [-1, 0], [[0, 0, 0], [0, 1, 0]], [("Xposition",), ("Zrotation",)])
    rotations, positions = _analytic(np.arange(frames) / fps)
    return Motion(skeleton, rotations, positions, 1.0 / fps)


# The last case has no simple ratio (1 / 166.5) and takes the floating-point path.
@pytest.mark.parametrize(
    ("source", "target", "frames"), [(120.0, 50.0, 61), (30.0, 120.0, 20), (120.0, 47.0, 50), (2.0, 333.0, 4)]
)
def test_resample_matches_analytic_motion(source, target, frames):
    resampled = resample(_analytic_motion(source, frames), target)
    count = int(np.floor((frames - 1) * target / source + 1e-9)) + 1  # same span, no extrapolation
    assert resampled.num_frames == count
    assert resampled.frame_time == pytest.approx(1.0 / target)
    rotations, positions = _analytic(np.arange(count) / target)
    np.testing.assert_allclose(resampled.rotations, rotations, atol=1e-9)
    np.testing.assert_allclose(resampled.positions, positions, atol=1e-9)


def test_resample_integer_factors_pick_frames(xia_dir):
    motion = read_bvh(xia_dir / "neutral_01_000.bvh")  # Frame Time 0.008333: not exactly 120 fps
    down = resample(motion, 30)
    assert np.array_equal(down.rotations, motion.rotations[::4])
    assert np.array_equal(down.positions, motion.positions[::4])
    up = resample(motion, 240)
    assert up.num_frames == 2 * motion.num_frames - 1
    assert np.array_equal(up.rotations[::2], motion.rotations)
    # Midpoints lie halfway along the geodesic between their neighbours.
    mid, r0, r1 = (
        torch.from_numpy(r) for r in (up.rotations[1::2], motion.rotations[:-1], motion.rotations[1:])
    )
    torch.testing.assert_close(roma.rotmat_geodesic_distance(mid, r0), roma.rotmat_geodesic_distance(mid, r1))


def test_resample_rejects_bad_rate():
    with pytest.raises(ValueError, match="positive frame rate"):
        resample(_analytic_motion(30.0, 5), 0.0)
