"""Frame-rate changes against analytic motion, and left/right mirroring on real Xia clips."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import roma
import torch

from walkdiff.errors import WalkdiffError
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.mirror import find_mirror_pairs, mirror
from walkdiff.motion.representation import XIA_CONTACTS, encode
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


def _partner(skeleton: Skeleton) -> np.ndarray:
    partner = np.arange(skeleton.num_joints)
    for left, right in find_mirror_pairs(skeleton):
        partner[left], partner[right] = right, left
    return partner


def _symmetrised(motion: Motion) -> Motion:
    """The clip on a left/right symmetric copy of its skeleton (right offsets = reflected left ones)."""
    offsets = motion.skeleton.offsets.copy()
    for left, right in find_mirror_pairs(motion.skeleton):
        offsets[right] = offsets[left] * [-1, 1, 1]
    middle = _partner(motion.skeleton) == np.arange(motion.skeleton.num_joints)
    offsets[middle, 0] = 0.0
    positions = motion.positions.copy()
    positions[:, 1:] = offsets[1:]
    return replace(motion, skeleton=replace(motion.skeleton, offsets=offsets), positions=positions)


def test_mirror_pairs_of_xia(xia_dir):
    skeleton = read_bvh(xia_dir / "neutral_01_000.bvh").skeleton
    names = {(skeleton.names[a], skeleton.names[b]) for a, b in find_mirror_pairs(skeleton)}
    assert {("LHipJoint", "RHipJoint"), ("LeftUpLeg", "RightUpLeg"), ("LThumb", "RThumb")} <= names
    assert len(names) == 12
    assert all(n.startswith(("Left", "L")) and not n.startswith("Lower") for n, _ in names)


def test_mirror_twice_is_identity(xia_dir):
    motion = read_bvh(xia_dir / "old_04_000.bvh")
    for axis in ("x", "z"):
        once = mirror(motion, axis=axis)
        assert not np.allclose(once.rotations, motion.rotations)
        twice = mirror(once, axis=axis)
        assert np.array_equal(twice.rotations, motion.rotations)
        assert np.array_equal(twice.positions, motion.positions)


def test_mirror_reflects_world_positions(xia_dir, tmp_path):
    motion = read_bvh(xia_dir / "neutral_03_000.bvh")
    partner = _partner(motion.skeleton)
    reflect = np.array([-1.0, 1.0, 1.0])
    # Exact on a symmetric skeleton...
    symmetric = _symmetrised(motion)
    world = motion_world_positions(symmetric)
    np.testing.assert_allclose(
        motion_world_positions(mirror(symmetric)), (world * reflect)[:, partner], atol=1e-9
    )
    # ... on Xia's own (asymmetric) skeleton only the root path is exact.
    world = motion_world_positions(motion)
    mirrored = motion_world_positions(mirror(motion))
    np.testing.assert_allclose(mirrored[:, 0], world[:, 0] * reflect, atol=1e-12)
    assert np.abs(mirrored - (world * reflect)[:, partner]).max() > 0.1
    # The mirrored clip is a valid clip of the original skeleton: it survives a BVH round trip.
    write_bvh(tmp_path / "mirrored.bvh", mirror(motion))
    np.testing.assert_allclose(
        motion_world_positions(read_bvh(tmp_path / "mirrored.bvh")), mirrored, atol=1e-3
    )


def test_mirror_swaps_contacts(xia_dir):
    motion = _symmetrised(read_bvh(xia_dir / "neutral_03_000.bvh"))
    contacts = encode(motion, XIA_CONTACTS)[:, -4:]
    mirrored = encode(mirror(motion), XIA_CONTACTS)[:, -4:]
    assert not np.array_equal(contacts[:, :2], contacts[:, 2:])  # the sides differ, so the swap shows
    assert np.array_equal(mirrored, contacts[:, [2, 3, 0, 1]])


def test_mirror_explicit_and_bad_pairs():
    skeleton = Skeleton(
        ["root", "arm_a", "hand_a", "arm_b", "hand_b"],
        [-1, 0, 1, 0, 3],
        [[0, 0, 0], [1, 0, 0], [1, 0, 0], [-1, 0, 0], [-1, 0, 0]],
        [("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")]
        + [("Zrotation",)] * 4,
    )
    assert find_mirror_pairs(skeleton) == []
    rotations = roma.random_rotmat((3, 5), dtype=torch.float64).numpy()
    positions = np.repeat(skeleton.offsets[None], 3, axis=0)
    motion = Motion(skeleton, rotations, positions, 0.1)
    mirrored = mirror(motion, pairs=[("arm_a", "arm_b"), ("hand_a", "hand_b")])
    world = motion_world_positions(motion)
    np.testing.assert_allclose(motion_world_positions(mirrored), (world * [-1, 1, 1])[:, [0, 3, 4, 1, 2]])
    with pytest.raises(WalkdiffError, match="two joints of the skeleton"):
        mirror(motion, pairs=[("arm_a", "leg")])
    with pytest.raises(WalkdiffError, match="do not match the hierarchy"):
        mirror(motion, pairs=[("arm_a", "hand_b")])
    with pytest.raises(WalkdiffError, match="more than one pair"):
        mirror(motion, pairs=[("arm_a", "arm_b"), ("arm_a", "hand_b")])
    with pytest.raises(WalkdiffError, match="mirror axis"):
        mirror(motion, axis="w")
