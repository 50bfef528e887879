"""Disguised copies of real Xia clips: the same motion, written the way other labs' exporters write it.

walkdiff must read users' own capture: any joint names, units, up axis, rotation order, frame rate, an
extra static root, position channels on every joint, labels in a manifest instead of the file name. The
functions here turn a `Motion` into such a copy while keeping the motion itself, so that a test can undo
the one known change and compare world joint positions with the original clip.

Every disguise maps world positions P (F, J, 3; row vectors) of the original joints by a known affine map
    P_disguised = scale * P @ up.T + translation        (on frames 0, k, 2k, ... for a frame step k)
which `DisguiseRecord.undo` inverts. Each function returns a new `Motion` and never changes its input:

- `rename(motion, convention)`: new joint names ('mixamo', 'unreal', 'smpl'); world map: identity.
- `static_root(motion, ...)`: a constant 6-channel root above the hips; identity (or the root's rigid
  transform with `compensate=False`).
- `scale_units(motion, factor)`: every offset, End Site and translation times `factor`; scale = factor.
- `rotation_order(motion, order)`: other Euler channel orders, same rotation matrices; identity.
- `z_up(motion)`: the clip in a Z-up world; up = U (+Y -> +Z, x fixed).
- `frame_rate(motion, fps)`: every k-th frame (integer ratio of rates); frame step k.
- `position_channels_everywhere(motion)`: position channels on non-root joints; identity.

`disguise(motion, steps)` chains them by name and `disguised_folder` writes a folder of disguised BVH
files under neutral names with a label manifest (`write_labels`).
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from walkdiff.common.files import write_text
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.resample import resample
from walkdiff.motion.rotations import euler_to_matrix
from walkdiff.motion.skeleton import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, Skeleton

CMU_TO_METRES = 0.056444  # one CMU unit in metres
# U: the rotation taking +Y to +Z with x fixed (+90 degrees about X): (x, y, z) -> (x, -z, y).
Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

CONVENTIONS = ("mixamo", "unreal", "smpl")

# Xia content id (1-28) -> the six content groups of the literature.
CONTENT_GROUPS = (
    ("walk", 1, 12),
    ("run", 13, 15),
    ("jump", 16, 17),
    ("punch", 18, 21),
    ("kick", 22, 23),
    ("trans", 24, 28),
)
_XIA_NAME = re.compile(r"^([a-z]+)_(\d{2})_(\d+)$")

# ---------------------------------------------------------------------------------------------- renaming

# CMU joints without a side: (mixamo, unreal, smpl).
_CENTRE = {
    "Hips": ("Hips", "pelvis", "pelvis"),
    "LowerBack": ("Spine", "spine_01", "spine1"),
    "Spine": ("Spine1", "spine_02", "spine2"),
    "Spine1": ("Spine2", "spine_03", "spine3"),
    "Neck": ("Neck", "neck_01", "neck"),
    "Neck1": ("Neck1", "neck_02", "upper_neck"),
    "Head": ("Head", "head", "head"),
}
# The part after CMU's side prefix (Left/Right/L/R): (mixamo, unreal, smpl) parts, the side added by
# the convention (mixamo 'Left' prefix, unreal '_l' suffix, smpl 'left_' prefix).
_SIDED = {
    "HipJoint": ("Hip", "hip", "pelvis"),
    "UpLeg": ("UpLeg", "thigh", "hip"),
    "Leg": ("Leg", "calf", "knee"),
    "Foot": ("Foot", "foot", "ankle"),
    "ToeBase": ("ToeBase", "ball", "foot"),
    "Shoulder": ("Shoulder", "clavicle", "collar"),
    "Arm": ("Arm", "upperarm", "shoulder"),
    "ForeArm": ("ForeArm", "lowerarm", "elbow"),
    "Hand": ("Hand", "hand", "wrist"),
    "FingerBase": ("HandMiddle1", "middle_01", "hand"),
    "HandIndex1": ("HandMiddle2", "middle_02", "middle1"),
    "Thumb": ("HandThumb1", "thumb_01", "thumb1"),
}
_SIDE = re.compile(r"^(Left|Right|L|R)(?=[A-Z])(.+)$")


def joint_side(name: str) -> str | None:
    """'left', 'right' or None for a joint name in any of CMU's or the three conventions' styles."""
    lowered = name.split(":")[-1]
    cmu = _SIDE.match(lowered)
    if cmu:
        return "left" if cmu.group(1).startswith("L") else "right"
    lowered = lowered.lower()
    if lowered.startswith("left_") or lowered.endswith("_l"):
        return "left"
    if lowered.startswith("right_") or lowered.endswith("_r"):
        return "right"
    return None


def _snake(name: str) -> str:
    name = re.sub(r"[^0-9A-Za-z]+", "_", name)
    return re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", name).strip("_").lower()


def _convention_name(name: str, convention: str) -> str:
    k = CONVENTIONS.index(convention)
    sided = _SIDE.match(name)
    if name in _CENTRE:
        base = _CENTRE[name][k]
    elif sided:
        side, part = ("Left" if sided.group(1).startswith("L") else "Right"), sided.group(2)
        base = _SIDED[part][k] if part in _SIDED else (part if k == 0 else _snake(part))
        if convention == "mixamo":
            base = side + base
        elif convention == "unreal":
            base = f"{base}_{side[0].lower()}"
        else:
            base = f"{side.lower()}_{base}"
    else:
        base = name if k == 0 else _snake(name) or "joint"
    return "mixamorig:" + base if convention == "mixamo" else base


def rename(motion: Motion, convention: str) -> tuple[Motion, dict[str, str]]:
    """Joint names in another convention, and the mapping old name -> new name.

    Xia's 31 CMU joints have a fixed table (e.g. unreal: Hips -> pelvis, LHipJoint -> hip_l, LeftUpLeg ->
    thigh_l; smpl: LeftUpLeg -> left_hip, LeftFoot -> left_ankle; mixamo: LowerBack -> mixamorig:Spine);
    any other name is converted by rule (CMU side prefix -> the convention's side marking, snake case for
    unreal/smpl, the 'mixamorig:' prefix). New names are unique (a clash gets a number appended) and keep
    the side (see `joint_side`).
    """
    if convention not in CONVENTIONS:
        raise ValueError(
            f"unknown naming convention {convention!r}: expected one of {', '.join(CONVENTIONS)}"
        )
    mapping: dict[str, str] = {}
    used: set[str] = set()
    for name in motion.skeleton.names:
        new = base = _convention_name(name, convention)
        number = 2
        while new in used:
            new, number = f"{base}{number}", number + 1
        used.add(new)
        mapping[name] = new
    skeleton = _skeleton(motion.skeleton, names=[mapping[n] for n in motion.skeleton.names])
    return replace(motion, skeleton=skeleton), mapping


def _skeleton(skeleton: Skeleton, **changes) -> Skeleton:
    """A copy of `skeleton` with `changes`; arrays and the End Site table are copied, not shared."""
    fields = {
        "names": list(skeleton.names),
        "parents": skeleton.parents.copy(),
        "offsets": skeleton.offsets.copy(),
        "channels": list(skeleton.channels),
        "end_sites": {j: np.array(o, dtype=np.float64) for j, o in skeleton.end_sites.items()},
    }
    fields.update(changes)
    return Skeleton(**fields)


# ------------------------------------------------------------------------------------------- static root

ROOT_CHANNELS = POSITION_CHANNELS + ("Zrotation", "Yrotation", "Xrotation")


def root_rotation(rotation_deg: Sequence[float] | None) -> np.ndarray:
    """Rotation matrix of `static_root`'s `rotation_deg` = (x, y, z) degrees, R = Rz(z) Ry(y) Rx(x)."""
    if rotation_deg is None:
        return np.eye(3)
    x, y, z = (float(a) for a in rotation_deg)
    return euler_to_matrix(np.array([z, y, x]), "ZYX")


def static_root(
    motion: Motion,
    name: str = "Root",
    offset: Sequence[float] = (0.0, 0.0, 0.0),
    rotation_deg: Sequence[float] | None = None,
    compensate: bool = True,
) -> Motion:
    """A new root joint `name` above the old root (the hips), constant on every frame.

    The new root has the 6 channels Xposition Yposition Zposition Zrotation Yrotation Xrotation. Its
    position channels hold `offset` and its rotation channels the rotation R0 = `root_rotation(
    rotation_deg)` (so (0, 0, 0, z, y, x) per frame; all zeros by default); its OFFSET line is 0 0 0, so
    readers that add OFFSET to the position channels and readers that replace it agree. The hips become its
    child with channels Xposition Yposition Zposition + their old rotation channels (all three, ZYX, if
    they had fewer and R0 is not the identity) and keep their OFFSET.

    With `compensate` (default) the hips' channels take the root out again: hips rotation R0^T R, hips
    translation R0^T (p - offset). Then every original joint's world position and world rotation is
    unchanged on every frame (up to float rounding); only the rest pose (all channels zero) turns by R0.
    Without it the hips keep their channels, and world positions become P @ R0.T + offset, world
    rotations R0 W: the copy is the original turned and moved as a whole.
    """
    sk = motion.skeleton
    if name in sk.names:
        raise ValueError(f"joint name {name!r} already in the skeleton")
    r0 = root_rotation(rotation_deg)
    t0 = np.asarray(offset, dtype=np.float64).reshape(3)
    frames = motion.num_frames
    hips_rotation, hips_position = motion.rotations[:, 0], motion.positions[:, 0]
    if compensate:
        hips_rotation = r0.T @ hips_rotation
        hips_position = (hips_position - t0) @ r0
    rotation_channels = tuple(c for c in sk.channels[0] if c in ROTATION_CHANNELS)
    if len(rotation_channels) < 3 and not np.allclose(hips_rotation, np.eye(3)):
        rotation_channels = ROOT_CHANNELS[3:]
    skeleton = Skeleton(
        names=[name, *sk.names],
        parents=np.concatenate([[-1], sk.parents + 1]),
        offsets=np.concatenate([np.zeros((1, 3)), sk.offsets]),
        channels=[ROOT_CHANNELS, POSITION_CHANNELS + rotation_channels, *sk.channels[1:]],
        end_sites={j + 1: np.array(o, dtype=np.float64) for j, o in sk.end_sites.items()},
    )
    rotations = np.concatenate(
        [np.broadcast_to(r0, (frames, 1, 3, 3)), hips_rotation[:, None], motion.rotations[:, 1:]], axis=1
    )
    positions = np.concatenate(
        [np.broadcast_to(t0, (frames, 1, 3)), hips_position[:, None], motion.positions[:, 1:]], axis=1
    )
    return Motion(skeleton, rotations, positions, motion.frame_time)


# ------------------------------------------------------------------------------------ units, axes, order


def scale_units(motion: Motion, factor: float) -> Motion:
    """Every OFFSET, End Site and translation (channel-driven or not) times `factor`; rotations kept.
    World positions become `factor` * P (CMU units -> metres: `CMU_TO_METRES`)."""
    if not factor > 0:
        raise ValueError(f"expected a positive unit factor, got {factor}")
    sk = motion.skeleton
    skeleton = _skeleton(
        sk,
        offsets=sk.offsets * factor,
        end_sites={j: np.asarray(o) * factor for j, o in sk.end_sites.items()},
    )
    return Motion(skeleton, motion.rotations.copy(), motion.positions * factor, motion.frame_time)


def rotation_order(motion: Motion, order: str, position_order: str | None = None) -> Motion:
    """Every joint with three rotation channels gets them in Euler `order` (e.g. 'XYZ'), in the same
    slots of its channel list; the rotation matrices are unchanged, so writing re-expresses the angles.
    With `position_order` (e.g. 'ZXY') every joint with three position channels lists them in that
    order. Joints with fewer channels keep theirs. World positions: unchanged."""
    for what, axes in (("rotation", order), ("position", position_order or "XYZ")):
        if sorted(axes.upper()) != ["X", "Y", "Z"]:
            raise ValueError(f"expected a {what} order of the three axes X, Y, Z, got {axes!r}")
    rotation_names = [f"{a}rotation" for a in order.upper()]
    position_names = [f"{a}position" for a in (position_order or "").upper()]
    channels = []
    for joint_channels in motion.skeleton.channels:
        rotations = [c for c in joint_channels if c in ROTATION_CHANNELS]
        positions = [c for c in joint_channels if c in POSITION_CHANNELS]
        new_rotations = iter(rotation_names if len(rotations) == 3 else rotations)
        new_positions = iter(position_names if position_order and len(positions) == 3 else positions)
        channels.append(
            tuple(
                next(new_rotations) if c in ROTATION_CHANNELS else next(new_positions) for c in joint_channels
            )
        )
    skeleton = _skeleton(motion.skeleton, channels=channels)
    return Motion(skeleton, motion.rotations.copy(), motion.positions.copy(), motion.frame_time)


# ------------------------------------------------------------------------------------------ twists


def _axis_rotations(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations by `angles` (N,) radians about the unit `axis` (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s, c = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def push_twists(motion: Motion, seed: int = 0) -> Motion:
    """Every joint turned about its bone by a random angle on every frame, the turn taken out again by its
    children: the same world joint positions written with other rotations, as another solver, retargeting
    tool or exporter would write them (the convention of twists is free).

    A joint with one child turns about the bone to that child, per frame; a joint with several children
    turns by one random constant rotation and its children's OFFSETs turn back with it. Joints with fewer
    than three rotation channels, or with such a child, keep their rotations.
    """
    rng = np.random.default_rng(seed)
    sk = motion.skeleton
    frames = motion.num_frames
    rotations = motion.rotations.copy()
    positions = motion.positions.copy()
    offsets = sk.offsets.copy()
    full = [sk.rotation_order(j) and len(sk.rotation_order(j)) == 3 for j in range(sk.num_joints)]
    for j in range(sk.num_joints):
        children = sk.children(j)
        if not children or not full[j] or not all(full[c] for c in children):
            continue
        if len(children) == 1 and np.linalg.norm(offsets[children[0]]) > 1e-9:
            axis = offsets[children[0]] / np.linalg.norm(offsets[children[0]])
            turn = _axis_rotations(axis, rng.uniform(-np.pi, np.pi, frames))
        else:
            axis = rng.normal(size=3)
            turn = np.broadcast_to(
                _axis_rotations(axis / np.linalg.norm(axis), rng.uniform(-np.pi, np.pi, 1)), (frames, 3, 3)
            )
            for c in children:
                offsets[c] = turn[0].T @ offsets[c]
        back = np.swapaxes(turn, -1, -2)
        rotations[:, j] = rotations[:, j] @ turn
        for c in children:
            rotations[:, c] = back @ rotations[:, c]
            # A translation given per frame (position channels) turns back like an OFFSET.
            positions[:, c] = (
                (back @ positions[:, c, :, None])[..., 0] if sk.position_order(c) else offsets[c]
            )
    return Motion(_skeleton(sk, offsets=offsets), rotations, positions, motion.frame_time)


# A channel about axis a of a partial channel set becomes a channel about U a (up to sign, which the
# written angle absorbs): X stays X, Y becomes Z, Z becomes Y.
_Z_UP_AXIS = {"X": "X", "Y": "Z", "Z": "Y"}


def z_up(motion: Motion) -> Motion:
    """The clip in a Z-up world, as a Z-up exporter writes it (its rest pose is Z-up too).

    With U = `Z_UP`, every local rotation R becomes U R U^T and every OFFSET, End Site and translation o
    becomes U o, so that world positions become U P (P @ U.T) and world rotations U W U^T. Joints with a
    full set of 3 position or 3 rotation channels keep their channel names; a partial set is renamed
    about the turned axes (a lone Yrotation becomes Zrotation) so that it can still hold the rotation.
    """
    u = Z_UP
    sk = motion.skeleton
    channels = []
    for joint_channels in sk.channels:
        full_rotations = sum(c in ROTATION_CHANNELS for c in joint_channels) == 3
        full_positions = sum(c in POSITION_CHANNELS for c in joint_channels) == 3
        channels.append(
            tuple(
                c
                if (full_rotations if c in ROTATION_CHANNELS else full_positions)
                else _Z_UP_AXIS[c[0]] + c[1:]
                for c in joint_channels
            )
        )
    skeleton = _skeleton(
        sk,
        offsets=sk.offsets @ u.T,
        channels=channels,
        end_sites={j: u @ np.asarray(o) for j, o in sk.end_sites.items()},
    )
    return Motion(skeleton, u @ motion.rotations @ u.T, motion.positions @ u.T, motion.frame_time)


# ---------------------------------------------------------------------------------------- frames, channels

_RATE_TOLERANCE = 1e-3  # Xia writes 0.008333 s for 120 fps: 120.0048 / 60 is 2 within 3e-5


def frame_step(motion: Motion, fps: float) -> int | None:
    """k when `fps` is the clip's rate divided by a whole number k (within 0.1%), else None."""
    if not fps > 0:
        raise ValueError(f"expected a positive frame rate, got {fps}")
    ratio = motion.fps / fps
    step = round(ratio)
    return step if step >= 1 and abs(ratio - step) <= _RATE_TOLERANCE * step else None


def frame_rate(motion: Motion, fps: float) -> Motion:
    """The clip at `fps`, Frame Time 1/fps. An integer ratio k of rates keeps frames 0, k, 2k, ... exactly
    (120 -> 60: every second frame); any other ratio falls back to walkdiff's `resample` (interpolated)."""
    step = frame_step(motion, fps)
    if step is None:
        return resample(motion, fps)
    rotations, positions = motion.rotations[::step].copy(), motion.positions[::step].copy()
    return Motion(_skeleton(motion.skeleton), rotations, positions, 1.0 / fps)


def position_channels_everywhere(motion: Motion, joints: Iterable[str] | None = None) -> Motion:
    """Xposition Yposition Zposition channels (before the rotation channels) on the named joints, by
    default every non-root joint that has none; their values are the bone offsets on every frame, as some
    exporters write. World positions: unchanged."""
    sk = motion.skeleton
    targets = {sk.index(n) for n in joints} if joints is not None else set(range(1, sk.num_joints))
    channels = [
        POSITION_CHANNELS + tuple(c for c in chans if c not in POSITION_CHANNELS)
        if j in targets and not any(c in POSITION_CHANNELS for c in chans)
        else chans
        for j, chans in enumerate(sk.channels)
    ]
    skeleton = _skeleton(sk, channels=channels)
    return Motion(skeleton, motion.rotations.copy(), motion.positions.copy(), motion.frame_time)


# ----------------------------------------------------------------------------------------------- chains


@dataclass
class DisguiseRecord:
    """What a chain of disguises did, enough to map the copy back onto the original.

    World positions of original joints: P_disguised = scale * P[::frame_step] @ up.T + translation.
    `names` maps each original joint to its name in the copy (joints added, like a static root, are not
    in it); `files` maps original file names to disguised ones (for `disguised_folder`).
    """

    steps: list[str]
    scale: float = 1.0
    up: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    names: dict[str, str] = field(default_factory=dict)
    frame_step: int | None = 1
    files: dict[str, str] = field(default_factory=dict)
    manifest: Path | None = None
    precision: int = 6

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Original world points (..., 3) -> where the copy has them."""
        return self.scale * np.asarray(points) @ self.up.T + self.translation

    def undo(self, points: np.ndarray) -> np.ndarray:
        """World points (..., 3) of the copy -> the original's world frame and units."""
        return (np.asarray(points) - self.translation) @ self.up / self.scale


DEFAULT_STEPS = ("unreal", "static_root", "metres", "order:XYZ", "z_up", "fps:60")
STEP_HELP = (
    "mixamo | unreal | smpl (rename), static_root, static_root:<axis><deg> (e.g. X-90: a rotated root,"
    " compensated in the hips), turned_root:<axis><deg> (not compensated: the clip turns), metres, cm,"
    " scale:<factor>, order:<XYZ>[:<position order>], z_up, fps:<rate>, positions"
)


def _axis_angle(spec: str, step: str) -> tuple[float, float, float]:
    match = re.fullmatch(r"([XYZxyz])([-+]?\d+(?:\.\d*)?)", spec)
    if not match:
        raise ValueError(f"bad disguise step {step!r}: expected an axis and degrees after ':', e.g. X-90")
    angles = [0.0, 0.0, 0.0]
    angles["XYZ".index(match.group(1).upper())] = float(match.group(2))
    return angles[0], angles[1], angles[2]


def apply_step(motion: Motion, step: str, record: DisguiseRecord) -> Motion:
    """One named disguise (see `STEP_HELP`); `record` is updated with its effect on world positions."""
    kind, _, arg = step.partition(":")
    if kind in CONVENTIONS and not arg:
        motion, mapping = rename(motion, kind)
        record.names = {original: mapping[current] for original, current in record.names.items()}
        return motion
    if kind in ("static_root", "turned_root"):
        rotation = _axis_angle(arg, step) if arg else None
        compensate = kind == "static_root"
        if not compensate:
            r0 = root_rotation(rotation)
            record.up = r0 @ record.up
            record.translation = r0 @ record.translation
        name = "Root"
        while name in motion.skeleton.names:
            name += "_"
        return static_root(motion, name, rotation_deg=rotation, compensate=compensate)
    if kind in ("metres", "cm", "scale"):
        factor = {"metres": CMU_TO_METRES, "cm": CMU_TO_METRES * 100}.get(kind) if not arg else None
        if factor is None:
            try:
                factor = float(arg) if kind == "scale" else math.nan
            except ValueError:
                factor = math.nan
        if not factor > 0:
            raise ValueError(f"bad disguise step {step!r}: expected metres, cm or scale:<positive factor>")
        record.scale *= factor
        record.translation = record.translation * factor
        return scale_units(motion, factor)
    if kind == "order" and arg:
        order, _, position_order = arg.partition(":")
        return rotation_order(motion, order, position_order or None)
    if kind == "z_up" and not arg:
        record.up = Z_UP @ record.up
        record.translation = Z_UP @ record.translation
        return z_up(motion)
    if kind == "fps" and arg:
        fps = float(arg)
        step_here = frame_step(motion, fps)
        record.frame_step = (
            None if step_here is None or record.frame_step is None else record.frame_step * step_here
        )
        return frame_rate(motion, fps)
    if kind == "positions" and not arg:
        return position_channels_everywhere(motion)
    raise ValueError(f"unknown disguise step {step!r}: expected one of {STEP_HELP}")


def disguise(motion: Motion, steps: Sequence[str] = DEFAULT_STEPS) -> tuple[Motion, DisguiseRecord]:
    """`motion` through the named steps in order, and the record of what they did."""
    record = DisguiseRecord(steps=list(steps), names={n: n for n in motion.skeleton.names})
    for step in steps:
        motion = apply_step(motion, step, record)
    return motion, record


# ------------------------------------------------------------------------------------------------ labels


def xia_labels(file_name: str | Path) -> tuple[str, str]:
    """(style, content group) of a Xia file name STYLE_CC_NNN(.bvh), e.g. ('angry', 'walk')."""
    stem = Path(file_name).name.removesuffix(".bvh")
    match = _XIA_NAME.match(stem)
    if not match:
        raise ValueError(f"{file_name!r} is not a Xia file name STYLE_CC_NNN.bvh")
    content = int(match.group(2))
    for group, first, last in CONTENT_GROUPS:
        if first <= content <= last:
            return match.group(1), group
    raise ValueError(f"{file_name!r}: content id {content} is not a Xia content id (01-28)")


LABEL_COLUMNS = ("file", "style", "content")


def write_labels(
    folder: str | Path,
    files: Mapping[str, str],
    kind: str = "csv",
    splits: Mapping[str, str] | None = None,
    originals: Mapping[str, str] | None = None,
    contents: Mapping[str, str] | None = None,
) -> Path:
    """Write `labels.csv` or `labels.json` in `folder`: one row per disguised file, columns file, style,
    content (and split when `splits` is given), rows in file order.

    `files` maps each original Xia file name (which gives the labels) to its disguised name (the `file`
    column); `splits` maps original names to a split name; `originals` maps a key of `files` that is not
    a Xia name (a tempo copy) to its Xia file; `contents` maps original names to a content label instead
    of their Xia group. JSON is a list of row objects.
    """
    originals = originals or {}
    if kind not in ("csv", "json"):
        raise ValueError(f"unknown label manifest kind {kind!r}: expected csv or json")
    columns = LABEL_COLUMNS + (("split",) if splits is not None else ())
    rows = []
    for key, disguised in sorted(files.items(), key=lambda item: item[1]):
        original = originals.get(key, key)
        style, content = xia_labels(original)
        row = {"file": disguised, "style": style, "content": (contents or {}).get(original, content)}
        if splits is not None:
            row["split"] = splits[original]
        rows.append(row)
    path = Path(folder) / f"labels.{kind}"
    if kind == "json":
        return write_text(path, json.dumps(rows, indent=2) + "\n")
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return write_text(path, buffer.getvalue())


# ------------------------------------------------------------------------------------------------ folder


def default_precision(scale: float) -> int:
    """Decimals for writing: 6 as Xia has at its own scale, plus the digits a smaller unit needs and one
    more (metres: 9)."""
    return 6 if scale >= 1 else 7 + math.ceil(-math.log10(scale))


def tempo(motion: Motion, speed: float) -> Motion:
    """The same movement performed `speed` times faster (a quicker or slower performer), at the clip's
    own frame rate: resampled in time, then played at the original rate."""
    if speed == 1:
        return motion
    return replace(resample(motion, motion.fps / speed), frame_time=motion.frame_time)


def disguised_folder(
    xia_dir: str | Path,
    out_dir: str | Path,
    clips: Iterable[str | Path],
    steps: Sequence[str] = DEFAULT_STEPS,
    labels: str = "csv",
    splits: Mapping[str, str] | None = None,
    precision: int | None = None,
    seed: int = 0,
    speeds: Sequence[float] = (1.0,),
    contents: Mapping[str, str] | None = None,
) -> DisguiseRecord:
    """Write the Xia `clips` (file names, with or without .bvh) through the same `steps` into `out_dir`.

    Files get neutral names take_0001.bvh ... numbered in a seeded random order (neither the name nor the
    number tells a label); the manifest (`write_labels`, kind `labels`) holds the labels. Values are
    written with `precision` decimals (default: `default_precision` of the chain's unit scale). With
    several `speeds`, every clip is written once per tempo (`tempo`), each copy in its clip's split: a
    larger folder of the same kind. `contents`: content labels by Xia file name, instead of the groups.
    Returns the record (identical for every clip; a clip whose frame step
    or names differ raises).
    """
    names = [Path(c).name if str(c).endswith(".bvh") else Path(c).name + ".bvh" for c in clips]
    if len(set(names)) != len(names):
        raise ValueError("the same clip is listed twice")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    copies = [(name, speed) for name in names for speed in speeds]
    numbers = np.random.default_rng(seed).permutation(len(copies)) + 1
    record: DisguiseRecord | None = None
    originals: dict[str, str] = {}  # disguised copy -> its Xia file, for the labels
    for (name, speed), number in zip(copies, numbers):
        motion, this = disguise(tempo(read_bvh(Path(xia_dir) / name), speed), steps)
        if record is None:
            record = this
            record.precision = precision if precision is not None else default_precision(record.scale)
        elif this.names != record.names or this.frame_step != record.frame_step:
            raise ValueError(f"{name}: the disguise differs from the first clip's (skeleton or frame rate)")
        copy = name if len(speeds) == 1 else f"{name.removesuffix('.bvh')}@{speed:g}.bvh"
        originals[copy] = name
        record.files[copy] = f"take_{number:04d}.bvh"
        write_bvh(out_dir / record.files[copy], motion, precision=record.precision)
    if record is None:
        raise ValueError("no clips given")
    record.manifest = write_labels(out_dir, record.files, labels, splits, originals, contents)
    return record


STRAIGHT_DEG = 20.0  # a walk turning less than this over the clip is labelled straight (`turn_labels`)


def turn_labels(xia_dir: str | Path, clips: Iterable, degrees: float) -> tuple[dict, dict]:
    """Content labels and splits by how each walk really turns (Xia's content ids do not tell: about half
    of `walk_lturn_l1` turns right): `walk-turn-left` beyond `degrees` to the body's left over the clip,
    `walk-turn-right` beyond it to the right, `walk` within `STRAIGHT_DEG`; clips in between are left
    out. Split: the first clip by name of each style and label with three or more is the test clip, the
    second of those with four or more the validation clip (so a scanned folder validates and its
    metrics callback measures while training). Returns ({file: label}, {file: split})."""
    from walkdiff.data.xia import PROFILE
    from walkdiff.motion.profile import SkeletonProfile
    from walkdiff.motion.representation import FeatureLayout, encode

    labels: dict[str, str] = {}
    profile = None
    for clip in sorted(clips, key=lambda c: c.name):
        motion = read_bvh(Path(xia_dir) / f"{clip.name}.bvh")
        profile = profile or SkeletonProfile.detect(motion, PROFILE)
        heading = encode(profile.to_canonical(motion), profile)[:, FeatureLayout.heading_vel.start]
        turn = math.degrees(float(heading.sum()))
        label = (
            "walk-turn-left" if turn > degrees else "walk-turn-right" if turn < -degrees
            else "walk" if abs(turn) < STRAIGHT_DEG else None
        )  # fmt: skip
        if label is not None:
            labels[f"{clip.name}.bvh"] = label
    groups: dict[tuple[str, str], list[str]] = {}
    for name, label in labels.items():
        groups.setdefault((xia_labels(name)[0], label), []).append(name)
    splits = {name: "train" for name in labels}
    for names in groups.values():
        if len(names) >= 3:
            splits[names[0]] = "test"
        if len(names) >= 4:
            splits[names[1]] = "val"
    return labels, splits


# Xia's one-off actions that name a side, by content id: lateral labels of another lab's export.
SIDED_ACTIONS = {18: "punch-right", 19: "punch-left", 20: "punch-right", 21: "punch-left",
                 22: "kick-left", 23: "kick-right"}  # fmt: skip


def action_labels(clips: Iterable) -> dict[str, str]:
    """Content labels of Xia's clips that are not walks: punches and kicks by the side they strike with
    (`punch-left` ... `kick-right`, from the content ids), the other actions by their group."""
    labels = {}
    for clip in clips:
        content = int(_XIA_NAME.match(clip.name).group(2))
        labels[f"{clip.name}.bvh"] = SIDED_ACTIONS.get(content) or xia_labels(clip.name)[1]
    return labels


def main(argv: Sequence[str] | None = None) -> None:
    """`python tests/disguise.py XIA_DIR OUT_DIR`: Xia's walks, disguised, labels and Xia's split in a CSV.

    The disguised dataset the README's own-data figures are measured on (no committed data: made here).
    """
    import argparse

    from walkdiff.data import xia
    from walkdiff.data.clips import ContentSelection

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("xia_dir")
    parser.add_argument("out_dir")
    parser.add_argument("--contents", default="walk", help="Xia content groups (default walk)")
    parser.add_argument("--steps", default=",".join(DEFAULT_STEPS), help="disguise chain, comma-separated")
    parser.add_argument(
        "--speeds",
        default="1",
        help="tempo copies of every clip, comma-separated (e.g. 0.8,1,1.2: 3x the data)",
    )
    parser.add_argument(
        "--turns",
        type=float,
        default=None,
        help="label the walks by how they turn instead (walk-turn-left / walk-turn-right beyond this many "
        f"degrees, walk within {STRAIGHT_DEG:g}, the others left out), a test clip per style and label; "
        "with other contents, punches and kicks by their side (punch-left ... kick-right)",
    )
    args = parser.parse_args(argv)
    clips = xia.list_clips(Path(args.xia_dir))
    splits = xia.split_clips(clips, ContentSelection.parse(args.contents, xia.GROUPS))
    split_of = {f"{c.name}.bvh": split for split, members in splits.items() for c in members}
    contents = None
    if args.turns is not None:
        walks = [c for members in splits.values() for c in members if xia.GROUPS[c.content] == "walk"]
        contents, turn_splits = turn_labels(args.xia_dir, walks, args.turns)
        # Other contents selected (--contents all): actions, sided ones by their side, in Xia's split.
        actions = [c for members in splits.values() for c in members if xia.GROUPS[c.content] != "walk"]
        contents |= action_labels(actions)
        split_of = turn_splits | {f"{c.name}.bvh": split_of[f"{c.name}.bvh"] for c in actions}
    record = disguised_folder(
        args.xia_dir, args.out_dir, sorted(split_of), args.steps.split(","), splits=split_of,
        speeds=[float(s) for s in args.speeds.split(",")], contents=contents,
    )  # fmt: skip
    print(f"wrote {len(record.files)} disguised clips and {record.manifest} ({', '.join(record.steps)})")


if __name__ == "__main__":
    main()


# ------------------------------------------------------------------------- rest poses and split roots


def _turn_to(axis: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the unit `axis` to the unit `direction` (Rodrigues)."""
    cross, cos = np.cross(axis, direction), float(axis @ direction)
    sin = np.linalg.norm(cross)
    if sin < 1e-12:
        return np.eye(3) if cos > 0 else _axis_rotations(np.array([0.0, 0.0, 1.0]), np.array([np.pi]))[0]
    return _axis_rotations(cross / sin, np.array([np.arctan2(sin, cos)]))[0]


def axis_rest(motion: Motion, axis: int = 0, joints: Iterable[str] | None = None) -> Motion:
    """A rest pose that is no pose: every bone of the named joints (default all) along the file's +/- axis
    `axis` (0 = X), its length kept, the sign that of the bone's own component; world positions unchanged.

    A joint j with one child bone (or, at a leaf, an End Site) gets a constant turn C_j taking the axis
    to its bone, so the child's OFFSET becomes C_j^T o = +/-|o| along the axis; its rotation becomes
    C_parent^T R_j C_j and every translation below it C_j^T p. Joints with several children (or fewer than
    three rotation channels) keep C = I: their children's OFFSETs cannot all lie on one axis. The root's
    turn, if any, changes its world rotation (W C): a profile's forward axis turns with it.
    """
    sk = motion.skeleton
    chosen = set(sk.names if joints is None else joints)
    unit = np.eye(3)[axis]
    turns = np.repeat(np.eye(3)[None], sk.num_joints, axis=0)
    for j in range(sk.num_joints):
        children = sk.children(j)
        bone = (
            sk.offsets[children[0]] if len(children) == 1 else sk.end_sites.get(j) if not children else None
        )
        if sk.names[j] not in chosen or bone is None or len(sk.rotation_order(j)) != 3:
            continue
        if np.linalg.norm(bone) > 1e-9:
            sign = 1.0 if bone[axis] >= 0 else -1.0
            turns[j] = _turn_to(sign * unit, bone / np.linalg.norm(bone))
    parent_turns = np.concatenate([np.eye(3)[None], turns[sk.parents[1:]]])  # C of each joint's parent
    back = np.swapaxes(parent_turns, -1, -2)
    rotations = back @ motion.rotations @ turns
    rotations[:, 0] = motion.rotations[:, 0] @ turns[0]
    positions = motion.positions.copy()
    positions[:, 1:] = (back[1:] @ motion.positions[:, 1:, :, None])[..., 0]
    offsets = sk.offsets.copy()
    offsets[1:] = (back[1:] @ sk.offsets[1:, :, None])[..., 0]
    ends = {j: turns[j].T @ np.asarray(o) for j, o in sk.end_sites.items()}
    return Motion(_skeleton(sk, offsets=offsets, end_sites=ends), rotations, positions, motion.frame_time)


def split_root(motion: Motion, carry: str = "ground", name: str = "Root", up: int = 1) -> Motion:
    """A new, unrotated root `name` above the hips that carries part of their translation; the hips
    (position channels) keep the rest, so world positions are unchanged.

    `carry="ground"`: the root carries the hips' path on the floor (up coordinate 0, axis `up` of the
    file) and the hips their height with its bob, as game rigs' ground-projected roots do: the root lies
    below the feet. `carry="path"`: the root carries the hips' translation smoothed over a second (height
    included) and the hips a small bob and sway around it: a root that looks static next to the hips.
    """
    hips = motion.positions[:, 0]
    if carry == "ground":
        carried = hips.copy()
        carried[:, up] = 0.0
    elif carry == "path":
        width = max(1, int(round(motion.fps)))
        kernel = np.ones(width) / width
        padded = np.pad(hips, ((width // 2, width - 1 - width // 2), (0, 0)), mode="edge")
        carried = np.stack([np.convolve(padded[:, i], kernel, mode="valid") for i in range(3)], axis=1)
    else:
        raise ValueError(f"unknown carry {carry!r}: expected ground or path")
    moved = static_root(motion, name)
    moved.positions[:, 0] = carried
    moved.positions[:, 1] = hips - carried
    return moved
