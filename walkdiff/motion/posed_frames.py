"""The body measured as it moves: up axis, height and facing from posed frames, and whether a rest pose
is a pose at all.

A BVH rest pose (every rotation the identity) is whatever the exporter made it: a T or A pose stood
upright, but also legs laid along one horizontal axis or every bone on one line. Measured on such a
rest pose, the body height comes out up to twice what it is and the facing axis tens of degrees off.
The posed frames cannot lie that way: the head is above the feet, the feet touch a floor, the hips
turn right to left across the direction the body faces. So:

- up: the file axis from the feet to the head over the clip (not the root's motion: a root that
  carries the path on the floor lies below the feet);
- height: the head's top (its End Sites and end joints) above the floor under the feet, the median
  over the frames where both feet are down (one foot, when a clip never has both down);
- facing: up x (right - left) of the top of the legs (rigid with the hips), turned into the root's
  own frame: the local axis whose heading follows it, a pelvis pitching as it may;
- `rest_pose_problem`: what makes a rest pose no pose (legs not below the hips, the head not above
  them, the bones on one line), or None.

Arrays of world positions are file axes, (F, J, 3); `up` is a unit file axis.
"""

from __future__ import annotations

import re

import numpy as np
import torch

from walkdiff.motion.kinematics import forward_kinematics
from walkdiff.motion.skeleton import Motion, Skeleton

_HEAD = re.compile(r"head", re.IGNORECASE)
_NOT_HEAD = re.compile(r"(end|nub|site|top|tip|twist|jaw|eye)", re.IGNORECASE)

GROUND_SHARE = 0.05  # of the body height: a foot this close to the floor is down
MIN_GROUNDED = 3  # frames with both feet down needed to measure on them alone
LEGS_DOWN = 0.6  # of a leg's length: how far a standing leg reaches below the hips in a real pose
HEAD_UP = 0.5  # of the bones from the root to the head: how far above the root a standing head is
# Second over first singular value of the rest points: bones on one line below this (a body without
# arms stands at 0.12; bent rest poses are left to the legs' and head's tests).
FLAT = 0.02
FORWARD_DEGREES = 10.0  # median heading error of a local axis that is taken as the forward axis
FORWARD_LENGTH = 0.25  # the least a forward axis may lie along the floor on any frame (else near vertical)


def snap_axis(v: np.ndarray, degrees: float) -> tuple[np.ndarray, float]:
    """The signed unit axis nearest `v` if within `degrees`, else `v` normalised; and the angle to it."""
    v = v / max(np.linalg.norm(v), 1e-12)
    axis = np.zeros(3)
    i = int(np.argmax(np.abs(v)))
    axis[i] = np.sign(v[i])
    angle = float(np.degrees(np.arccos(np.clip(v @ axis, -1, 1))))
    return (axis if angle <= degrees else v), angle


def subtree(skeleton: Skeleton, joint: int) -> list[int]:
    """`joint` and every joint below it, in file order."""
    inside = {joint}
    for j in range(joint + 1, skeleton.num_joints):  # parents precede children
        if skeleton.parents[j] in inside:
            inside.add(j)
    return sorted(inside)


def ancestors(skeleton: Skeleton, joint: int) -> list[int]:
    """The joints above `joint`, from the top of the tree down."""
    out = []
    while skeleton.parents[joint] >= 0:
        joint = int(skeleton.parents[joint])
        out.append(joint)
    return out[::-1]


def depth(skeleton: Skeleton, joint: int) -> int:
    return len(ancestors(skeleton, joint))


def is_static(motion: Motion, joint: int, tolerance: float) -> bool:
    """Whether `joint`'s local transform stays the same over the clip."""
    rot = motion.rotations[:, joint]
    pos = motion.positions[:, joint]
    return bool(np.abs(rot - rot[:1]).max() < 1e-6 and np.abs(pos - pos[:1]).max() < tolerance)


def world_transforms(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """World positions (F, J, 3) and rotations (F, J, 3, 3) of every joint, file axes."""
    pos, rot = forward_kinematics(
        torch.tensor(motion.rotations), torch.tensor(motion.positions), motion.skeleton.parents, True
    )
    return pos.numpy(), rot.numpy()


def rest_points(skeleton: Skeleton) -> np.ndarray:
    """Rest-pose positions of every joint and End Site (identity rotations)."""
    j = skeleton.num_joints
    pos = forward_kinematics(
        torch.eye(3, dtype=torch.float64).expand(j, 3, 3), torch.tensor(skeleton.offsets), skeleton.parents
    ).numpy()
    ends = [pos[joint] + offset for joint, offset in skeleton.end_sites.items()]
    return np.concatenate([pos, np.reshape(ends, (-1, 3))])


CONTACT_SHARE = 0.1  # of the body's extent: how far short of its farthest point a floor contact may end


def floor_contacts(pose: np.ndarray, top: int, ends: list[int]) -> int:
    """How many joints touch the floor the chains from `top` to `ends` would stand on, counting `ends`;
    0 when `ends` are not (within CONTACT_SHARE of the body's extent) its farthest points the way from
    `top` to them. Legs stand on a floor the other feet touch too; eye stalks, claws or antennae end short
    of other parts or alone. `pose`: world positions (J, 3)."""
    down = pose[ends].mean(axis=0) - pose[top]
    if np.linalg.norm(down) < 1e-12:
        return 0
    along = (pose - pose[top]) @ (down / np.linalg.norm(down))
    floor = float(along.max()) - CONTACT_SHARE * float(np.ptp(pose, axis=0).max())
    return int((along >= floor).sum()) if float(along[ends].min()) >= floor else 0


def _bone_length(skeleton: Skeleton, top: int, joint: int) -> float:
    """Length along the bones from `top` down to `joint` (a joint below it)."""
    length = 0.0
    while joint != top and joint >= 0:
        length += float(np.linalg.norm(skeleton.offsets[joint]))
        joint = int(skeleton.parents[joint])
    return length


# ---------------------------------------------------------------- the head and the points of a part


def find_head(skeleton: Skeleton, root: int, pairs, feet_joints: list[int]) -> int | None:
    """The head: the shallowest body joint named like one (not its End/Top helper), else the centre leaf
    farthest from the root along the bones outside the legs; None for a body without such a leaf."""
    body = subtree(skeleton, root)
    named = [
        j for j in body if _HEAD.search(skeleton.names[j]) and not _NOT_HEAD.search(skeleton.names[j])
    ]  # fmt: skip
    if named:
        return min(named, key=lambda j: (len(ancestors(skeleton, j)), j))
    sided = {j for pair in pairs for j in pair}
    legs = {a for f in feet_joints for a in [f, *ancestors(skeleton, f)] if a in body and a != root}
    leaves = [
        j for j in body[1:]
        if not skeleton.children(j) and j not in sided and not legs & {j, *ancestors(skeleton, j)}
    ]  # fmt: skip
    if not leaves:
        return None
    return max(leaves, key=lambda j: _bone_length(skeleton, root, j))


def part_points(world: np.ndarray, world_rot: np.ndarray, skeleton: Skeleton, joints) -> np.ndarray:
    """(F, n, 3) world positions of `joints`, every joint below them and their End Sites."""
    inside = sorted({j for top in joints for j in subtree(skeleton, top)})
    ends = [j for j in inside if j in skeleton.end_sites]
    points = [world[:, inside]]
    if ends:
        offsets = np.stack([skeleton.end_sites[j] for j in ends])  # (E, 3)
        points.append(world[:, ends] + np.einsum("feij,ej->fei", world_rot[:, ends], offsets))
    return np.concatenate(points, axis=1)


# ---------------------------------------------------------------- up, height and facing


def posed_up(world: np.ndarray, top: int, feet_joints: list[int]) -> tuple[np.ndarray, float, float]:
    """The file axis from the feet to `top` (the head, else the root) over the clip; how many degrees the
    mean direction is off it; the share of frames whose own direction is within 60 degrees of it."""
    rise = world[:, top] - world[:, feet_joints].mean(axis=1)
    unit = rise / np.maximum(np.linalg.norm(rise, axis=1, keepdims=True), 1e-12)
    axis, angle = snap_axis(unit.mean(axis=0), 90.0)
    return axis, angle, float(np.mean(unit @ axis > 0.5))


def posed_height(head: np.ndarray, left: np.ndarray, right: np.ndarray, up: np.ndarray) -> tuple[float, str]:
    """The body's height on posed frames, and how it was measured.

    `head`, `left`, `right`: (F, n, 3) points of the head part and of each foot (joints and End Sites).
    The floor is the 5th percentile of the lowest foot point; the height the median, over frames with
    both feet down (within GROUND_SHARE of a first estimate of the floor), of the head's top above it.
    """
    top = (head @ up).max(axis=1)
    low_left, low_right = (left @ up).min(axis=1), (right @ up).min(axis=1)
    floor = float(np.percentile(np.minimum(low_left, low_right), 5))
    rough = max(float(np.median(top)) - floor, 1e-12)
    near = GROUND_SHARE * rough
    both = (low_left - floor < near) & (low_right - floor < near)
    either = (low_left - floor < near) | (low_right - floor < near)
    if both.sum() >= MIN_GROUNDED:
        frames, how = both, "both feet down"
    elif either.sum() >= MIN_GROUNDED:
        frames, how = either, "one foot down"
    else:
        frames, how = np.ones_like(both), "any"
    height = float(np.median(top[frames])) - floor
    return height, f"posed frames: head top above the floor, median of {int(frames.sum())} frames ({how})"


def body_height_on_frames(
    world: np.ndarray, world_rot: np.ndarray, skeleton: Skeleton, head: int, heels: list[int], up: np.ndarray
) -> tuple[float, str]:
    """`posed_height` of the head part and the two feet (each heel with the joints and End Sites below)."""
    parts = [part_points(world, world_rot, skeleton, [j]) for j in (head, *heels)]
    return posed_height(*parts, up)


def posed_forward(
    world: np.ndarray,
    world_rot: np.ndarray,
    skeleton: Skeleton,
    root: int,
    pairs,
    heels: list[int],
    up: np.ndarray,
    head: int | None = None,
) -> tuple[np.ndarray, float] | None:
    """The root's local axis (file axes) the body faces over the clip, and its median heading error in
    degrees; None when it cannot be told.

    Per frame the body faces up x (right - left), right and left the top of the legs (the first
    left/right pair along the leg chains that stands apart: rigid with the hips), else the mean of
    every pair. Only the heading (the axis turned into the world and laid on the floor) matters, and a
    pelvis pitches a lot (up to 60 degrees on Xia's clips), most in a crouch: so it is measured on the
    quarter of the frames where the trunk (root to `head`) stands most upright, and the axis is the
    signed local axis nearest the mean local facing whose heading is within FORWARD_DEGREES of the
    facing on the median frame and which stays FORWARD_LENGTH along the floor on every frame; else the
    mean local facing itself. (On Xia with its rest pose hidden: +z on all 277 walks; the pelvis's +y
    on 10 of 572 clips, jumps of a hunched walker, whose heading it follows within 4 degrees.)
    """
    if not pairs:
        return None
    chains = [{h, *ancestors(skeleton, h)} for h in heels]
    legs = sorted(
        (p for p in pairs if len(chains) == 2 and p[0] in chains[0] and p[1] in chains[1]),
        key=lambda p: len(ancestors(skeleton, p[0])),
    )
    apart = [p for p in legs if np.linalg.norm(world[:, p[1]] - world[:, p[0]], axis=1).min() > 1e-9]
    chosen = apart[:1] or list(pairs)
    lateral = np.mean([world[:, b] - world[:, a] for a, b in chosen], axis=0)  # (F, 3)
    facing = _on_floor(np.cross(up, lateral), up)
    keep = np.linalg.norm(facing, axis=1) > 0.5
    if head is not None:  # measured where the trunk stands most upright: a crouch pitches the pelvis far
        spine = world[:, head] - world[:, root]
        lean = spine @ up / np.maximum(np.linalg.norm(spine, axis=1), 1e-12)
        keep &= lean >= np.percentile(lean[keep], 75) if keep.any() else keep
    if not keep.any():
        return None
    rot, facing = world_rot[keep, root], facing[keep]
    mean = np.einsum("fji,fj->fi", rot, facing).mean(axis=0)
    if np.linalg.norm(mean) < 0.3:
        return None
    for i in np.argsort(-np.abs(mean)):
        axis = np.zeros(3)
        axis[i] = np.sign(mean[i])
        heading = _on_floor(rot @ axis, up, normalise=False)
        length = np.linalg.norm(heading, axis=1)
        cosine = np.sum(heading * facing, axis=1) / np.maximum(length, 1e-12)
        error = np.degrees(np.arccos(np.clip(cosine, -1, 1)))
        if length.min() > FORWARD_LENGTH and np.median(error) <= FORWARD_DEGREES:
            return axis, float(np.median(error))
    mean = mean / np.linalg.norm(mean)
    error = np.degrees(np.arccos(np.clip(np.sum(_on_floor(rot @ mean, up) * facing, axis=1), -1, 1)))
    return mean, float(np.median(error))


def _on_floor(v: np.ndarray, up: np.ndarray, normalise: bool = True) -> np.ndarray:
    """(F, 3) vectors with their `up` component taken out, made unit length (zero stays zero) unless not."""
    flat = v - np.outer(v @ up, up)
    if not normalise:
        return flat
    norms = np.linalg.norm(flat, axis=1, keepdims=True)
    return np.where(norms > 1e-12, flat / np.maximum(norms, 1e-12), 0.0)


def walking_forward(world: np.ndarray, world_rot: np.ndarray, root: int, up: np.ndarray) -> np.ndarray | None:
    """The root's local axis (file axes) along which it walks, averaged over the clip; None if it stays."""
    step = np.diff(world[:, root], axis=0, append=world[-1:, root])
    step -= np.outer(step @ up, up)
    norms = np.linalg.norm(step, axis=1)
    keep = norms > 1e-9
    if not keep.any():
        return None
    return np.einsum("fji,fj->fi", world_rot[keep, root], step[keep] / norms[keep, None]).mean(axis=0)


def rest_forward(rest: np.ndarray, root: int, heels: list[int], pairs) -> np.ndarray | None:
    """The root's local axis (file axes) the rest pose faces: up (heels to root) x (right - left). Rest
    positions relative to the root are in the root's own frame (every rotation is the identity)."""
    if not pairs or not heels:
        return None
    up = rest[root] - rest[heels].mean(axis=0)
    facing = np.cross(up, np.mean([rest[b] - rest[a] for a, b in pairs], axis=0))
    return facing if np.linalg.norm(facing) > 1e-9 else None


def rest_height(rest: np.ndarray, skeleton: Skeleton, root: int, feet_joints: list[int]) -> float:
    """Extent of the rest pose (joints and End Sites) along the feet-to-root direction: the body's
    height whatever way the rest pose is turned, T or A pose alike. Without feet: its largest extent."""
    points = rest[: skeleton.num_joints]
    up = points[root] - points[feet_joints].mean(axis=0) if feet_joints else np.zeros(3)
    if np.linalg.norm(up) < 1e-9:
        return float(np.ptp(rest, axis=0).max())
    return float(np.ptp(rest @ (up / np.linalg.norm(up))))


# ---------------------------------------------------------------- is the rest pose a pose


def rest_pose_problem(
    rest: np.ndarray,
    skeleton: Skeleton,
    root: int,
    heels: list[int],
    head: int | None,
) -> str | None:
    """Why the rest pose (`rest`: joints then End Sites, identity rotations) is no pose to measure the
    body on, or None when it stands: the bones not on one line, legs reaching down from the hips, the
    head above them. (Its height is not compared with the posed body's: a clip may crouch throughout.)"""
    points = rest[: skeleton.num_joints]
    centred = rest - rest.mean(axis=0)
    singular = np.linalg.svd(centred, compute_uv=False)
    if singular[0] > 0 and singular[1] < FLAT * singular[0]:
        direction = np.linalg.svd(centred, full_matrices=False)[2][0]
        return f"its bones lie on one line (along {_direction_name(direction)})"
    top = head if head is not None else root
    up = points[top] - points[heels].mean(axis=0)
    if np.linalg.norm(up) < 1e-12:
        return "its head is level with its feet"
    up = up / np.linalg.norm(up)
    for heel in heels:
        leg = _bone_length(skeleton, root, heel)
        drop = float((points[root] - points[heel]) @ up)
        if leg > 0 and drop < LEGS_DOWN * leg:
            along = _direction_name(points[heel] - points[root])
            return (
                f"its legs do not reach down from the hips ({skeleton.names[heel]} "
                f"{drop / leg:.0%} of the leg below them; the leg points {along})"
            )
    if head is not None:
        neck = _bone_length(skeleton, root, head)
        if neck > 0 and float((points[head] - points[root]) @ up) < HEAD_UP * neck:
            return f"its head {skeleton.names[head]} is not above the hips"
    return None


def _direction_name(v: np.ndarray) -> str:
    """'+x' for the axis a direction lies along (within 20 degrees), else its components."""
    axis, angle = snap_axis(np.asarray(v, dtype=np.float64), 20.0)
    if angle <= 20.0:
        i = int(np.argmax(np.abs(axis)))
        return ("+" if axis[i] > 0 else "-") + "xyz"[i]
    return "(" + ", ".join(f"{x:.2f}" for x in axis) + ")"
