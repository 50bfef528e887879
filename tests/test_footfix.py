"""Foot clean-up: two-bone IK, pinning on synthetic sliding feet, and skating cut on real Xia clips."""

from __future__ import annotations

import numpy as np
import pytest
import synthetic
import torch

from walkdiff.metrics.physics import FootSkating
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.footfix import (
    ankle_offsets,
    contact_runs,
    fix_feet,
    fix_feet_features,
    planted_heights,
    set_down,
    two_bone_ik,
)
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.representation import FeatureLayout, decode, encode, features_to_positions
from walkdiff.motion.resample import resample
from walkdiff.motion.skeleton import Motion

CONTACTS = synthetic.XIA_CONTACTS


def test_contact_runs_and_offsets_fade_out():
    assert contact_runs(np.array([0, 1, 1, 0, 0, 1], dtype=bool)) == [(1, 3), (5, 6)]
    assert contact_runs(np.zeros(4, dtype=bool)) == []
    heel = np.zeros((12, 3))
    heel[:, 0] = np.arange(12.0)  # slides 1 unit per frame along x
    contacts = np.zeros((12, 2))
    contacts[4:7, 0] = 1  # heel down on frames 4-6: pinned at x = 5
    offset = ankle_offsets(heel, heel.copy(), contacts, blend=2)
    np.testing.assert_allclose((heel + offset)[4:7, 0], 5.0)
    np.testing.assert_allclose(offset[:, 1], 0.0)  # heights are left alone
    # One frame before and after: 2/3 of the neighbouring offset; three frames away: none.
    np.testing.assert_allclose(offset[[3, 7], 0], [2 / 3 * 1.0, 2 / 3 * -1.0])
    assert not offset[:2].any() and not offset[9:].any()


def test_two_bone_ik_reaches_targets_and_straightens_out_of_reach():
    motion = synthetic.walking(40, fps=30.0)
    sk = motion.skeleton
    ankle = sk.index("LeftFoot")
    world = motion_world_positions(motion)
    hip = world[:, sk.index("LeftUpLeg")]
    rng = np.random.default_rng(0)
    # Within reach (the synthetic legs are often straight: the knee has to bend from there).
    near = hip + 0.85 * (world[:, ankle] - hip) + rng.uniform(-0.5, 0.5, (40, 3))
    far = hip + (world[:, ankle] - hip) * 3.0  # three leg lengths away
    for targets, reachable in ((near, True), (far, False)):
        rotations = two_bone_ik(
            motion.rotations, motion.positions, sk.parents, ankle, targets, np.ones(40, bool)
        )
        np.testing.assert_allclose(
            rotations @ rotations.swapaxes(-1, -2), np.broadcast_to(np.eye(3), rotations.shape), atol=1e-9
        )
        fixed = motion_world_positions(Motion(sk, rotations, motion.positions, motion.frame_time))
        if reachable:
            np.testing.assert_allclose(fixed[:, ankle], targets, atol=1e-6)
        else:  # pointing at the target, fully stretched
            direction = (fixed[:, ankle] - hip) / np.linalg.norm(
                fixed[:, ankle] - hip, axis=-1, keepdims=True
            )
            wanted = (targets - hip) / np.linalg.norm(targets - hip, axis=-1, keepdims=True)
            np.testing.assert_allclose(direction, wanted, atol=1e-6)
        # The foot keeps its world orientation, the other leg and the upper body do not move.
        untouched = [sk.index(n) for n in ("Hips", "RightFoot", "RightToeBase", "Spine", "Head")]
        np.testing.assert_allclose(fixed[:, untouched], world[:, untouched], atol=1e-9)


def test_sliding_synthetic_feet_are_pinned_and_the_rest_is_untouched():
    motion = synthetic.walking(90, fps=30.0)  # feet swing while the root glides: they slide in any "contact"
    sk = motion.skeleton
    contacts = np.zeros((90, 4))
    contacts[20:30, 0:2] = 1  # left heel and toe down for a third of a second
    contacts[50:58, 3] = 1  # right toe only
    fixed = fix_feet(motion, contacts, CONTACTS)
    before, after = motion_world_positions(motion), motion_world_positions(fixed)
    for joint, frames in (
        ("LeftFoot", slice(20, 30)),
        ("LeftToeBase", slice(20, 30)),
        ("RightToeBase", slice(50, 58)),
    ):
        j = sk.index(joint)
        slide_before = np.linalg.norm(np.diff(before[frames, j][:, [0, 2]], axis=0), axis=1).max()
        slide_after = np.linalg.norm(np.diff(after[frames, j][:, [0, 2]], axis=0), axis=1).max()
        assert slide_before > 0.1 and slide_after < 0.05 * slide_before, joint
    np.testing.assert_array_equal(fixed.positions, motion.positions)  # the root and bone offsets
    upper = [sk.index(n) for n in ("Spine", "Head")]
    np.testing.assert_array_equal(fixed.rotations[:, upper], motion.rotations[:, upper])
    # Far from any contact nothing changes; bone lengths are kept everywhere.
    np.testing.assert_array_equal(fixed.rotations[:10], motion.rotations[:10])
    bones = lambda w: np.linalg.norm(w[:, 1:] - w[:, sk.parents[1:]], axis=-1)  # noqa: E731
    np.testing.assert_allclose(bones(after), bones(before), atol=1e-9)


def skating(positions: torch.Tensor, contacts: torch.Tensor, skeleton) -> dict[str, float]:
    metric = FootSkating([skeleton.index(n) for n in CONTACTS.joints], 30.0, CONTACTS.speed_threshold)
    metric.update(positions, contacts)
    return {k: float(v) for k, v in metric.compute().items()}


def test_fix_feet_halves_skating_on_real_clips_with_artificial_slide(xia_dir):
    names = ["neutral_01_000", "old_07_000", "angry_01_000", "sexy_02_000"]
    rows = []
    for k, name in enumerate(names):
        motion = resample(read_bvh(xia_dir / f"{name}.bvh"), 30.0)
        contacts = encode(motion, synthetic.xia_profile(motion))[:, -4:]
        time = np.arange(motion.num_frames) / 30.0
        slid = Motion(motion.skeleton, motion.rotations, motion.positions.copy(), motion.frame_time)
        slid.positions[:, 0, 0] += 1.0 * np.sin(
            2 * np.pi * 1.3 * time + k
        )  # the body sways over planted feet
        slid.positions[:, 0, 2] += 0.8 * np.sin(2 * np.pi * 0.9 * time)
        rows.append((motion, slid, fix_feet(slid, contacts, CONTACTS), contacts))
    sk = rows[0][0].skeleton

    def score(i: int) -> dict[str, float]:
        positions = [torch.from_numpy(motion_world_positions(r[i]))[None] for r in rows]
        metric = FootSkating([sk.index(n) for n in CONTACTS.joints], 30.0, CONTACTS.speed_threshold)
        for p, r in zip(positions, rows):
            metric.update(p, torch.from_numpy(r[3])[None])
        return {k: float(v) for k, v in metric.compute().items()}

    real, slid, fixed = score(0), score(1), score(2)
    assert slid["slide_speed"] > 4 * real["slide_speed"] and slid["skate_ratio"] > 0.3
    assert (
        fixed["slide_speed"] < 0.5 * slid["slide_speed"] and fixed["skate_ratio"] < 0.5 * slid["skate_ratio"]
    )
    assert fixed["slide_speed"] < 2 * real["slide_speed"] + 0.2


def test_fix_feet_features_changes_only_rotations(xia_dir):
    motion = resample(read_bvh(xia_dir / "proud_01_000.bvh"), 30.0)
    layout = FeatureLayout(motion.skeleton.num_joints)
    profile = synthetic.xia_profile(motion)
    raw = encode(motion, profile)[:48].reshape(2, 24, -1)  # two windows, as the evaluator sees them
    raw[..., layout.root_vel] *= 1.4  # the root outruns its feet: they slide backwards
    # A sampled 6D rotation is not exactly orthonormal: scaled, the arm's pose is the same.
    arm = layout.rotations.start + 6 * motion.skeleton.index("LeftArm")
    raw[..., arm : arm + 6] *= 1.02
    fixed = fix_feet_features(raw, profile, 30.0)
    keep = np.ones(layout.dim, bool)
    keep[layout.rotations] = False
    np.testing.assert_array_equal(fixed[..., keep], raw[..., keep])
    # Joints the IK does not move keep their channels as they were, not re-encoded; the legs change.
    np.testing.assert_array_equal(fixed[..., arm : arm + 6], raw[..., arm : arm + 6])
    knee = layout.rotations.start + 6 * motion.skeleton.index("LeftLeg")
    assert np.abs(fixed[..., knee : knee + 6] - raw[..., knee : knee + 6]).max() > 1e-3
    offsets = torch.from_numpy(motion.skeleton.offsets)
    positions = [
        features_to_positions(torch.from_numpy(x).double(), offsets, motion.skeleton.parents)
        for x in (raw, fixed)
    ]
    contacts = torch.from_numpy(raw[..., layout.contacts])
    before, after = (skating(p, contacts, motion.skeleton) for p in positions)
    assert after["slide_speed"] < 0.5 * before["slide_speed"]


def test_grounding_puts_planted_feet_back_on_the_training_floor(xia_dir):
    """Real clips, lifted or sunk by a few units, come back to where their planted feet stood."""
    from walkdiff.data.xia import list_clips, load
    from walkdiff.motion.footfix import ground, planted_heights

    clips = [c for c in list_clips(xia_dir) if c.content == 0][:8]
    raws = [encode(resample(load(c), 30.0), synthetic.xia_profile(load(c))) for c in clips]
    skeleton = load(clips[0]).skeleton
    heights = planted_heights(raws, skeleton, CONTACTS)
    assert np.all(np.isfinite(heights)) and np.all(np.abs(heights) < 2.0)
    layout = FeatureLayout(skeleton.num_joints)
    window = np.stack([r[:24] for r in raws])  # (8, 24, D)
    shifted = window.copy()
    shifted[..., layout.root_height] += np.linspace(-3, 3, 8)[:, None, None].astype(np.float32)
    grounded = ground(shifted, skeleton, CONTACTS, heights)
    # Each clip lands within a fraction of the contact height of where it was (its floor differs a bit).
    error = grounded[..., 0, layout.root_height.start] - window[..., 0, layout.root_height.start]
    assert np.abs(error).max() < CONTACTS.height_threshold
    np.testing.assert_array_equal(np.delete(grounded, layout.root_height.start, -1),
                                  np.delete(shifted, layout.root_height.start, -1))  # fmt: skip
    # No planted frame, no shift; a joint never planted in the data (NaN) is left out.
    flying = shifted.copy()
    flying[..., layout.contacts] = 0
    np.testing.assert_array_equal(ground(flying, skeleton, CONTACTS, heights), flying)
    partial = ground(shifted, skeleton, CONTACTS, np.array([heights[0], np.nan, np.nan, np.nan]))
    assert np.isfinite(partial).all()


def test_grounding_moves_a_clip_only_by_how_much_further_off_it_is_than_real_clips(xia_dir):
    """The tolerance is the 95th percentile of the shift real windows would get; a clip within it stays,
    one beyond it moves by the excess only, towards the floor it would have reached."""
    from walkdiff.data.xia import list_clips, load
    from walkdiff.motion.footfix import ground, ground_shifts, ground_tolerance, planted_heights

    clips = [c for c in list_clips(xia_dir) if c.content == 0][:8]
    raws = [encode(resample(load(c), 30.0), synthetic.xia_profile(load(c))) for c in clips]
    skeleton = load(clips[0]).skeleton
    heights = planted_heights(raws, skeleton, CONTACTS)
    tolerance = ground_tolerance(raws, skeleton, CONTACTS, heights, window=24)
    windows = np.stack([r[s : s + 24] for r in raws for s in range(0, len(r) - 23, 24)])
    sizes = np.abs(ground_shifts(windows, skeleton, CONTACTS, heights))
    assert tolerance == pytest.approx(np.quantile(sizes, 0.95)) and 0 < tolerance < CONTACTS.height_threshold
    layout = FeatureLayout(skeleton.num_joints)
    root = layout.root_height.start
    window = raws[0][None, :24]
    full = ground_shifts(window, skeleton, CONTACTS, heights)[0]
    for lift in (0.0, 3.0, -3.0):
        moved = window.copy()
        moved[..., root] += np.float32(lift)
        shift = full - lift  # what the whole grounding would move it by
        expected = np.sign(shift) * max(abs(shift) - tolerance, 0.0)
        got = ground(moved, skeleton, CONTACTS, heights, tolerance)[0, 0, root] - moved[0, 0, root]
        assert got == pytest.approx(expected, abs=1e-4)
    assert ground_tolerance([r[:10] for r in raws], skeleton, CONTACTS, heights, window=24) == 0.0


def test_set_down_pins_stance_feet_the_labels_miss_but_not_a_foot_sweeping_past(xia_dir):
    """Generated clips label only some of their stance frames: `set_down` adds every frame where the clip
    puts a foot down by the geometry skating is judged by, near where real planted feet stand and slower
    than a few contact speeds. On a real clip with its labels taken away it finds them again; the same
    clip dragged along at 5 contact speeds has no foot down; a joint never planted (NaN) never is."""
    motion = resample(read_bvh(xia_dir / "proud_01_000.bvh"), 30.0)
    profile = synthetic.xia_profile(motion)
    spec, skeleton = profile.contacts, profile.canonical_skeleton
    raw = encode(motion, profile)
    layout = FeatureLayout(skeleton.num_joints)
    labels = raw[:, layout.contacts] > 0.5
    heights = planted_heights([raw], skeleton, spec)
    clip = decode(raw, skeleton, 1 / 30.0)
    found = set_down(clip, np.zeros_like(labels, dtype=float), spec, heights) > 0.5
    assert labels.sum() > 20 and (found & labels).sum() >= 0.9 * labels.sum()
    assert (set_down(clip, labels.astype(float), spec, heights) >= labels).all()  # the labels are kept
    dragged = Motion(clip.skeleton, clip.rotations, clip.positions.copy(), clip.frame_time)
    dragged.positions[:, 0, 0] += np.arange(clip.num_frames) * 5 * spec.speed_threshold / 30.0
    assert not set_down(dragged, np.zeros_like(labels, dtype=float), spec, heights).any()
    never = np.full(4, np.nan)
    assert not set_down(clip, np.zeros_like(labels, dtype=float), spec, never).any()
    assert (set_down(clip, labels.astype(float), spec, None) == labels).all()  # no floor: the labels
