"""Left/right mirroring: the mirrored clip is the reflected, side-swapped motion on any skeleton.

"Body height" below is the range of the world Y coordinate over the skeleton's rest pose (all local
rotations identity), End Sites included: 23.9 units for Xia, 158.7 cm for ZEGGS.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest
import roma
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.kinematics import forward_kinematics, motion_world_positions
from walkdiff.motion.mirror import find_mirror_pairs, mirror, rest_corrections
from walkdiff.motion.skeleton import Motion, Skeleton

SIGN = {"x": np.array([-1.0, 1.0, 1.0]), "z": np.array([1.0, 1.0, -1.0])}
ROT6 = ("Zrotation", "Yrotation", "Xrotation")
POS6 = ("Xposition", "Yposition", "Zposition", *ROT6)
XIA_EVERY = 29  # every 29th of Xia's 572 sorted clips: 20 clips of all styles and contents
ZEGGS_TAKE = "067_Speech_2_x_1_0.bvh"


# ---------------------------------------------------------------------------------------------------
# Helpers


def _partner(skeleton: Skeleton) -> np.ndarray:
    partner = np.arange(skeleton.num_joints)
    for left, right in find_mirror_pairs(skeleton):
        partner[left], partner[right] = right, left
    return partner


def _world(motion: Motion) -> np.ndarray:
    """(F, J + E, 3) world positions of the joints, then of the End Sites in joint order."""
    positions, rotations = forward_kinematics(
        torch.tensor(motion.rotations),
        torch.tensor(motion.positions),
        motion.skeleton.parents,
        return_rotations=True,
    )
    ends = [
        positions[:, j] + rotations[:, j] @ torch.tensor(offset, dtype=torch.float64)
        for j, offset in sorted(motion.skeleton.end_sites.items())
    ]
    return torch.cat([positions, *(e[:, None] for e in ends)], dim=1).numpy()


def _point_partner(skeleton: Skeleton, partner: np.ndarray) -> np.ndarray:
    """`partner` extended to the End Sites of `_world` (an End Site goes with its joint)."""
    ends = sorted(skeleton.end_sites)
    slot = {j: skeleton.num_joints + i for i, j in enumerate(ends)}
    return np.concatenate([partner, np.array([slot[partner[j]] for j in ends], dtype=np.int64)])


def _errors(motion: Motion, mirrored: Motion, axis: str = "x") -> np.ndarray:
    """(F, J + E) distance of every mirrored joint and End Site from the true reflection M P[partner]."""
    target = (_world(motion) * SIGN[axis])[:, _point_partner(motion.skeleton, _partner(motion.skeleton))]
    return np.linalg.norm(_world(mirrored) - target, axis=-1)


def _rest(skeleton: Skeleton) -> np.ndarray:
    """(J + E, 3) world positions of the rest pose (every local rotation the identity)."""
    rest = Motion(skeleton, np.tile(np.eye(3), (1, skeleton.num_joints, 1, 1)), skeleton.offsets[None], 1.0)
    return _world(rest)[0]


def _height(skeleton: Skeleton) -> float:
    y = _rest(skeleton)[:, 1]
    return float(y.max() - y.min())


def _translated(skeleton: Skeleton) -> np.ndarray:
    translated = np.array([bool(skeleton.position_order(j)) for j in range(skeleton.num_joints)])
    translated[0] = True
    return translated


def _local_mirror(motion: Motion, axis: str = "x") -> Motion:
    """The previous method, for comparison: M R M on local rotations, swapped between partners."""
    sign, partner = SIGN[axis], _partner(motion.skeleton)
    rotations = motion.rotations[:, partner] * np.outer(sign, sign)
    positions = motion.positions[:, partner] * sign
    fixed = ~_translated(motion.skeleton)
    positions[:, fixed] = motion.skeleton.offsets[fixed]
    return replace(motion, rotations=rotations, positions=positions)


def _residual_bound(skeleton: Skeleton, axis: str = "x") -> np.ndarray:
    """(J + E,) bound on the mirror's error from bones that no rotation can match to their partner.

    The mirrored bone to child c of joint j lies W'[j] o[c] = M W[partner j] M Q[j] o[c] away from its
    parent, the reflected one M W[partner j] o[partner c]: they differ by |Q[j] o[c] - M o[partner c]|
    in every frame, and the errors add up along the chain (translated joints are placed exactly).
    """
    sign, partner = SIGN[axis], _partner(skeleton)
    q = rest_corrections(skeleton, partner, axis)
    offsets, parents, translated = skeleton.offsets, skeleton.parents, _translated(skeleton)
    bound = np.zeros(skeleton.num_joints)
    for j in range(1, skeleton.num_joints):
        p = parents[j]
        if not translated[j]:
            bound[j] = bound[p] + np.linalg.norm(q[p] @ offsets[j] - sign * offsets[partner[j]])
    ends = [
        bound[j] + np.linalg.norm(q[j] @ e - sign * skeleton.end_sites[partner[j]])
        for j, e in sorted(skeleton.end_sites.items())
    ]
    return np.concatenate([bound, ends])


def _equal_lengths(motion: Motion) -> Motion:
    """The clip on its skeleton with every right bone scaled to its left partner's length.

    Bone directions are untouched, so a rest pose that is not mirror-symmetric stays so.
    """
    skeleton = motion.skeleton
    offsets = skeleton.offsets.copy()
    end_sites = {j: e.copy() for j, e in skeleton.end_sites.items()}
    for left, right in find_mirror_pairs(skeleton):
        length = np.linalg.norm(offsets[right])
        if length > 0:
            offsets[right] *= np.linalg.norm(offsets[left]) / length
        if right in end_sites and np.linalg.norm(end_sites[right]) > 0:
            end_sites[right] *= np.linalg.norm(end_sites[left]) / np.linalg.norm(end_sites[right])
    positions = motion.positions.copy()
    fixed = ~_translated(skeleton)
    positions[:, fixed] = offsets[fixed]
    skeleton = replace(skeleton, offsets=offsets, end_sites=end_sites)
    return replace(motion, skeleton=skeleton, positions=positions)


def _symmetrised(motion: Motion) -> Motion:
    """The clip on a left/right symmetric copy of its skeleton (right offsets = reflected left ones)."""
    offsets = motion.skeleton.offsets.copy()
    for left, right in find_mirror_pairs(motion.skeleton):
        offsets[right] = offsets[left] * SIGN["x"]
    middle = _partner(motion.skeleton) == np.arange(motion.skeleton.num_joints)
    offsets[middle, 0] = 0.0
    positions = motion.positions.copy()
    positions[:, 1:] = offsets[1:]
    return replace(motion, skeleton=replace(motion.skeleton, offsets=offsets), positions=positions)


def _rotation(rotvec) -> np.ndarray:
    return roma.rotvec_to_rotmat(torch.as_tensor(np.asarray(rotvec, dtype=np.float64))).numpy()


# A small humanoid with a three-fingered hand (a joint with several non-collinear children), End Sites,
# and shoulders that carry position channels. Left side only; the right side is its mirror image.
_LEFT_AND_CENTRE = [
    ("Hips", None, (0.0, 0.0, 0.0), None),
    ("LeftUpLeg", "Hips", (1.5, -1.0, 0.2), None),
    ("LeftLeg", "LeftUpLeg", (0.3, -7.0, 0.3), None),
    ("LeftFoot", "LeftLeg", (0.0, -7.0, -0.2), None),
    ("LeftToe", "LeftFoot", (0.1, -0.5, 2.3), (0.0, 0.0, 1.0)),
    ("Spine", "Hips", (0.0, 2.0, 0.1), None),
    ("Chest", "Spine", (0.0, 3.0, -0.2), None),
    ("Neck", "Chest", (0.0, 2.0, 0.1), None),
    ("Head", "Neck", (0.0, 1.5, 0.3), (0.0, 1.8, 0.0)),
    ("LeftShoulder", "Chest", (1.0, 1.5, 0.0), None),
    ("LeftArm", "LeftShoulder", (2.0, 0.2, 0.0), None),
    ("LeftForeArm", "LeftArm", (4.5, 0.0, -0.1), None),
    ("LeftHand", "LeftForeArm", (4.0, 0.0, 0.0), None),
    ("LeftThumb", "LeftHand", (0.5, 0.0, 0.8), (0.6, 0.0, 0.3)),
    ("LeftIndex", "LeftHand", (1.2, 0.1, 0.4), (0.8, 0.0, 0.0)),
    ("LeftPinky", "LeftHand", (1.0, 0.0, -0.5), (0.6, 0.0, 0.0)),
]


def _humanoid(right_scale: float = 1.0) -> Skeleton:
    """Depth-first: hips, left leg, right leg, spine to head, left arm, right arm."""
    legs, arms = _LEFT_AND_CENTRE[1:5], _LEFT_AND_CENTRE[9:]

    def right(side):
        return [
            (
                n.replace("Left", "Right"),
                p.replace("Left", "Right"),
                tuple(np.multiply(o, SIGN["x"]) * right_scale),
                None if e is None else tuple(np.multiply(e, SIGN["x"]) * right_scale),
            )
            for n, p, o, e in side
        ]

    rows = _LEFT_AND_CENTRE[0:1] + legs + right(legs) + _LEFT_AND_CENTRE[5:9] + arms + right(arms)
    names = [r[0] for r in rows]
    return Skeleton(
        names=names,
        parents=np.array([-1 if r[1] is None else names.index(r[1]) for r in rows]),
        offsets=np.array([r[2] for r in rows], dtype=np.float64),
        channels=[POS6 if i == 0 or "Shoulder" in n else ROT6 for i, n in enumerate(names)],
        end_sites={i: np.array(r[3], dtype=np.float64) for i, r in enumerate(rows) if r[3] is not None},
    )


def _random_motion(skeleton: Skeleton, frames: int = 40, seed: int = 0) -> Motion:
    rng = np.random.default_rng(seed)
    rotations = _rotation(rng.normal(0.0, 0.6, (frames, skeleton.num_joints, 3)))
    positions = np.repeat(skeleton.offsets[None], frames, axis=0)
    positions[:, 0] = [0.0, 16.0, 0.0] + np.cumsum(rng.normal(0.0, 0.3, (frames, 3)), axis=0)
    shoulders = [j for j, n in enumerate(skeleton.names) if "Shoulder" in n]
    positions[:, shoulders] += rng.normal(0.0, 0.3, (frames, len(shoulders), 3))
    return Motion(skeleton, rotations, positions, 1.0 / 30)


def _reframed(motion: Motion, frames: dict[str, np.ndarray]) -> Motion:
    """The same world motion on a skeleton whose joint k has its local frame turned by frames[k].

    The children's offsets and translations (and the End Site) are re-expressed in the turned frame
    and the local rotations compensate, R'[k] = T[parent]^T R[k] T[k], so the world positions stay
    those of `motion`; the skeleton's rest pose is no longer mirror-symmetric.
    """
    skeleton = motion.skeleton
    turn = np.tile(np.eye(3), (skeleton.num_joints, 1, 1))
    for name, t in frames.items():
        turn[skeleton.index(name)] = t
    parent_turn = turn[skeleton.parents]
    parent_turn[0] = np.eye(3)
    back = parent_turn.transpose(0, 2, 1)
    rotations = back @ motion.rotations @ turn
    positions = np.einsum("jab,fjb->fja", back, motion.positions)
    skeleton = replace(
        skeleton,
        offsets=np.einsum("jab,jb->ja", back, skeleton.offsets),
        end_sites={j: turn[j].T @ e for j, e in skeleton.end_sites.items()},
    )
    return Motion(skeleton, rotations, positions, motion.frame_time)


def _asymmetric(right_scale: float = 1.0, seed: int = 0) -> Motion:
    """Random motion on the humanoid, re-expressed with asymmetric local frames.

    The right leg's frames are turned by 40 degrees about each joint's own bone, the whole left arm
    chain (hand with its fingers included) by large random rotations, and the chest (a centre joint)
    is yawed and rolled.
    """
    motion = _random_motion(_humanoid(right_scale), seed=seed)
    skeleton = motion.skeleton
    frames = {}
    for name in ("RightUpLeg", "RightLeg", "RightFoot", "RightToe"):
        bone = skeleton.offsets[skeleton.index(name)]
        frames[name] = _rotation(np.radians(40.0) * bone / np.linalg.norm(bone))
    rng = np.random.default_rng(seed + 100)
    for name in ("LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand", "LeftThumb", "LeftIndex"):
        axis = rng.normal(size=3)
        frames[name] = _rotation(rng.uniform(0.5, 2.5) * axis / np.linalg.norm(axis))
    frames["Chest"] = _rotation([0.1, 0.6, 0.3])
    return _reframed(motion, frames)


def _centre_asymmetry(skeleton: Skeleton, axis: str = "x") -> float:
    """max |Q - M Q^T M| over the centre-line joints."""
    partner = _partner(skeleton)
    q = rest_corrections(skeleton, partner, axis)
    centre = partner == np.arange(skeleton.num_joints)
    flip = np.outer(SIGN[axis], SIGN[axis])
    return float(np.abs(q[centre] - q[centre].transpose(0, 2, 1) * flip).max())


def _assert_twice_is_identity(motion: Motion, axis: str = "x") -> None:
    twice = mirror(mirror(motion, axis=axis), axis=axis)
    np.testing.assert_allclose(twice.rotations, motion.rotations, rtol=0, atol=1e-8)
    np.testing.assert_allclose(twice.positions, motion.positions, rtol=0, atol=1e-8)


# ---------------------------------------------------------------------------------------------------
# Real clips


def _xia_clip(xia_dir, index: int) -> Motion:
    return read_bvh(sorted(xia_dir.glob("*.bvh"))[index * XIA_EVERY])


@pytest.mark.parametrize("index", range(20))
def test_mirror_xia_clips(xia_dir, index):
    _check_real_clip(_xia_clip(xia_dir, index))


def test_mirror_zeggs(zeggs_dir):
    motion = read_bvh(zeggs_dir / ZEGGS_TAKE).slice(0, 300)
    assert motion.skeleton.num_joints == 75
    assert len(find_mirror_pairs(motion.skeleton)) == 33
    _check_real_clip(motion)


def _check_real_clip(motion: Motion) -> None:
    """Twice is the identity; the only error left is that of bones longer on one side than the other.

    Real skeletons are not symmetric: Xia's right shin is 0.28 units (1.2% of body height) longer than
    its left one, ZEGGS's right forearm 2.9 cm (1.8%) shorter. A mirror that keeps the skeleton's bone
    offsets cannot close such a gap, so the reflection is checked exactly on the clip with each right
    bone scaled to its partner's length (rest directions untouched), and on the clip itself every
    joint must lie within the bone-length bound of `_residual_bound`.
    """
    height = _height(motion.skeleton)
    _assert_twice_is_identity(motion)
    _assert_twice_is_identity(motion, axis="z")

    equal = _equal_lengths(motion)
    assert _errors(equal, mirror(equal)).max() < 1e-9 * height
    assert _errors(equal, mirror(equal, axis="z"), axis="z").max() < 1e-9 * height

    errors = _errors(motion, mirror(motion))
    print(
        f"mirror vs reflection: mean {errors.mean() / height:.2%}, max {errors.max() / height:.2%} of height"
    )
    assert (errors.max(axis=0) <= _residual_bound(motion.skeleton) + 1e-9 * height).all()
    assert errors.max() < 0.025 * height
    assert errors.max() <= _errors(motion, _local_mirror(motion)).max() + 1e-9 * height


def test_mirror_centre_corrections_are_symmetric(xia_dir, zeggs_dir):
    """Q = M Q^T M on the centre line, which mirroring twice relies on, holds by symmetry of Kabsch."""
    for skeleton in (_xia_clip(xia_dir, 0).skeleton, read_bvh(zeggs_dir / ZEGGS_TAKE).skeleton):
        assert _centre_asymmetry(skeleton) < 1e-12
    skeleton = _asymmetric().skeleton
    chest = skeleton.index("Chest")
    for axis in ("x", "z"):
        q = rest_corrections(skeleton, _partner(skeleton), axis)
        assert np.abs(q[chest] - np.eye(3)).max() > 0.3  # a real correction, not the identity
        assert _centre_asymmetry(skeleton, axis) < 1e-12


def test_mirror_symmetric_skeleton_is_the_local_mirror(xia_dir, tmp_path):
    """On a symmetric skeleton every correction is the identity: old and new method agree, exactly."""
    motion = _symmetrised(read_bvh(xia_dir / "neutral_03_000.bvh"))
    mirrored = mirror(motion)
    np.testing.assert_allclose(mirrored.rotations, _local_mirror(motion).rotations, rtol=0, atol=1e-12)
    assert _errors(motion, mirrored).max() < 1e-9
    # The mirrored clip is a valid clip of the original skeleton: it survives a BVH round trip.
    write_bvh(tmp_path / "mirrored.bvh", mirror(read_bvh(xia_dir / "neutral_03_000.bvh")))
    np.testing.assert_allclose(
        motion_world_positions(read_bvh(tmp_path / "mirrored.bvh")),
        motion_world_positions(mirror(read_bvh(xia_dir / "neutral_03_000.bvh"))),
        atol=1e-3,
    )


FEET = ("LeftFoot", "LeftToeBase", "RightFoot", "RightToeBase")


def _contacts(motion: Motion) -> np.ndarray:
    """(F, 4) bool: Xia's heel and toe joints slower than 5 units/s and within 0.5 units of their floor.

    The floor of a joint is its 5th height percentile over the clip (Xia's two feet do not reach the
    same height: the skeleton is not symmetric).
    """
    feet = motion_world_positions(motion)[:, [motion.skeleton.index(n) for n in FEET]]
    speed = np.linalg.norm(np.diff(feet, axis=0), axis=-1) * motion.fps
    speed = np.concatenate([speed, speed[-1:]])
    height = feet[..., 1] - np.percentile(feet[..., 1], 5.0, axis=0)
    return (speed < 5.0) & (height < 0.5)


def test_mirror_swaps_foot_contacts(xia_dir):
    """Contacts of mirrored walks: the mirror's left foot is planted when the original's right foot was.

    Every 10th of Xia's walking clips (contents 01-12; 28 clips, 5103 frames). On Xia's own skeleton the
    mirrored left leg is the (shorter) left leg moving like the right one, so a few frames at the edge
    of a threshold flip; with the bone lengths made equal the contacts swap exactly.
    """
    walks = [p for p in sorted(xia_dir.glob("*.bvh")) if int(p.stem.split("_")[1]) <= 12][::10]
    agree, differ, frames = np.zeros(4), 0, 0
    for path in walks:
        motion = read_bvh(path)
        contacts = _contacts(motion)  # left heel, left toe, right heel, right toe
        swapped = _contacts(mirror(motion))[:, [2, 3, 0, 1]]
        agree += (swapped == contacts).sum(axis=0)
        differ += (contacts[:, :2] != contacts[:, 2:]).any(axis=1).sum()
        frames += motion.num_frames
        equal = _equal_lengths(motion)
        np.testing.assert_array_equal(_contacts(mirror(equal))[:, [2, 3, 0, 1]], _contacts(equal))
    assert len(walks) == 28
    assert differ > 0.2 * frames  # the feet are often in different states, so a missed swap shows
    assert (agree / frames >= 0.99).all(), agree / frames


def test_find_mirror_pairs_of_xia(xia_dir):
    skeleton = _xia_clip(xia_dir, 0).skeleton
    names = {(skeleton.names[a], skeleton.names[b]) for a, b in find_mirror_pairs(skeleton)}
    assert {("LHipJoint", "RHipJoint"), ("LeftUpLeg", "RightUpLeg"), ("LThumb", "RThumb")} <= names
    assert len(names) == 12
    assert all(n.startswith(("Left", "L")) and not n.startswith("Lower") for n, _ in names)


def test_mirror_is_fast(xia_dir):
    motion = _xia_clip(xia_dir, 0)
    frames = np.arange(377) % motion.num_frames
    motion = replace(motion, rotations=motion.rotations[frames], positions=motion.positions[frames])
    assert motion.skeleton.num_joints == 31
    best = np.inf
    for _ in range(3):
        start = time.perf_counter()
        mirror(motion)
        best = min(best, time.perf_counter() - start)
    assert best < 0.05


# ---------------------------------------------------------------------------------------------------
# Synthetic skeletons


@pytest.mark.parametrize("axis", ["x", "z"])
def test_mirror_asymmetric_rest_pose(axis):
    """Local frames that are not mirror images: the local mirror is far off, the new one exact."""
    motion = _asymmetric()
    height = _height(motion.skeleton)
    rest = _rest(motion.skeleton)
    left, right = motion.skeleton.index("LeftToe"), motion.skeleton.index("RightToe")
    assert np.linalg.norm(rest[left] * SIGN["x"] - rest[right]) > 1.0  # the rest pose is asymmetric

    assert _errors(motion, _local_mirror(motion, axis), axis).max() > 0.2 * height
    assert _errors(motion, mirror(motion, axis=axis), axis).max() < 1e-6
    _assert_twice_is_identity(motion, axis)


def test_mirror_unequal_bone_lengths():
    """Right bones 1% longer than the left ones (and asymmetric frames): within 1% of body height."""
    motion = _asymmetric(right_scale=1.01, seed=1)
    height = _height(motion.skeleton)
    errors = _errors(motion, mirror(motion))
    assert 1e-4 * height < errors.max() < 0.01 * height
    # Joints with position channels are placed exactly, whatever the bones above them.
    shoulders = [motion.skeleton.index(n) for n in ("LeftShoulder", "RightShoulder")]
    assert errors[:, shoulders].max() < 1e-9
    _assert_twice_is_identity(motion)


def test_mirror_translated_joints_keep_their_channels():
    motion = _asymmetric()
    mirrored = mirror(motion)
    fixed = ~_translated(motion.skeleton)
    np.testing.assert_array_equal(
        mirrored.positions[:, fixed],
        np.broadcast_to(motion.skeleton.offsets[fixed], mirrored.positions[:, fixed].shape),
    )
    shoulder = motion.skeleton.index("LeftShoulder")
    assert np.abs(mirrored.positions[:, shoulder] - motion.skeleton.offsets[shoulder]).max() > 0.1


def _named_skeleton(centre: list[str], left: list[str], right: list[str]) -> Skeleton:
    """root = centre[0]; the other centre joints form a spine, left and right a leg each."""
    names, parents, offsets = [centre[0]], [-1], [[0.0, 0.0, 0.0]]
    for side, x in ((left, 1.0), (right, -1.0)):
        for i, name in enumerate(side):
            names.append(name)
            parents.append(0 if i == 0 else len(names) - 2)
            offsets.append([x * (1.0 if i == 0 else 0.2), -3.0 if i else -0.5, 0.1 * i])
    for i, name in enumerate(centre[1:]):
        names.append(name)
        parents.append(0 if i == 0 else len(names) - 2)
        offsets.append([0.0, 2.0, 0.1])
    return Skeleton(names, np.array(parents), np.array(offsets), [POS6] + [ROT6] * (len(names) - 1))


CONVENTIONS = {
    "cmu": (["Hips", "LowerBack", "Spine"], ["LHipJoint", "LeftUpLeg", "LeftFoot", "LThumb"]),
    "mixamo": (["mixamorig:Hips", "mixamorig:Spine"], ["mixamorig:LeftUpLeg", "mixamorig:LeftFoot"]),
    "smpl": (["pelvis", "spine1", "spine2"], ["left_hip", "left_knee", "left_ankle"]),
    "smpl_caps": (["Pelvis", "Spine1", "Neck"], ["L_Hip", "L_Knee", "L_Ankle"]),
    "unreal": (["pelvis", "spine_01", "spine_02"], ["thigh_l", "calf_l", "foot_l"]),
    "game_caps": (["Root", "Spine"], ["Thigh_L", "Calf_L", "Foot_L"]),
    "blender": (["hips", "spine"], ["thigh.L", "shin.L", "foot.L", "hand.l"]),
    "daz": (["hip", "abdomenLower", "lowerJaw"], ["lThigh", "lShin", "lFoot"]),
    "biped": (["Bip01", "Bip01 Spine", "Bip01 Neck"], ["Bip01 L Thigh", "Bip01 L Calf", "Bip01 L Foot"]),
    "biped001": (["Bip001 Pelvis", "Bip001 Spine"], ["Bip001 L Thigh", "Bip001 L Foot"]),
}
RIGHT_SPELLING = {
    "cmu": ["RHipJoint", "RightUpLeg", "RightFoot", "RThumb"],
    "mixamo": ["mixamorig:RightUpLeg", "mixamorig:RightFoot"],
    "smpl": ["right_hip", "right_knee", "right_ankle"],
    "smpl_caps": ["R_Hip", "R_Knee", "R_Ankle"],
    "unreal": ["thigh_r", "calf_r", "foot_r"],
    "game_caps": ["Thigh_R", "Calf_R", "Foot_R"],
    "blender": ["thigh.R", "shin.R", "foot.R", "hand.r"],
    "daz": ["rThigh", "rShin", "rFoot"],
    "biped": ["Bip01 R Thigh", "Bip01 R Calf", "Bip01 R Foot"],
    "biped001": ["Bip001 R Thigh", "Bip001 R Foot"],
}


@pytest.mark.parametrize("convention", list(CONVENTIONS))
def test_name_conventions(convention):
    centre, left = CONVENTIONS[convention]
    right = RIGHT_SPELLING[convention]
    skeleton = _named_skeleton(centre, left, right)
    found = {(skeleton.names[a], skeleton.names[b]) for a, b in find_mirror_pairs(skeleton)}
    assert found == set(zip(left, right))
    motion = _random_motion(skeleton, frames=5)
    assert _errors(motion, mirror(motion)).max() < 1e-9
    _assert_twice_is_identity(motion)


def test_mirror_without_pairs_is_refused():
    skeleton = _named_skeleton(["Hips", "Spine", "Head"], ["UpLegA", "FootA"], ["UpLegB", "FootB"])
    assert find_mirror_pairs(skeleton) == []
    motion = _random_motion(skeleton, frames=3)
    with pytest.raises(WalkdiffError, match="no left/right joint pairs found by name.*turn mirroring off"):
        mirror(motion)
    with pytest.raises(WalkdiffError, match="no left/right joint pairs"):
        mirror(motion, pairs=[])
    with pytest.raises(WalkdiffError, match="no left/right joint pairs"):
        mirror(motion, partner=np.arange(skeleton.num_joints))


def test_mirror_explicit_pairs_partner_and_bad_input():
    skeleton = Skeleton(
        ["root", "arm_a", "hand_a", "arm_b", "hand_b"],
        [-1, 0, 1, 0, 3],
        [[0, 0, 0], [1, 0, 0], [1, 0, 0], [-1, 0, 0], [-1, 0, 0]],
        [POS6] + [("Zrotation",)] * 4,
    )
    assert find_mirror_pairs(skeleton) == []
    rotations = roma.random_rotmat((3, 5), dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    positions = np.repeat(skeleton.offsets[None], 3, axis=0)
    motion = Motion(skeleton, rotations.numpy(), positions, 0.1)
    mirrored = mirror(motion, pairs=[("arm_a", "arm_b"), ("hand_a", "hand_b")])
    world = motion_world_positions(motion)
    np.testing.assert_allclose(motion_world_positions(mirrored), (world * SIGN["x"])[:, [0, 3, 4, 1, 2]])
    by_index = mirror(motion, partner=np.array([0, 3, 4, 1, 2]))
    np.testing.assert_array_equal(by_index.rotations, mirrored.rotations)
    np.testing.assert_array_equal(by_index.positions, mirrored.positions)

    with pytest.raises(WalkdiffError, match="two joints of the skeleton"):
        mirror(motion, pairs=[("arm_a", "leg")])
    with pytest.raises(WalkdiffError, match="do not match the hierarchy"):
        mirror(motion, pairs=[("arm_a", "hand_b")])
    with pytest.raises(WalkdiffError, match="more than one pair"):
        mirror(motion, pairs=[("arm_a", "arm_b"), ("arm_a", "hand_b")])
    with pytest.raises(WalkdiffError, match="mirror axis"):
        mirror(motion, axis="w")
    with pytest.raises(WalkdiffError, match="do not match the hierarchy"):
        mirror(motion, partner=np.array([0, 4, 3, 2, 1]))
    with pytest.raises(WalkdiffError, match="more than one pair"):
        mirror(motion, partner=np.array([0, 3, 4, 3, 2]))
    with pytest.raises(WalkdiffError, match="joint indices"):
        mirror(motion, partner=np.array([0, 3, 4]))
    with pytest.raises(WalkdiffError, match="either pairs or partner"):
        mirror(motion, pairs=[("arm_a", "arm_b")], partner=np.array([0, 3, 4, 1, 2]))
