"""What differs between skeletons, found from a BVH clip: a `SkeletonProfile`.

Motion capture from different labs differs in ways the representation must not care about: which
joint carries the root motion (a static `Root` above the hips is common in game rigs), the feet's
names, which axis is up, the units, the body's size. A profile records all of it (root, feet, left/right
pairs, up and facing axes, units, body height, contact thresholds), found from one clip and overridable
in configuration (`walkdiff.motion.profile_detection`), and is saved in every feature cache and
checkpoint.

Everything below works in the *canonical* frame: Y up, the root's subtree only (the body), every
local rotation and offset expressed in that frame (R -> U R U^T, o -> U o with U taking the file's
up axis to +Y). A canonical clip has the same world positions as the file's, turned by U.
`to_canonical` and `to_file` convert a clip both ways; the round trip is exact for the folded and
non-body joints when they are static, as the profile found them, and for joints above the root that
carried part of its path along some axes (`carriers`) when they carried it all along those axes.
`check_layout` refuses a clip of the skeleton whose layout the features would misread or drop.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion import posed_frames as posed
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.posed_frames import ancestors, subtree, world_transforms
from walkdiff.motion.profile_detection import (
    NO_FEET,
    axis_name,
    axis_rotation,
    detect_fields,
    translation_off_offsets,
)
from walkdiff.motion.skeleton import Motion, Skeleton, skeleton_from_dict, skeleton_to_dict

BONE_TOLERANCE = 0.01  # body heights: a bone longer or shorter than this is another skeleton
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
    # Joints above the root whose translation moved in the clip (a root carrying the path, the hips a bob),
    # with the axes of their parent's frame it moved along: export gives them the root's path there again.
    carriers: dict[str, list[int]] = field(default_factory=dict)
    found: dict[str, str] = field(default_factory=dict)  # how each field was found
    notes: tuple[str, ...] = ()  # anything suspicious

    @classmethod
    def detect(
        cls, motion: Motion, overrides: dict | None = None, path: str | Path | None = None
    ) -> SkeletonProfile:
        """The profile of `motion`'s skeleton; `overrides` (config) win over detection. Errors name
        `path`, the file `motion` was read from, when given."""
        try:
            return cls(skeleton=motion.skeleton, **detect_fields(motion, overrides))
        except WalkdiffError as error:
            if path is None or error.path is not None:
                raise
            raise WalkdiffError(error.reason, path=path) from error

    # ------------------------------------------------------------ what the representation reads

    @property
    def root_index(self) -> int:
        return self.skeleton.index(self.root)

    @property
    def body(self) -> list[int]:
        """File joint indices of the body (the root's subtree), in file order."""
        return subtree(self.skeleton, self.root_index)

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
        world = motion_world_positions(motion)[:, [names.index(n) for n in canonical.names]] @ self.turn.T
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

    def check_layout(self, motion: Motion, path=None) -> None:
        """A WalkdiffError naming what differs when `motion`, a clip of this skeleton, is laid out
        otherwise than the profile in a way its features would silently lose or misread: translation on a
        body joint below the root, the body standing along another axis, a body of another size (units).
        Joints above the root that move are reconciled: they are folded into the root on every frame."""
        self.check(motion.skeleton, path)
        problems = layout_differences(self, motion)
        if problems:
            raise WalkdiffError(
                "laid out otherwise than the dataset's skeleton profile (found from its first clip): "
                + "; ".join(problems)
                + ". Give such clips their own folder (or profile), or leave them out (data.on_error: skip)",
                path=path,
            )

    def posed_body_height(self, motion: Motion, transforms=None) -> float | None:
        """How tall the body of `motion` (a clip of this skeleton) is on its posed frames, along the
        profile's up: the head's top above the floor under the feet, the median over frames with both
        feet down (`walkdiff.motion.posed_frames.posed_height`); None without feet or a head.
        `transforms`: the clip's world positions and rotations, when already at hand."""
        if not self.feet:
            return None
        skeleton = motion.skeleton
        head = _head(self, skeleton)
        if head is None:
            return None
        world, world_rot = transforms if transforms is not None else world_transforms(motion)
        heels = [skeleton.index(self.feet["left_heel"]), skeleton.index(self.feet["right_heel"])]
        up = np.asarray(self.up) / np.linalg.norm(self.up)
        return posed.body_height_on_frames(world, world_rot, skeleton, head, heels, up)[0]

    # ------------------------------------------------------------ conversions

    def _chain(
        self, rotations: np.ndarray, positions: np.ndarray, joint: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """World rotation (..., 3, 3) and position (..., 3) of the frame `joint` (default: the root) hangs
        in: its parent's."""
        rot = np.broadcast_to(np.eye(3), rotations.shape[:-3] + (3, 3)).copy()
        pos = np.zeros(positions.shape[:-2] + (3,))
        for j in ancestors(self.skeleton, self.root_index if joint is None else joint):
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
        root = self.root_index
        world_rot = u.T @ motion.rotations[:, 0] @ u
        world_pos = motion.positions[:, 0] @ u
        for name, axes in self.carriers.items():  # top down: a carrier's parents are placed first
            j = s.index(name)
            parent_rot, parent_pos = self._chain(rotations, positions, j)
            local = np.einsum("fji,fj->fi", parent_rot, world_pos - parent_pos)
            positions[:, j, axes] = local[:, axes]
        chain_rot, chain_pos = self._chain(rotations, positions)
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
            "carriers": {n: list(axes) for n, axes in self.carriers.items()},
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
            carriers={n: [int(a) for a in axes] for n, axes in data.get("carriers", {}).items()},
            found=dict(data.get("found", {})),
            notes=tuple(data.get("notes", ())),
        )

    def describe(self) -> list[str]:
        """Lines for `inspect` and `data scan`."""
        f = self.feet
        folded = [self.skeleton.names[j] for j in ancestors(self.skeleton, self.root_index)]
        up, forward_text = axis_name(np.asarray(self.up)), axis_name(np.asarray(self.forward))
        return [
            f"root:      {self.root}"
            + (f" (static above it, folded: {', '.join(folded)})" if folded and not self.carriers else "")
            + (f" (translation shared with {', '.join(self.carriers)} above it)" if self.carriers else "")
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
            f"height:    {self.body_height:.4g} units = {self.body_height * self.metres_per_unit:.2f} m"
            f" [{self.found.get('body_height', '')}]",
            f"rest pose: {self.found.get('rest_pose', 'not checked')}",
            f"contacts:  slower than {self.contact_speed:.3g} units/s and within {self.contact_height:.3g} "
            f"units of the foot's floor [{self.found.get('contacts', '')}]",
        ]


# ---------------------------------------------------------------- helpers

LAYOUT_UP_DEGREES = 45.0  # a clip whose body stands farther than this from the profile's up is refused
LAYOUT_SIZE = 2.0  # nor one whose posed body is this many times taller or shorter than the profile's
# nor one with translation below the root that leaves the bone offsets by this many body heights: motion
# the features would drop (looser than `convert`'s check: bone lengths of raw capture jitter a little)
LAYOUT_TRANSLATION = 0.01


def layout_differences(profile: SkeletonProfile, motion: Motion) -> list[str]:
    """What in `motion` the profile cannot reconcile (see `SkeletonProfile.check_layout`), as phrases."""
    skeleton, height = motion.skeleton, profile.body_height
    root = skeleton.index(profile.root)
    problems = [
        f"translation on {skeleton.names[j]!r} below the root {profile.root!r} leaves its bone offset by up "
        f"to {off:.3g} {profile.units} (the features keep only the root's)"
        for j, off in translation_off_offsets(motion, root, LAYOUT_TRANSLATION * height)
    ]
    if not profile.feet:
        return problems
    transforms = world, _ = world_transforms(motion)
    feet = [skeleton.index(profile.feet[k]) for k in ("left_heel", "left_toe", "right_heel", "right_toe")]
    head = _head(profile, skeleton)
    top = head if head is not None else root
    up, _, share = posed.posed_up(world, top, feet[::2])
    profile_up = np.asarray(profile.up) / np.linalg.norm(profile.up)
    angle = float(np.degrees(np.arccos(np.clip(up @ profile_up, -1.0, 1.0))))
    if angle > LAYOUT_UP_DEGREES and share >= 0.9:
        problems.append(
            f"the body stands along {axis_name(up)} (feet to {skeleton.names[top]} on {share:.0%} of the "
            f"frames), the profile's up is {axis_name(profile_up)}"
        )
        return problems  # its height along the profile's up means nothing
    measured = profile.posed_body_height(motion, transforms)
    if measured is not None:
        if not height / LAYOUT_SIZE <= measured <= height * LAYOUT_SIZE:
            problems.append(
                f"the posed body is {measured:.4g} units tall, the profile's {height:.4g} {profile.units} "
                "(other units or another body)"
            )
    return problems


def _head(profile: SkeletonProfile, skeleton: Skeleton) -> int | None:
    """The head joint of `skeleton` (`posed_frames.find_head`) with the profile's root, pairs and feet."""
    pairs = [(skeleton.index(a), skeleton.index(b)) for a, b in profile.mirror_pairs]
    feet = [skeleton.index(profile.feet[k]) for k in ("left_heel", "left_toe", "right_heel", "right_toe")]
    return posed.find_head(skeleton, skeleton.index(profile.root), pairs, feet)


def _listed(names: list[str], limit: int = 8) -> str:
    return ", ".join(names[:limit]) + (" ..." if len(names) > limit else "")


def _parent_name(skeleton: Skeleton, name: str) -> str | None:
    p = int(skeleton.parents[skeleton.names.index(name)])
    return None if p < 0 else skeleton.names[p]
