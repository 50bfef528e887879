"""Built-in target rigs (`walkdiff.retarget.rigs`): each is a standing human of the asked stature, in its
own names, axes, units and local frames, with the proportions of the published table, that BVH keeps and
the skeleton profile reads right.

The table's figures are written out here, not imported: Drillis & Contini (1966), fractions of stature H.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion import smpl
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.kinematics import forward_kinematics
from walkdiff.motion.mirror import find_mirror_pairs
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.profile_detection import AXES, axis_rotation
from walkdiff.retarget.rigs import RIGS, SPECS, STATURE_M, rig

# Joints playing each role on the left side (and the centre), per rig.
ROLES = {
    "mixamo": dict(
        pelvis="mixamorig:Hips", neck="mixamorig:Neck", head="mixamorig:Head", hip="mixamorig:LeftUpLeg",
        knee="mixamorig:LeftLeg", ankle="mixamorig:LeftFoot", ball="mixamorig:LeftToeBase",
        shoulder="mixamorig:LeftArm", elbow="mixamorig:LeftForeArm", wrist="mixamorig:LeftHand",
    ),
    "unreal": dict(
        pelvis="pelvis", neck="neck_01", head="head", hip="thigh_l", knee="calf_l", ankle="foot_l",
        ball="ball_l", shoulder="upperarm_l", elbow="lowerarm_l", wrist="hand_l",
    ),
    "smpl": dict(
        pelvis="pelvis", neck="neck", head="head", hip="left_hip", knee="left_knee", ankle="left_ankle",
        ball="left_foot", shoulder="left_shoulder", elbow="left_elbow", wrist="left_wrist",
    ),
}  # fmt: skip
FEET = {
    "mixamo": (
        "mixamorig:LeftFoot",
        "mixamorig:LeftToeBase",
        "mixamorig:RightFoot",
        "mixamorig:RightToeBase",
    ),
    "unreal": ("foot_l", "ball_l", "foot_r", "ball_r"),
    "smpl": ("left_ankle", "left_foot", "right_ankle", "right_foot"),
}
ARM_DROP_DEG = {"mixamo": 0.0, "unreal": 45.0, "smpl": 0.0}


def axis(name: str) -> np.ndarray:
    return np.asarray(AXES[name], dtype=np.float64)


def posed(motion):
    """World positions (J, 3), world rotations (J, 3, 3) and End Site places {joint: (3,)} of frame 0."""
    pos, rot = forward_kinematics(
        torch.tensor(motion.rotations), torch.tensor(motion.positions), motion.skeleton.parents, True
    )
    pos, rot = pos.numpy()[0], rot.numpy()[0]
    ends = {j: pos[j] + rot[j] @ o for j, o in motion.skeleton.end_sites.items()}
    return pos, rot, ends


def units_per_metre(name: str) -> float:
    return 1.0 / SPECS[name].metres_per_unit


# ---------------------------------------------------------------- the API


def test_unknown_rig_is_refused_naming_the_known_ones():
    with pytest.raises(WalkdiffError, match="unknown rig 'maya'.*mixamo, unreal, smpl"):
        rig("maya")
    assert rig(" Mixamo ").skeleton.names == rig("mixamo").skeleton.names


@pytest.mark.parametrize("height", [0, -1.7, 175, float("nan"), "tall"])
def test_a_stature_that_is_no_human_height_in_metres_is_refused(height):
    with pytest.raises(WalkdiffError, match="stature in metres"):
        rig("smpl", height=height)


# ---------------------------------------------------------------- every rig


@pytest.mark.parametrize("name", RIGS)
def test_bvh_round_trip_keeps_the_rig(name, tmp_path):
    motion = rig(name)
    write_bvh(tmp_path / "rig.bvh", motion)
    back = read_bvh(tmp_path / "rig.bvh")
    s, b = motion.skeleton, back.skeleton
    assert b.names == s.names and np.array_equal(b.parents, s.parents) and b.channels == s.channels
    np.testing.assert_allclose(b.offsets, s.offsets, atol=1e-6)
    assert set(b.end_sites) == set(s.end_sites)
    for j, offset in s.end_sites.items():
        np.testing.assert_allclose(b.end_sites[j], offset, atol=1e-6)
    np.testing.assert_allclose(back.rotations, motion.rotations, atol=1e-7)
    np.testing.assert_allclose(posed(back)[0], posed(motion)[0], atol=1e-6 * units_per_metre(name))
    assert back.num_frames == 1


@pytest.mark.parametrize("height", [None, 1.6])
@pytest.mark.parametrize("name", RIGS)
def test_stature_in_the_rigs_units_along_its_up_axis_feet_on_the_floor(name, height):
    motion = rig(name, height)
    pos, _, ends = posed(motion)
    up = axis(SPECS[name].up)
    heights = np.concatenate([pos, np.reshape(list(ends.values()), (-1, 3))]) @ up
    expected = (height or STATURE_M) * units_per_metre(name)
    assert abs(np.ptp(heights) - expected) < 0.02 * expected
    assert abs(heights.min()) < 1e-9 * expected  # nothing below the floor, something on it
    balls = [motion.skeleton.index(j) for j in (ROLES[name]["ball"], *_right(name, ["ball"]))]
    assert np.abs(pos[balls] @ up).max() < 1e-9 * expected  # the balls of both feet on the floor


@pytest.mark.parametrize("name", RIGS)
def test_left_joints_on_the_characters_left_and_the_sides_mirror_each_other(name):
    motion = rig(name)
    pos, _, ends = posed(motion)
    spec = SPECS[name]
    left, up, forward = axis(spec.left), axis(spec.up), axis(spec.forward)
    assert np.allclose(np.cross(up, forward), left)  # the rig's left is the character's left
    pairs = find_mirror_pairs(motion.skeleton)
    assert len(pairs) >= 8
    centre = pos[0] - (pos[0] @ left) * left
    mirror = np.eye(3) - 2 * np.outer(left, left)
    for a, b in pairs:
        assert (pos[a] - centre) @ left > 0, motion.skeleton.names[a]
        assert (pos[b] - centre) @ left < 0, motion.skeleton.names[b]
        np.testing.assert_allclose(mirror @ (pos[a] - centre), pos[b] - centre, atol=1e-9)
    # The toes point where the body faces.
    ankle, ball = (motion.skeleton.index(ROLES[name][k]) for k in ("ankle", "ball"))
    assert (pos[ball] - pos[ankle]) @ forward > 0.05 * np.ptp(pos @ up)


@pytest.mark.parametrize("name", RIGS)
def test_proportions_are_the_tables(name):
    """Drillis & Contini (1966) as fractions of stature; the arms at the rig's rest angle."""
    motion = rig(name, 1.8)
    pos, _, ends = posed(motion)
    tall = 1.8 * units_per_metre(name)
    up = axis(SPECS[name].up)
    at = {role: pos[motion.skeleton.index(joint)] for role, joint in ROLES[name].items()}
    right = {
        r: pos[motion.skeleton.index(j)]
        for r, j in zip(("hip", "shoulder"), _right(name, ["hip", "shoulder"]))
    }
    height = {role: (p @ up) / tall for role, p in at.items()}
    assert height["knee"] == pytest.approx(0.285, abs=1e-6)
    assert height["ankle"] == pytest.approx(0.039, abs=1e-6)
    assert height["hip"] == pytest.approx(0.530, abs=1e-6)
    assert height["shoulder"] == pytest.approx(0.818, abs=1e-6)
    assert height["neck"] == pytest.approx(0.818, abs=1e-6)
    assert height["head"] == pytest.approx(0.870, abs=1e-6)

    def length(a, b):
        return np.linalg.norm(at[a] - at[b]) / tall

    assert length("hip", "knee") + length("knee", "ankle") == pytest.approx(0.530 - 0.039, abs=1e-6)
    assert length("shoulder", "elbow") == pytest.approx(0.186, abs=1e-6)
    assert length("elbow", "wrist") == pytest.approx(0.146, abs=1e-6)
    wrist = motion.skeleton.index(ROLES[name]["wrist"])
    fingertip = ends[wrist] if wrist in ends else ends[motion.skeleton.children(wrist)[0]]  # SMPL: hand
    assert np.linalg.norm(fingertip - at["wrist"]) / tall == pytest.approx(0.108, abs=1e-6)
    assert np.linalg.norm(at["shoulder"] - right["shoulder"]) / tall == pytest.approx(0.259, abs=1e-6)
    assert np.linalg.norm(at["hip"] - right["hip"]) / tall == pytest.approx(0.191 / 2, abs=1e-6)
    arm = at["elbow"] - at["shoulder"]
    drop = np.degrees(np.arcsin(-(arm @ up) / np.linalg.norm(arm)))
    assert drop == pytest.approx(ARM_DROP_DEG[name], abs=1e-6)


def _right(name: str, roles) -> list[str]:
    swap = {"mixamo": ("Left", "Right"), "unreal": ("_l", "_r"), "smpl": ("left_", "right_")}[name]
    return [ROLES[name][r].replace(*swap) for r in roles]


@pytest.mark.parametrize("name", RIGS)
def test_profile_detection_reads_each_rig_right(name):
    motion = rig(name)
    spec = SPECS[name]
    profile = SkeletonProfile.detect(motion)
    np.testing.assert_allclose(profile.up, axis(spec.up))
    assert profile.units == spec.units and profile.metres_per_unit == spec.metres_per_unit
    assert profile.body_height == pytest.approx(STATURE_M * units_per_metre(name), rel=0.02)
    assert tuple(profile.feet[k] for k in ("left_heel", "left_toe", "right_heel", "right_toe")) == FEET[name]
    assert profile.root == ROLES[name]["pelvis"]
    assert profile.can_mirror
    # The canonical root's facing axis, turned back into the file, is the rig's forward axis.
    _, rot, _ = posed(motion)
    turn = axis_rotation(profile.up)
    facing = rot[profile.root_index] @ turn.T @ np.asarray(profile.forward)
    np.testing.assert_allclose(facing, axis(spec.forward), atol=1e-9)


# ---------------------------------------------------------------- each rig's own conventions


def test_mixamo_channels_and_identity_frames():
    motion = rig("mixamo")
    s = motion.skeleton
    assert s.names[0] == "mixamorig:Hips" and "mixamorig:HeadTop_End" in s.names
    assert s.channels[0] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
    assert all(c == ("Zrotation", "Xrotation", "Yrotation") for c in s.channels[1:])
    np.testing.assert_allclose(motion.rotations, np.broadcast_to(np.eye(3), motion.rotations.shape))
    arm = s.offsets[s.index("mixamorig:LeftForeArm")]
    assert arm[0] > 0 and np.allclose(arm[1:], 0)  # T-pose: the arm along +X


def test_unreal_bones_run_along_their_local_x_like_ue_skeletons():
    motion = rig("unreal")
    s = motion.skeleton
    assert s.names[:3] == ["root", "pelvis", "spine_01"]
    assert [n for n, c in zip(s.names, s.channels) if "Xposition" in c] == ["root", "pelvis"]
    np.testing.assert_allclose(motion.positions[0, 0], 0.0)  # the root on the floor
    not_identity = [j for j in range(1, s.num_joints) if not np.allclose(motion.rotations[0, j], np.eye(3))]
    assert len(not_identity) >= 10
    for j in range(1, s.num_joints):
        children = s.children(j)
        along = s.offsets[children[0]] if children else s.end_sites[j]
        sign = -1.0 if s.names[j].endswith("_r") else 1.0  # right side mirrored: +X back to the parent
        assert sign * along[0] > 0 and np.allclose(along[1:], 0, atol=1e-9), s.names[j]
    # Proper rotations everywhere (mirrored joint frames stay right-handed).
    np.testing.assert_allclose(np.linalg.det(motion.rotations[0]), 1.0, atol=1e-12)


def test_smpl_rig_is_walkdiffs_smpl_skeleton():
    motion = rig("smpl")
    s = motion.skeleton
    assert s.names == list(smpl.NAMES) and np.array_equal(s.parents, smpl.PARENTS)
    assert s.channels[0] == smpl.ROOT_CHANNELS and all(c == smpl.JOINT_CHANNELS for c in s.channels[1:])
    assert s.num_joints == 24
