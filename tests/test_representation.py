"""Features: exact round trips on all of Xia, analytic root paths, contacts, the normaliser."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import roma
import torch
from synthetic import xia_profile

from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import (
    FeatureLayout,
    Normalizer,
    decode,
    decode_root,
    encode,
    features_to_positions,
    start_pose,
)
from walkdiff.motion.skeleton import Motion, Skeleton

FPS = 30.0
# The toy skeleton's feet and Xia's contact thresholds, given rather than found (its rest pose is tiny).
FEET = {
    "left_heel": "LeftFoot", "left_toe": "LeftToe", "right_heel": "RightFoot", "right_toe": "RightToe",
    "contact_speed": 5.0, "contact_height": 0.5, "up": "+y", "forward": "+z",
}  # fmt: skip


def _profile(motion: Motion) -> SkeletonProfile:
    return SkeletonProfile.detect(motion, FEET)


def _skeleton() -> Skeleton:
    names = ["Hips", "LeftFoot", "LeftToe", "RightFoot", "RightToe"]
    offsets = [[0, 0, 0], [1, -9, 0], [0, -1, 2], [-1, -9, 0], [0, -1, 2]]
    channels = [("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")]
    channels += [("Zrotation", "Yrotation", "Xrotation")] * 4
    return Skeleton(names, [-1, 0, 1, 0, 3], offsets, channels)


def _rot(rotvec) -> np.ndarray:
    return roma.rotvec_to_rotmat(torch.as_tensor(rotvec, dtype=torch.float64)).numpy()


def _clip(root_positions: np.ndarray, root_rotations: np.ndarray) -> Motion:
    """The toy skeleton with bent knees following a root path."""
    skeleton = _skeleton()
    frames = len(root_positions)
    rotations = np.repeat(_rot(np.full((5, 3), 0.1))[None], frames, axis=0)
    rotations[:, 0] = root_rotations
    positions = np.repeat(skeleton.offsets[None], frames, axis=0)
    positions[:, 0] = root_positions
    return Motion(skeleton, rotations, positions, 1.0 / FPS)


def _round_trip_error(motion: Motion, features: np.ndarray, profile: SkeletonProfile | None = None) -> float:
    position, heading = start_pose(motion, profile or _profile(motion))
    decoded = decode(features, motion.skeleton, motion.frame_time, position, heading)
    return float(np.abs(motion_world_positions(decoded) - motion_world_positions(motion)).max())


def test_layout():
    layout = FeatureLayout(31)
    assert layout.dim == 194
    blocks = [layout.root_vel, layout.root_height, layout.heading_vel, layout.rotations, layout.contacts]
    covered = np.concatenate([np.arange(layout.dim)[block] for block in blocks])
    assert np.array_equal(covered, np.arange(layout.dim))  # blocks tile the vector in order
    assert FeatureLayout.from_dim(194) == layout
    with pytest.raises(ValueError, match="8 \\+ 6"):
        FeatureLayout.from_dim(195)


def test_straight_walk():
    heading, speed, tilt = 0.7, 15.0, 0.2
    t = np.arange(40) / FPS
    direction = np.array([math.sin(heading), 0.0, math.cos(heading)])
    path = np.array([3.0, 10.0, -2.0]) + speed * t[:, None] * direction
    # A forward tilt (about X) must not change the heading.
    root_rot = _rot([0.0, heading, 0.0]) @ _rot([tilt, 0.0, 0.0])
    motion = _clip(path, np.repeat(root_rot[None], len(t), axis=0))
    x = encode(motion, _profile(motion))
    layout = FeatureLayout(5)
    assert x.dtype == np.float32 and x.shape == (40, layout.dim)
    np.testing.assert_allclose(x[:, layout.root_vel], [[0.0, speed / FPS]] * 40, atol=1e-6)
    np.testing.assert_allclose(x[:, layout.root_height], 10.0)
    np.testing.assert_allclose(x[:, layout.heading_vel], 0.0, atol=1e-6)
    root_6d = x[:, layout.rotations][:, :6]
    np.testing.assert_allclose(root_6d, np.tile(_rot([tilt, 0, 0])[:, :2].T.reshape(6), (40, 1)), atol=1e-6)
    assert _round_trip_error(motion, x) < 1e-4
    # A single frame has no next frame: zero velocities, and it still decodes.
    single = encode(motion.slice(0, 1), _profile(motion))
    assert np.array_equal(single[:, :2], [[0.0, 0.0]]) and single[0, 3] == 0.0
    assert _round_trip_error(motion.slice(0, 1), single) < 1e-4
    # Without a start pose the walk starts at the origin facing +Z.
    root = decode(x, motion.skeleton, motion.frame_time).root_positions
    np.testing.assert_allclose(root, (path - path[0] + [0, 10, 0]) @ _rot([0, -heading, 0]).T, atol=1e-4)


def test_turning_root_wraps_heading():
    omega, radius, frames = math.pi, 6.0, 75  # 2.5 s at pi rad/s: the heading passes +-pi twice
    heading = 0.5 + omega * np.arange(frames) / FPS
    path = radius * np.stack([-np.cos(heading), np.full(frames, 1.5), np.sin(heading)], axis=-1)
    motion = _clip(path, _rot(heading[:, None] * [0.0, 1.0, 0.0]))
    x = encode(motion, _profile(motion))
    step = omega / FPS
    np.testing.assert_allclose(x[:, 3], step, atol=1e-6)
    chord = [radius * (1 - math.cos(step)), radius * math.sin(step)]
    np.testing.assert_allclose(x[:, :2], np.tile(chord, (frames, 1)), atol=1e-6)
    assert _round_trip_error(motion, x) < 1e-4


def test_torch_decoding_matches_and_has_gradients():
    t = np.arange(30) / FPS
    heading = 0.3 + 2.0 * t
    path = np.stack([4 * np.sin(t), 10 + 0.2 * np.cos(5 * t), 3 * t], axis=-1)
    motion = _clip(path, _rot(heading[:, None] * [0.0, 1.0, 0.0]))
    position, start_heading = start_pose(motion, _profile(motion))
    x = torch.tensor(encode(motion, _profile(motion)), dtype=torch.float64).repeat(2, 1, 1).requires_grad_()
    offsets, parents = torch.from_numpy(motion.skeleton.offsets), motion.skeleton.parents
    world = features_to_positions(x, offsets, parents, position, start_heading)
    assert world.shape == (2, 30, 5, 3)
    np.testing.assert_allclose(world[1].detach().numpy(), motion_world_positions(motion), atol=1e-4)
    root = decode_root(x, torch.tensor(position), torch.tensor([start_heading, start_heading]))
    np.testing.assert_allclose(root[0].detach().numpy(), path, atol=1e-4)
    (world.square().sum() + root.square().sum()).backward()
    assert torch.isfinite(x.grad).all()
    layout = FeatureLayout(5)
    assert x.grad[..., layout.root_vel].abs().sum() > 0 and x.grad[..., layout.rotations].abs().sum() > 0
    assert torch.all(x.grad[..., layout.contacts] == 0)


def test_contacts_speed_height_and_floor_offset():
    # Still for 20 frames, then rising slowly (below the speed threshold) until high above the floor.
    frames, rise = 40, 2.0 / FPS
    height = 10.0 + rise * np.maximum(0, np.arange(frames) - 19)
    path = np.stack([np.zeros(frames), height, np.zeros(frames)], axis=-1)
    still = np.repeat(np.eye(3)[None], frames, axis=0)
    contacts = encode(_clip(path, still), _profile(_clip(path, still)))[:, -4:]
    lifted = (height - 10.0) >= FEET["contact_height"]
    assert np.array_equal(contacts, np.repeat(~lifted[:, None], 4, axis=1).astype(np.float32))
    assert 0 < lifted.sum() < frames - 20  # some slow frames are out of contact by height alone
    # Moving fast: out of contact even on the floor.
    fast = path + np.stack([np.arange(frames) * 1.0, np.zeros(frames), np.zeros(frames)], axis=-1)
    assert not encode(_clip(fast, still), _profile(_clip(fast, still)))[:, -4:].any()
    # A floor 100 units up gives the same labels.
    raised_clip = _clip(path + [0.0, 100.0, 0.0], still)
    raised = encode(raised_clip, _profile(raised_clip))[:, -4:]
    assert np.array_equal(raised, contacts)


def test_features_do_not_depend_on_placement(xia_dir):
    motion = read_bvh(xia_dir / "neutral_03_000.bvh")
    turn = _rot([0.0, 2.0, 0.0])
    moved = Motion(
        motion.skeleton,
        motion.rotations.copy(),
        motion.positions.copy(),
        motion.frame_time,
    )
    moved.rotations[:, 0] = turn @ motion.rotations[:, 0]
    moved.positions[:, 0] = motion.root_positions @ turn.T + [50.0, 0.0, -20.0]
    x, y = encode(motion, xia_profile(motion)), encode(moved, xia_profile(motion))
    np.testing.assert_allclose(x, y, atol=1e-5)
    assert 0 < x[:, -4:].mean() < 1  # feet do touch and leave the ground in a walk


@pytest.fixture
def one_thread():
    """Per-clip tensors are small: a second intra-op thread only spins (4x slower on 2 busy cores)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.mark.slow
def test_round_trip_every_xia_clip(xia_dir, one_thread):
    paths = sorted(xia_dir.glob("*.bvh"))
    assert paths
    start, cpu = time.perf_counter(), time.process_time()
    worst = 0.0
    for path in paths:
        motion = read_bvh(path)
        x = encode(motion, xia_profile(motion))
        assert x.shape == (motion.num_frames, 194)
        assert set(np.unique(x[:, -4:])) <= {0.0, 1.0}
        worst = max(worst, _round_trip_error(motion, x, xia_profile(motion)))
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    print(f"round trip of {len(paths)} Xia clips: worst {worst:.2e} units, {wall:.1f} s ({cpu:.1f} s CPU)")
    assert worst < 1e-3


def test_normalizer():
    rng = np.random.default_rng(0)
    train = [rng.normal([1.0, -5.0, 3.0], [2.0, 0.5, 0.0], size=(n, 3)).astype(np.float32) for n in (50, 70)]
    normalizer = Normalizer.fit(train)
    z = normalizer.normalize(np.concatenate(train))
    assert z.dtype == np.float32
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=1e-5)
    # The constant channel is only centred.
    np.testing.assert_allclose(z.std(axis=0), [1.0, 1.0, 0.0], atol=1e-5)
    assert normalizer.std[2] == 1.0
    np.testing.assert_allclose(normalizer.denormalize(z), np.concatenate(train), atol=1e-5)
    # Torch path, and the statistics travel in a state dict.
    restored = Normalizer(3)
    restored.load_state_dict(normalizer.state_dict())
    x = torch.tensor(train[0], dtype=torch.float64)
    torch.testing.assert_close(restored.normalize(x), torch.tensor(z[:50], dtype=torch.float64))
    torch.testing.assert_close(restored.denormalize(restored(x)), x)
    assert Normalizer.fit(train[0]).mean.tolist() == pytest.approx(train[0].mean(axis=0).tolist(), abs=1e-5)


def test_decode_rejects_wrong_width():
    with pytest.raises(ValueError, match="expected features"):
        decode(np.zeros((3, 40)), _skeleton(), 1 / FPS)
