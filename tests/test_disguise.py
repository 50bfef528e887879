"""Disguised copies of real Xia clips (tests/disguise.py): each disguise alone and in a chain, written as
BVH and read back, puts every joint and End Site where the original has it once the known change (units,
up axis, root turn, frame step, names) is undone; the label manifest and the new names are checked too."""

from __future__ import annotations

import csv
import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from disguise import (
    CMU_TO_METRES,
    CONVENTIONS,
    Z_UP,
    disguise,
    disguised_folder,
    joint_side,
    rename,
    rotation_order,
    scale_units,
    static_root,
    xia_labels,
    z_up,
)
from test_datamodule import README_COUNTS  # clips per style and group, from the data README

from walkdiff.motion.bvh import format_bvh, parse_bvh, read_bvh
from walkdiff.motion.kinematics import forward_kinematics
from walkdiff.motion.skeleton import Motion

RELATIVE_TOLERANCE = 1e-5  # of body height (about 24 CMU units for Xia)

# The content ids of data/README.md, whose name prefix is the content group.
README_CONTENTS = (
    "walk_s1 walk_s2 walk_lturn_s1 walk_rturn_s1 walk_lturn_l1 walk_lturn_l2 walk_l1 walk_l2 walk_rturn_s2 "
    "walk_lturn_s2 walk_rturn_l1 walk_lturn_l3 run run_lturn run_rturn jump_1 jump_2 punch_r punch_l "
    "punch_qr punch_ql kick_l kick_r trans_jump2walk trans_walk2jump trans_punch2kick trans_walk2punch "
    "trans_run2jump"
).split()
GROUPS = ("walk", "run", "jump", "punch", "kick", "trans")

SINGLE_STEPS = [
    "mixamo",
    "unreal",
    "smpl",
    "static_root",
    "static_root:X-90",
    "turned_root:X-90",
    "metres",
    "order:XYZ",
    "order:YXZ:ZXY",
    "z_up",
    "fps:60",
    "positions",
]
CHAINS = {
    "unreal_metres_zup_60": ["unreal", "static_root", "metres", "order:XYZ", "z_up", "fps:60"],
    "mixamo_blender": ["mixamo", "positions", "turned_root:X90", "cm", "order:YZX:ZYX", "fps:30"],
    "smpl_zup_root": ["smpl", "z_up", "static_root:Z30", "scale:0.01", "fps:40"],
}


def content_group(file_name: str) -> str:
    """The test's own reading of a Xia name: the README content name's prefix."""
    return README_CONTENTS[int(file_name.split("_")[1]) - 1].split("_")[0]


@pytest.fixture(scope="module")
def clips(xia_dir: Path) -> list[str]:
    """Five real clips: one per content group walk, run, jump, punch, kick, each of another style."""
    names = sorted(p.name for p in xia_dir.glob("*.bvh"))
    chosen: list[str] = []
    for group in GROUPS[:5]:
        styles = {c.split("_")[0] for c in chosen}
        chosen.append(next(n for n in names if content_group(n) == group and n.split("_")[0] not in styles))
    return chosen


@pytest.fixture(scope="module")
def originals(xia_dir: Path, clips: list[str]) -> dict[str, Motion]:
    return {name: read_bvh(xia_dir / name) for name in clips}


def world_points(motion: Motion) -> dict[str, np.ndarray]:
    """(F, 3) world trajectory of every joint and of every End Site ('<joint> End Site')."""
    positions, rotations = forward_kinematics(
        torch.tensor(motion.rotations),
        torch.tensor(motion.positions),
        motion.skeleton.parents,
        return_rotations=True,
    )
    positions, rotations = positions.numpy(), rotations.numpy()
    names = motion.skeleton.names
    points = {name: positions[:, j] for j, name in enumerate(names)}
    for j, end in motion.skeleton.end_sites.items():
        points[f"{names[j]} End Site"] = positions[:, j] + rotations[:, j] @ end
    return points


def body_height(motion: Motion) -> float:
    """Height of the rest pose (bone offsets, no rotation) along Y."""
    eye = torch.eye(3, dtype=torch.float64).expand(motion.skeleton.num_joints, 3, 3)
    rest = forward_kinematics(eye, torch.tensor(motion.skeleton.offsets), motion.skeleton.parents)
    return float(np.ptp(rest[:, 1].numpy()))


def round_trip_error(original: Motion, copy: Motion, record, undo: bool = True) -> float:
    """Largest distance, over all frames, joints and End Sites of the original, between the original and
    the copy mapped back (names through the record, positions through `record.undo`), over body height."""
    before, after = world_points(original), world_points(copy)
    assert record.frame_step is not None
    error = 0.0
    for name, track in before.items():
        joint = name.removesuffix(" End Site")
        mapped = record.names[joint] + name[len(joint) :]
        restored = record.undo(after[mapped]) if undo else after[mapped]
        expected = track[:: record.frame_step]
        assert restored.shape == expected.shape, f"{name}: frames {restored.shape} vs {expected.shape}"
        error = max(error, float(np.abs(restored - expected).max()))
    assert len(before) == original.skeleton.num_joints + len(original.skeleton.end_sites)
    return error / body_height(original)


def check_folder(out: Path, originals: dict[str, Motion], record) -> dict[str, Motion]:
    """Every disguised file of the folder read back agrees with its original within the tolerance."""
    copies = {}
    assert sorted(record.files) == sorted(originals)
    for name, original in originals.items():
        copy = read_bvh(out / record.files[name])
        error = round_trip_error(original, copy, record)
        assert error <= RELATIVE_TOLERANCE, f"{name} -> {record.files[name]}: {error:.2e} of body height"
        copies[name] = copy
    return copies


@pytest.mark.parametrize("step", SINGLE_STEPS)
def test_each_disguise_alone_keeps_world_positions(step, xia_dir, clips, originals, tmp_path):
    record = disguised_folder(xia_dir, tmp_path, clips, steps=[step])
    copies = check_folder(tmp_path, originals, record)
    # The copy really is disguised: names, channels, frames or offsets differ from the original's.
    first = copies[clips[0]]
    original = originals[clips[0]]
    changed = (
        first.skeleton.names != original.skeleton.names
        or first.skeleton.channels != original.skeleton.channels
        or first.num_frames != original.num_frames
        or not np.allclose(first.skeleton.offsets, original.skeleton.offsets)
    )
    assert changed, f"{step} left the skeleton and frames as they were"


@pytest.mark.parametrize("chain", list(CHAINS))
def test_chain_of_disguises_keeps_world_positions(chain, xia_dir, clips, originals, tmp_path):
    record = disguised_folder(xia_dir, tmp_path, clips, steps=CHAINS[chain])
    copies = check_folder(tmp_path, originals, record)
    copy = copies[clips[0]]
    assert not set(copy.skeleton.names) & set(originals[clips[0]].skeleton.names)
    assert record.precision >= (8 if record.scale < 0.1 else 6)


def test_full_chain_record(xia_dir, clips, originals, tmp_path):
    steps = ["unreal", "static_root", "metres", "order:XYZ", "z_up", "fps:60"]
    record = disguised_folder(xia_dir, tmp_path, clips, steps=steps)
    assert record.scale == CMU_TO_METRES
    np.testing.assert_array_equal(record.up, Z_UP)
    assert record.frame_step == 2
    assert record.names["LeftUpLeg"] == "thigh_l" and record.names["Hips"] == "pelvis"
    copy = read_bvh(tmp_path / record.files[clips[0]])
    assert copy.skeleton.names[:2] == ["Root", "pelvis"]
    assert copy.frame_time == pytest.approx(1 / 60, rel=1e-12)
    assert {copy.skeleton.rotation_order(j) for j in range(copy.skeleton.num_joints)} == {"XYZ"}
    # Metres, Z up: the pelvis is about 0.9 m above the floor along Z, and the head above it.
    points = world_points(copy)
    assert 0.7 < np.median(points["pelvis"][:, 2]) < 1.2
    assert (points["head"][:, 2] > points["pelvis"][:, 2]).all()


def test_check_sees_an_error_of_a_ten_thousandth_of_body_height(clips, originals):
    original = originals[clips[0]]
    copy, record = disguise(original, ["z_up", "metres"])
    assert round_trip_error(original, copy, record) <= RELATIVE_TOLERANCE
    assert round_trip_error(original, copy, record, undo=False) > 0.01  # undoing is what makes it agree
    height = body_height(original)
    bent = Motion(copy.skeleton, copy.rotations, copy.positions.copy(), copy.frame_time)
    bent.positions[:, copy.skeleton.index("LeftFoot"), 0] += 1e-4 * height * CMU_TO_METRES
    assert round_trip_error(original, bent, record) > RELATIVE_TOLERANCE
    # Bones left Y-up (only the rotations and the root turned): caught.
    bones_left_y_up = z_up(scale_units(original, CMU_TO_METRES))
    bones_left_y_up.positions[:, 1:] = original.positions[:, 1:] * CMU_TO_METRES
    assert round_trip_error(original, bones_left_y_up, record) > RELATIVE_TOLERANCE


def test_end_sites_follow_the_disguise(clips, originals):
    """Xia's End Sites are all at their joint (zero offsets); give them length to see them move."""
    original = originals[clips[0]]
    sk = original.skeleton
    ends = {j: np.array([0.3, -0.2, 1.7]) * (1 + k) for k, j in enumerate(sk.end_sites)}
    motion = Motion(replace(sk, end_sites=ends), original.rotations, original.positions, original.frame_time)
    steps = ["mixamo", "static_root", "metres", "order:XYZ", "z_up", "fps:60"]
    copy, record = disguise(motion, steps)
    copy = parse_bvh(format_bvh(copy, precision=9))
    assert round_trip_error(motion, copy, record) <= RELATIVE_TOLERANCE
    copy.skeleton.end_sites = {j + 1: e * CMU_TO_METRES for j, e in ends.items()}  # not turned Z-up
    assert round_trip_error(motion, copy, record) > RELATIVE_TOLERANCE


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_renamed_skeleton(convention, clips, originals, xia_dir, tmp_path):
    original = originals[clips[0]]
    record = disguised_folder(xia_dir, tmp_path, clips[:1], steps=[convention])
    copy = read_bvh(tmp_path / record.files[clips[0]])
    names = copy.skeleton.names
    assert len(set(names)) == len(names) == original.skeleton.num_joints
    assert not set(names) & set(original.skeleton.names)
    assert sorted(record.names) == sorted(original.skeleton.names)
    assert [record.names[n] for n in original.skeleton.names] == names
    for old, new in record.names.items():
        side = (
            "left" if old.startswith("L") and old != "LowerBack" else "right" if old.startswith("R") else None
        )
        assert joint_side(new) == side, f"{convention}: {old} -> {new}"
        if convention == "mixamo":
            assert new.startswith("mixamorig:")
            assert side is None or new.startswith(f"mixamorig:{side.title()}")
        elif convention == "unreal":
            assert side is None or new.endswith(f"_{side[0]}")
        else:
            assert side is None or new.startswith(f"{side}_")
    expected = {
        "mixamo": {
            "Hips": "mixamorig:Hips",
            "LeftUpLeg": "mixamorig:LeftUpLeg",
            "LowerBack": "mixamorig:Spine",
        },
        "unreal": {"Hips": "pelvis", "LHipJoint": "hip_l", "LeftUpLeg": "thigh_l", "LeftLeg": "calf_l"},
        "smpl": {"Hips": "pelvis", "LeftUpLeg": "left_hip", "LeftLeg": "left_knee", "LeftFoot": "left_ankle"},
    }[convention]
    assert {k: record.names[k] for k in expected} == expected
    more = {
        "mixamo": {"LeftFoot": "mixamorig:LeftFoot", "LeftToeBase": "mixamorig:LeftToeBase"},
        "unreal": {"LeftFoot": "foot_l", "LeftToeBase": "ball_l", "Neck": "neck_01", "RightHand": "hand_r"},
        "smpl": {"LeftToeBase": "left_foot", "RightUpLeg": "right_hip", "Head": "head"},
    }[convention]
    assert {k: record.names[k] for k in more} == more


def test_rename_of_unknown_names_stays_unique_and_sided(clips, originals):
    motion = static_root(originals[clips[0]], name="LeftRoot")
    for convention in CONVENTIONS:
        renamed, mapping = rename(motion, convention)
        assert len(set(renamed.skeleton.names)) == renamed.skeleton.num_joints
        assert joint_side(mapping["LeftRoot"]) == "left"
    with pytest.raises(ValueError, match="naming convention"):
        rename(motion, "maya")


def frame_values(path: Path) -> np.ndarray:
    lines = path.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("Frame Time:")) + 1
    return np.array([[float(x) for x in line.split()] for line in lines[start:]])


@pytest.mark.parametrize(
    ("step", "root_values"), [("static_root", (0, 0, 0)), ("static_root:X-90", (0, 0, -90))]
)
def test_static_root_is_constant(step, root_values, xia_dir, clips, originals, tmp_path):
    record = disguised_folder(xia_dir, tmp_path, clips[:1], steps=[step])
    path = tmp_path / record.files[clips[0]]
    copy = read_bvh(path)
    sk = copy.skeleton
    assert sk.names[:2] == ["Root", "Hips"] and sk.parents[1] == 0
    assert sk.channels[0] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
    assert sk.channels[1] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
    np.testing.assert_array_equal(sk.offsets[0], 0)
    values = frame_values(path)
    np.testing.assert_allclose(values[:, :6], np.broadcast_to([0, 0, 0, *root_values], (len(values), 6)))
    hips = values[:, 6:9]
    assert np.ptp(hips, axis=0).max() > 1  # the hips carry the clip's translation
    # A compensated turn changes the hips' channels but no world position (checked in the round trip).
    original = originals[clips[0]]
    if root_values != (0, 0, 0):
        assert not np.allclose(copy.rotations[:, 1], original.rotations[:, 0], atol=1e-3)
    assert round_trip_error(original, copy, record) <= RELATIVE_TOLERANCE
    assert record.up is not None and np.array_equal(record.up, np.eye(3))


def test_turned_root_turns_the_clip(xia_dir, clips, originals, tmp_path):
    record = disguised_folder(xia_dir, tmp_path, clips[:1], steps=["turned_root:X-90"])
    copy = read_bvh(tmp_path / record.files[clips[0]])
    np.testing.assert_allclose(record.up, [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-12)
    np.testing.assert_allclose(copy.rotations[:, 1], originals[clips[0]].rotations[:, 0], atol=1e-6)
    # -90 degrees about X takes the original's up (+Y) to -Z.
    hips = world_points(copy)["Hips"]
    np.testing.assert_allclose(-hips[:, 2], world_points(originals[clips[0]])["Hips"][:, 1], atol=1e-4)


def test_rotation_order_keeps_matrices(xia_dir, clips, originals, tmp_path):
    record = disguised_folder(xia_dir, tmp_path, clips[:1], steps=["order:YXZ:ZXY"])
    copy = read_bvh(tmp_path / record.files[clips[0]])
    assert copy.skeleton.channels[0] == (
        "Zposition",
        "Xposition",
        "Yposition",
        "Yrotation",
        "Xrotation",
        "Zrotation",
    )
    assert all(c == ("Yrotation", "Xrotation", "Zrotation") for c in copy.skeleton.channels[1:])
    np.testing.assert_allclose(copy.rotations, originals[clips[0]].rotations, atol=1e-7)
    with pytest.raises(ValueError, match="rotation order"):
        rotation_order(copy, "XXY")


def test_z_up_rest_pose_and_world(xia_dir, clips, originals, tmp_path):
    record = disguised_folder(xia_dir, tmp_path, clips[:1], steps=["z_up"])
    copy = read_bvh(tmp_path / record.files[clips[0]])
    original = originals[clips[0]]
    np.testing.assert_array_equal(Z_UP @ [0, 1, 0], [0, 0, 1])
    np.testing.assert_allclose(copy.skeleton.offsets, original.skeleton.offsets @ Z_UP.T, atol=1e-6)
    leg = copy.skeleton.offsets[copy.skeleton.index("LeftLeg")]
    assert leg[2] < -5 and abs(leg[1]) < 1e-9  # the shin points down Z in the rest pose
    before, after = world_points(original), world_points(copy)
    np.testing.assert_allclose(after["Head"], before["Head"] @ Z_UP.T, atol=1e-4)


def test_metres(xia_dir, clips, originals, tmp_path):
    record = disguised_folder(xia_dir, tmp_path, clips[:1], steps=["metres"])
    assert record.precision >= 8 and record.scale == CMU_TO_METRES
    copy = read_bvh(tmp_path / record.files[clips[0]])
    original = originals[clips[0]]
    np.testing.assert_allclose(copy.skeleton.offsets, original.skeleton.offsets * CMU_TO_METRES, atol=1e-8)
    for j, end in original.skeleton.end_sites.items():
        np.testing.assert_allclose(copy.skeleton.end_sites[j], end * CMU_TO_METRES, atol=1e-8)
    assert 1.2 < body_height(copy) < 1.6


def test_frame_rate(xia_dir, clips, originals, tmp_path):
    record = disguised_folder(xia_dir, tmp_path, clips[:1], steps=["fps:30"])
    path = tmp_path / record.files[clips[0]]
    assert record.frame_step == 4
    assert re.search(r"^Frame Time: 0\.0333333", path.read_text(), re.MULTILINE)
    copy = read_bvh(path)
    original = originals[clips[0]]
    assert copy.num_frames == len(range(0, original.num_frames, 4))
    np.testing.assert_allclose(copy.positions[:, 0], original.positions[::4, 0], atol=1e-6)
    # A rate that is no whole fraction of 120 fps is interpolated: no frame step to undo.
    assert disguise(original, ["fps:50"])[1].frame_step is None


def test_position_channels_everywhere(xia_dir, clips, originals, tmp_path):
    record = disguised_folder(xia_dir, tmp_path, clips[:1], steps=["positions"])
    copy = read_bvh(tmp_path / record.files[clips[0]])
    sk = copy.skeleton
    assert all(c[:3] == ("Xposition", "Yposition", "Zposition") and len(c) == 6 for c in sk.channels)
    np.testing.assert_allclose(
        copy.positions[:, 1:], np.broadcast_to(sk.offsets[1:], copy.positions[:, 1:].shape)
    )


@pytest.mark.parametrize("kind", ["csv", "json"])
def test_manifest_labels(kind, xia_dir, clips, tmp_path):
    splits = {name: "test" if i % 2 else "train" for i, name in enumerate(clips)}
    record = disguised_folder(xia_dir, tmp_path, clips, steps=["smpl"], labels=kind, splits=splits)
    assert record.manifest == tmp_path / f"labels.{kind}"
    if kind == "csv":
        with record.manifest.open(newline="") as f:
            reader = csv.DictReader(f)
            assert reader.fieldnames == ["file", "style", "content", "split"]
            rows = list(reader)
    else:
        rows = json.loads(record.manifest.read_text())
    back = {disguised: original for original, disguised in record.files.items()}
    assert sorted(r["file"] for r in rows) == sorted(p.name for p in tmp_path.glob("*.bvh"))
    assert len(rows) == len(clips)
    for row in rows:
        original = back[row["file"]]
        assert re.fullmatch(r"take_\d{4}\.bvh", row["file"])
        assert row["style"] == original.split("_")[0]
        assert row["content"] == content_group(original)
        assert row["split"] == splits[original]
    assert {r["content"] for r in rows} == set(GROUPS[:5])
    # The numbering does not follow the clips' (label-sorted) order.
    assert [record.files[c] for c in clips] != sorted(record.files.values())


def test_xia_labels_match_the_readme(xia_dir):
    counts = {style: [0] * 6 for style in README_COUNTS}
    for path in xia_dir.glob("*.bvh"):
        style, content = xia_labels(path.name)
        assert content == content_group(path.name)
        counts[style][GROUPS.index(content)] += 1
    assert {style: tuple(c) for style, c in counts.items()} == README_COUNTS
    for bad in ("angry_29_000.bvh", "take_0001.bvh", "angry_1_000.bvh"):
        with pytest.raises(ValueError):
            xia_labels(bad)


def test_disguises_leave_their_input_alone(clips, originals):
    original = originals[clips[0]]
    rotations, positions = original.rotations.copy(), original.positions.copy()
    offsets, channels = original.skeleton.offsets.copy(), list(original.skeleton.channels)
    ends = {j: e.copy() for j, e in original.skeleton.end_sites.items()}
    disguise(original, [*CHAINS["unreal_metres_zup_60"], "positions", "turned_root:Y45"])
    np.testing.assert_array_equal(original.rotations, rotations)
    np.testing.assert_array_equal(original.positions, positions)
    np.testing.assert_array_equal(original.skeleton.offsets, offsets)
    assert original.skeleton.channels == channels
    assert all(np.array_equal(original.skeleton.end_sites[j], e) for j, e in ends.items())
    with pytest.raises(ValueError, match="unknown disguise step"):
        disguise(original, ["y_up"])
