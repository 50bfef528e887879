"""Retargeting (`walkdiff.motion.retarget`) on tests that know the answer.

- A copy of Xia's own skeleton with another rest pose (arms from T to A pose, legs spread and bent),
  every local frame turned at random (the motion compensated), Z up, other units, another rotation
  order, Unreal names and a static root: the clip must come back with the source's world joint
  positions, and go back again (A -> B -> A).
- Copies with other proportions (legs 0.8x and 1.25x, arms 1.2x, two spine joints inserted): bone
  directions, hand and foot orientation, the root's path scaled by the leg ratio, feet planted.
- Real pairs: Xia onto the ZEGGS skeleton (its first frame as the target's rest) and back, ZEGGS onto Xia.
- Rest poses that are no pose (every bone along one axis), a partial map (no fingers, one spine joint),
  and speed.

Positions are compared in body heights (Xia: 24.13 units), directions in degrees.
"""

from __future__ import annotations

import time

import disguise
import numpy as np
import pytest
import roma
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.metrics.physics import skating_sums
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.humanoid import SIDES, humanoid_map
from walkdiff.motion.posed_frames import subtree
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import foot_contacts
from walkdiff.motion.rest_alignment import forward_kinematics_np
from walkdiff.motion.retarget import Retargeter, retarget
from walkdiff.motion.rotations import euler_to_matrix
from walkdiff.motion.skeleton import Motion, Skeleton

HEIGHT = 24.13  # Xia's body height, units
# Bones (role to role) whose world direction must follow the source's; the legs' two long bones are
# bent by the foot IK when the proportions differ, and checked without it.
BONES = [
    ("left_clavicle", "left_upper_arm"), ("left_upper_arm", "left_forearm"), ("left_forearm", "left_hand"),
    ("left_foot", "left_toe"), ("neck", "head"), ("pelvis", "neck"), ("left_thigh", "right_thigh"),
    ("left_upper_arm", "right_upper_arm"),
]  # fmt: skip
BONES += [(a.replace("left", "right"), b.replace("left", "right")) for a, b in BONES if "right" not in b]
LEGS = [(f"{s}_{a}", f"{s}_{b}") for s in SIDES for a, b in (("thigh", "shin"), ("shin", "foot"))]


@pytest.fixture(scope="module")
def xia(xia_dir) -> Motion:
    return read_bvh(xia_dir / "strutting_08_002.bvh").slice(0, 120)


@pytest.fixture(scope="module")
def zeggs(zeggs_dir) -> Motion:
    return read_bvh(zeggs_dir / "067_Speech_2_x_1_0.bvh")


# ---------------------------------------------------------------- rigs that know the answer


def reframe(motion: Motion, turns: np.ndarray) -> Motion:
    """Every joint's local frame turned by `turns[j]` (J, 3, 3), the motion compensated: the same world
    joint positions, world rotations W @ turns, offsets and rest pose turned with the frames."""
    s = motion.skeleton
    up = np.concatenate([np.eye(3)[None], turns[s.parents[1:]]])  # each joint's parent's turn
    back = np.swapaxes(up, -1, -2)
    rotations = back @ motion.rotations @ turns
    rotations[:, 0] = motion.rotations[:, 0] @ turns[0]
    positions = motion.positions.copy()
    positions[:, 1:] = (back[1:] @ positions[:, 1:, :, None])[..., 0]
    offsets = s.offsets.copy()
    offsets[1:] = (back[1:] @ offsets[1:, :, None])[..., 0]
    ends = {j: turns[j].T @ np.asarray(e) for j, e in s.end_sites.items()}
    skeleton = Skeleton(list(s.names), s.parents.copy(), offsets, list(s.channels), ends)
    return Motion(skeleton, rotations, positions, motion.frame_time)


def about(axis: str, degrees: float) -> np.ndarray:
    return euler_to_matrix(np.array([degrees]), axis)


def reposed(motion: Motion) -> Motion:
    """Arms from the T to an A pose (45 degrees down), legs spread 10 and bent forward 15 degrees at rest."""
    s = motion.skeleton
    turns = np.repeat(np.eye(3)[None], s.num_joints, axis=0)
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        for j in subtree(s, s.index(f"{side}Arm")):
            turns[j] = about("Z", -45.0 * sign).T
        for j in subtree(s, s.index(f"{side}UpLeg")):
            turns[j] = (about("X", 15.0) @ about("Z", 10.0 * sign)).T
    return reframe(motion, turns)


def random_frames(motion: Motion, seed: int = 0) -> Motion:
    """Every local frame turned at random: the rest pose becomes a crumpled heap (no pose at all)."""
    q = np.random.default_rng(seed).normal(size=(motion.skeleton.num_joints, 4))
    return reframe(
        motion, roma.unitquat_to_rotmat(torch.tensor(q / np.linalg.norm(q, axis=1)[:, None])).numpy()
    )


def scaled(skeleton: Skeleton, joints, factor: float) -> Skeleton:
    """The bones into `joints` (and their End Sites) `factor` times as long."""
    offsets, ends = skeleton.offsets.copy(), {j: np.array(e) for j, e in skeleton.end_sites.items()}
    for j in (skeleton.index(n) for n in joints):
        offsets[j] *= factor
        if j in ends:
            ends[j] *= factor
    return Skeleton(list(skeleton.names), skeleton.parents.copy(), offsets, list(skeleton.channels), ends)


def legs(skeleton: Skeleton, factor: float) -> Skeleton:
    return scaled(
        skeleton, [f"{s}{p}" for s in ("Left", "Right") for p in ("Leg", "Foot", "ToeBase")], factor
    )


def arms(skeleton: Skeleton, factor: float) -> Skeleton:
    below = [j for s in ("Left", "Right") for j in subtree(skeleton, skeleton.index(f"{s}Arm"))[1:]]
    return scaled(skeleton, [skeleton.names[j] for j in below], factor)


def inserted(skeleton: Skeleton, child: str, name: str) -> Skeleton:
    """A new joint `name` halfway along the bone into `child`."""
    c = skeleton.index(child)
    renumber = [j if j < c else j + 1 for j in range(skeleton.num_joints)]
    parents = [-1 if p < 0 else renumber[p] for p in skeleton.parents]
    parents.insert(c, parents[c])
    parents[c + 1] = c
    offsets = list(skeleton.offsets)
    offsets[c] = offsets[c] / 2
    offsets.insert(c, offsets[c].copy())
    channels = list(skeleton.channels)
    channels.insert(c, ("Zrotation", "Yrotation", "Xrotation"))
    ends = {renumber[j]: e for j, e in skeleton.end_sites.items()}
    names = list(skeleton.names)
    names.insert(c, name)
    return Skeleton(names, np.array(parents), np.array(offsets), channels, ends)


def longer_spine(skeleton: Skeleton) -> Skeleton:
    return inserted(inserted(skeleton, "Spine", "SpineMid0"), "Spine1", "SpineMid1")


def merged(skeleton: Skeleton, drop: list[str]) -> Skeleton:
    """Joints `drop` taken out of the rest pose: their children hang from their parents (offsets added);
    a dropped leaf goes with its bone."""
    keep = [j for j, n in enumerate(skeleton.names) if n not in drop]
    new = {j: i for i, j in enumerate(keep)}
    parents, offsets = [], []
    for j in keep:
        p, offset = int(skeleton.parents[j]), skeleton.offsets[j].copy()
        while p >= 0 and skeleton.names[p] in drop:
            offset, p = offset + skeleton.offsets[p], int(skeleton.parents[p])
        parents.append(-1 if p < 0 else new[p])
        offsets.append(offset)
    ends = {new[j]: e for j, e in skeleton.end_sites.items() if j in new}
    return Skeleton(
        [skeleton.names[j] for j in keep],
        np.array(parents),
        np.array(offsets),
        [skeleton.channels[j] for j in keep],
        ends,
    )


# ---------------------------------------------------------------- measures


def world(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    return forward_kinematics_np(motion.rotations, motion.positions, motion.skeleton.parents)


def position_error(a: Motion, b: Motion, height: float = HEIGHT) -> np.ndarray:
    """(F, J) distances between the same joints of two clips, in body heights."""
    pa, pb = world(a)[0], world(b)[0]
    names = [n for n in a.skeleton.names if n in b.skeleton.names]
    ia, ib = [a.skeleton.index(n) for n in names], [b.skeleton.index(n) for n in names]
    return np.linalg.norm(pa[:, ia] - pb[:, ib], axis=-1) / height


def degrees(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def canonical_points(motion: Motion) -> np.ndarray:
    return world(motion)[0] @ SkeletonProfile.detect(motion.slice(0, 1)).turn.T


def bone_errors(source: Motion, target: Motion, bones=BONES) -> np.ndarray:
    """(F, bones) angles between the world directions of the same role-to-role bones (canonical axes)."""
    ms, mt = humanoid_map(source), humanoid_map(target)
    ps, pt = canonical_points(source), canonical_points(target)
    out = []
    for a, b in bones:
        js = [source.skeleton.index(ms.joint(r)) for r in (a, b)]
        jt = [target.skeleton.index(mt.joint(r)) for r in (a, b)]
        out.append(degrees(pt[:, jt[1]] - pt[:, jt[0]], ps[:, js[1]] - ps[:, js[0]]))
    return np.stack(out, axis=1)


def turn_degrees(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles of the rotations taking each of `b` (..., 3, 3) to `a`."""
    trace = np.trace(a @ np.swapaxes(b, -1, -2), axis1=-2, axis2=-1)
    return np.degrees(np.arccos(np.clip((trace - 1) / 2, -1.0, 1.0)))


def sides_kept(source: Motion, target: Motion, ratio: float) -> bool:
    """Every left hand and foot of the target nearer the source's same joint (scaled) than the other's."""
    ms, mt = humanoid_map(source), humanoid_map(target)
    ps, pt = canonical_points(source) * ratio, canonical_points(target)
    for part in ("hand", "foot"):
        for side, other in (("left", "right"), ("right", "left")):
            t = pt[:, target.skeleton.index(mt.joint(f"{side}_{part}"))]
            same, swapped = (ps[:, source.skeleton.index(ms.joint(f"{s}_{part}"))] for s in (side, other))
            if np.mean(np.linalg.norm(t - same, axis=1)) >= np.mean(np.linalg.norm(t - swapped, axis=1)):
                return False
    return True


def foot_measures(motion: Motion, contacts: np.ndarray, height: float) -> tuple[float, float, float]:
    """The project's skate ratio (its own profile's speed threshold) and mean horizontal slide speed (body
    heights/s) over the given contacts, and how far any contact joint goes below the level it is planted
    at (the 5th percentile of its planted heights), in body heights."""
    profile = SkeletonProfile.detect(motion)
    feet = [motion.skeleton.index(n) for n in profile.contacts.joints]
    positions = torch.tensor(world(motion)[0] @ profile.turn.T)[None]
    steps, skating, speed = skating_sums(
        positions, torch.tensor(contacts)[None], feet, motion.fps, profile.contact_speed
    )
    heights = positions[0, :, feet, 1].numpy()
    planted = contacts > 0.5
    floors = [np.percentile(heights[planted[:, i], i], 5) for i in range(4)]
    below = max(float((floors[i] - heights[:, i]).max()) for i in range(4))
    return float(skating / steps), float(speed / steps) / height, below / height


def path_length(motion: Motion, joint: str) -> float:
    points = canonical_points(motion)[:, motion.skeleton.index(joint)]
    return float(np.linalg.norm(np.diff(points[:, [0, 2]], axis=0), axis=1).sum())


# ---------------------------------------------------------------- same proportions: the answer is known


def test_other_rest_pose_frames_axes_and_units_give_the_same_world_positions(xia, tmp_path):
    """Target A: A-pose arms, re-posed legs, Unreal names, a static root, rotation order XYZ, Z up, inches;
    given as a skeleton (its rest pose is a pose). Target B: every local frame turned at random (its rest
    pose a heap), Z up, metres; given as a clip (frame 0 is its reference). Both must reproduce the
    source's world positions, after undoing the known axis and unit change, and come back A -> B -> A."""
    a, record_a = disguise.disguise(
        reposed(xia), ["unreal", "static_root", "order:XYZ", "scale:2.54", "z_up"]
    )
    b, record_b = disguise.disguise(random_frames(xia), ["metres", "z_up"])
    # The renaming calls Xia's index finger (FingerBase, HandIndex1) the middle one: say which it is.
    fingers = {f"{s}_index": [f"middle_01_{s[0]}", f"middle_02_{s[0]}"] for s in SIDES}
    fingers |= {f"{s}_middle": [] for s in SIDES}
    to_a = Retargeter(xia, a.skeleton, target_map=fingers)
    assert to_a.target_ref.how == "its rest pose" and to_a.leg_ratio == pytest.approx(2.54)
    on_a = to_a(xia)
    assert on_a.rest_joints == ("Root",)  # the static root above the pelvis keeps its rest pose
    assert position_error(on_a.motion, a, record_a.scale * HEIGHT).max() < 1e-6
    # Hands and feet keep their facing: world rotations as the known answer's. The A pose swings the arms
    # about the forward axis (no twist: exact); spreading and bending a leg at rest also rolls the foot
    # about its own bone by about a degree, which nothing in a rig's geometry can show.
    rotations, expected = world(on_a.motion)[1], world(a)[1]
    for joint, bound in (("hand_l", 1e-3), ("hand_r", 1e-3), ("foot_l", 2.0), ("foot_r", 2.0)):
        j = a.skeleton.index(joint)
        assert turn_degrees(rotations[:, j], expected[:, j]).max() < bound, joint
    on_b = retarget(on_a.motion, b, source_map=fingers)
    assert position_error(on_b, b, record_b.scale * HEIGHT).max() < 1e-6
    back = retarget(on_b, xia.skeleton)
    assert position_error(back, xia).max() < 1e-6  # A -> B -> A
    write_bvh(tmp_path / "a.bvh", on_a.motion, precision=9)
    again = read_bvh(tmp_path / "a.bvh")
    assert again.skeleton.channels == a.skeleton.channels
    assert position_error(again, a, record_a.scale * HEIGHT).max() < 1e-6


def test_pinned_feet_move_only_by_the_sources_own_sliding(xia):
    """`feet="pin"` holds planted feet still: on the same proportions the clip moves only where the
    source's own feet slid while planted (this clip: under 2.5% of body height, 0.05% on average)."""
    pinned = retarget(xia, xia.skeleton, feet="pin")
    error = position_error(pinned, xia)
    assert error.max() < 0.025 and error.mean() < 0.0005
    assert position_error(retarget(xia, xia.skeleton, feet="off"), xia).max() < 1e-9


# ---------------------------------------------------------------- other proportions


@pytest.mark.parametrize("change", ["legs 0.8", "legs 1.25", "arms 1.2", "longer spine"])
def test_other_proportions(xia, change):
    """Bone directions within 2 deg median / 5 deg p95 (legs too, where the foot IK is off), hands and
    feet within 10 deg of the source's world turn, the root's path the source's times the leg ratio
    (within 1%), feet planted: skating and sliding no worse than 1.1x the source's, contacts kept, no
    foot deeper below its floor than the source's plus 1% of body height, no side swapped."""
    kind, _, amount = change.partition(" ")
    skeleton = {
        "legs": lambda s: legs(s, float(amount)), "arms": lambda s: arms(s, float(amount)),
        "longer": longer_spine,
    }[kind](xia.skeleton)  # fmt: skip
    result = Retargeter(xia, skeleton)(xia)
    out, ratio = result.motion, result.leg_ratio
    assert ratio == pytest.approx(float(amount) if kind == "legs" else 1.0, rel=0.02)
    errors = bone_errors(xia, out)
    assert np.median(errors) < 2.0 and np.percentile(errors, 95) < 5.0
    free = Retargeter(xia, skeleton, feet="off")(xia).motion
    leg_errors = bone_errors(xia, free, LEGS)
    assert np.median(leg_errors) < 2.0 and np.percentile(leg_errors, 95) < 5.0
    rotations_s, rotations_t = world(xia)[1], world(out)[1]
    for joint in ("LeftHand", "RightHand", "LeftFoot", "RightFoot"):
        turn = turn_degrees(rotations_t[:, skeleton.index(joint)], rotations_s[:, xia.skeleton.index(joint)])
        assert turn.max() < 10.0, joint
    assert path_length(out, "Hips") == pytest.approx(path_length(xia, "Hips") * ratio, rel=0.01)
    skate_s, slide_s, below_s = foot_measures(xia, result.contacts, HEIGHT)
    skate_t, slide_t, below_t = foot_measures(out, result.contacts, HEIGHT * ratio)
    assert skate_t <= 1.1 * skate_s + 0.01 and slide_t <= 1.1 * slide_s
    assert below_t <= below_s + 0.01
    own = foot_contacts(out, SkeletonProfile.detect(out).contacts)
    if kind != "legs":  # contacts are measured against thresholds of the body's height, not the legs'
        assert ((own > 0.5) & (result.contacts > 0.5)).sum() >= 0.98 * (result.contacts > 0.5).sum()
    assert sides_kept(xia, out, ratio)


# ---------------------------------------------------------------- real pairs


def test_xia_onto_zeggs_and_back(xia, zeggs):
    """Onto the ZEGGS skeleton, its first frame as the target's rest pose (4 spine joints against 3, no
    hip joints, full fingers against an index and a thumb) and back onto Xia; and ZEGGS's own clip onto
    Xia. Mapped bones follow the source, sides are kept; the round trip stays within 1% of body height on
    average (the hip joints Xia has and ZEGGS has not come back rigid)."""
    to_zeggs = Retargeter(xia, zeggs.slice(0, 1))
    result = to_zeggs(xia)
    out = result.motion
    assert out.skeleton is zeggs.skeleton and out.num_frames == xia.num_frames
    assert {"LeftHandMiddle1", "RightHandPinky4", "HeadEnd"} <= set(result.rest_joints)
    errors = bone_errors(xia, out)
    assert np.median(errors) < 2.0 and np.percentile(errors, 95) < 5.0
    assert sides_kept(xia, out, result.leg_ratio)
    back = Retargeter(out, xia.slice(0, 1))
    assert back.rest_joints == ("LHipJoint", "RHipJoint")
    error = position_error(back(out).motion, xia)
    assert error.mean() < 0.01 and error.max() < 0.03
    clip = zeggs.slice(600, 720)
    on_xia = Retargeter(clip, xia.slice(0, 1))(clip)
    errors = bone_errors(clip, on_xia.motion)
    assert np.median(errors) < 2.0 and np.percentile(errors, 95) < 5.0
    assert sides_kept(clip, on_xia.motion, on_xia.leg_ratio)


# ---------------------------------------------------------------- rest poses that are no pose


def test_rest_poses_that_are_no_pose_align_on_a_reference_frame(xia):
    """Every bone along +x at rest (`disguise.axis_rest`): as the target, its first frame is its reference;
    as the source, a standing frame of the clip is found (or the user's). Both exact; a target given as a
    bare skeleton with such a rest pose is refused, saying why."""
    laid = disguise.axis_rest(xia)
    assert position_error(retarget(xia, laid), xia).max() < 1e-6
    from_laid = Retargeter(laid, xia.skeleton)
    assert "its rest pose is no pose: its bones lie on one line" in from_laid.source_ref.how
    assert position_error(from_laid(laid).motion, xia).max() < 1e-6
    given = Retargeter(laid, xia.skeleton, reference_frame=7)
    assert given.source_ref.how == "frame 7 of the clip (given)"
    assert position_error(given(laid).motion, xia).max() < 1e-6
    with pytest.raises(WalkdiffError, match="target's reference pose.*is no pose: its bones lie on one line"):
        Retargeter(xia, laid.skeleton)


def test_partial_map_leaves_the_rest_in_rest_pose(xia, zeggs):
    """A rig with one spine joint and no fingers: the map says so, retargeting onto it works (the spine's
    bend goes into its one joint), and from it onto ZEGGS the fingers it cannot drive stay in their rest
    pose and are reported."""
    small = merged(xia.skeleton, ["LowerBack", "Spine1", "Neck1", "LeftFingerBase", "LeftHandIndex1",
                                  "LThumb", "RightFingerBase", "RightHandIndex1", "RThumb"])  # fmt: skip
    m = humanoid_map(small)
    assert m.spine == ("Spine",) and m.fingers == {}
    assert any(line.startswith("left fingers") and "left in rest pose" in line for line in m.describe(small))
    on_small = Retargeter(xia, small)(xia)
    assert on_small.rest_joints == ()
    errors = bone_errors(xia, on_small.motion, [b for b in BONES if b != ("pelvis", "neck")])
    assert np.median(errors) < 2.0
    trunk = bone_errors(xia, on_small.motion, [("pelvis", "neck")])
    assert np.median(trunk) < 3.0  # the chord of a 3-joint spine, by one joint
    onward = Retargeter(on_small.motion, zeggs.slice(0, 1))(on_small.motion)
    fingers = [n for n in zeggs.skeleton.names if "Hand" in n and n[-1].isdigit()]
    assert set(fingers) <= set(onward.rest_joints)
    assert any(
        note.startswith("left in their reference pose: ") and "LeftHandThumb1" in note
        for note in onward.notes
    )


def test_bad_input_is_refused(xia, zeggs):
    with pytest.raises(WalkdiffError, match="feet 'glue': expected one of follow, pin, off"):
        Retargeter(xia, xia.skeleton, feet="glue")
    retargeter = Retargeter(xia, xia.skeleton)
    with pytest.raises(WalkdiffError, match="not on the source skeleton"):
        retargeter(zeggs.slice(0, 5))
    with pytest.raises(WalkdiffError, match="target_frame 5: the target clip has 1 frames"):
        Retargeter(xia, xia.slice(0, 1), target_frame=5)


# ---------------------------------------------------------------- speed


def test_speed(xia_dir):
    """A prepared retargeter converts a 300-frame clip at thousands of frames per second (the target is
    10,000 on 2 cores; the bound here leaves room for a busy machine)."""
    clip = read_bvh(xia_dir / "neutral_01_000.bvh").slice(0, 300)
    retargeter = Retargeter(clip, legs(clip.skeleton, 1.25))
    best = float("inf")
    for _ in range(5):
        start = time.perf_counter()
        retargeter(clip)
        best = min(best, time.perf_counter() - start)
    assert clip.num_frames / best > 3000


def test_the_retarget_command_writes_each_built_in_rig_and_a_users_rig(xia_dir, zeggs_dir, tmp_path, capsys):
    """`walkdiff retarget SRC --to TARGET --out OUT`: the target's own skeleton, the source's frames, the
    feet on the target's floor; a BVH rig and .glb; bad targets and outputs named."""
    from walkdiff.cli.main import main
    from walkdiff.motion.kinematics import motion_world_positions
    from walkdiff.motion.rigs import SPECS, rig

    source = xia_dir / "proud_01_000.bvh"
    frames = read_bvh(source).num_frames
    for name in ("mixamo", "unreal", "smpl"):
        out = tmp_path / f"{name}.bvh"
        assert main(["retarget", str(source), "--to", name, "--out", str(out)]) == 0
        written, built = read_bvh(out), rig(name)
        assert written.skeleton.names == built.skeleton.names and written.num_frames == frames
        up = "xyz".index(SPECS[name].up[1])
        heights = motion_world_positions(written)[..., up]
        stature = motion_world_positions(built)[0, :, up].max()
        assert abs(np.percentile(heights.min(axis=1), 50)) < 0.05 * stature  # standing on its floor
    assert "legs" in capsys.readouterr().out
    glb = tmp_path / "zeggs.glb"
    zeggs = zeggs_dir / "067_Speech_2_x_1_0.bvh"
    assert main(["retarget", str(source), "--to", str(zeggs), "--out", str(glb)]) == 0
    assert glb.read_bytes()[:4] == b"glTF"
    assert main(["retarget", str(source), "--to", "maya", "--out", str(tmp_path / "x.bvh")]) == 1
    assert (
        "expected a BVH file of your rig or a built-in rig (mixamo, unreal, smpl)" in capsys.readouterr().err
    )
    assert main(["retarget", str(source), "--to", "smpl", "--out", str(tmp_path / "x.fbx")]) == 1
    assert "expected an output ending in .bvh or .glb" in capsys.readouterr().err
    assert main(["retarget", str(source), "--to", "smpl", "--out", str(tmp_path / "smpl.bvh")]) == 1
    assert "pass --overwrite" in capsys.readouterr().err


def test_inspect_prints_the_humanoid_map(xia_dir, capsys):
    from walkdiff.cli.main import main

    assert main(["inspect", str(xia_dir / "proud_01_000.bvh")]) == 0
    out = capsys.readouterr().out
    assert "humanoid map (what `walkdiff retarget` uses):" in out
    assert "left_thigh      LeftUpLeg [name]" in out and "right_hand      RightHand [name]" in out
