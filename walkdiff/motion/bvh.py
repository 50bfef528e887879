"""Read and write BVH files: any hierarchy, any rotation order per joint, position channels on any joint.

Reading gives a `Motion` in the conventions of `walkdiff.motion.skeleton`. A joint's missing rotation
channels mean no rotation about that axis, missing position channels mean the bone offset. Writing keeps
each joint's channels (and so its rotation order) as they were read. Bad input raises `WalkdiffError`
with the file, the line and what was expected.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_atomic
from walkdiff.motion.rotations import euler_to_matrix, matrix_to_euler
from walkdiff.motion.skeleton import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, Skeleton

# Channel names are matched case-insensitively (some exporters write XROTATION) and stored canonically.
_CHANNEL_NAMES = {name.lower(): name for name in POSITION_CHANNELS + ROTATION_CHANNELS}
# Errors quote at most this many characters of a file, and only once it has started like a BVH file: a
# path mistyped onto another file (a key, a password file) must not be echoed.
QUOTE_LIMIT = 24


def quoted(text: str) -> str:
    """`text` quoted for an error message, cut to QUOTE_LIMIT characters."""
    return repr(text if len(text) <= QUOTE_LIMIT else text[: QUOTE_LIMIT - 1] + "…")


def values_per_frame(skeleton: Skeleton) -> int:
    """Numbers on each frame line: one per channel of every joint."""
    return sum(len(c) for c in skeleton.channels)


def read_bvh(path: str | Path) -> Motion:
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise WalkdiffError(f"cannot read the BVH file ({e.strerror})", path=path) from None
    return parse_bvh(_decode(data, path), path)


def _decode(data: bytes, path: Path) -> str:
    nul = data.find(b"\0")
    if nul >= 0:
        line = data.count(b"\n", 0, nul) + 1
        raise WalkdiffError("binary data (NUL byte): expected a BVH text file", path=path, line=line)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        msg = f"undecodable byte 0x{data[e.start]:02x}: expected a BVH text file in UTF-8"
        raise WalkdiffError(msg, path=path, line=line) from None


def parse_bvh(text: str, path: str | Path = "<string>") -> Motion:
    """Parse BVH text; `path` only names the source in error messages."""
    lines = text.splitlines()
    if not text.strip():
        raise WalkdiffError("empty file: expected a BVH file starting with HIERARCHY", path=path, line=1)
    motion_index = next((i for i, line in enumerate(lines) if line.strip().upper() == "MOTION"), None)
    hierarchy_end = len(lines) if motion_index is None else motion_index
    tokens = [(token, i + 1) for i, line in enumerate(lines[:hierarchy_end]) for token in line.split()]
    end = ("end of file", len(lines)) if motion_index is None else ("MOTION", motion_index + 1)
    skeleton = _HierarchyParser(tokens, end, path).parse()
    if motion_index is None:
        msg = "missing MOTION section: expected MOTION, Frames: and Frame Time: after the hierarchy"
        raise WalkdiffError(msg, path=path, line=len(lines))
    values, frame_time = _parse_motion(lines, motion_index + 1, skeleton, path)
    rotations, positions = _channels_to_motion(values, skeleton)
    return Motion(skeleton, rotations, positions, frame_time)


class _HierarchyParser:
    """Recursive descent over (token, line) pairs of the HIERARCHY section."""

    def __init__(self, tokens: list[tuple[str, int]], end: tuple[str, int], path: str | Path):
        self.tokens = tokens
        self.pos = 0
        self.end = end  # what stops the hierarchy ('MOTION' or 'end of file') and its line
        self.path = path
        self.names: list[str] = []
        self.parents: list[int] = []
        self.offsets: list[list[float]] = []
        self.channels: list[tuple[str, ...]] = []
        self.end_sites: dict[int, np.ndarray] = {}

    def error(self, message: str, line: int) -> WalkdiffError:
        return WalkdiffError(message, path=self.path, line=line)

    def peek(self) -> str | None:
        return self.tokens[self.pos][0] if self.pos < len(self.tokens) else None

    def take(self, expected: str) -> tuple[str, int]:
        if self.pos == len(self.tokens):
            what, line = self.end
            raise self.error(f"hierarchy truncated: expected {expected}, found {what}", line)
        self.pos += 1
        return self.tokens[self.pos - 1]

    def keyword(self, word: str, expected: str | None = None) -> int:
        token, line = self.take(expected or word)
        if token.upper() != word.upper():
            raise self.error(f"expected {expected or word}, found {quoted(token)}", line)
        return line

    def rest_of_line(self, line: int) -> list[str]:
        """Tokens left on `line`, up to an opening brace (which may share the line)."""
        rest = []
        while self.pos < len(self.tokens) and self.tokens[self.pos][1] == line and self.peek() != "{":
            rest.append(self.take("")[0])
        return rest

    def number(self, what: str) -> float:
        token, line = self.take(f"a number for {what}")
        try:
            value = float(token)
        except ValueError:
            raise self.error(f"expected a number for {what}, found {quoted(token)}", line) from None
        if not np.isfinite(value):
            raise self.error(f"expected a finite number for {what}, found {quoted(token)}", line)
        return value

    def parse(self) -> Skeleton:
        token, line = self.take("HIERARCHY")
        if token.upper() != "HIERARCHY":  # not a BVH file: none of it is quoted
            raise self.error("not a BVH file: expected one starting with HIERARCHY", line)
        self.keyword("ROOT")
        self.joint(parent=-1, line=self.tokens[self.pos - 1][1])
        if self.pos < len(self.tokens):
            token, line = self.tokens[self.pos]
            msg = f"expected MOTION after the root joint's closing '}}', found {quoted(token)}"
            msg += " (unbalanced braces?)"
            raise self.error(msg, line)
        return Skeleton(self.names, self.parents, self.offsets, self.channels, self.end_sites)

    def joint(self, parent: int, line: int) -> None:
        name = " ".join(self.rest_of_line(line))
        if not name:
            raise self.error("expected a joint name after ROOT/JOINT", line)
        if name in self.names:
            raise self.error(f"duplicate joint name {quoted(name)}: expected unique joint names", line)
        index = len(self.names)
        self.names.append(name)
        self.parents.append(parent)
        opened = self.keyword("{", f"'{{' opening joint {quoted(name)}")
        self.offsets.append(self.offset(f"OFFSET of joint {quoted(name)}"))
        self.channels.append(self.channel_list(name) if (self.peek() or "").upper() == "CHANNELS" else ())
        while True:
            expected = f"JOINT, End Site or '}}' closing joint {quoted(name)} (opened at line {opened})"
            token, line = self.take(expected)
            if token == "}":
                return
            if token.upper() == "JOINT":
                self.joint(parent=index, line=line)
            elif token.upper() == "END":
                self.end_site(index, name, line)
            else:
                raise self.error(f"expected {expected}, found {quoted(token)}", line)

    def offset(self, what: str) -> list[float]:
        self.keyword("OFFSET", what)
        return [self.number(what) for _ in range(3)]

    def end_site(self, joint: int, name: str, line: int) -> None:
        self.keyword("Site", "'Site' after 'End'")
        if joint in self.end_sites:
            raise self.error(f"second End Site in joint {quoted(name)}: expected at most one per joint", line)
        self.keyword("{", "'{' opening the End Site")
        self.end_sites[joint] = np.array(self.offset(f"OFFSET of the End Site of {quoted(name)}"))
        self.keyword("}", f"'}}' closing the End Site of {quoted(name)}")

    def channel_list(self, name: str) -> tuple[str, ...]:
        line = self.take("CHANNELS")[1]
        same_line = self.pos < len(self.tokens) and self.tokens[self.pos][1] == line
        count_token = (self.peek() if same_line else None) or ""
        if not count_token.isdigit() or int(count_token) > 6:
            shown = quoted(count_token) if count_token else "(none)"
            raise self.error(f"bad CHANNELS count {shown}: expected a whole number from 0 to 6", line)
        self.pos += 1
        found = self.rest_of_line(line)
        unknown = [c for c in found if c.lower() not in _CHANNEL_NAMES]
        if unknown:
            allowed = ", ".join(POSITION_CHANNELS + ROTATION_CHANNELS)
            msg = f"unknown channel name {quoted(unknown[0])} in joint {quoted(name)}: "
            msg += f"expected one of {allowed}"
            raise self.error(msg, line)
        if len(found) != int(count_token):
            msg = f"bad CHANNELS count: expected {count_token} channel names after it, found {len(found)}"
            raise self.error(msg, line)
        channels = tuple(_CHANNEL_NAMES[c.lower()] for c in found)
        if len(set(channels)) != len(channels):
            raise self.error(
                f"repeated channel in joint {quoted(name)}: expected each channel at most once", line
            )
        return channels


def _parse_motion(
    lines: list[str], start: int, skeleton: Skeleton, path: str | Path
) -> tuple[np.ndarray, float]:
    """Frames:, Frame Time: and the frame lines after MOTION -> ((F, C) channel values, frame time)."""
    header = (i for i in range(start, len(lines)) if lines[i].strip())
    frames_index = next(header, None)
    fields = [] if frames_index is None else lines[frames_index].split()
    frames_line = len(lines) if frames_index is None else frames_index + 1
    if len(fields) != 2 or fields[0].upper() != "FRAMES:" or not fields[1].isdigit():
        raise WalkdiffError("expected 'Frames: <number of frames>' after MOTION", path=path, line=frames_line)
    num_frames = int(fields[1])
    if num_frames == 0:
        raise WalkdiffError("Frames: 0: expected a clip of at least one frame", path=path, line=frames_line)

    time_index = next(header, None)
    fields = [] if time_index is None else lines[time_index].split()
    time_line = len(lines) if time_index is None else time_index + 1
    if len(fields) != 3 or [f.upper() for f in fields[:2]] != ["FRAME", "TIME:"]:
        raise WalkdiffError("expected 'Frame Time: <seconds>' after Frames:", path=path, line=time_line)
    try:
        frame_time = float(fields[2])
    except ValueError:
        frame_time = float("nan")
    if not frame_time > 0 or not np.isfinite(frame_time):
        msg = f"expected a positive number of seconds for Frame Time, found {quoted(fields[2])}"
        raise WalkdiffError(msg, path=path, line=time_line)

    num_channels = values_per_frame(skeleton)
    # (line number, tokens) of every non-blank line: one split per line serves the count check and parsing.
    body = enumerate(map(str.split, lines[time_index + 1 :]), time_index + 2)
    rows = [(n, tokens) for n, tokens in body if tokens]
    for n, tokens in rows:
        if len(tokens) != num_channels:
            msg = f"expected {num_channels} values per frame (one per channel), found {len(tokens)}"
            raise WalkdiffError(msg, path=path, line=n)
    if len(rows) != num_frames:
        msg = f"Frames: says {num_frames} but {len(rows)} frame lines follow: expected one line per frame"
        raise WalkdiffError(msg, path=path, line=frames_line)
    try:
        values = np.array([float(token) for _, tokens in rows for token in tokens], dtype=np.float64)
    except ValueError:
        values = None
    if values is None or not np.isfinite(values).all():
        _raise_bad_value(rows, path)
    return values.reshape(num_frames, num_channels), frame_time


def _raise_bad_value(rows: list[tuple[int, list[str]]], path: str | Path) -> None:
    """Slow path: find the first token that is not a finite number."""
    for n, tokens in rows:
        for k, token in enumerate(tokens, 1):
            try:
                ok = np.isfinite(float(token))
            except ValueError:
                ok = False
            if not ok:
                msg = f"expected a number for value {k} of the frame, found {quoted(token)}"
                raise WalkdiffError(msg, path=path, line=n)


def _channel_columns(skeleton: Skeleton) -> tuple[list[tuple[int, int, int]], dict[str, tuple[list, list]]]:
    """Where each channel lives in a frame line.

    Returns the position channels as (column, joint, axis) and the rotation channels grouped by rotation
    order as {order: (joints, columns per joint)}, so that each order is converted in one call.
    """
    positions: list[tuple[int, int, int]] = []
    rotations: dict[str, tuple[list, list]] = {}
    column = 0
    for joint, channels in enumerate(skeleton.channels):
        rotation_columns = []
        for name in channels:
            if name in POSITION_CHANNELS:
                positions.append((column, joint, "XYZ".index(name[0])))
            else:
                rotation_columns.append(column)
            column += 1
        if rotation_columns:
            joints, columns = rotations.setdefault(skeleton.rotation_order(joint), ([], []))
            joints.append(joint)
            columns.append(rotation_columns)
    return positions, rotations


def _channels_to_motion(values: np.ndarray, skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    num_frames, num_joints = len(values), skeleton.num_joints
    positions = np.broadcast_to(skeleton.offsets, (num_frames, num_joints, 3)).copy()
    rotations = np.broadcast_to(np.eye(3), (num_frames, num_joints, 3, 3)).copy()
    position_columns, rotation_groups = _channel_columns(skeleton)
    for column, joint, axis in position_columns:
        positions[:, joint, axis] = values[:, column]
    for order, (joints, columns) in rotation_groups.items():
        rotations[:, joints] = euler_to_matrix(values[:, columns], order)
    return rotations, positions


def _motion_to_channels(motion: Motion) -> np.ndarray:
    skeleton = motion.skeleton
    values = np.empty((motion.num_frames, values_per_frame(skeleton)))
    position_columns, rotation_groups = _channel_columns(skeleton)
    for column, joint, axis in position_columns:
        values[:, column] = motion.positions[:, joint, axis]
    for order, (joints, columns) in rotation_groups.items():
        values[:, columns] = matrix_to_euler(motion.rotations[:, joints], order)
    return values


FRAMES_PER_CHUNK = 2000  # frames converted to text at a time: long clips are written in bounded memory


def format_bvh(motion: Motion, precision: int = 6) -> str:
    """BVH text of `motion`: values with `precision` decimals, each joint's channels in its own order."""
    return "".join(_bvh_chunks(motion, precision))


def write_bvh(path: str | Path, motion: Motion, precision: int = 6) -> None:
    """Write atomically: a temporary file in the same folder replaces `path` only once complete.

    The text goes out a chunk of frames at a time, so a clip of any length is never held as one string.
    """

    def save(f) -> None:
        for chunk in _bvh_chunks(motion, precision):
            f.write(chunk.encode("utf-8"))

    write_atomic(path, save)


def _bvh_chunks(motion: Motion, precision: int) -> Iterator[str]:
    """The hierarchy, then the frame rows FRAMES_PER_CHUNK at a time."""
    skeleton = motion.skeleton
    shape = (motion.num_frames, skeleton.num_joints)
    if motion.rotations.shape != (*shape, 3, 3) or motion.positions.shape != (*shape, 3):
        raise ValueError(
            f"motion arrays {motion.rotations.shape} / {motion.positions.shape} do not match "
            f"{skeleton.num_joints} joints"
        )
    if skeleton.parents[0] != -1 or (skeleton.parents[1:] < 0).any():
        raise ValueError("a BVH file holds one hierarchy: expected joint 0 to be the only root")

    def numbers(xs: np.ndarray) -> str:
        return " ".join(f"{x:.{precision}f}" for x in xs)

    out = ["HIERARCHY"]

    def write_joint(joint: int, depth: int) -> None:
        pad = "\t" * depth
        keyword = "ROOT" if depth == 0 else "JOINT"
        out.extend([f"{pad}{keyword} {skeleton.names[joint]}", pad + "{"])
        out.append(f"{pad}\tOFFSET {numbers(skeleton.offsets[joint])}")
        channels = skeleton.channels[joint]
        if channels:
            out.append(f"{pad}\tCHANNELS {len(channels)} {' '.join(channels)}")
        for child in skeleton.children(joint):
            write_joint(child, depth + 1)
        if joint in skeleton.end_sites:
            end = skeleton.end_sites[joint]
            out.extend([f"{pad}\tEnd Site", pad + "\t{", f"{pad}\t\tOFFSET {numbers(end)}", pad + "\t}"])
        out.append(pad + "}")

    write_joint(0, 0)
    # repr keeps the frame time exactly as read (0.008333 stays 0.008333, 1/120 keeps all its digits).
    out.extend(["MOTION", f"Frames: {motion.num_frames}", f"Frame Time: {float(motion.frame_time)!r}"])
    yield "\n".join(out) + "\n"
    row = " ".join([f"%.{precision}f"] * values_per_frame(skeleton))
    for start in range(0, motion.num_frames, FRAMES_PER_CHUNK):
        values = _motion_to_channels(motion.slice(start, start + FRAMES_PER_CHUNK))
        yield "".join(row % tuple(frame) + "\n" for frame in values.tolist())
