"""Retargeting (`walkdiff.retarget.retargeter`) on tests that know the answer.

- A copy of Xia's own skeleton with another rest pose (arms from T to A pose, legs spread and bent),
  every local frame turned at random (the motion compensated), Z up, other units, another rotation
  order, Unreal names and a static root: the clip must come back with the source's world joint
  positions, and go back again (A -> B -> A).
- Copies with other proportions (legs 0.8x and 1.25x, arms 1.2x, two spine joints inserted): bone
  directions, hand and foot orientation, the root's path scaled by the leg ratio, feet planted.
- Real pairs: Xia onto the ZEGGS skeleton (its first frame as the target's rest) and back, ZEGGS onto Xia.
- Rest poses that are no pose (every bone along one axis), a partial map (no fingers, one spine joint),
  and speed.

Positions are compared in body heights (Xia: 24.13 units), directions in degrees. The rig variants
(`walkdiff.bench.rig_variants`) and the measures (`walkdiff.bench.retarget`) are shared with `walkdiff
bench retarget`, which writes these figures over several clips.
"""

from __future__ import annotations

import time

import disguise
import numpy as np
import pytest

from walkdiff.bench.retarget import (
    BONES,
    LEGS,
    bone_angles,
    bone_errors,
    foot_measures,
    path_length,
    position_error,
    sides_kept,
    turn_degrees,
    world,
)
from walkdiff.bench.rig_variants import arms, legs, longer_spine, merged, random_frames, reposed
from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.humanoid import SIDES, humanoid_map
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import foot_contacts
from walkdiff.motion.skeleton import Motion, Skeleton
from walkdiff.retarget.retargeter import Retargeter, retarget

HEIGHT = 24.13  # Xia's body height, units


@pytest.fixture(scope="module")
def xia(xia_dir) -> Motion:
    return read_bvh(xia_dir / "strutting_08_002.bvh").slice(0, 120)


@pytest.fixture(scope="module")
def zeggs(zeggs_dir) -> Motion:
    return read_bvh(zeggs_dir / "067_Speech_2_x_1_0.bvh")


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
    assert position_error(back, xia, HEIGHT).max() < 1e-6  # A -> B -> A
    write_bvh(tmp_path / "a.bvh", on_a.motion, precision=9)
    again = read_bvh(tmp_path / "a.bvh")
    assert again.skeleton.channels == a.skeleton.channels
    assert position_error(again, a, record_a.scale * HEIGHT).max() < 1e-6


def test_contact_thresholds_follow_the_legs_not_the_height(xia):
    """A foot's speed and lift go with the stride: a rig with legs 1.25x (its height grows less) gets
    contact thresholds 1.25x, so the same walk keeps the same contacts; a rig with no legs to find
    takes its thresholds from its body height and says so."""
    longer = retarget(xia, legs(xia.skeleton, 1.25))
    a, b = SkeletonProfile.detect(xia), SkeletonProfile.detect(longer)
    assert b.body_height / a.body_height < 1.2
    assert b.contact_height / a.contact_height == pytest.approx(1.25, rel=1e-9)
    assert b.contact_speed / a.contact_speed == pytest.approx(1.25, rel=1e-9)
    assert "leg lengths" in a.found["contacts"]
    trunk = xia.skeleton.index("Spine")
    chain = [j for j in range(xia.skeleton.num_joints) if j in (0, trunk)]
    skeleton = Skeleton(
        [xia.skeleton.names[j] for j in chain], [-1, 0], xia.skeleton.offsets[chain],
        [xia.skeleton.channels[j] for j in chain], {1: np.array([0.0, 5.0, 0.0])},
    )  # fmt: skip
    stub = Motion(skeleton, xia.rotations[:, chain], xia.positions[:, chain], xia.frame_time)
    found = SkeletonProfile.detect(stub)
    assert "body heights" in found.found["contacts"] and "no legs found" in found.found["contacts"]
    assert found.contact_height == pytest.approx(0.02 * found.body_height)


def test_pinned_feet_move_only_by_the_sources_own_sliding(xia):
    """`feet="pin"` holds planted feet still: on the same proportions the clip moves only where the
    source's own feet slid while planted (this clip: under 2.5% of body height, 0.05% on average)."""
    pinned = retarget(xia, xia.skeleton, feet="pin")
    error = position_error(pinned, xia, HEIGHT)
    assert error.max() < 0.025 and error.mean() < 0.0005
    assert position_error(retarget(xia, xia.skeleton, feet="off"), xia, HEIGHT).max() < 1e-9


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
    Xia. Mapped bones follow the source, and the hip line too (ZEGGS's thighs hang from its pelvis,
    Xia's from hip joints that turn: the pelvis follows the line they make); sides
    are kept; the round trip stays within 1% of body height on average. It cannot be exact: ZEGGS has
    no joints for Xia's hip joints, which come back rigid with a pelvis that carried their turn, and
    where ZEGGS's legs could not reach Xia's pushing-off feet its body went lower."""
    to_zeggs = Retargeter(xia, zeggs.slice(0, 1))
    result = to_zeggs(xia)
    out = result.motion
    assert out.skeleton is zeggs.skeleton and out.num_frames == xia.num_frames
    assert {"LeftHandMiddle1", "RightHandPinky4", "HeadEnd"} <= set(result.rest_joints)
    errors = bone_errors(xia, out)
    assert np.median(errors) < 2.0 and np.percentile(errors, 95) < 5.0
    assert np.median(dict(bone_angles(xia, out))["left_thigh-right_thigh"]) < 0.01
    assert sides_kept(xia, out, result.leg_ratio)
    back = Retargeter(out, xia.slice(0, 1))
    assert back.rest_joints == ("LHipJoint", "RHipJoint")
    error = position_error(back(out).motion, xia, HEIGHT)
    assert error.mean() < 0.01 and error.max() < 0.06
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
    assert position_error(retarget(xia, laid), xia, HEIGHT).max() < 1e-6
    from_laid = Retargeter(laid, xia.skeleton)
    assert "its rest pose is no pose: its bones lie on one line" in from_laid.source_ref.how
    assert position_error(from_laid(laid).motion, xia, HEIGHT).max() < 1e-6
    given = Retargeter(laid, xia.skeleton, reference_frame=7)
    assert given.source_ref.how == "frame 7 of the clip (given)"
    assert position_error(given(laid).motion, xia, HEIGHT).max() < 1e-6
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
    from walkdiff.retarget.rigs import SPECS, rig

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


def test_the_retarget_command_says_each_note_once(xia_dir, zeggs_dir, tmp_path, capsys):
    """The report listed the leg ratio and the joints left in their reference pose twice."""
    from walkdiff.cli.main import main

    out = tmp_path / "zeggs.bvh"
    to = zeggs_dir / "067_Speech_2_x_1_0.bvh"
    assert main(["retarget", str(xia_dir / "proud_01_000.bvh"), "--to", str(to), "--out", str(out)]) == 0
    lines = [line.strip() for line in capsys.readouterr().out.splitlines()]
    notes = [line for line in lines if line.startswith("note: ") or "reference pose" in line]
    assert any(n.startswith("note: leg ratio") for n in notes)
    assert any(n.startswith("note: left in their reference pose: ") for n in notes)
    assert len(notes) == len(set(notes)) and sum("reference pose:" in n for n in notes) == 1, lines
