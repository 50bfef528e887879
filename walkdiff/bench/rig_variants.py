"""Copies of a clip's own rig whose retargeting answer is known (`walkdiff bench retarget` and the tests).

Same proportions (`reframe`, `reposed`, `random_frames`, `axes_and_units`, `rotation_order`): the copy
holds the same motion with other rest poses, local frames, axes, units or channels, so a retargeter must
give back the source's world joint positions (up to the known turn and scale). Other proportions
(`legs`, `arms`, `hips`, `longer_spine`, `merged`): only the bone lengths or the joint count change, so bone
directions must follow the source's. Limbs and the spine are found by the humanoid map's roles, so
every builder works on any humanoid rig, not only Xia's.
"""

from __future__ import annotations

import numpy as np

from walkdiff.motion.humanoid import SIDES, humanoid_map
from walkdiff.motion.posed_frames import rest_points, snap_axis, subtree
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.skeleton import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, Skeleton

ARM_DROP_DEG = 45.0  # T to A pose
LEG_SPREAD_DEG = 10.0
LEG_SWING_DEG = 15.0


def turn_about(axis: np.ndarray, degrees: float) -> np.ndarray:
    """The rotation by `degrees` about `axis` (right hand), Rodrigues' formula."""
    a = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    angle = np.radians(degrees)
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _skeleton(s: Skeleton, offsets=None, channels=None, ends=None) -> Skeleton:
    return Skeleton(
        list(s.names),
        s.parents.copy(),
        s.offsets.copy() if offsets is None else offsets,
        list(s.channels if channels is None else channels),
        {j: np.array(e) for j, e in s.end_sites.items()} if ends is None else ends,
    )


# ---------------------------------------------------------------- same proportions


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
    return Motion(_skeleton(s, offsets, ends=ends), rotations, positions, motion.frame_time)


def body_axes(motion: Motion) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rig's (left, up, forward) file axes at rest: up from its profile, left from the right thigh to
    the left one (snapped to a file axis within 10 degrees), forward = left x up."""
    s, m = motion.skeleton, humanoid_map(motion)
    up = np.asarray(SkeletonProfile.detect(motion).up, dtype=np.float64)
    rest = rest_points(s)
    left = rest[s.index(m.left_thigh)] - rest[s.index(m.right_thigh)]
    left, _ = snap_axis(left - (left @ up) * up, 10.0)
    return left, up, np.cross(left, up)


def reposed(motion: Motion) -> Motion:
    """Arms turned 45 degrees further down (T to A pose) about the forward axis; legs spread 10 degrees
    and swung 15 degrees about the left axis, at rest. The rest pose changes, the motion does not: the
    test rigs of T-pose against A-pose failures."""
    s, m = motion.skeleton, humanoid_map(motion)
    left, _, forward = body_axes(motion)
    turns = np.repeat(np.eye(3)[None], s.num_joints, axis=0)
    for side, sign in zip(SIDES, (1.0, -1.0)):
        for j in subtree(s, s.index(m.joint(f"{side}_upper_arm"))):
            turns[j] = turn_about(forward, -ARM_DROP_DEG * sign).T
        leg = turn_about(left, LEG_SWING_DEG) @ turn_about(forward, LEG_SPREAD_DEG * sign)
        for j in subtree(s, s.index(m.joint(f"{side}_thigh"))):
            turns[j] = leg.T
    return reframe(motion, turns)


def random_turns(count: int, seed: int = 0) -> np.ndarray:
    """(count, 3, 3) rotations uniformly at random (normalised Gaussian quaternions, x y z w)."""
    q = np.random.default_rng(seed).normal(size=(count, 4))
    x, y, z, w = (q / np.linalg.norm(q, axis=1)[:, None]).T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )


def random_frames(motion: Motion, seed: int = 0) -> Motion:
    """Every local frame turned at random: the rest pose becomes a crumpled heap (no pose at all), as
    some exports write it."""
    return reframe(motion, random_turns(motion.skeleton.num_joints, seed))


def axes_and_units(motion: Motion, up_turn: np.ndarray, scale: float) -> Motion:
    """The same clip in a world turned by `up_turn` (e.g. +Y to +Z) and in other units: world positions
    become scale * P @ up_turn.T. Every local frame turns with the world, so the rig's joint frames look
    like a native rig of those axes, not like a Y-up rig laid on its back."""
    s = motion.skeleton
    turned = reframe(motion, np.repeat(up_turn.T[None], s.num_joints, axis=0))
    rotations, positions = turned.rotations, turned.positions * scale
    rotations[:, 0] = up_turn @ rotations[:, 0]
    positions[:, 0] = positions[:, 0] @ up_turn.T
    t = turned.skeleton
    offsets = t.offsets * scale
    offsets[0] = up_turn @ offsets[0]
    ends = {j: np.asarray(e) * scale for j, e in t.end_sites.items()}
    return Motion(_skeleton(t, offsets, ends=ends), rotations, positions, motion.frame_time)


def rotation_order(motion: Motion, order: str) -> Motion:
    """Every joint with three rotation channels lists them in Euler `order` ('XYZ'); the rotation
    matrices do not change, only what a written file holds."""
    names = [f"{a}rotation" for a in order.upper()]
    channels = []
    for joint in motion.skeleton.channels:
        own = [c for c in joint if c in ROTATION_CHANNELS]
        rotations = iter(names if len(own) == 3 else own)
        channels.append(tuple(next(rotations) if c in ROTATION_CHANNELS else c for c in joint))
    skeleton = _skeleton(motion.skeleton, channels=channels)
    return Motion(skeleton, motion.rotations.copy(), motion.positions.copy(), motion.frame_time)


# ---------------------------------------------------------------- other proportions


def scaled(skeleton: Skeleton, joints, factor: float) -> Skeleton:
    """The bones into `joints` (names, and their End Sites) `factor` times as long."""
    offsets, ends = skeleton.offsets.copy(), {j: np.array(e) for j, e in skeleton.end_sites.items()}
    for j in (skeleton.index(n) for n in joints):
        offsets[j] *= factor
        if j in ends:
            ends[j] *= factor
    return _skeleton(skeleton, offsets, ends=ends)


def _below(skeleton: Skeleton, role: str) -> list[str]:
    """The joints below each side's joint of `role` ('thigh'), not it."""
    m = humanoid_map(skeleton)
    tops = [skeleton.index(m.joint(f"{side}_{role}")) for side in SIDES]
    return [skeleton.names[j] for top in tops for j in subtree(skeleton, top)[1:]]


def legs(skeleton: Skeleton, factor: float) -> Skeleton:
    """Every bone below the thighs `factor` times as long: the legs' length ratio is `factor`."""
    return scaled(skeleton, _below(skeleton, "thigh"), factor)


def arms(skeleton: Skeleton, factor: float) -> Skeleton:
    """Every bone below the upper arms (forearm, hand, fingers) `factor` times as long."""
    return scaled(skeleton, _below(skeleton, "upper_arm"), factor)


def hips(skeleton: Skeleton, factor: float) -> Skeleton:
    """The hips `factor` times as wide: the bones from the pelvis to each thigh stretched sideways (along
    the rest pose's right-to-left line between the thighs), the legs themselves kept: another
    hip-width-to-leg ratio."""
    m = humanoid_map(skeleton)
    rest = rest_points(skeleton)
    thighs = [skeleton.index(m.joint(f"{side}_thigh")) for side in SIDES]
    across = rest[thighs[0]] - rest[thighs[1]]
    across /= max(np.linalg.norm(across), 1e-12)
    offsets, pelvis = skeleton.offsets.copy(), skeleton.index(m.pelvis)
    for joint in thighs:
        while joint != pelvis:  # offsets are in rest (identity) frames: the world's directions
            offsets[joint] += (factor - 1) * (offsets[joint] @ across) * across
            joint = int(skeleton.parents[joint])
    return _skeleton(skeleton, offsets)


def inserted(skeleton: Skeleton, child: str, name: str) -> Skeleton:
    """A new joint `name` halfway along the bone into `child` (with `child`'s rotation channels)."""
    c = skeleton.index(child)
    renumber = [j if j < c else j + 1 for j in range(skeleton.num_joints)]
    parents = [-1 if p < 0 else renumber[p] for p in skeleton.parents]
    parents.insert(c, parents[c])
    parents[c + 1] = c
    offsets = list(skeleton.offsets)
    offsets[c] = offsets[c] / 2
    offsets.insert(c, offsets[c].copy())
    channels = list(skeleton.channels)
    rotation = tuple(ch for ch in channels[c] if ch not in POSITION_CHANNELS)
    channels.insert(c, rotation or ("Zrotation", "Yrotation", "Xrotation"))
    ends = {renumber[j]: e for j, e in skeleton.end_sites.items()}
    names = list(skeleton.names)
    names.insert(c, name)
    return Skeleton(names, np.array(parents), np.array(offsets), channels, ends)


def longer_spine(skeleton: Skeleton) -> Skeleton:
    """Two joints more in the spine: halfway along the bones into its second and third joints (or into
    the neck: the chain from the first spine joint up to the neck or head)."""
    m = humanoid_map(skeleton)
    chain = [*m.spine, m.neck or m.head]
    for k, child in enumerate(((chain[1:] or chain[:1]) * 2)[:2]):
        skeleton = inserted(skeleton, child, f"SpineMid{k}")
    return skeleton


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
