"""Retargeting: a clip of one humanoid skeleton played by another, on the target's own skeleton.

The target keeps its names, hierarchy, channels, bone lengths, units and axes; only its rotations and
the translation of the joint that carries its root motion change. Per clip (`Retargeter.__call__`):

1. rotations: every target joint on a chain of the humanoid map turns in the world as its source joint
   turns away from its reference pose, with the rest-pose difference taken out per bone, and chains
   the rigs divide differently (spines of other lengths, CMU's hip joints) spread over the target's
   joints (`walkdiff.retarget.rest_alignment`). Joints on no chain (a static root, twist and IK helpers,
   fingers only the target has) keep their reference pose; `RetargetResult.rest_joints` names them.
   Left and right are never swapped: roles carry their side from the maps.
2. proportions: the pelvis goes where the source's does along the ground, times the legs' length ratio
   (target over source, each in its own units: units convert with it); the up axes convert through
   each rig's profile (canonical Y up). Up and down, the middle of the thighs rises and falls as the
   source's does (times the ratio): rigs put their pelvis joint at other places over the hips, and a
   nearly straight leg bends far for a little height. A vertical shift then puts the target's planted
   feet at the source's planted heights (times the ratio).
3. feet: contacts are measured on the source with its profile's thresholds. With `feet="follow"`
   (default) each foot walks the source's foot path, scaled, by the foot clean-up's two-bone IK
   (`walkdiff.motion.footfix.bend_leg`) on every frame (`follow_goals`): the ankle goes as high as
   the source's (each joint at its own height above the floor), and along the ground the foot is
   anchored on whichever of heel and toe is lower, so the joint on the ground goes where the source's
   goes whatever the feet's lengths. Where on the ground is the target's own: the path is moved by how
   far the target's foot stands from it with its legs as the source's rotations put them (its hip
   width, thigh-to-shin proportions, ankle height), held over each contact, so a leg bends away from
   the source's direction only by how much that changes while its foot is down; high in the air the
   leg is free. It adds no sliding of its own (the skate ratio with each rig's own profile stays the
   source's), and a target of the same proportions reproduces the source exactly. Where a leg could
   not reach a planted goal (a target whose hips sit higher over its feet, pushing off), the body is
   lowered as much as that needs around those frames. `"pin"` also holds every planted foot still on
   its contact, the clean-up's own rule: it removes the source's sliding too (on Xia, half the mean
   slide speed) but jumps a little where heel and toe contacts change. `"off"` leaves the legs as the
   rotations put them.

A `Retargeter` does the per-rig work once (profiles, maps, reference poses, per-joint constants) and
then converts any clip of the source skeleton; `retarget` is the one-call form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.threads import single_thread
from walkdiff.motion.footfix import MAX_REACH, ankle_offsets, bend_leg, contact_runs
from walkdiff.motion.humanoid import SIDES, HumanoidMap, humanoid_map, leg_length
from walkdiff.motion.kinematics import depth_levels, forward_kinematics
from walkdiff.motion.posed_frames import ancestors, rest_pose_problem
from walkdiff.motion.profile import ContactSpec, SkeletonProfile
from walkdiff.motion.representation import contact_state
from walkdiff.motion.rotations import rotation_between
from walkdiff.motion.skeleton import Motion, Skeleton
from walkdiff.retarget.body_check import check_body
from walkdiff.retarget.rest_alignment import (
    Drive,
    Reference,
    alignment,
    pose_points,
    reference_pose,
)

FEET_MODES = ("follow", "pin", "off")
BLEND_SECONDS = 0.05  # a pinned foot's correction fades in and out over this long around its contact
AIR_BAND = (1.0, 2.0)  # a foot's goal goes from the ground path to the free leg between these heights
DROP_SECONDS = 0.15  # the body lowered where a leg cannot reach eases in and out over this long


@dataclass(frozen=True)
class RetargetResult:
    """A retargeted clip and what was done to it.

    `contacts` (F, 4): the source's contacts as the target's left heel, left toe, right heel, right toe;
    `leg_ratio`: target leg length over the source's; `rest_joints`: target joints left in their
    reference pose; `notes`: the reference poses used and anything else a user should know."""

    motion: Motion
    contacts: np.ndarray
    leg_ratio: float
    rest_joints: tuple[str, ...]
    notes: tuple[str, ...]


class Retargeter:
    """Retargets clips of `source`'s skeleton onto `target` (see the module docstring).

    `source`: a clip of the source skeleton (its profile and, when its rest pose is no pose, its
    reference frame come from it). `target`: the target rig, a `Skeleton` (its rest pose is its
    reference) or a `Motion` (its frame `target_frame` is; None: its rest pose), e.g. a BVH of the
    user's rig. Maps: a `HumanoidMap`, a dict of overrides, or None (found). `reference_frame`: the
    frame of `source` to align on instead of the source's rest pose (by default used only when the
    rest pose is no pose: then a standing frame is found). Profiles are detected unless given. A source
    or target that does not stand like a biped (`walkdiff.retarget.body_check`) is refused unless `force`.
    """

    def __init__(
        self,
        source: Motion,
        target: Motion | Skeleton,
        source_map: HumanoidMap | dict | None = None,
        target_map: HumanoidMap | dict | None = None,
        reference_frame: int | None = None,
        *,
        target_frame: int | None = 0,
        feet: str = "follow",
        source_profile: SkeletonProfile | None = None,
        target_profile: SkeletonProfile | None = None,
        force: bool = False,
    ):
        if feet not in FEET_MODES:
            raise WalkdiffError(f"retarget: feet {feet!r}: expected one of {', '.join(FEET_MODES)}")
        self.feet = feet
        target_motion, target_frame = _target_motion(target, target_frame)
        self.source_skeleton, self.target_skeleton = source.skeleton, target_motion.skeleton
        self.source_profile = source_profile or SkeletonProfile.detect(source)
        frame_clip = target_motion.slice(target_frame or 0, (target_frame or 0) + 1)
        self.target_profile = target_profile or SkeletonProfile.detect(frame_clip)
        self.source_map = _map(source, source_map, "the source (the clip's skeleton)")
        self.target_map = _map(frame_clip, target_map, "the target rig")
        if not force:  # measured on the posed frames: before the source's rest pose is looked at
            check_body(source, self.source_map, "the source (the clip's skeleton)")
        self.source_ref = _source_reference(
            source, self.source_map, self.source_profile.turn, reference_frame
        )
        how = "its rest pose" if target_frame is None else f"its frame {target_frame}"
        self.target_ref = reference_pose(
            target_motion, target_frame, self.target_profile.turn, self.target_map, how
        )
        problem = _pose_problem(self.target_ref)
        if problem:
            raise WalkdiffError(
                f"retarget: the target's reference pose ({how}) is no pose: {problem}; give the target as a "
                "clip whose first frame (target_frame) stands"
            )
        if not force:
            check_body(frame_clip, self.target_map, "the target rig")
        self.drives, self.links = alignment(self.source_ref, self.target_ref)
        self.leg_ratio = _leg_length(self.target_ref) / _leg_length(self.source_ref)
        # The same in metres: how much farther the target travels than the source.
        self.metric_leg_ratio = (
            self.leg_ratio * self.target_profile.metres_per_unit / self.source_profile.metres_per_unit
        )
        self._prepare()

    # ------------------------------------------------------------ set-up

    def _prepare(self) -> None:
        """Index arrays and constants for the per-clip work."""
        tgt, src = self.target_ref, self.source_ref
        self.driven = np.array([d.target for d in self.drives])
        self.drivers = np.array([d.source for d in self.drives])
        self.constants = np.stack([d.constant for d in self.drives])
        self.swings = [(i, d) for i, d in enumerate(self.drives) if d.chord is not None]
        skeleton = self.target_skeleton
        driven = set(self.driven.tolist())
        self.root_driven = 0 in driven
        is_driven = np.isin(np.arange(skeleton.num_joints), self.driven)
        self.levels = [
            (level[is_driven[level]], level[~is_driven[level]])
            for level in depth_levels(skeleton.parents)[1:]
        ]
        self.rest_joints = tuple(n for j, n in enumerate(skeleton.names) if j not in driven)
        # Reference local transforms; the root's in canonical axes (the world the per-clip work runs in).
        self.local_rotations = tgt.local_rotations.copy()
        self.local_positions = tgt.local_positions.copy()
        self.local_rotations[0] = tgt.turn @ self.local_rotations[0]
        self.local_positions[0] = tgt.turn @ self.local_positions[0]
        self.pelvis = (src.index("pelvis"), tgt.index("pelvis"))
        self.source_hips = [src.index(f"{side}_thigh") for side in SIDES]
        self.target_hips = [tgt.index(f"{side}_thigh") for side in SIDES]
        self.carrier = _carrier(skeleton, tgt.index("pelvis"))
        feet = [(f"{s}_foot", f"{s}_toe") for s in SIDES]
        self.source_feet = [_contact_joint(src, role) for pair in feet for role in pair]
        self.target_feet = [_contact_joint(tgt, role) for pair in feet for role in pair]
        p = self.source_profile
        names = self.source_skeleton.names
        self.contact_spec = ContactSpec(
            *(names[j] for j in self.source_feet),
            speed_threshold=p.contact_speed,
            height_threshold=p.contact_height,
        )
        self.legs = [_ik_chain(skeleton, tgt, side) for side in SIDES]
        self.notes = [
            f"source aligned on {src.how}, target on {tgt.how}",
            f"leg ratio {self.leg_ratio:.4g} (target over source, each in its own units)",
        ]
        self.notes += [
            f"foot IK off on the {side} leg: {leg}"
            for side, leg in zip(SIDES, self.legs)
            if isinstance(leg, str)
        ]
        if self.rest_joints:
            self.notes.append(f"left in their reference pose: {', '.join(self.rest_joints)}")

    def describe(self) -> list[str]:
        """Lines for a report: both maps' roles side by side, and the notes."""
        lines = []
        target_roles = self.target_map.roles()
        for role, joint in self.source_map.roles().items():
            lines.append(f"{role:15s} {joint} -> {target_roles.get(role, '(none)')}")
        return lines + [f"note: {n}" for n in self.notes]

    # ------------------------------------------------------------ per clip

    def __call__(self, motion: Motion) -> RetargetResult:
        with single_thread():  # contact detection's small torch operations: threads only wait
            return self._retarget(motion)

    def _retarget(self, motion: Motion) -> RetargetResult:
        if not motion.skeleton.same_hierarchy(self.source_skeleton):
            raise WalkdiffError(
                "retarget: the clip is not on the source skeleton this retargeter was made for "
                f"({motion.skeleton.num_joints} joints vs {self.source_skeleton.num_joints})"
            )
        turn = self.source_ref.turn
        positions, rotations = forward_kinematics(
            motion.rotations, motion.positions, self.source_skeleton.parents, return_rotations=True
        )
        positions, rotations = positions @ turn.T, turn @ rotations
        world = self._driven_rotations(positions, rotations)
        local_rot, local_pos, world_rot = self._locals(world, motion.num_frames)
        self._place_pelvis(local_pos, world_rot, self.leg_ratio * positions[:, self.pelvis[0]])
        self._lift_hips(local_pos, world_rot, self.leg_ratio * positions[:, self.source_hips, 1].mean(axis=1))
        source_feet = positions[:, self.source_feet]
        low, slow = contact_state(source_feet, motion.fps, self.contact_spec)
        contacts = (low & slow).astype(np.float64)
        feet = _positions_of(self.target_skeleton, local_pos, world_rot, self.target_feet)
        shift = _vertical_shift(self.leg_ratio * source_feet[..., 1], feet[..., 1], contacts > 0.5)
        self._shift(local_pos, world_rot, shift)
        feet[..., 1] += shift
        if self.feet != "off":
            scaled = self.leg_ratio * positions[:, self.source_feet]
            self._fix_feet(local_rot, local_pos, world_rot, feet, scaled, contacts, motion.fps)
        inverse = self.target_ref.turn.T
        local_rot[:, 0] = inverse @ local_rot[:, 0]
        local_pos[:, 0] = local_pos[:, 0] @ inverse.T
        out = Motion(self.target_skeleton, local_rot, local_pos, motion.frame_time)
        return RetargetResult(out, contacts, self.leg_ratio, self.rest_joints, tuple(self.notes))

    def _driven_rotations(self, positions: np.ndarray, rotations: np.ndarray) -> np.ndarray:
        """(F, n, 3, 3) canonical world rotations of the driven target joints."""
        world = rotations[:, self.drivers] @ self.constants
        if not self.swings:
            return world
        index = [i for i, _ in self.swings]
        now = np.stack([_chord(d, positions, rotations) for _, d in self.swings], axis=1)
        turned = np.stack([rotations[:, d.source] @ d.chord[3] for _, d in self.swings], axis=1)
        world[:, index] = rotation_between(turned, now) @ world[:, index]
        return world

    def _locals(self, world: np.ndarray, frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Local rotations and translations (F, J, ...) of the target, and its world rotations: a driven
        joint's local rotation from its world one, any other's world rotation from its reference local
        one."""
        local_rot = np.broadcast_to(self.local_rotations, (frames, *self.local_rotations.shape)).copy()
        local_pos = np.broadcast_to(self.local_positions, (frames, *self.local_positions.shape)).copy()
        world_rot = np.empty_like(local_rot)
        world_rot[:, self.driven] = world
        if self.root_driven:
            local_rot[:, 0] = world_rot[:, 0]
        else:
            world_rot[:, 0] = local_rot[:, 0]
        parents = self.target_skeleton.parents
        for driven, kept in self.levels:  # below the root, a tree level at a time
            if driven.size:
                local_rot[:, driven] = (
                    np.swapaxes(world_rot[:, parents[driven]], -1, -2) @ world_rot[:, driven]
                )
            if kept.size:
                world_rot[:, kept] = world_rot[:, parents[kept]] @ local_rot[:, kept]
        return local_rot, local_pos, world_rot

    def _lift_hips(self, local_pos: np.ndarray, world_rot: np.ndarray, height: np.ndarray) -> None:
        """Move the body vertically so that the middle of the thighs is at `height` (F,), up to one
        shift for the clip (set later by the feet)."""
        now = _positions_of(self.target_skeleton, local_pos, world_rot, self.target_hips).mean(axis=1)[:, 1]
        self._shift(local_pos, world_rot, height - now - np.median(height - now))

    def _place_pelvis(self, local_pos: np.ndarray, world_rot: np.ndarray, place: np.ndarray) -> None:
        """Set the carrier's translation so that the pelvis lands on `place` (F, 3) (joints between
        them keep their reference transforms)."""
        now = _positions_of(self.target_skeleton, local_pos, world_rot, [self.pelvis[1]])[:, 0]
        self._move_carrier(local_pos, world_rot, place - now)

    def _move_carrier(self, local_pos: np.ndarray, world_rot: np.ndarray, delta: np.ndarray) -> None:
        parent = int(self.target_skeleton.parents[self.carrier])
        if parent < 0:
            local_pos[:, self.carrier] += delta
        else:
            local_pos[:, self.carrier] += np.einsum("fji,fj->fi", world_rot[:, parent], delta)

    def _shift(self, local_pos: np.ndarray, world_rot: np.ndarray, shift: float | np.ndarray) -> None:
        """The whole body moved up by `shift` (a float, or (F,) per frame)."""
        delta = np.zeros((local_pos.shape[0], 3))
        delta[:, 1] = shift
        self._move_carrier(local_pos, world_rot, delta)

    def _fix_feet(self, local_rot, local_pos, world_rot, feet, source, contacts, fps) -> None:
        """Two-bone IK on each leg that has one, its ankle onto `follow_goals` (pinned on contacts for
        `pin`), the body lowered first where a leg could not reach (`_reach_drop`); the foot keeps its
        world turn. `source` (F, 4, 3): the source's heels and toes (as `feet`), scaled."""
        blend = max(1, int(round(BLEND_SECONDS * fps)))
        band = self.leg_ratio * self.source_profile.contact_height
        tiny = 1e-9 * self.target_ref.size
        parents = self.target_skeleton.parents
        legs = []
        for side, chain in enumerate(self.legs):
            if isinstance(chain, str):
                continue
            pair = slice(2 * side, 2 * side + 2)
            heel, toe, on = feet[:, 2 * side], feet[:, 2 * side + 1], contacts[:, pair]
            goal = follow_goals(heel, toe, source[:, pair], on, band)
            if self.feet == "pin":
                goal = goal + ankle_offsets(goal, goal + toe - heel, on, blend)
            legs.append((chain, heel, goal, (on > 0.5).any(axis=1)))
        drop = self._reach_drop(local_pos, world_rot, [(c, g, p) for c, _, g, p in legs], fps)
        if drop.any():
            self._shift(local_pos, world_rot, -drop)
        for chain, heel, goal, _ in legs:
            thigh, shin, foot = chain[-3:]
            rows = np.flatnonzero(np.linalg.norm(goal - heel, axis=-1) > tiny)
            if not rows.size:
                continue  # a target of the source's own proportions: nothing to bend
            rot = world_rot[rows]
            places = _positions_of(self.target_skeleton, local_pos[rows], rot, [thigh, shin, foot])
            hip_turn, knee_turn = bend_leg(*places.transpose(1, 0, 2), rot[:, thigh], goal[rows])
            hip_world, knee_world = hip_turn @ rot[:, thigh], knee_turn @ rot[:, shin]
            local_rot[rows, thigh] = np.swapaxes(rot[:, parents[thigh]], -1, -2) @ hip_world
            local_rot[rows, shin] = np.swapaxes(hip_world, -1, -2) @ knee_world
            local_rot[rows, foot] = np.swapaxes(knee_world, -1, -2) @ rot[:, foot]
            world_rot[rows, thigh], world_rot[rows, shin] = hip_world, knee_world

    def _reach_drop(self, local_pos, world_rot, legs, fps: float) -> np.ndarray:
        """(F,) how far to lower the whole body so that every planted foot's goal is in its leg's reach:
        a target whose hips sit higher over its feet than the source's (scaled) would otherwise stand
        on tiptoe where the source's legs stretch (pushing off). A leg reaches at least as far as its
        ankle stands from its hip now. Lowered only around the frames that need it, eased in and out
        over DROP_SECONDS (a drop for the whole clip bent every stance of it for one push-off)."""
        frames = local_pos.shape[0]
        need = np.zeros(frames)
        for chain, goal, planted in legs:
            if not planted.any():
                continue
            places = _positions_of(self.target_skeleton, local_pos[planted], world_rot[planted], chain[-3:])
            hip, knee, ankle = places.transpose(1, 0, 2)
            length = np.linalg.norm(knee - hip, axis=-1) + np.linalg.norm(ankle - knee, axis=-1)
            reach = np.maximum(MAX_REACH * length, np.linalg.norm(ankle - hip, axis=-1))
            across = np.linalg.norm((goal[planted] - hip)[:, [0, 2]], axis=-1)
            above = hip[:, 1] - goal[planted, 1]
            need[planted] = np.maximum(need[planted], above - np.sqrt(np.maximum(reach**2 - across**2, 0.0)))
        return _eased_above(np.maximum(need, 0.0), max(1, int(round(DROP_SECONDS * fps))))


def follow_goals(
    heel: np.ndarray,
    toe: np.ndarray,
    source: np.ndarray,
    contacts: np.ndarray,
    band: float,
) -> np.ndarray:
    """(F, 3) ankle goals of one target foot that make it walk the source's foot path (`source` (F, 2,
    3): its heel and toe, scaled) in the target's own stance. The ankle goes as high as the source's.
    Along the ground the foot is anchored on the lower of the two: the source's heel path while the
    heel is the lower (a heel strike), the source's toe path less the target's own heel-to-toe while
    the toe is (the foot rolling over it), in between within `band` of each other (a flat foot); so the
    joint touching the ground goes where the source's goes, whatever the feet's lengths.

    Where on the ground is the target's own: `heel`, `toe` (F, 3) are its joints as the source's
    rotations put them (the legs free), which carry its hip width, its thigh-to-shin proportions and
    its ankle height. Each joint keeps its own height above the floor; along the ground the path moves
    by how far the free foot is from the source's (scaled), held at its mean over each contact run
    (`contacts` (F, 2)), so a planted foot moves only as the source's does and its leg bends away from
    the source's directions only by how that offset changes during the contact. Above AIR_BAND times
    `band` (the contact height) the goal is the free ankle, moved only by the correction the planted
    frames on either side needed: the leg swings as the source's does."""
    lift = np.zeros((2, 3))
    for k, joint in enumerate((heel, toe)):
        planted = contacts[:, k] > 0.5
        frames = planted if planted.any() else slice(None)
        lift[k, 1] = np.median(joint[frames, 1] - source[frames, k, 1])
    by_heel = source[:, 0] + lift[0]
    by_toe = source[:, 1] + lift[1] - (toe - heel)
    above = source[..., 1]
    weight = np.clip(0.5 + (above[:, 0] - above[:, 1]) / (2 * band), 0.0, 1.0)
    goal = by_heel + weight[:, None] * (by_toe - by_heel)
    goal[:, 1] = by_heel[:, 1]
    offset = (heel - goal)[:, [0, 2]]  # the free foot against the source's path
    planted = (contacts > 0.5).any(axis=1)
    goal[:, [0, 2]] += _held_over_runs(offset, planted)
    if not planted.any() or planted.all():
        return goal
    # High in the air the leg is free: the free ankle, moved by the correction the planted frames
    # needed, carried linearly between them; the ground path back below AIR_BAND contact heights.
    frames = np.arange(len(goal))
    fix = goal - heel
    carried = np.stack([np.interp(frames, frames[planted], fix[planted, i]) for i in range(3)], axis=1)
    free = heel + carried
    floor = np.percentile(source[..., 1], 5, axis=0) + lift[:, 1]
    sole = (toe - heel)[:, 1]
    low = np.minimum(
        np.minimum(goal[:, 1] - floor[0], goal[:, 1] + sole - floor[1]),
        np.minimum(free[:, 1] - floor[0], free[:, 1] + sole - floor[1]),
    )
    air = np.clip((low / band - AIR_BAND[0]) / (AIR_BAND[1] - AIR_BAND[0]), 0.0, 1.0)
    air[planted] = 0.0
    return goal + air[:, None] * (free - goal)


def _held_over_runs(values: np.ndarray, planted: np.ndarray) -> np.ndarray:
    """(F, k) `values` replaced by their mean over each run of `planted` frames and interpolated
    linearly between runs (held at the first and last run's outside them); as given when nothing is
    planted."""
    runs = contact_runs(planted)
    if not runs:
        return values
    held = np.empty_like(values)
    for start, stop in runs:
        held[start:stop] = values[start:stop].mean(axis=0)
    frames = np.arange(len(values))
    return np.stack([np.interp(frames, frames[planted], held[planted, i]) for i in range(values.shape[1])], 1)


def _eased_above(values: np.ndarray, radius: int) -> np.ndarray:
    """(F,) a smooth curve never below `values` (F,): the largest value within `radius` frames, then
    averaged over the same window (an average of maxima that each cover the frame)."""
    width = 2 * radius + 1
    peaks = np.lib.stride_tricks.sliding_window_view(np.pad(values, radius, mode="edge"), width).max(axis=1)
    return np.lib.stride_tricks.sliding_window_view(np.pad(peaks, radius, mode="edge"), width).mean(axis=1)


def retarget(
    source: Motion,
    target_rest: Motion | Skeleton,
    source_map: HumanoidMap | dict | None = None,
    target_map: HumanoidMap | dict | None = None,
    reference_frame: int | None = None,
    **options,
) -> Motion:
    """`source` played by the target rig (see `Retargeter` for the arguments and options)."""
    return Retargeter(source, target_rest, source_map, target_map, reference_frame, **options)(source).motion


# ---------------------------------------------------------------- helpers


def _chord(drive: Drive, positions: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """(F, 3) the source's chord a drive follows, per frame."""
    chain, lo, hi, _ = drive.chord
    ends = []
    for share in (lo, hi):
        k, t = chain.locate(share)
        a, b = (_point_at(chain.points[i], positions, rotations) for i in (k, k + 1))
        ends.append((1 - t) * a + t * b)
    return ends[1] - ends[0]


def _point_at(point, positions: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    joint, offset = point
    if offset is None:
        return positions[:, joint]
    return positions[:, joint] + rotations[:, joint] @ offset


def _positions_of(skeleton: Skeleton, local_pos: np.ndarray, world_rot: np.ndarray, joints) -> np.ndarray:
    """(F, n, 3) world positions of `joints` from local translations and world rotations."""
    needed = sorted({a for j in joints for a in [*ancestors(skeleton, j), j]})
    places: dict[int, np.ndarray] = {}
    for j in needed:
        p = int(skeleton.parents[j])
        places[j] = (
            local_pos[:, j]
            if p < 0
            else places[p] + np.einsum("fij,fj->fi", world_rot[:, p], local_pos[:, j])
        )
    return np.stack([places[j] for j in joints], axis=1)


def _vertical_shift(source_heights: np.ndarray, target_heights: np.ndarray, planted: np.ndarray) -> float:
    """How far to lift the target so its planted feet stand where the source's do (median over the
    planted frames and joints; over every frame's lowest joint when nothing is planted)."""
    if planted.any():
        return float(np.median((source_heights - target_heights)[planted]))
    return float(np.median(source_heights.min(axis=1) - target_heights.min(axis=1)))


def _target_motion(target: Motion | Skeleton, frame: int | None) -> tuple[Motion, int | None]:
    if isinstance(target, Skeleton):
        rotations = np.broadcast_to(np.eye(3), (1, target.num_joints, 3, 3)).copy()
        return Motion(target, rotations, target.offsets[None].copy(), 1.0 / 30.0), None
    if frame is not None and not -target.num_frames <= frame < target.num_frames:
        raise WalkdiffError(f"retarget: target_frame {frame}: the target clip has {target.num_frames} frames")
    return target, (frame % target.num_frames if frame is not None else None)


def _map(motion: Motion, given: HumanoidMap | dict | None, which: str) -> HumanoidMap:
    if isinstance(given, HumanoidMap):
        return given
    try:
        return humanoid_map(motion, given)
    except WalkdiffError as error:  # say which of the two rigs it is
        raise WalkdiffError(
            f"retarget: {which} is {error.reason}", path=error.path, line=error.line
        ) from None


def _pose_problem(ref: Reference) -> str | None:
    heels = [ref.index(f"{s}_foot") for s in SIDES]
    return rest_pose_problem(pose_points(ref), ref.skeleton, ref.index("pelvis"), heels, ref.index("head"))


def _source_reference(source: Motion, hmap: HumanoidMap, turn: np.ndarray, frame: int | None) -> Reference:
    """The source's rest pose when it is a pose, else the given frame, else its most upright frame."""
    if frame is not None:
        if not -source.num_frames <= frame < source.num_frames:
            raise WalkdiffError(f"retarget: reference_frame {frame}: the clip has {source.num_frames} frames")
        return reference_pose(
            source, frame % source.num_frames, turn, hmap, f"frame {frame} of the clip (given)"
        )
    rest = reference_pose(source, None, turn, hmap, "its rest pose")
    problem = _pose_problem(rest)
    if problem is None:
        return rest
    skeleton = source.skeleton
    positions = forward_kinematics(source.rotations, source.positions, skeleton.parents)
    up = positions @ turn.T
    head, feet = skeleton.index(hmap.head), [skeleton.index(hmap.joint(f"{s}_foot")) for s in SIDES]
    standing = int(np.argmax(up[:, head, 1] - up[:, feet, 1].min(axis=1)))
    ref = reference_pose(
        source, standing, turn, hmap, f"frame {standing} of the clip (its rest pose is no pose: {problem})"
    )
    if _pose_problem(ref):
        raise WalkdiffError(
            f"retarget: the source's rest pose is no pose ({problem}) and no frame of the clip stands: "
            "give a reference_frame"
        )
    return ref


def _leg_length(ref: Reference) -> float:
    try:
        return leg_length(ref.skeleton, ref.hmap)
    except WalkdiffError as error:
        raise WalkdiffError(f"retarget: {error.reason}") from None


def _carrier(skeleton: Skeleton, pelvis: int) -> int:
    """The joint whose translation carries the root motion: the pelvis when it has position channels,
    else the nearest joint above it that has (the root has its translation in any case)."""
    joint = pelvis
    while joint > 0 and not skeleton.position_order(joint):
        joint = int(skeleton.parents[joint])
    return max(joint, 0)


def _contact_joint(ref: Reference, role: str) -> int:
    """The joint of a contact role; the foot when a rig has no toe."""
    index = ref.index(role)
    return index if index is not None else ref.index(role.replace("_toe", "_foot"))


def _ik_chain(skeleton: Skeleton, ref: Reference, side: str) -> list[int] | str:
    """The joints from the root down to the foot, for two-bone IK; or why the leg cannot take it."""
    thigh, shin, foot = (ref.index(f"{side}_{p}") for p in ("thigh", "shin", "foot"))
    if skeleton.parents[foot] != shin or skeleton.parents[shin] != thigh:
        return "joints between its thigh, shin and foot (two-bone IK needs the three in a row)"
    return [*ancestors(skeleton, foot), foot]
