"""What differs between skeletons, found from a BVH clip: a `SkeletonProfile`.

Motion capture from different labs differs in ways the representation must not care about: which
joint carries the root motion (a static `Root` above the hips is common in game rigs), the feet's
names, which axis is up, the units, the body's size. A profile records all of it, found from one clip
and overridable in configuration, and is saved in every feature cache and checkpoint:

- root: the joint whose translation moves. Static joints above it (constant transform over the clip)
  are *folded*: their transform is applied to the root and restored, as it was, on export.
- feet: heel (ankle) and toe of each side, by name over the common conventions (CMU, Mixamo, SMPL,
  Unreal, DAZ, Biped ...), else the ends of the two leg chains (the left/right pair nearest the root).
- left/right pairs by name (`walkdiff.motion.mirror.find_mirror_pairs`).
- up: the signed file axis from the feet to the root over the clip; `forward`: the root's local axis
  that points where the body faces (up x (right - left) over the clip's left/right pairs).
- units (metres per unit) from the body height when it is a human height in m, cm, mm or inches;
  otherwise estimated for a 1.7 m body and said so.
- contact thresholds from the body height: speed `CONTACT_SPEED` heights/s (per frame: that over the
  frame rate), height `CONTACT_HEIGHT` heights. On Xia (25.4 units tall) that is 5.1 units/s and
  0.51 units, within 2% of the thresholds measured by hand on its foot speeds.

Everything below works in the *canonical* frame: Y up, the root's subtree only (the body), every
local rotation and offset expressed in that frame (R -> U R U^T, o -> U o with U taking the file's
up axis to +Y). A canonical clip has the same world positions as the file's, turned by U.
`to_canonical` and `to_file` convert a clip both ways; the round trip is exact for the folded and
non-body joints when they are static, as the profile found them.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.kinematics import forward_kinematics
from walkdiff.motion.mirror import find_mirror_pairs
from walkdiff.motion.skeleton import Motion, Skeleton, skeleton_from_dict, skeleton_to_dict

CONTACT_SPEED = 0.2  # body heights per second
CONTACT_HEIGHT = 0.02  # body heights above the foot's own floor
ASSUMED_HEIGHT_M = 1.7  # when the units cannot be told from the body height
BONE_TOLERANCE = 0.01  # body heights: a bone longer or shorter than this is another skeleton

# Body heights (file units) of a human in each unit, and metres per unit.
_UNITS = (
    ("m", 1.0, 1.0, 2.3),
    ("cm", 0.01, 100.0, 230.0),
    ("mm", 0.001, 1000.0, 2300.0),
    ("in", 0.0254, 39.0, 91.0),
)
_UNIT_NAMES = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "inch": 0.0254, "ft": 0.3048}

_AXES = {
    "+x": (1, 0, 0),
    "-x": (-1, 0, 0),
    "+y": (0, 1, 0),
    "-y": (0, -1, 0),
    "+z": (0, 0, 1),
    "-z": (0, 0, -1),
}

# Heel/ankle and toe names; words that rule a joint out (fingers, end joints, twist/roll helpers).
_HEEL = re.compile(r"(foot|ankle|heel)", re.IGNORECASE)
_TOE = re.compile(r"(toe|ball)", re.IGNORECASE)
_NOT_FOOT = re.compile(r"(end|nub|site|index|thumb|finger|twist|roll|ik|target|pole)", re.IGNORECASE)

NO_FEET = (
    "no feet found (no joints named like feet/ankles/toes on both sides, no left/right leg chains): "
    "contacts need them; name them in the profile (left_heel, left_toe, right_heel, right_toe)"
)

OVERRIDE_FIELDS = (
    "root", "left_heel", "left_toe", "right_heel", "right_toe", "up", "forward", "units",
    "body_height", "contact_speed", "contact_height", "mirror_pairs",
)  # fmt: skip

TO_FILE_FRAMES = 4096  # frames converted at a time by SkeletonProfile.to_file


@dataclass(frozen=True)
class ContactSpec:
    """Which joints touch the ground and when a joint counts as touching it.

    A joint is in contact when it moves slower than `speed_threshold` (units/s) and is lower than
    `height_threshold` (units) above its own floor, the `floor_percentile`-th percentile of its height
    over the clip. A per-joint floor copes with clips whose floor is offset, and with skeletons whose
    left and right feet do not reach the same height.
    """

    left_heel: str
    left_toe: str
    right_heel: str
    right_toe: str
    speed_threshold: float
    height_threshold: float
    floor_percentile: float = 5.0

    @property
    def joints(self) -> tuple[str, str, str, str]:
        return (self.left_heel, self.left_toe, self.right_heel, self.right_toe)


def axis_rotation(up: tuple[float, float, float]) -> np.ndarray:
    """The proper rotation U with U @ up = +Y (the smallest turn; a half turn about X for -Y)."""
    up = np.asarray(up, dtype=np.float64)
    y = np.array([0.0, 1.0, 0.0])
    if np.allclose(up, y):
        return np.eye(3)
    if np.allclose(up, -y):
        return np.diag([1.0, -1.0, -1.0])
    axis = np.cross(up, y)
    angle = np.arccos(np.clip(up @ y, -1.0, 1.0))
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _axis_name(v: np.ndarray) -> str:
    """'+y' for an axis, '(0.00, 0.94, 0.33)' for any other direction."""
    name = next((name for name, a in _AXES.items() if np.allclose(a, v)), None)
    return name or "(" + ", ".join(f"{x:.2f}" for x in v) + ")"


def _snap(v: np.ndarray, degrees: float) -> tuple[np.ndarray, float]:
    """The signed unit axis nearest `v` if within `degrees`, else `v` normalised; and the angle to it."""
    v = v / max(np.linalg.norm(v), 1e-12)
    axis = np.zeros(3)
    i = int(np.argmax(np.abs(v)))
    axis[i] = np.sign(v[i])
    angle = float(np.degrees(np.arccos(np.clip(v @ axis, -1, 1))))
    return (axis if angle <= degrees else v), angle


def _subtree(skeleton: Skeleton, joint: int) -> list[int]:
    inside = {joint}
    for j in range(joint + 1, skeleton.num_joints):  # parents precede children
        if skeleton.parents[j] in inside:
            inside.add(j)
    return sorted(inside)


def _ancestors(skeleton: Skeleton, joint: int) -> list[int]:
    out = []
    while skeleton.parents[joint] >= 0:
        joint = int(skeleton.parents[joint])
        out.append(joint)
    return out[::-1]


def _depth(skeleton: Skeleton, joint: int) -> int:
    return len(_ancestors(skeleton, joint))


def _is_static(motion: Motion, joint: int, tolerance: float) -> bool:
    rot = motion.rotations[:, joint]
    pos = motion.positions[:, joint]
    return bool(np.abs(rot - rot[:1]).max() < 1e-6 and np.abs(pos - pos[:1]).max() < tolerance)


def _world(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    pos, rot = forward_kinematics(
        torch.tensor(motion.rotations), torch.tensor(motion.positions), motion.skeleton.parents, True
    )
    return pos.numpy(), rot.numpy()


def _rest_points(skeleton: Skeleton) -> np.ndarray:
    """Rest-pose positions of every joint and End Site (identity rotations)."""
    j = skeleton.num_joints
    pos = forward_kinematics(
        torch.eye(3, dtype=torch.float64).expand(j, 3, 3), torch.tensor(skeleton.offsets), skeleton.parents
    ).numpy()
    ends = [pos[joint] + offset for joint, offset in skeleton.end_sites.items()]
    return np.concatenate([pos, np.reshape(ends, (-1, 3))])


def find_root(motion: Motion) -> tuple[int, list[str]]:
    """The joint that carries the root motion, and notes on how it was chosen.

    From joint 0 down: while the joint is static over the clip and a joint below it has position
    channels, move to the shallowest such joint whose translation changes (or, if none does, the
    shallowest with position channels).
    """
    skeleton = motion.skeleton
    extent = max(np.ptp(_rest_points(skeleton), axis=0).max(), 1e-9)
    tolerance = 1e-6 * extent
    joint, notes = 0, []
    while _is_static(motion, joint, tolerance):
        below = [j for j in _subtree(skeleton, joint)[1:] if skeleton.position_order(j)]
        if not below:
            break
        moving = [j for j in below if np.ptp(motion.positions[:, j], axis=0).max() > tolerance]
        candidates = moving or below
        best = min(candidates, key=lambda j: (_depth(skeleton, j), j))
        notes.append(f"{skeleton.names[joint]!r} is static: root motion taken from {skeleton.names[best]!r}")
        joint = best
    return joint, notes


def _leg_pair(skeleton: Skeleton, pairs: list[tuple[int, int]], root: int) -> tuple[int, int] | None:
    """The left/right pair nearest the root inside its subtree: the hips of the two legs."""
    body = set(_subtree(skeleton, root))
    inside = [p for p in pairs if p[0] in body and p[1] in body]
    return min(inside, key=lambda p: (_depth(skeleton, p[0]), p[0])) if inside else None


def _chain_end(skeleton: Skeleton, joint: int) -> list[int]:
    """The joints from `joint` to the leaf farthest from it along the bones."""
    best: tuple[float, list[int]] = (-1.0, [joint])

    def walk(j: int, length: float, path: list[int]) -> None:
        nonlocal best
        children = skeleton.children(j)
        if not children and length > best[0]:
            best = (length, path)
        for c in children:
            walk(c, length + float(np.linalg.norm(skeleton.offsets[c])), path + [c])

    walk(joint, 0.0, [joint])
    return best[1]


def find_feet(
    skeleton: Skeleton, pairs: list[tuple[int, int]], root: int
) -> tuple[dict[str, str], str, list[str]]:
    """{left_heel, left_toe, right_heel, right_toe} joint names, how they were found, notes."""
    body = _subtree(skeleton, root)
    left = {a for a, _ in pairs}
    right = {b for _, b in pairs}
    names = skeleton.names
    feet: dict[str, str] = {}
    for side, members in (("left", left), ("right", right)):
        heels = [
            j for j in body if j in members and _HEEL.search(names[j]) and not _NOT_FOOT.search(names[j])
        ]
        heels = [j for j in heels if not _TOE.search(names[j])]
        if not heels:
            break
        heel = heels[0]
        toes = [
            j
            for j in _subtree(skeleton, heel)[1:]
            if _TOE.search(names[j]) and not _NOT_FOOT.search(names[j])
        ]
        if not toes:  # a foot joint whose child is the toe under another name
            toes = [c for c in skeleton.children(heel) if not _NOT_FOOT.search(names[c])]
        feet[f"{side}_heel"] = names[heel]
        feet[f"{side}_toe"] = names[toes[0]] if toes else names[heel]
    if len(feet) == 4:
        return feet, "by name", []
    legs = _leg_pair(skeleton, pairs, root)
    if legs is None:
        return {}, "not found", [NO_FEET]
    out = {}
    for side, hip in zip(("left", "right"), legs):
        chain = _chain_end(skeleton, hip)
        toe, heel = chain[-1], chain[-2] if len(chain) > 1 else chain[-1]
        out[f"{side}_heel"], out[f"{side}_toe"] = names[heel], names[toe]
    return (
        out,
        "geometry (ends of the leg chains)",
        ["feet not found by name: the ends of the leg chains are used"],
    )


def _units(height: float) -> tuple[float, str]:
    for name, metres, low, high in _UNITS:
        if low <= height <= high:
            return metres, name
    return ASSUMED_HEIGHT_M / height, f"unknown (a {ASSUMED_HEIGHT_M} m body assumed)"


@dataclass(frozen=True)
class SkeletonProfile:
    skeleton: Skeleton  # the file's skeleton, as read
    root: str
    feet: dict[str, str]  # left_heel, left_toe, right_heel, right_toe
    mirror_pairs: tuple[tuple[str, str], ...]
    up: tuple[float, float, float]  # the file axis that points up
    forward: tuple[float, float, float]  # the canonical root's local axis the body faces
    metres_per_unit: float
    units: str
    body_height: float  # file units
    contact_speed: float  # units / s
    contact_height: float  # units
    # Local rotation (3x3) and translation (3,) of every joint outside the body (folded or helper).
    fixed: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    found: dict[str, str] = field(default_factory=dict)  # how each field was found
    notes: tuple[str, ...] = ()  # anything suspicious

    # ------------------------------------------------------------ detection

    @classmethod
    def detect(cls, motion: Motion, overrides: dict | None = None) -> SkeletonProfile:
        """The profile of `motion`'s skeleton; `overrides` (config) win over detection."""
        overrides = dict(overrides or {})
        unknown = sorted(set(overrides) - set(OVERRIDE_FIELDS))
        if unknown:
            raise WalkdiffError(
                f"profile: unknown field(s) {', '.join(unknown)}; expected {', '.join(OVERRIDE_FIELDS)}"
            )
        skeleton = motion.skeleton
        found, notes = {}, []

        if overrides.get("root") is not None:
            root = _joint(skeleton, overrides["root"], "profile.root")
            found["root"] = "config"
        else:
            root, root_notes = find_root(motion)
            notes += root_notes
            found["root"] = "moving translation"

        if overrides.get("mirror_pairs") is not None:
            pairs = [
                (_joint(skeleton, a, "profile.mirror_pairs"), _joint(skeleton, b, "profile.mirror_pairs"))
                for a, b in overrides["mirror_pairs"]
            ]
            found["mirror_pairs"] = "config"
        else:
            pairs = find_mirror_pairs(skeleton)
            found["mirror_pairs"] = "by name"
        if not pairs:
            notes.append("no left/right joint pairs found by name: mirroring is not possible")

        feet_keys = ("left_heel", "left_toe", "right_heel", "right_toe")
        if all(overrides.get(k) for k in feet_keys):
            feet = {k: skeleton.names[_joint(skeleton, overrides[k], f"profile.{k}")] for k in feet_keys}
            found["feet"] = "config"
        else:
            feet, how, feet_notes = find_feet(skeleton, pairs, root)
            feet.update({k: skeleton.names[_joint(skeleton, overrides[k], f"profile.{k}")]
                         for k in feet_keys if overrides.get(k)})  # fmt: skip
            found["feet"], notes = how, notes + feet_notes

        world, world_rot = _world(motion)
        heels = [skeleton.index(feet["left_heel"]), skeleton.index(feet["right_heel"])] if feet else []
        if overrides.get("up") is not None:
            up = _axis(overrides["up"], "profile.up")
            found["up"] = "config"
        elif not feet:
            up = np.array([0.0, 1.0, 0.0])
            found["up"] = "assumed (no feet to measure it from)"
            notes.append("up axis assumed +y: without feet it cannot be measured; set profile.up")
        else:
            rise = (world[:, root] - world[:, heels].mean(axis=1)).mean(axis=0)
            up, angle = _snap(rise, 90.0)
            found["up"] = f"feet to root ({angle:.0f} deg off the axis)"
            if angle > 30:
                notes.append(
                    f"the body's up direction is {angle:.0f} deg off every axis: up taken as {_axis_name(up)}"
                )
        turn = axis_rotation(up)

        chain = _ancestors(skeleton, root)
        body = _subtree(skeleton, root)
        if overrides.get("forward") is not None:
            forward = _axis(overrides["forward"], "profile.forward")
            found["forward"] = "config"
        else:
            forward, how = _detect_forward(motion, world, world_rot, root, pairs, turn, feet)
            found["forward"] = how
            if how.startswith("assumed"):
                notes.append(f"facing direction not found: {how}")

        rest = _rest_points(skeleton)
        height = _body_height(rest, skeleton, root, heels, feet)
        if overrides.get("body_height") is not None:
            height = _positive(overrides["body_height"], "profile.body_height")
            found["body_height"] = "config"
        else:
            found["body_height"] = "rest pose, heel to top, stood upright"
        if overrides.get("units") is not None:
            metres, units = _parse_units(overrides["units"])
            found["units"] = "config"
        else:
            metres, units = _units(height)
            found["units"] = "body height"
            if units.startswith("unknown"):
                notes.append(
                    f"body height {height:.3g} units is no human height in m, cm, mm or inches: {units}"
                )

        fps = motion.fps
        speed = overrides.get("contact_speed")
        speed = _positive(speed, "profile.contact_speed") if speed is not None else CONTACT_SPEED * height
        lift = overrides.get("contact_height")
        lift = _positive(lift, "profile.contact_height") if lift is not None else CONTACT_HEIGHT * height
        found["contacts"] = (
            "config"
            if "contact_speed" in overrides or "contact_height" in overrides
            else (
                f"{CONTACT_SPEED} body heights/s ({speed / fps:.3g} units per frame at {fps:g} fps), "
                f"{CONTACT_HEIGHT} body heights"
            )
        )

        extent = float(np.ptp(rest, axis=0).max())
        for j in chain:
            if not _is_static(motion, j, 1e-6 * extent):
                notes.append(
                    f"{skeleton.names[j]!r} above the root moves: export puts it back at frame 0's pose"
                )
        moved = np.linalg.norm(
            np.diff(world[:, root][:, [i for i in range(3) if not up[i]]], axis=0), axis=1
        ).sum()
        hips_range = np.ptp(world[:, body], axis=0).max() if motion.num_frames > 1 else 0.0
        if moved < 1e-6 * extent and hips_range > 0.1 * height:
            notes.append("the root does not move while the body does: root motion may sit on another joint")

        fixed = {
            skeleton.names[j]: (motion.rotations[0, j].copy(), motion.positions[0, j].copy())
            for j in range(skeleton.num_joints)
            if j not in body
        }
        return cls(
            skeleton=skeleton,
            root=skeleton.names[root],
            feet=feet,
            mirror_pairs=tuple((skeleton.names[a], skeleton.names[b]) for a, b in pairs),
            up=tuple(float(v) for v in up),
            forward=tuple(float(v) for v in forward),
            metres_per_unit=float(metres),
            units=units,
            body_height=float(height),
            contact_speed=float(speed),
            contact_height=float(lift),
            fixed=fixed,
            found=found,
            notes=tuple(notes),
        )

    # ------------------------------------------------------------ what the representation reads

    @property
    def root_index(self) -> int:
        return self.skeleton.index(self.root)

    @property
    def body(self) -> list[int]:
        """File joint indices of the body (the root's subtree), in file order."""
        return _subtree(self.skeleton, self.root_index)

    @property
    def turn(self) -> np.ndarray:
        """U: file axes -> canonical axes (up -> +Y)."""
        return axis_rotation(self.up)

    @property
    def contacts(self) -> ContactSpec:
        if not self.feet:
            raise WalkdiffError(f"skeleton profile: {NO_FEET}")
        f = self.feet
        return ContactSpec(
            f["left_heel"], f["left_toe"], f["right_heel"], f["right_toe"],
            speed_threshold=self.contact_speed, height_threshold=self.contact_height,
        )  # fmt: skip

    @property
    def body_pairs(self) -> tuple[tuple[str, str], ...]:
        """The left/right pairs inside the body (the canonical skeleton's)."""
        body = {self.skeleton.names[j] for j in self.body}
        return tuple(p for p in self.mirror_pairs if p[0] in body and p[1] in body)

    @property
    def can_mirror(self) -> bool:
        return bool(self.body_pairs)

    @property
    def canonical_skeleton(self) -> Skeleton:
        """The body in canonical axes: the skeleton the features and models use."""
        s, u, body = self.skeleton, self.turn, self.body
        index = {j: i for i, j in enumerate(body)}
        offsets = s.offsets[body] @ u.T
        offsets[0] = 0.0  # the root's place is its translation
        channels = [s.channels[j] for j in body]
        channels[0] = (
            "Xposition",
            "Yposition",
            "Zposition",
            *[c for c in s.channels[body[0]] if "rotation" in c],
        )
        if len(channels[0]) == 3:
            channels[0] = (*channels[0], "Zrotation", "Yrotation", "Xrotation")
        return Skeleton(
            names=[s.names[j] for j in body],
            parents=[-1] + [index[int(s.parents[j])] for j in body[1:]],
            offsets=offsets,
            channels=channels,
            end_sites={index[j]: u @ o for j, o in s.end_sites.items() if j in index},
        )

    def check(self, skeleton: Skeleton, path=None) -> None:
        """A WalkdiffError naming the joints that differ when `skeleton` is not the profile's hierarchy."""
        if skeleton.same_hierarchy(self.skeleton):
            return
        mine, theirs = self.skeleton.names, skeleton.names
        missing = [n for n in mine if n not in theirs]
        extra = [n for n in theirs if n not in mine]
        moved = [
            n for n in mine
            if n in theirs and _parent_name(self.skeleton, n) != _parent_name(skeleton, n)
        ]  # fmt: skip
        parts = []
        if missing:
            parts.append(f"missing {_listed(missing)}")
        if extra:
            parts.append(f"extra {_listed(extra)}")
        if moved:
            parts.append(f"other parent for {_listed(moved)}")
        if not parts:
            parts.append("same joints in another order")
        raise WalkdiffError(
            f"another skeleton than the dataset's ({len(theirs)} joints vs {len(mine)}): {'; '.join(parts)}",
            path=path,
        )

    def body_positions(self, motion: Motion, path=None) -> np.ndarray:
        """World positions (F, J, 3) of the body's joints, canonical axes, from any clip of this body.

        Joints are found by name and placed by the clip's own hierarchy, so another rotation convention,
        channel order or root layout (a static parent above the root) reads the same. A clip on another
        skeleton (a body joint missing or re-parented, a bone of another length) is refused, naming
        the joints that differ.
        """
        canonical = self.canonical_skeleton
        names = list(motion.skeleton.names)
        missing = [n for n in canonical.names if n not in names]
        moved = [
            n for n in canonical.names[1:]
            if n in names and _parent_name(motion.skeleton, n) != _parent_name(canonical, n)
        ]  # fmt: skip
        if missing or moved:
            parts = [f"missing {_listed(missing)}"] if missing else []
            parts += [f"other parent for {_listed(moved)}"] if moved else []
            raise WalkdiffError(f"not the evaluator's skeleton: {'; '.join(parts)}", path=path)
        world = _world(motion)[0][:, [names.index(n) for n in canonical.names]] @ self.turn.T
        bones = np.linalg.norm(world[:, 1:] - world[:, canonical.parents[1:]], axis=-1).mean(axis=0)
        expected = np.linalg.norm(canonical.offsets[1:], axis=-1)
        off = np.flatnonzero(np.abs(bones - expected) > BONE_TOLERANCE * self.body_height) + 1
        if off.size:
            shown = ", ".join(
                f"{canonical.names[j]} ({bones[j - 1]:.4g} vs {expected[j - 1]:.4g})" for j in off[:6]
            )
            raise WalkdiffError(
                f"not the evaluator's skeleton: bone lengths differ (file vs evaluator, {self.units}) "
                f"at {shown}{' ...' if off.size > 6 else ''}",
                path=path,
            )
        return world

    # ------------------------------------------------------------ conversions

    def _chain(self, rotations: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rotation (..., 3, 3) and position (..., 3) of the root's parent frame."""
        rot = np.broadcast_to(np.eye(3), rotations.shape[:-3] + (3, 3)).copy()
        pos = np.zeros(positions.shape[:-2] + (3,))
        for j in _ancestors(self.skeleton, self.root_index):
            pos = pos + (rot @ positions[..., j, :, None])[..., 0]
            rot = rot @ rotations[..., j, :, :]
        return rot, pos

    def to_canonical(self, motion: Motion) -> Motion:
        """The clip on the canonical skeleton (see the module docstring); same motion, axes turned."""
        self.check(motion.skeleton)
        u, body = self.turn, self.body
        chain_rot, chain_pos = self._chain(motion.rotations, motion.positions)
        rotations = u @ motion.rotations[:, body] @ u.T
        positions = motion.positions[:, body] @ u.T
        root = self.root_index
        rotations[:, 0] = u @ chain_rot @ motion.rotations[:, root] @ u.T
        positions[:, 0] = (chain_rot @ motion.positions[:, root, :, None])[..., 0] + chain_pos
        positions[:, 0] = positions[:, 0] @ u.T
        return Motion(self.canonical_skeleton, rotations, positions, motion.frame_time)

    def to_file(self, motion: Motion) -> Motion:
        """A canonical clip back on the file's skeleton, axes and static joints.

        Every frame is converted on its own: a long clip goes TO_FILE_FRAMES frames at a time into the
        result, so its temporaries stay small.
        """
        frames, joints = motion.num_frames, self.skeleton.num_joints
        if frames <= TO_FILE_FRAMES:
            return self._to_file(motion)
        rotations, positions = np.empty((frames, joints, 3, 3)), np.empty((frames, joints, 3))
        for start in range(0, frames, TO_FILE_FRAMES):
            part = self._to_file(motion.slice(start, start + TO_FILE_FRAMES))
            rotations[start : start + len(part.rotations)] = part.rotations
            positions[start : start + len(part.positions)] = part.positions
        return Motion(self.skeleton, rotations, positions, motion.frame_time)

    def _to_file(self, motion: Motion) -> Motion:
        s, u, body = self.skeleton, self.turn, self.body
        frames = motion.num_frames
        rotations = np.repeat(np.eye(3)[None, None], frames, axis=0).repeat(s.num_joints, axis=1)
        positions = np.repeat(s.offsets[None], frames, axis=0)
        for name, (rot, pos) in self.fixed.items():
            j = s.index(name)
            rotations[:, j], positions[:, j] = rot, pos
        rotations[:, body] = u.T @ motion.rotations @ u
        positions[:, body] = motion.positions @ u
        chain_rot, chain_pos = self._chain(rotations, positions)
        root = self.root_index
        world_rot = u.T @ motion.rotations[:, 0] @ u
        world_pos = motion.positions[:, 0] @ u
        inverse = np.swapaxes(chain_rot, -1, -2)
        rotations[:, root] = inverse @ world_rot
        positions[:, root] = (inverse @ (world_pos - chain_pos)[..., None])[..., 0]
        return Motion(s, rotations, positions, motion.frame_time)

    # ------------------------------------------------------------ saving and showing

    def to_dict(self) -> dict:
        return {
            "skeleton": skeleton_to_dict(self.skeleton),
            "root": self.root,
            "feet": dict(self.feet),
            "mirror_pairs": [list(p) for p in self.mirror_pairs],
            "up": list(self.up),
            "forward": list(self.forward),
            "metres_per_unit": self.metres_per_unit,
            "units": self.units,
            "body_height": self.body_height,
            "contact_speed": self.contact_speed,
            "contact_height": self.contact_height,
            "fixed": {n: [r.tolist(), p.tolist()] for n, (r, p) in self.fixed.items()},
            "found": dict(self.found),
            "notes": list(self.notes),
        }

    @classmethod
    def from_dict(cls, data: dict) -> SkeletonProfile:
        return cls(
            skeleton=skeleton_from_dict(data["skeleton"]),
            root=data["root"],
            feet=dict(data["feet"]),
            mirror_pairs=tuple(tuple(p) for p in data["mirror_pairs"]),
            up=tuple(data["up"]),
            forward=tuple(data["forward"]),
            metres_per_unit=float(data["metres_per_unit"]),
            units=data["units"],
            body_height=float(data["body_height"]),
            contact_speed=float(data["contact_speed"]),
            contact_height=float(data["contact_height"]),
            fixed={
                n: (np.asarray(r, dtype=np.float64), np.asarray(p, dtype=np.float64))
                for n, (r, p) in data["fixed"].items()
            },  # fmt: skip
            found=dict(data.get("found", {})),
            notes=tuple(data.get("notes", ())),
        )

    def describe(self) -> list[str]:
        """Lines for `inspect` and `data scan`."""
        f = self.feet
        folded = [self.skeleton.names[j] for j in _ancestors(self.skeleton, self.root_index)]
        up, forward_text = _axis_name(np.asarray(self.up)), _axis_name(np.asarray(self.forward))
        return [
            f"root:      {self.root}"
            + (f" (static above it, folded: {', '.join(folded)})" if folded else "")
            + f" [{self.found.get('root', '')}]",
            (
                f"feet:      left {f.get('left_heel')} / {f.get('left_toe')}, "
                f"right {f.get('right_heel')} / {f.get('right_toe')}"
                if f
                else "feet:      none found"
            )
            + f" [{self.found.get('feet', '')}]",
            f"pairs:     {len(self.mirror_pairs)} left/right"
            + (f" (e.g. {self.mirror_pairs[0][0]} / {self.mirror_pairs[0][1]})" if self.mirror_pairs else "")
            + (" [mirroring possible]" if self.can_mirror else " [no mirroring]"),
            f"axes:      up {up} [{self.found.get('up', '')}], root faces local {forward_text} (canonical)"
            f" [{self.found.get('forward', '')}]",
            f"units:     {self.units}, {self.metres_per_unit:.6g} m per unit [{self.found.get('units', '')}]",
            f"height:    {self.body_height:.4g} units = {self.body_height * self.metres_per_unit:.2f} m",
            f"contacts:  slower than {self.contact_speed:.3g} units/s and within {self.contact_height:.3g} "
            f"units of the foot's floor [{self.found.get('contacts', '')}]",
        ]


# ---------------------------------------------------------------- helpers


def _listed(names: list[str], limit: int = 8) -> str:
    return ", ".join(names[:limit]) + (" ..." if len(names) > limit else "")


def _parent_name(skeleton: Skeleton, name: str) -> str | None:
    p = int(skeleton.parents[skeleton.names.index(name)])
    return None if p < 0 else skeleton.names[p]


def _joint(skeleton: Skeleton, name: str, field_name: str) -> int:
    if name not in skeleton.names:
        raise WalkdiffError(
            f"{field_name}: joint {name!r} not in the skeleton ({', '.join(skeleton.names[:12])}"
            f"{' ...' if skeleton.num_joints > 12 else ''})"
        )
    return skeleton.names.index(name)


def _axis(value, field_name: str) -> np.ndarray:
    if isinstance(value, str):
        key = value.strip().lower()
        key = key if key[:1] in "+-" else "+" + key
        if key not in _AXES:
            raise WalkdiffError(
                f"{field_name}: expected one of {', '.join(_AXES)} or a 3-vector, got {value!r}"
            )
        return np.asarray(_AXES[key], dtype=np.float64)
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) < 1e-9:
        raise WalkdiffError(f"{field_name}: expected an axis name or a non-zero 3-vector, got {value!r}")
    return v / np.linalg.norm(v)


def _positive(value, field_name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not np.isfinite(v) or v <= 0:
        raise WalkdiffError(f"{field_name}: expected a positive finite number, got {value!r}")
    return v


def _parse_units(value) -> tuple[float, str]:
    if isinstance(value, str) and value.strip().lower() in _UNIT_NAMES:
        return _UNIT_NAMES[value.strip().lower()], value.strip().lower()
    metres = _positive(value, "profile.units (metres per unit, or m / cm / mm / in / ft)")
    return metres, f"{metres:g} m per unit (config)"


def _detect_forward(motion, world, world_rot, root, pairs, turn, feet) -> tuple[np.ndarray, str]:
    """The canonical root's local axis the body faces.

    From the rest pose when there are left/right pairs: up (heels to root) x (right - left), in the
    root's own frame, so every clip of a skeleton gives the same axis whatever it does. Without pairs,
    the mean walking direction of the clip in the root's frame.
    """
    skeleton = motion.skeleton
    if pairs and feet:
        rest = _rest_points(skeleton)[: skeleton.num_joints]
        heels = [skeleton.index(feet["left_heel"]), skeleton.index(feet["right_heel"])]
        # Rest positions relative to the root are in the root's own frame (every rotation is identity).
        up = rest[root] - rest[heels].mean(axis=0)
        lateral = np.mean([rest[b] - rest[a] for a, b in pairs], axis=0)
        facing = turn @ np.cross(up, lateral)
        if np.linalg.norm(facing) > 1e-9:
            forward, angle = _snap(facing, 30.0)
            return forward, f"rest pose: up x (right - left) ({angle:.0f} deg off the axis)"
    rot = turn @ world_rot[:, root] @ turn.T  # canonical world rotation of the root
    root_path = world[:, root] @ turn.T
    facing = np.diff(root_path, axis=0, append=root_path[-1:])
    facing[:, 1] = 0
    norms = np.linalg.norm(facing, axis=1, keepdims=True)
    if norms.max() < 1e-9:
        return np.array([0.0, 0.0, 1.0]), "assumed +z (no left/right pairs and no walking)"
    local = np.einsum("fji,fj->fi", rot, facing / np.maximum(norms, 1e-12))
    forward, angle = _snap(local[norms[:, 0] > 1e-9].mean(axis=0), 30.0)
    return forward, f"walking direction ({angle:.0f} deg off the axis)"


def _body_height(rest, skeleton, root, heels, feet) -> float:
    """Extent of the rest pose (joints and End Sites) along the feet-to-root direction: the body's
    height whatever way the rest pose is turned, T or A pose alike. Without feet: its largest extent."""
    points = rest[: skeleton.num_joints]
    feet_joints = heels + [skeleton.index(feet[k]) for k in ("left_toe", "right_toe")] if feet else []
    up = points[root] - points[feet_joints].mean(axis=0) if feet_joints else np.zeros(3)
    if np.linalg.norm(up) < 1e-9:
        return float(np.ptp(rest, axis=0).max())
    return float(np.ptp(rest @ (up / np.linalg.norm(up))))
