"""The humanoid map (`walkdiff.motion.humanoid`): roles found by name over every naming convention it
claims, by the hierarchy's shape when names say nothing, from overrides; rigs without limbs refused.

Rigs are Xia's real CMU skeleton (and ZEGGS's) renamed: the right answer is always Xia's own map."""

from __future__ import annotations

import re

import disguise
import numpy as np
import pytest

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.humanoid import SINGLE_ROLES, HumanoidMap, humanoid_map, read_name
from walkdiff.motion.posed_frames import subtree
from walkdiff.motion.skeleton import Motion, Skeleton

XIA_ROLES = {
    "pelvis": "Hips", "neck": "Neck", "head": "Head",
    "left_clavicle": "LeftShoulder", "left_upper_arm": "LeftArm", "left_forearm": "LeftForeArm",
    "left_hand": "LeftHand", "left_thigh": "LeftUpLeg", "left_shin": "LeftLeg", "left_foot": "LeftFoot",
    "left_toe": "LeftToeBase",
    "right_clavicle": "RightShoulder", "right_upper_arm": "RightArm", "right_forearm": "RightForeArm",
    "right_hand": "RightHand", "right_thigh": "RightUpLeg", "right_shin": "RightLeg",
    "right_foot": "RightFoot", "right_toe": "RightToeBase",
}  # fmt: skip

# Xia's joints in other conventions, built by hand: centre joints, then the parts of a side (the side
# written by `SIDED`). Keys: Xia's names without their side.
CENTRE = {
    "unity": dict(Hips="Hips", LowerBack="Spine", Spine="Chest", Spine1="UpperChest", Neck="Neck",
                  Neck1="NeckTwist", Head="Head"),
    "suffix_L": dict(Hips="Pelvis", LowerBack="Spine_01", Spine="Spine_02", Spine1="Chest", Neck="Neck",
                     Neck1="Neck_02", Head="Head"),
    "prefix_L": dict(Hips="Pelvis", LowerBack="Spine1", Spine="Spine2", Spine1="Spine3", Neck="Neck",
                     Neck1="Neck2", Head="Head"),
    "blender": dict(Hips="hips", LowerBack="spine", Spine="spine.001", Spine1="chest", Neck="neck",
                    Neck1="neck.001", Head="head"),
    "daz": dict(Hips="hip", LowerBack="abdomenLower", Spine="abdomenUpper", Spine1="chestUpper",
                Neck="neckLower", Neck1="neckUpper", Head="head"),
    "biped": dict(Hips="Bip01 Pelvis", LowerBack="Bip01 Spine", Spine="Bip01 Spine1", Spine1="Bip01 Spine2",
                  Neck="Bip01 Neck", Neck1="Bip01 Neck1", Head="Bip01 Head"),
}  # fmt: skip
PARTS = {  # HipJoint, UpLeg, Leg, Foot, ToeBase, Shoulder, Arm, ForeArm, Hand, FingerBase, HandIndex1, Thumb
    "unity": ("HipRoot", "UpperLeg", "LowerLeg", "Foot", "Toes", "Shoulder", "UpperArm", "LowerArm", "Hand",
              "IndexProximal", "IndexIntermediate", "ThumbProximal"),
    "suffix_L": ("HipRoot", "Thigh", "Calf", "Foot", "Toe", "Clavicle", "UpperArm", "ForeArm", "Hand",
                 "Index1", "Index2", "Thumb1"),
    "prefix_L": ("Pelvis", "Hip", "Knee", "Ankle", "Foot", "Collar", "Shoulder", "Elbow", "Wrist",
                 "Index1", "Index2", "Thumb1"),
    "blender": ("pelvis", "thigh", "shin", "foot", "toe", "shoulder", "upper_arm", "forearm", "hand",
                "f_index.01", "f_index.02", "thumb.01"),
    "daz": ("Pelvis", "ThighBend", "Shin", "Foot", "Toe", "Collar", "ShldrBend", "ForearmBend", "Hand",
            "Index1", "Index2", "Thumb1"),
    "biped": ("HipRoot", "Thigh", "Calf", "Foot", "Toe0", "Clavicle", "UpperArm", "Forearm", "Hand",
              "Finger1", "Finger11", "Finger0"),
}  # fmt: skip
XIA_PARTS = ("HipJoint", "UpLeg", "Leg", "Foot", "ToeBase", "Shoulder", "Arm", "ForeArm", "Hand",
             "FingerBase", "HandIndex1", "Thumb")  # fmt: skip
SIDED = {  # how each convention writes a side onto a part
    "unity": lambda side, part: f"{side.capitalize()}{part}",
    "suffix_L": lambda side, part: f"{part}_{side[0].upper()}",
    "prefix_L": lambda side, part: f"{side[0].upper()}_{part}",
    "blender": lambda side, part: f"{part}.{side[0].upper()}",
    "daz": lambda side, part: f"{side[0]}{part}",
    "biped": lambda side, part: f"Bip01 {side[0].upper()} {part}",
}


@pytest.fixture(scope="module")
def xia(xia_dir) -> Motion:
    return read_bvh(xia_dir / "neutral_01_000.bvh").slice(0, 60)


@pytest.fixture(scope="module")
def zeggs(zeggs_dir) -> Motion:
    return read_bvh(zeggs_dir / "067_Speech_2_x_1_0.bvh").slice(0, 30)


def renamed(motion: Motion, names: list[str]) -> Motion:
    s = motion.skeleton
    skeleton = Skeleton(names, s.parents.copy(), s.offsets.copy(), list(s.channels), dict(s.end_sites))
    return Motion(skeleton, motion.rotations, motion.positions, motion.frame_time)


def by_hand(motion: Motion, convention: str) -> tuple[Motion, dict[str, str]]:
    """Xia in a convention of `CENTRE` / `PARTS` / `SIDED`, and the mapping old name -> new name."""
    mapping = {}
    for name in motion.skeleton.names:
        if name in CENTRE[convention]:
            mapping[name] = CENTRE[convention][name]
            continue
        side, part = re.match(r"(Left|Right|L|R)(.+)", name).groups()
        side = "left" if side.startswith("L") else "right"
        mapping[name] = SIDED[convention](side, PARTS[convention][XIA_PARTS.index(part)])
    return renamed(motion, [mapping[n] for n in motion.skeleton.names]), mapping


def expected_roles(mapping: dict[str, str]) -> dict[str, str]:
    return {role: mapping[joint] for role, joint in XIA_ROLES.items()}


def without(motion: Motion, tops: list[str]) -> Motion:
    """The clip with the subtrees of `tops` removed."""
    s = motion.skeleton
    drop = {j for top in tops for j in subtree(s, s.index(top))}
    keep = [j for j in range(s.num_joints) if j not in drop]
    new = {j: i for i, j in enumerate(keep)}
    skeleton = Skeleton(
        [s.names[j] for j in keep],
        np.array([-1 if s.parents[j] < 0 else new[int(s.parents[j])] for j in keep]),
        s.offsets[keep],
        [s.channels[j] for j in keep],
        {new[j]: e for j, e in s.end_sites.items() if j in new},
    )
    return Motion(skeleton, motion.rotations[:, keep], motion.positions[:, keep], motion.frame_time)


# ---------------------------------------------------------------- by name


def test_reading_names_over_conventions():
    assert read_name("mixamorig:LeftUpLeg") == read_name("LeftUpLeg")
    assert (read_name("Bip01 L Calf").side, read_name("Bip01 L Calf").key) == ("left", "calf")
    assert (read_name("lShldrBend").side, read_name("lShldrBend").key) == ("left", "shldrbend")
    assert (read_name("upper_arm.R").side, read_name("upper_arm.R").key) == ("right", "upperarm")
    assert (read_name("LHipJoint").side, read_name("LHipJoint").key) == ("left", "hipjoint")
    assert read_name("thigh_twist_01_l").helper and read_name("HeadTop_End").helper
    assert not read_name("LowerBack").side and not read_name("Hips").side


def test_cmu_map_of_xia(xia):
    m = humanoid_map(xia)
    assert m.roles() == XIA_ROLES
    assert m.spine == ("LowerBack", "Spine", "Spine1")
    assert m.fingers == {
        "left_thumb": ("LThumb",), "left_index": ("LeftFingerBase", "LeftHandIndex1"),
        "right_thumb": ("RThumb",), "right_index": ("RightFingerBase", "RightHandIndex1"),
    }  # fmt: skip
    assert m.in_between(xia.skeleton) == ["Neck1", "LHipJoint", "RHipJoint"]
    assert m.unmapped(xia.skeleton) == []
    lines = m.describe(xia.skeleton)
    assert any(line.startswith("left_thigh") and "LeftUpLeg [name]" in line for line in lines)
    assert any(line.startswith("unmapped") and "(none)" in line for line in lines)


def test_zeggs_map_with_fingers_and_end_joints(zeggs):
    m = humanoid_map(zeggs)
    assert (m.pelvis, m.neck, m.head, m.left_hand, m.right_toe) == (
        "Hips",
        "Neck",
        "Head",
        "LeftHand",
        "RightToeBase",
    )
    assert m.spine == ("Spine", "Spine1", "Spine2", "Spine3")
    assert len(m.fingers) == 10 and m.fingers["right_pinky"][0] == "RightHandPinky1"
    unmapped = m.unmapped(zeggs.skeleton)
    assert "HeadEnd" in unmapped and "LeftForeArmEnd" in unmapped and "LeftHand" not in unmapped


@pytest.mark.parametrize("convention", disguise.CONVENTIONS)
def test_generated_conventions(xia, convention):
    """Mixamo (`mixamorig:LeftArm`), Unreal (`thigh_l`, `calf_l`, `ball_l`, and CMU's hip joint as
    `hip_l`, a helper) and SMPL (`left_hip` is the thigh, `left_shoulder` the upper arm, `left_foot` the
    toe) by `tests/disguise.py`."""
    motion, mapping = disguise.rename(xia, convention)
    m = humanoid_map(motion)
    assert m.roles() == expected_roles(mapping)
    assert m.spine == tuple(mapping[n] for n in ("LowerBack", "Spine", "Spine1"))


@pytest.mark.parametrize("convention", sorted(CENTRE))
def test_conventions_by_hand(xia, convention):
    """Unity humanoid, `_L` / `L_` / `.L` side marks, DAZ Genesis (`lThighBend`, `lShin`, `lCollar`,
    `lShldrBend`), 3ds Max Biped (`Bip01 L Thigh`, `Bip01 L Calf`, fingers `Finger0`... numbered)."""
    motion, mapping = by_hand(xia, convention)
    m = humanoid_map(motion)
    assert m.roles() == expected_roles(mapping)
    assert m.found["left_thigh"] == "name"
    assert m.fingers[f"left_{'index'}"] == (mapping["LeftFingerBase"], mapping["LeftHandIndex1"])
    assert m.fingers["right_thumb"] == (mapping["RThumb"],)


# ---------------------------------------------------------------- by the hierarchy


def test_unknown_names_are_mapped_by_the_hierarchy(xia, zeggs):
    """Joints named b00, b01, ...: limbs from symmetric chains, sides from where the toes point, on a
    Y-up CMU rig, the same rig Z-up, and ZEGGS (its head falls on the end joint above the head)."""
    for clip in (xia, disguise.z_up(xia), zeggs):
        names = clip.skeleton.names
        anonymous = renamed(clip, [f"b{j:02d}" for j in range(len(names))])
        m, truth = humanoid_map(anonymous), humanoid_map(clip)
        for role in SINGLE_ROLES:
            if role != "head":
                assert getattr(m, role) == f"b{names.index(getattr(truth, role)):02d}", role
        assert m.found["left_hand"] == "geometry"
        assert any("sides from the pose" in n for n in m.notes)


def test_names_decide_the_sides_the_hierarchy_found(xia):
    """Side marks alone (roles unknown): the hierarchy finds the limbs, the names their sides, even when
    the names contradict the pose (a rig whose 'left' is on the viewer's left)."""
    names = [
        f"{'Lf' if n.startswith('L') else 'Rt' if n.startswith('R') else 'C'}_{j}"
        for j, n in enumerate(xia.skeleton.names)
    ]
    swapped = [n.replace("Lf_", "X_").replace("Rt_", "L_").replace("X_", "R_") for n in names]
    m = humanoid_map(renamed(xia, swapped))
    assert m.left_hand == swapped[xia.skeleton.index("RightHand")]
    assert any("sides from names" in n for n in m.notes)


def test_rigs_without_limbs_are_refused(xia):
    with pytest.raises(
        WalkdiffError, match=r"no arms \(left_upper_arm, left_forearm, left_hand, right_upper_arm"
    ):
        humanoid_map(without(xia, ["LeftShoulder", "RightShoulder"]))
    with pytest.raises(WalkdiffError, match=r"no legs \(left_thigh, left_shin, left_foot, right_thigh"):
        humanoid_map(without(xia, ["LHipJoint", "RHipJoint"]))
    with pytest.raises(WalkdiffError, match=r"no arms \(left_upper_arm, left_forearm, left_hand\)"):
        humanoid_map(without(xia, ["LeftShoulder"]))


# ---------------------------------------------------------------- overrides


def test_overrides_win_and_are_checked(xia):
    m = humanoid_map(xia, {"left_hand": "LeftFingerBase", "neck": None, "left_index": []})
    assert m.left_hand == "LeftFingerBase" and m.found["left_hand"] == "config"
    assert m.neck is None and m.spine == ("LowerBack", "Spine", "Spine1", "Neck", "Neck1")
    assert "left_index" not in m.fingers
    again = humanoid_map(xia, humanoid_map(xia).to_dict())
    assert again.roles() == XIA_ROLES and again.spine == ("LowerBack", "Spine", "Spine1")
    with pytest.raises(WalkdiffError, match="unknown role.*left_elbow"):
        humanoid_map(xia, {"left_elbow": "LeftForeArm"})
    with pytest.raises(WalkdiffError, match="left_hand: expected a joint name of the skeleton, got 'Paw'"):
        humanoid_map(xia, {"left_hand": "Paw"})
    with pytest.raises(WalkdiffError, match="left_hand: expected a joint name"):
        humanoid_map(xia, {"left_hand": None})  # a hand is not optional
    with pytest.raises(WalkdiffError, match="'LeftArm' is not below 'LeftForeArm'"):
        humanoid_map(xia, {"left_upper_arm": "LeftForeArm", "left_forearm": "LeftArm"})
    spine = (
        r"spine: expected the joints between the pelvis and the neck \(LowerBack, Spine, Spine1\), got Spine"
    )
    with pytest.raises(WalkdiffError, match=spine):
        humanoid_map(xia, {"spine": ["Spine"]})
    with pytest.raises(WalkdiffError, match="left_index: expected a chain .* 'LThumb' is not"):
        humanoid_map(xia, {"left_index": ["LeftFingerBase", "LThumb"]})
    with pytest.raises(WalkdiffError, match="joint 'LeftArm' is both left_clavicle and left_upper_arm"):
        humanoid_map(xia, {"left_clavicle": "LeftArm"})
    assert isinstance(m, HumanoidMap)
