"""How a `SkeletonProfile` is found from a BVH clip: each field the configuration does not give.

- root: the joint whose translation moves. Static joints above it (constant transform over the clip)
  are *folded*: their transform is applied to the root and restored, as it was, on export. When a
  lone joint above the hips moves and the hips' translation moves too (a root carrying the path on the
  floor, the hips their height and bob), the hips are the root and the joint above is folded in on
  every frame; export gives it the hips' path again along the axes it moved on (`find_carriers`).
- feet: heel (ankle) and toe of each side, by name over the common conventions (CMU, Mixamo, SMPL,
  Unreal, DAZ, Biped ...), else the ends of the two leg chains (the left/right pair nearest the root).
- left/right pairs by name (`walkdiff.motion.mirror.find_mirror_pairs`).
- up: the signed file axis from the feet to the head over the posed frames, not the root's motion.
- body height and `forward` (the root's local axis the body faces) from the rest pose when it is a
  pose, the same for every clip of a skeleton; from the posed frames when the rest pose is no pose
  (legs laid along an axis, bones on one line), said in `found` and `notes`
  (`walkdiff.motion.posed_frames`).
- units (metres per unit) from the body height when it is a human height in m, cm, mm or inches;
  otherwise estimated for a 1.7 m body and said so.
- contact thresholds from the legs' length (thigh to foot, by the humanoid map): speed `CONTACT_SPEED`
  leg lengths/s (per frame: that over the frame rate), height `CONTACT_HEIGHT` leg lengths. On Xia
  (legs 14.6 units) that is 4.8 units/s and 0.48 units, within 2% of the thresholds measured by hand on
  its foot speeds. Legs, not the body height: a foot's speed and lift go with the stride, and rigs
  differ in how much of their height is legs (Xia's legs are 0.61 of it, ZEGGS' and the Mixamo-like
  rig's 0.49), so the same walk on two rigs gets the same contacts. A rig without recognisable legs
  takes `CONTACT_SPEED_HEIGHTS` and `CONTACT_HEIGHT_HEIGHTS` of its body height, and says so.

Also the axis geometry a profile uses to turn a clip into its canonical frame.
"""

from __future__ import annotations

import re

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion import posed_frames as posed
from walkdiff.motion.humanoid import humanoid_map, leg_length
from walkdiff.motion.mirror import find_mirror_pairs
from walkdiff.motion.posed_frames import (
    ancestors,
    depth,
    floor_contacts,
    is_static,
    rest_points,
    subtree,
    world_transforms,
)
from walkdiff.motion.posed_frames import snap_axis as _snap
from walkdiff.motion.skeleton import Motion, Skeleton

CONTACT_SPEED = 0.326  # leg lengths per second
CONTACT_HEIGHT = 0.0326  # leg lengths above the foot's own floor
CONTACT_SPEED_HEIGHTS = 0.2  # body heights per second, for a rig whose legs are not found
CONTACT_HEIGHT_HEIGHTS = 0.02  # body heights
ASSUMED_HEIGHT_M = 1.7  # when the units cannot be told from the body height
LOST_TRANSLATION = 1e-3  # body heights: translation below the root beyond this is motion the features lose

# Body heights (file units) of a human in each unit, and metres per unit.
_UNITS = (
    ("m", 1.0, 1.0, 2.3),
    ("cm", 0.01, 100.0, 230.0),
    ("mm", 0.001, 1000.0, 2300.0),
    ("in", 0.0254, 39.0, 91.0),
)
_UNIT_NAMES = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "inch": 0.0254, "ft": 0.3048}

AXES = {
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


# ---------------------------------------------------------------- axes


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


def axis_name(v: np.ndarray) -> str:
    """'+y' for an axis, '(0.00, 0.94, 0.33)' for any other direction."""
    name = next((name for name, a in AXES.items() if np.allclose(a, v)), None)
    return name or "(" + ", ".join(f"{x:.2f}" for x in v) + ")"


# ---------------------------------------------------------------- the tree and its poses


# ---------------------------------------------------------------- root and feet


def find_root(motion: Motion) -> tuple[int, list[str]]:
    """The joint that carries the root motion, and notes on how it was chosen.

    From joint 0 down: while the joint is static over the clip and a joint below it has position
    channels, move to the shallowest such joint whose translation changes (or, if none does, the
    shallowest with position channels). A joint that moves hands on to the joint where its one-child
    chain branches into the body (the hips below a lone root) when that joint's translation moves or
    leaves its OFFSET too: the translation is split between them (a root carrying the path, the hips
    a bob), and the features keep only the lower joint's, with the upper one folded in per frame.
    """
    skeleton = motion.skeleton
    extent = max(np.ptp(rest_points(skeleton), axis=0).max(), 1e-9)
    tolerance = 1e-6 * extent
    joint, notes = 0, []
    while True:
        if not is_static(motion, joint, tolerance):
            carried = [j for j in _one_child_chain(skeleton, joint) if _own_translation(motion, j, tolerance)]
            if not carried:
                break
            notes.append(
                f"the translation is split between {skeleton.names[joint]!r} and "
                f"{skeleton.names[carried[0]]!r}: root motion taken from {skeleton.names[carried[0]]!r}, "
                f"{skeleton.names[joint]!r} folded into it on every frame"
            )
            joint = carried[0]
            continue
        below = [j for j in subtree(skeleton, joint)[1:] if skeleton.position_order(j)]
        if not below:
            break
        moving = [j for j in below if np.ptp(motion.positions[:, j], axis=0).max() > tolerance]
        candidates = moving or below
        best = min(candidates, key=lambda j: (depth(skeleton, j), j))
        notes.append(f"{skeleton.names[joint]!r} is static: root motion taken from {skeleton.names[best]!r}")
        joint = best
    return joint, notes


def _one_child_chain(skeleton: Skeleton, joint: int) -> list[int]:
    """The joints below `joint` while each link has one child: down to where the body branches."""
    chain, children = [], skeleton.children(joint)
    while len(children) == 1:
        chain.append(children[0])
        children = skeleton.children(children[0])
    return chain


def _own_translation(motion: Motion, joint: int, tolerance: float) -> bool:
    """Whether `joint` has position channels whose values move or leave its OFFSET."""
    if not motion.skeleton.position_order(joint):
        return False
    positions = motion.positions[:, joint]
    return bool(
        np.ptp(positions, axis=0).max() > tolerance
        or np.abs(positions - motion.skeleton.offsets[joint]).max() > tolerance
    )


def find_carriers(motion: Motion, root: int) -> dict[str, list[int]]:
    """Joints above the root whose translation moves, and the axes (of their parent's frame) it moves
    along: on export they carry the root's path along those axes again, as the file had it."""
    skeleton = motion.skeleton
    tolerance = 1e-6 * max(np.ptp(rest_points(skeleton), axis=0).max(), 1e-9)
    carriers = {}
    for j in ancestors(skeleton, root):
        axes = [a for a in range(3) if np.ptp(motion.positions[:, j, a]) > tolerance]
        if axes:
            carriers[skeleton.names[j]] = axes
    return carriers


def translation_off_offsets(motion: Motion, root: int, tolerance: float) -> list[tuple[int, float]]:
    """Body joints below the root whose translation leaves their OFFSET by more than `tolerance` on
    some frame, and by how much: motion the features (rotations below the root) cannot hold."""
    skeleton, out = motion.skeleton, []
    for j in subtree(skeleton, root)[1:]:
        if skeleton.position_order(j):
            off = float(np.linalg.norm(motion.positions[:, j] - skeleton.offsets[j], axis=-1).max())
            if off > tolerance:
                out.append((j, off))
    return out


def _leg_pair(
    skeleton: Skeleton, pairs: list[tuple[int, int]], root: int, pose: np.ndarray | None
) -> tuple[int, int] | None:
    """The left/right pair nearest the root inside its subtree, among those whose chains end on the floor
    where most joints touch it in `pose` (J, 3; `floor_contacts`): the hips of the two legs, never eye
    stalks or claws."""
    body = set(subtree(skeleton, root))
    inside = [p for p in pairs if p[0] in body and p[1] in body]
    if pose is not None:
        contacts = {p: floor_contacts(pose, root, [_chain_end(skeleton, j)[-1] for j in p]) for p in inside}
        inside = [p for p in inside if contacts[p] == max(contacts.values()) > 0]
    return min(inside, key=lambda p: (depth(skeleton, p[0]), p[0])) if inside else None


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
    skeleton: Skeleton, pairs: list[tuple[int, int]], root: int, pose: np.ndarray | None = None
) -> tuple[dict[str, str], str, list[str]]:
    """{left_heel, left_toe, right_heel, right_toe} joint names, how they were found, notes. `pose`: world
    positions (J, 3) of a posed frame, where legs found from the hierarchy must end on the floor."""
    body = subtree(skeleton, root)
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
            j for j in subtree(skeleton, heel)[1:] if _TOE.search(names[j]) and not _NOT_FOOT.search(names[j])
        ]
        if not toes:  # a foot joint whose child is the toe under another name
            toes = [c for c in skeleton.children(heel) if not _NOT_FOOT.search(names[c])]
        feet[f"{side}_heel"] = names[heel]
        feet[f"{side}_toe"] = names[toes[0]] if toes else names[heel]
    if len(feet) == 4:
        return feet, "by name", []
    legs = _leg_pair(skeleton, pairs, root, pose)
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


# ---------------------------------------------------------------- axes, height and units


def units_of_height(height: float) -> tuple[float, str]:
    """Metres per unit and the unit's name for a body `height` units tall: the unit in which that is a
    human height, else what makes it ASSUMED_HEIGHT_M."""
    for name, metres, low, high in _UNITS:
        if low <= height <= high:
            return metres, name
    return ASSUMED_HEIGHT_M / height, f"unknown (a {ASSUMED_HEIGHT_M} m body assumed)"


# ---------------------------------------------------------------- a profile's fields


def detect_fields(motion: Motion, overrides: dict | None = None) -> dict:
    """Every field of `motion`'s `SkeletonProfile` but its skeleton; `overrides` (config) win."""
    detection = _Detection(motion, overrides)
    root = detection.root()
    pairs = detection.mirror_pairs()
    feet = detection.feet(pairs, root)
    up = detection.up(root, pairs, feet)
    height = detection.body_height(root, feet, up)
    forward = detection.forward(root, pairs, feet, up)
    metres, units = detection.units(height)
    speed, lift = detection.contact_thresholds(height)
    detection.check_root_motion(root, up, height)
    skeleton = motion.skeleton
    body = subtree(skeleton, root)
    return dict(
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
        fixed={  # every joint outside the body, as it stands at the first frame
            skeleton.names[j]: (motion.rotations[0, j].copy(), motion.positions[0, j].copy())
            for j in range(skeleton.num_joints)
            if j not in body
        },
        carriers=find_carriers(motion, root),
        found=detection.found,
        notes=tuple(detection.notes),
    )


class _Detection:
    """One clip's profile, field by field: a field the configuration gives is taken as it is, any other
    is found from the clip. `found` says how each was found, `notes` holds anything suspicious.

    Up, height and facing are measured on the posed frames (`walkdiff.motion.posed_frames`); the rest
    pose gives height and facing (the same for every clip of a skeleton) only when it is a pose."""

    def __init__(self, motion: Motion, overrides: dict | None):
        overrides = dict(overrides or {})
        unknown = sorted(set(overrides) - set(OVERRIDE_FIELDS))
        if unknown:
            raise WalkdiffError(
                f"profile: unknown field(s) {', '.join(unknown)}; expected {', '.join(OVERRIDE_FIELDS)}"
            )
        self.motion, self.skeleton, self.overrides = motion, motion.skeleton, overrides
        self.found: dict[str, str] = {}
        self.notes: list[str] = []
        self.world, self.world_rot = world_transforms(motion)
        self.rest = rest_points(motion.skeleton)
        self.head: int | None = None
        self.rest_problem: str | None = None  # why the rest pose is no pose, once measured

    def root(self) -> int:
        if self.overrides.get("root") is not None:
            self.found["root"] = "config"
            return _joint(self.skeleton, self.overrides["root"], "profile.root")
        root, notes = find_root(self.motion)
        self.notes += notes
        self.found["root"] = "moving translation"
        return root

    def mirror_pairs(self) -> list[tuple[int, int]]:
        if self.overrides.get("mirror_pairs") is not None:
            field_name = "profile.mirror_pairs"
            pairs = [
                (_joint(self.skeleton, a, field_name), _joint(self.skeleton, b, field_name))
                for a, b in self.overrides["mirror_pairs"]
            ]
            self.found["mirror_pairs"] = "config"
        else:
            pairs = find_mirror_pairs(self.skeleton)
            self.found["mirror_pairs"] = "by name"
        if not pairs:
            self.notes.append("no left/right joint pairs found by name: mirroring is not possible")
        return pairs

    def feet(self, pairs: list[tuple[int, int]], root: int) -> dict[str, str]:
        """All four feet joints when the configuration names them; else those found, with any the
        configuration names in their place."""
        keys = ("left_heel", "left_toe", "right_heel", "right_toe")
        given = {
            k: self.skeleton.names[_joint(self.skeleton, self.overrides[k], f"profile.{k}")]
            for k in keys
            if self.overrides.get(k)
        }
        if len(given) == len(keys):
            self.found["feet"] = "config"
            return given
        feet, self.found["feet"], notes = find_feet(self.skeleton, pairs, root, self.world[0])
        self.notes += notes
        return feet | given

    def _heels(self, feet: dict[str, str]) -> list[int]:
        return (
            [self.skeleton.index(feet["left_heel"]), self.skeleton.index(feet["right_heel"])] if feet else []
        )

    def _feet_joints(self, feet: dict[str, str]) -> list[int]:
        return [self.skeleton.index(feet[k]) for k in ("left_heel", "left_toe", "right_heel", "right_toe")]

    def up(self, root: int, pairs, feet: dict[str, str]) -> np.ndarray:
        """The file axis from the feet to the head over the clip (to the root without a head)."""
        if feet:
            self.head = posed.find_head(self.skeleton, root, pairs, self._feet_joints(feet))
        if self.overrides.get("up") is not None:
            self.found["up"] = "config"
            return _axis(self.overrides["up"], "profile.up")
        if not feet:
            self.found["up"] = "assumed (no feet to measure it from)"
            self.notes.append("up axis assumed +y: without feet it cannot be measured; set profile.up")
            return np.array([0.0, 1.0, 0.0])
        top = self.head if self.head is not None else root
        up, angle, share = posed.posed_up(self.world, top, self._heels(feet))
        self.found["up"] = f"feet to {self.skeleton.names[top]} ({angle:.0f} deg off the axis)"
        if angle > 30:
            self.notes.append(
                f"the body's up direction is {angle:.0f} deg off every axis: up taken as {axis_name(up)}"
            )
        elif share < 0.9:
            self.notes.append(
                f"the body stands along {axis_name(up)} on only {share:.0%} of the frames (lying, rolling?)"
            )
        return up

    def body_height(self, root: int, feet: dict[str, str], up: np.ndarray) -> float:
        """From the rest pose when it is a pose (same for every clip), else from the posed frames."""
        rest = posed.rest_height(self.rest, self.skeleton, root, self._feet_joints(feet) if feet else [])
        measured, how = None, ""
        if feet:
            heels = self._heels(feet)
            self.rest_problem = posed.rest_pose_problem(self.rest, self.skeleton, root, heels, self.head)
            if self.head is not None:
                measured, how = posed.body_height_on_frames(
                    self.world, self.world_rot, self.skeleton, self.head, heels, up
                )
        posed_text = f" (posed frames: {measured:.4g})" if measured is not None else ""
        self.found["rest_pose"] = (
            "not checked (no feet)" if not feet
            else f"no pose: {self.rest_problem}" if self.rest_problem
            else f"a standing pose, {rest:.4g} units tall{posed_text}"
        )  # fmt: skip
        if self.rest_problem:
            self.notes.append(
                f"the rest pose is no pose ({self.rest_problem}): body height and facing are measured on "
                "the posed frames"
                + ("" if measured is not None else ", but without a head the height is the rest pose's")
            )
        if self.overrides.get("body_height") is not None:
            self.found["body_height"] = "config"
            return _positive(self.overrides["body_height"], "profile.body_height")
        if self.rest_problem and measured is not None and measured > 0:
            self.found["body_height"] = how
            return measured
        self.found["body_height"] = "rest pose, heel to top, stood upright"
        if not rest > 0:  # one joint without an end site, or all offsets zero: units would divide by 0
            raise WalkdiffError(
                "the rest pose is a single point (every joint and end site at the root), so it has no body "
                "height to find the units and contact thresholds from: give the profile a body_height in "
                "file units (--profile FILE, or data.profile)"
            )
        return rest

    def forward(self, root: int, pairs, feet: dict[str, str], up: np.ndarray) -> np.ndarray:
        """The canonical root's local axis the body faces: from the rest pose when it is a pose (every clip
        of a skeleton gives the same), else from the posed frames, else from the walking direction."""
        if self.overrides.get("forward") is not None:
            self.found["forward"] = "config"
            return _axis(self.overrides["forward"], "profile.forward")
        turn = axis_rotation(up)
        rest = None if self.rest_problem else posed.rest_forward(self.rest, root, self._heels(feet), pairs)
        if rest is not None:
            forward, angle = _snap(turn @ rest, 30.0)
            self.found["forward"] = f"rest pose: up x (right - left) ({angle:.0f} deg off the axis)"
            return forward
        measured = posed.posed_forward(
            self.world, self.world_rot, self.skeleton, root, pairs, self._heels(feet), up, self.head
        )
        if measured is not None:
            self.found["forward"] = f"posed frames: up x (right - left) (heading {measured[1]:.0f} deg off)"
            return _snap(turn @ measured[0], 0.5)[0]  # an axis stays exact through the turn
        facing = posed.walking_forward(self.world, self.world_rot, root, up)
        if facing is None:
            self.found["forward"] = "assumed +z (no left/right pairs and no walking)"
            self.notes.append(f"facing direction not found: {self.found['forward']}")
            return np.array([0.0, 0.0, 1.0])
        forward, angle = _snap(turn @ facing, 30.0)
        self.found["forward"] = f"walking direction ({angle:.0f} deg off the axis)"
        return forward

    def units(self, height: float) -> tuple[float, str]:
        """Metres per unit and the units' name."""
        if self.overrides.get("units") is not None:
            self.found["units"] = "config"
            return _parse_units(self.overrides["units"])
        metres, units = units_of_height(height)
        self.found["units"] = "body height"
        if units.startswith("unknown"):
            self.notes.append(
                f"body height {height:.3g} units is no human height in m, cm, mm or inches: {units}"
            )
        return metres, units

    def contact_thresholds(self, height: float) -> tuple[float, float]:
        """The speed (units/s) and height (units) below which a foot is planted."""
        speed, lift = self.overrides.get("contact_speed"), self.overrides.get("contact_height")
        if speed is not None or lift is not None:
            self.found["contacts"] = "config"
        legs = self.leg_length()
        scale, unit = (legs, "leg lengths") if legs else (height, "body heights")
        fractions = (
            (CONTACT_SPEED, CONTACT_HEIGHT) if legs else (CONTACT_SPEED_HEIGHTS, CONTACT_HEIGHT_HEIGHTS)
        )
        speed = _positive(speed, "profile.contact_speed") if speed is not None else fractions[0] * scale
        lift = _positive(lift, "profile.contact_height") if lift is not None else fractions[1] * scale
        fps = self.motion.fps
        if "contacts" not in self.found:
            self.found["contacts"] = (
                f"{fractions[0]} {unit}/s ({speed / fps:.3g} units per frame at {fps:g} fps), "
                f"{fractions[1]} {unit}" + (f" (legs {legs:.4g} units)" if legs else " (no legs found)")
            )
        return speed, lift

    def leg_length(self) -> float | None:
        """The legs' length by the humanoid map (thigh to foot); None for a rig without legs."""
        try:
            return leg_length(self.skeleton, humanoid_map(self.motion.slice(0, 1)))
        except WalkdiffError:
            return None

    def check_root_motion(self, root: int, up: np.ndarray, height: float) -> None:
        """Notes on joints above the root that move (export rebuilds their path, not their turn), on
        translation below the root (the features do not keep it) and on a root that stays while the body
        moves (the root motion is likely elsewhere)."""
        skeleton, motion, world = self.skeleton, self.motion, self.world
        extent = float(np.ptp(self.rest, axis=0).max())
        for j in ancestors(skeleton, root):
            if np.abs(motion.rotations[:, j] - motion.rotations[:1, j]).max() > 1e-6:
                self.notes.append(
                    f"{skeleton.names[j]!r} above the root turns: export keeps its frame-0 turn and puts the "
                    "rest on the root (world positions are kept)"
                )
        lost = translation_off_offsets(motion, root, LOST_TRANSLATION * height)
        if lost:
            shown = ", ".join(f"{skeleton.names[j]!r} (up to {d:.3g} units)" for j, d in lost[:4])
            self.notes.append(
                f"translation below the root {skeleton.names[root]!r} leaves the bone offsets on {shown}: "
                "the features keep only the root's, so such clips do not convert back"
            )
        moved = np.linalg.norm(
            np.diff(world[:, root][:, [i for i in range(3) if not up[i]]], axis=0), axis=1
        ).sum()
        body = subtree(skeleton, root)
        hips_range = np.ptp(world[:, body], axis=0).max() if motion.num_frames > 1 else 0.0
        if moved < 1e-6 * extent and hips_range > 0.1 * height:
            self.notes.append(
                "the root does not move while the body does: root motion may sit on another joint"
            )


# ---------------------------------------------------------------- overrides


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
        if key not in AXES:
            raise WalkdiffError(
                f"{field_name}: expected one of {', '.join(AXES)} or a 3-vector, got {value!r}"
            )
        return np.asarray(AXES[key], dtype=np.float64)
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
