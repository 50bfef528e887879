"""BVH reading and writing: synthetic odd files, round trips, an independent reader, real data, bad input."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.rotations import (
    euler_to_matrix,
    matrix_to_6d,
    matrix_to_euler,
    matrix_to_quaternion,
    quaternion_to_matrix,
    sixd_to_matrix,
)


def axis_rotation(axis: str, degrees: float) -> np.ndarray:
    """Right-handed rotation about one axis, written out by hand as the reference."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return {
        "X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


def hand_euler(angles: list[float], order: str) -> np.ndarray:
    """BVH semantics: the first channel in the file is the outermost factor."""
    m = np.eye(3)
    for axis, angle in zip(order, angles, strict=True):
        m = m @ axis_rotation(axis, angle)
    return m


# ---------------------------------------------------------------- rotations


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "ZX", "Y"])
def test_euler_matches_hand_built_product_and_inverts(order):
    rng = np.random.default_rng(0)
    angles = rng.uniform(-170, 170, size=(5, len(order)))
    angles[:, len(order) // 2] /= 2  # keep the middle angle inside the range matrix_to_euler returns
    matrices = euler_to_matrix(angles, order)
    expected = np.stack([hand_euler(list(a), order) for a in angles])
    np.testing.assert_allclose(matrices, expected, atol=1e-12)
    np.testing.assert_allclose(matrix_to_euler(matrices, order), angles, atol=1e-9)


def test_6d_and_quaternion_round_trip():
    m = torch.as_tensor(euler_to_matrix(np.random.default_rng(1).uniform(-90, 90, (4, 2, 3)), "ZYX"))
    sixd = matrix_to_6d(m)
    assert sixd.shape == (4, 2, 6)
    torch.testing.assert_close(sixd[..., :3], m[..., :, 0])  # first column, then second
    torch.testing.assert_close(sixd_to_matrix(sixd), m)
    torch.testing.assert_close(quaternion_to_matrix(matrix_to_quaternion(m)), m)
    noise = torch.randn(sixd.shape, dtype=sixd.dtype, generator=torch.Generator().manual_seed(0))
    noisy = sixd_to_matrix(sixd + 0.1 * noise)
    torch.testing.assert_close(noisy @ noisy.transpose(-1, -2), torch.eye(3, dtype=m.dtype).expand_as(noisy))
    torch.testing.assert_close(torch.linalg.det(noisy), torch.ones(4, 2, dtype=m.dtype))


# ---------------------------------------------------------------- a synthetic, deliberately odd file

# joint name -> (parent, offset, channels); the hierarchy text below must agree with it.
ODD_JOINTS = {
    "root": (None, [1.0, 2.0, 3.0], "Zrotation Xposition Yrotation Yposition Xrotation Zposition"),
    "a": ("root", [0.0, 1.0, 0.0], "Xrotation Yrotation Zrotation"),
    "slider": ("a", [0.0, 2.0, 0.0], "Xposition Yposition Zposition"),
    "b": ("slider", [0.5, 0.0, 0.0], "Zrotation Xrotation Yrotation"),
    "c": ("root", [-1.0, 0.0, 0.25], "Yposition Yrotation Zrotation Xrotation"),
    "left hand": ("c", [0.0, -1.5, 0.0], "Xrotation"),
    "fixed": ("root", [0.0, 0.0, -2.0], ""),
}

ODD_HIERARCHY = """HIERARCHY
ROOT root
{
\tOFFSET 1 2 3
\tCHANNELS 6 Zrotation Xposition Yrotation Yposition Xrotation Zposition
\tJOINT a
\t{
\t\tOFFSET 0.0 1.0 0.0
\t\tCHANNELS 3 Xrotation Yrotation Zrotation
\t\tJOINT slider
\t\t{
\t\t\tOFFSET 0 2 0
\t\t\tCHANNELS 3 Xposition Yposition Zposition
\t\t\tJOINT b {
\t\t\t\tOFFSET 0.5 0 0
\t\t\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\t\t\tEnd Site
\t\t\t\t{
\t\t\t\t\tOFFSET 0 0 1.5
\t\t\t\t}
\t\t\t}
\t\t}
\t}
    JOINT c
    {
        OFFSET -1 0 0.25
        CHANNELS 4 Yposition Yrotation Zrotation Xrotation
\t    JOINT left hand
\t    {
\t\t\tOFFSET 0 -1.5 0
\t\t\tCHANNELS 1 Xrotation
\t\t\tEnd Site
\t\t\t{
\t\t\t\tOFFSET 0 -0.5 0
\t\t\t}
\t\t}
\t}
\tJOINT fixed
\t{
\t\tOFFSET 0 0 -2
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 0 -1
\t\t}
\t}
}
MOTION"""


def odd_file(tmp_path: Path, num_frames: int = 4) -> tuple[Path, np.ndarray]:
    """Write the odd file with CRLF line ends and random values; return it and the values as read."""
    num_values = sum(len(c.split()) for _, _, c in ODD_JOINTS.values())
    rng = np.random.default_rng(7)
    rows = [[f"{v:.6f}" for v in rng.uniform(-120, 120, num_values)] for _ in range(num_frames)]
    frame_lines = [" \t".join(row[:5]) + "  " + " ".join(row[5:]) for row in rows]
    text = ODD_HIERARCHY + f"\nFrames:\t{num_frames}\nFrame Time: 0.0333333\n" + "\n".join(frame_lines) + "\n"
    path = tmp_path / "odd.bvh"
    path.write_bytes(text.replace("\n", "\r\n").encode())
    return path, np.array([[float(v) for v in row] for row in rows])


def expected_odd_motion(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Local rotations and translations computed channel by channel, independently of the reader."""
    rotations, positions = [], []
    for frame in values:
        column = 0
        frame_rotations, frame_positions = [], []
        for _, offset, channels in ODD_JOINTS.values():
            rotation, translation = np.eye(3), list(offset)
            for name in channels.split():
                if name.endswith("rotation"):
                    rotation = rotation @ axis_rotation(name[0], frame[column])
                else:
                    translation["XYZ".index(name[0])] = frame[column]
                column += 1
            frame_rotations.append(rotation)
            frame_positions.append(translation)
        rotations.append(frame_rotations)
        positions.append(frame_positions)
    return np.array(rotations), np.array(positions)


def test_odd_hierarchy_mixed_orders_crlf_tabs(tmp_path):
    path, values = odd_file(tmp_path)
    motion = read_bvh(path)
    skeleton = motion.skeleton
    names = list(ODD_JOINTS)
    assert skeleton.names == names
    parents = [-1 if parent is None else names.index(parent) for parent, _, _ in ODD_JOINTS.values()]
    assert skeleton.parents.tolist() == parents
    np.testing.assert_array_equal(skeleton.offsets, [o for _, o, _ in ODD_JOINTS.values()])
    assert skeleton.channels == [tuple(c.split()) for _, _, c in ODD_JOINTS.values()]
    orders = [skeleton.rotation_order(j) for j in range(len(names))]
    assert orders == ["ZYX", "XYZ", "", "ZXY", "YZX", "X", ""]
    assert sorted(skeleton.end_sites) == [names.index("b"), names.index("left hand"), names.index("fixed")]
    np.testing.assert_array_equal(skeleton.end_sites[names.index("left hand")], [0, -0.5, 0])
    assert motion.num_frames == 4 and motion.frame_time == 0.0333333

    rotations, positions = expected_odd_motion(values)
    np.testing.assert_allclose(motion.rotations, rotations, atol=1e-12)
    np.testing.assert_allclose(motion.positions, positions, atol=1e-12)


def test_round_trip_keeps_numbers_orders_and_end_sites(tmp_path):
    path, _ = odd_file(tmp_path, num_frames=30)
    motion = read_bvh(path)
    out = tmp_path / "sub" / "again.bvh"
    out.parent.mkdir()
    write_bvh(out, motion)
    again = read_bvh(out)

    assert again.skeleton.names == motion.skeleton.names
    assert again.skeleton.channels == motion.skeleton.channels
    assert again.frame_time == motion.frame_time
    assert sorted(again.skeleton.end_sites) == sorted(motion.skeleton.end_sites)
    for joint, offset in motion.skeleton.end_sites.items():
        np.testing.assert_allclose(again.skeleton.end_sites[joint], offset, atol=1e-6)
    np.testing.assert_allclose(again.rotations, motion.rotations, atol=1e-5)
    np.testing.assert_allclose(again.positions, motion.positions, atol=1e-5)
    text = out.read_text()
    assert "CHANNELS 4 Yposition Yrotation Zrotation Xrotation" in text
    assert "Frame Time: 0.0333333\n" in text
    assert [p.name for p in out.parent.iterdir()] == ["again.bvh"]  # no temporary file left behind


def test_frame_time_keeps_all_digits(tmp_path):
    path, _ = odd_file(tmp_path)
    motion = read_bvh(path)
    motion.frame_time = 1 / 120
    write_bvh(tmp_path / "fps.bvh", motion)
    assert read_bvh(tmp_path / "fps.bvh").frame_time == 1 / 120


def test_failed_write_leaves_the_old_file(tmp_path):
    path, _ = odd_file(tmp_path)
    motion = read_bvh(path)
    before = path.read_bytes()
    broken = motion.slice(0, 2)
    broken.positions = broken.positions[:, :3]
    with pytest.raises(ValueError, match="do not match"):
        write_bvh(path, broken)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["odd.bvh"]


# ---------------------------------------------------------------- real data


def test_euler_convention_matches_pybvh(xia_dir):
    pybvh = pytest.importorskip("pybvh")
    path = xia_dir / "neutral_01_000.bvh"
    reference = pybvh.read_bvh_file(path)
    root_positions, rotations = reference.to_rotmat()
    motion = read_bvh(path)
    assert motion.skeleton.names == reference.joint_names
    np.testing.assert_allclose(motion.rotations, rotations, atol=1e-9)
    np.testing.assert_allclose(motion.root_positions, root_positions, atol=1e-9)
    joints = [n for n in reference.nodes if not n.is_end_site()]
    np.testing.assert_allclose(motion.skeleton.offsets, [n.offset for n in joints], atol=1e-12)
    end_sites = {motion.skeleton.index(n.parent.name): n.offset for n in reference.nodes if n.is_end_site()}
    assert sorted(motion.skeleton.end_sites) == sorted(end_sites)
    for joint, offset in end_sites.items():
        np.testing.assert_allclose(motion.skeleton.end_sites[joint], offset)


@pytest.mark.slow
def test_reads_all_xia_clips_and_round_trips_a_sample(xia_dir, tmp_path):
    files = sorted(xia_dir.glob("*.bvh"))
    assert len(files) == 572
    start = time.perf_counter()
    motions = [read_bvh(f) for f in files]
    seconds = time.perf_counter() - start
    assert seconds < 30, f"reading the Xia set took {seconds:.1f} s"  # ~4 s measured; catches a slow parser
    first = motions[0].skeleton
    assert first.num_joints == 31
    assert sum(m.num_frames for m in motions) == 79_829
    for f, m in zip(files, motions, strict=True):
        assert m.skeleton.same_hierarchy(first), f.name
        assert m.frame_time == pytest.approx(1 / 120, rel=1e-4), f.name
        assert 19 <= m.num_frames <= 377, f.name

    for f, m in list(zip(files, motions, strict=True))[::14]:  # 41 clips across all styles and contents
        out = tmp_path / f.name
        write_bvh(out, m)
        again = read_bvh(out)
        assert again.frame_time == m.frame_time
        np.testing.assert_allclose(again.rotations, m.rotations, atol=1e-5, err_msg=f.name)
        np.testing.assert_allclose(again.positions, m.positions, atol=1e-5, err_msg=f.name)


# ---------------------------------------------------------------- bad input

GOOD = [
    "HIERARCHY",  # 1
    "ROOT Hips",  # 2
    "{",  # 3
    "\tOFFSET 0 0 0",  # 4
    "\tCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation",  # 5
    "\tJOINT Spine",  # 6
    "\t{",  # 7
    "\t\tOFFSET 0 1 0",  # 8
    "\t\tCHANNELS 3 Zrotation Xrotation Yrotation",  # 9
    "\t\tEnd Site",  # 10
    "\t\t{",  # 11
    "\t\t\tOFFSET 0 1 0",  # 12
    "\t\t}",  # 13
    "\t}",  # 14
    "}",  # 15
    "MOTION",  # 16
    "Frames: 2",  # 17
    "Frame Time: 0.033333",  # 18
    "1 2 3 4 5 6 7 8 9",  # 19
    "1 2 3 4 5 6 7 8 9",  # 20
]


def edited(**lines: str | None) -> str:
    """GOOD with some lines replaced (key 'l19' is line 19) or removed (None)."""
    out = list(GOOD)
    for key, text in lines.items():
        out[int(key[1:]) - 1] = text
    return "\n".join(line for line in out if line is not None) + "\n"


def test_good_base_file_reads(tmp_path):
    (tmp_path / "good.bvh").write_text(edited())
    motion = read_bvh(tmp_path / "good.bvh")
    assert motion.num_frames == 2 and motion.skeleton.names == ["Hips", "Spine"]


BAD_TEXT = {
    "empty": (" \n\n", 1, ["empty file", "expected", "HIERARCHY"]),
    "truncated_hierarchy": ("\n".join(GOOD[:9]) + "\n", 9, ["truncated", "expected", "Spine", "end of file"]),
    "missing_closing_brace": (edited(l14=None), 15, ["expected", "'}'", "Hips", "found MOTION"]),
    "extra_closing_brace": (edited(l15="}\n}"), 16, ["expected MOTION", "'}'", "unbalanced"]),
    "too_few_values": (edited(l20="1 2 3 4 5 6 7 8"), 20, ["expected 9 values", "found 8"]),
    "too_many_values": (edited(l19="1 2 3 4 5 6 7 8 9 10"), 19, ["expected 9 values", "found 10"]),
    "non_numeric": (edited(l20="1 2 3 4 5 6 x7 8 9"), 20, ["expected a number", "'x7'", "value 7"]),
    "not_finite": (edited(l19="1 2 nan 4 5 6 7 8 9"), 19, ["expected a number", "'nan'", "value 3"]),
    "unknown_channel": (
        edited(l9="\t\tCHANNELS 3 Zrotation Xrot Yrotation"),
        9,
        ["unknown channel name 'Xrot'", "Spine", "expected one of", "Xrotation"],
    ),
    "channel_count_mismatch": (
        edited(l9="\t\tCHANNELS 4 Zrotation Xrotation Yrotation"),
        9,
        ["bad CHANNELS count", "expected 4", "found 3"],
    ),
    "channel_count_not_a_number": (
        edited(l9="\t\tCHANNELS three Zrotation Xrotation Yrotation"),
        9,
        ["bad CHANNELS count 'three'", "expected a whole number"],
    ),
    "frames_count_disagrees": (edited(l17="Frames: 3"), 17, ["Frames: says 3", "2 frame lines", "expected"]),
    "missing_motion": ("\n".join(GOOD[:15]) + "\n", 15, ["missing MOTION", "expected MOTION"]),
    "bad_frames_line": (edited(l17="Frames: many"), 17, ["expected 'Frames:"]),
    "bad_frame_time": (edited(l18="Frame Time: -1"), 18, ["expected a positive number", "Frame Time"]),
    "bad_offset": (edited(l8="\t\tOFFSET 0 one 0"), 8, ["expected a number", "OFFSET", "Spine", "'one'"]),
}


@pytest.mark.parametrize("case", list(BAD_TEXT))
def test_bad_text_names_file_line_and_expectation(tmp_path, case):
    text, line, phrases = BAD_TEXT[case]
    path = tmp_path / f"{case}.bvh"
    path.write_text(text)
    with pytest.raises(WalkdiffError) as error:
        read_bvh(path)
    message = str(error.value)
    assert message.startswith(f"{path}:{line}: "), message
    assert error.value.line == line
    for phrase in phrases:
        assert phrase in message, message


def test_a_file_that_is_not_bvh_is_never_quoted(tmp_path):
    """A path mistyped onto another file (here a password file) names the file, never its content; once
    a file starts like a BVH, a bad token is quoted, cut to a few characters."""
    path = tmp_path / "passwd"
    path.write_text("\nroot:x:0:0:root:/root:/bin/bash\ndaemon:x:1:1:daemon:/usr/sbin:/usr/sbin/nologin\n")
    with pytest.raises(WalkdiffError) as error:
        read_bvh(path)
    assert str(error.value) == f"{path}:2: not a BVH file: expected one starting with HIERARCHY"
    secret = "x" * 40
    path.write_text(edited(l8=f"\t\tOFFSET 0 {secret} 0"))
    with pytest.raises(WalkdiffError) as error:
        read_bvh(path)
    assert f"found '{'x' * 23}…'" in str(error.value) and secret not in str(error.value)


def test_binary_file_with_nul_bytes(tmp_path):
    path = tmp_path / "binary.bvh"
    path.write_bytes(b"HIERARCHY\nROOT Hips\n\x00\x01\x02")
    with pytest.raises(WalkdiffError, match=r"binary\.bvh:3: binary data.*expected a BVH text file"):
        read_bvh(path)


def test_undecodable_file(tmp_path):
    path = tmp_path / "latin.bvh"
    path.write_bytes(edited().encode().replace(b"ROOT Hips", b"ROOT H\xe9ps"))
    with pytest.raises(WalkdiffError, match=r"latin\.bvh:2: undecodable byte 0xe9.*expected a BVH text file"):
        read_bvh(path)
