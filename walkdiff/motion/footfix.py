"""Foot clean-up: feet on the ground (`ground`, vertical) and pinned while in contact (`fix_feet`, IK).

Grounding: a generated clip is shifted vertically so that its planted feet stand at the height real
planted feet have in the training data, by as much as it is further off than real clips are by the same
measure. A whole-body offset of a few centimetres is invisible in a clip but puts swinging feet under the
contact height, where they count as sliding; so does moving a clip that stood as a real one does.

For each foot (heel and toe joints of a `ContactSpec`), every run of frames in which the heel is in contact
gets one ground point, the mean horizontal position of the heel over that run; the same for the toe. In a
contact frame the ankle (the heel joint) is moved by the mean offset that puts its contacting joints on
their points, so the foot moves rigidly; heights are left alone (skating is horizontal sliding, and the
model's heights already touch the floor). Around each contact the offset fades out over `blend` frames,
so the leg does not snap when the foot lifts off.

The legs reach the moved ankle by analytic two-bone IK: the knee bends in its own bend plane to get the
hip-ankle distance right, then the hip swings the whole leg onto the target; the foot keeps its world
orientation, so the toe follows the ankle. Only hip, knee and ankle rotations of frames near a contact
change; the root and every other joint are untouched. A target out of reach gets a straight leg.
"""

from __future__ import annotations

import numpy as np
import torch

from walkdiff.motion.kinematics import forward_kinematics, motion_world_positions
from walkdiff.motion.profile import ContactSpec, SkeletonProfile
from walkdiff.motion.representation import FeatureLayout, decode, encode, features_to_positions
from walkdiff.motion.rotations import rotation_between
from walkdiff.motion.skeleton import Motion, Skeleton

# A leg is never stretched to exactly its full length: the knee angle would lose its direction.
MAX_REACH = 0.999
# A foot the clip puts down counts as planted below this many contact speeds: a stance foot that slips
# (generated slides run at 1-3 contact speeds over low runs of 12 frames, median), not a swing passing low.
SLIP_SPEEDS = 3.0


def contact_runs(contact: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of every run of True in a (F,) boolean array."""
    padded = np.concatenate([[False], contact.astype(bool), [False]])
    edges = np.flatnonzero(padded[1:] != padded[:-1])
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


def _pin_offsets(position: np.ndarray, contact: np.ndarray, held: np.ndarray | None = None) -> np.ndarray:
    """(F, 3) horizontal offsets moving a joint onto the mean of each of its contact runs (0 elsewhere);
    a run that reaches `held` frames (kept as given: an edit's) is pinned where the held frames have it."""
    offset = np.zeros_like(position)
    for start, stop in contact_runs(contact):
        run = slice(start, stop)
        if held is not None and held[run].any():
            run = np.flatnonzero(held[start:stop]) + start
        anchor = position[run][:, [0, 2]].mean(axis=0)
        offset[start:stop, [0, 2]] = anchor - position[start:stop, [0, 2]]
    return offset


def ankle_offsets(
    heel: np.ndarray, toe: np.ndarray, contacts: np.ndarray, blend: int, held: np.ndarray | None = None
) -> np.ndarray:
    """(F, 3) ankle offsets for one foot from heel and toe world positions (F, 3) and contacts (F, 2)."""
    heel_on, toe_on = contacts[:, 0] > 0.5, contacts[:, 1] > 0.5
    count = heel_on.astype(float) + toe_on
    total = _pin_offsets(heel, heel_on, held) + _pin_offsets(toe, toe_on, held)
    offset = total / np.maximum(count, 1)[:, None]
    active = count > 0
    if not active.any() or blend <= 0:
        return offset
    # Outside contact: the offset of the nearest contact frame, fading linearly to 0 over `blend` frames.
    frames = np.arange(len(offset))
    on = np.flatnonzero(active)
    nearest = on[np.clip(np.searchsorted(on, frames), 1, len(on) - 1) - 1]
    after = on[np.clip(np.searchsorted(on, frames), 0, len(on) - 1)]
    nearest = np.where(np.abs(after - frames) < np.abs(nearest - frames), after, nearest)
    weight = np.clip(1 - np.abs(nearest - frames) / (blend + 1), 0, 1)
    return np.where(active[:, None], offset, weight[:, None] * offset[nearest])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _turn_about(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(F, 3, 3) rotations by `angle` (F,) about unit axes (F, 3) (Rodrigues)."""
    k = np.zeros(axis.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -axis[..., 2], axis[..., 1], -axis[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def bend_leg(
    hip: np.ndarray, knee: np.ndarray, ankle: np.ndarray, hip_rot: np.ndarray, targets: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The world turns (F, 3, 3) to put on the hip and on the knee (left-multiplied on their world
    rotations) so that a leg of world joint positions (F, 3) reaches `targets` (F, 3): the knee bends in
    its own bend plane to get the hip-ankle distance right, then the hip swings the bent leg onto the
    target; a target out of reach gets a straight leg pointing at it. `hip_rot`: the hip's world
    rotations (F, 3, 3), for the bend axis of frames whose leg is straight."""
    a, b, c = hip, knee, ankle
    upper, lower = np.linalg.norm(b - a, axis=-1), np.linalg.norm(c - b, axis=-1)
    reach = np.clip(
        np.linalg.norm(targets - a, axis=-1), np.abs(upper - lower) + 1e-6, MAX_REACH * (upper + lower)
    )
    cos_now = np.sum((a - b) * (c - b), axis=-1) / (upper * lower)
    cos_new = (upper**2 + lower**2 - reach**2) / (2 * upper * lower)
    bend = np.arccos(np.clip(cos_new, -1, 1)) - np.arccos(np.clip(cos_now, -1, 1))
    normal = np.cross(a - b, c - b)
    size = np.linalg.norm(normal, axis=-1)
    # A straight leg has no bend plane: use the hip-frame axis of the frame bent the most.
    reference = int(size.argmax())
    fallback = hip_rot @ (hip_rot[reference].T @ _unit(normal[reference]))
    axis = _unit(np.where((size < 1e-6 * upper * lower)[:, None], fallback, normal))
    knee_turn = _turn_about(axis, bend)
    bent = b + np.einsum("fij,fj->fi", knee_turn, c - b)
    swing = rotation_between(bent - a, targets - a)
    return swing, swing @ knee_turn


def two_bone_ik(
    rotations: np.ndarray,
    positions: np.ndarray,
    parents: np.ndarray,
    ankle: int,
    targets: np.ndarray,
    frames: np.ndarray,
) -> np.ndarray:
    """Local rotations (F, J, 3, 3) with the leg ending at `ankle` bent to reach `targets` (F, 3)
    (`bend_leg`). The knee is the ankle's parent and the hip the knee's. Only `frames` (a boolean (F,)
    mask) change; the foot keeps its world orientation."""
    world, world_rot = forward_kinematics(
        torch.tensor(rotations), torch.tensor(positions), parents, return_rotations=True
    )
    return reach(
        rotations, world.double().numpy(), world_rot.double().numpy(), parents, ankle, targets, frames
    )


def reach(
    rotations: np.ndarray,
    world: np.ndarray,
    world_rot: np.ndarray,
    parents: np.ndarray,
    ankle: int,
    targets: np.ndarray,
    frames: np.ndarray,
) -> np.ndarray:
    """`two_bone_ik` given the pose's world positions (F, J, 3) and rotations (F, J, 3, 3) already."""
    knee = int(parents[ankle])
    hip = int(parents[knee])
    hip_turn, knee_turn = bend_leg(
        world[:, hip], world[:, knee], world[:, ankle], world_rot[:, hip], np.asarray(targets, np.float64)
    )
    hip_world, knee_world = hip_turn @ world_rot[:, hip], knee_turn @ world_rot[:, knee]
    out = np.array(rotations, copy=True)
    out[:, hip] = np.swapaxes(world_rot[:, int(parents[hip])], -1, -2) @ hip_world
    out[:, knee] = np.swapaxes(hip_world, -1, -2) @ knee_world
    out[:, ankle] = np.swapaxes(knee_world, -1, -2) @ world_rot[:, ankle]
    mask = np.asarray(frames, dtype=bool)[:, None, None, None]
    return np.where(mask, out, rotations).astype(np.asarray(rotations).dtype)


def fix_feet(
    motion: Motion, contacts: np.ndarray, spec: ContactSpec, blend: int = 3, held: np.ndarray | None = None
) -> Motion:
    """The clip with its feet pinned during contacts (F, 4), ordered as `spec.joints` (> 0.5: in contact).
    `held` (F,) bool: frames an edit keeps as given; a contact that reaches them is pinned where they put
    the foot, so the made frames join them without a slide."""
    skeleton = motion.skeleton
    contacts = np.asarray(contacts)
    if contacts.shape != (motion.num_frames, 4):
        raise ValueError(f"expected contacts ({motion.num_frames}, 4), got {contacts.shape}")
    world = forward_kinematics(
        torch.tensor(motion.rotations), torch.tensor(motion.positions), skeleton.parents
    ).numpy()
    rotations = motion.rotations
    joints = [skeleton.index(name) for name in spec.joints]
    for side, (heel, toe) in enumerate((joints[:2], joints[2:])):
        offset = ankle_offsets(
            world[:, heel], world[:, toe], contacts[:, 2 * side : 2 * side + 2], blend, held
        )
        moved = np.abs(offset).sum(-1) > 0
        if moved.any():
            # The legs do not share joints below the pelvis, so each sees the world positions of the input.
            rotations = two_bone_ik(
                rotations, motion.positions, skeleton.parents, heel, world[:, heel] + offset, moved
            )
    return Motion(skeleton, rotations, motion.positions, motion.frame_time)


def set_down(motion: Motion, labels: np.ndarray, spec: ContactSpec, heights: np.ndarray | None) -> np.ndarray:
    """The contacts (F, 4) to pin in a generated clip: where the model labels a foot planted (`labels`),
    and where the clip itself puts it down, within the contact height of where real planted feet stand
    (`heights`, `planted_heights`; NaN: never) and slower than SLIP_SPEEDS contact speeds. The model marks
    only a third of the steps where its feet slide by the geometric rule skating is judged by: the rest
    are stance feet it labels as swinging. `heights` None: the labels alone."""
    labels = np.asarray(labels, dtype=np.float64)
    if heights is None:
        return labels
    feet = motion_world_positions(motion)[:, [motion.skeleton.index(n) for n in spec.joints]]
    if len(feet) < 2:  # no step to measure a speed by
        return labels
    speed = np.linalg.norm(np.gradient(feet[..., [0, 2]], axis=0), axis=-1) * motion.fps
    with np.errstate(invalid="ignore"):  # a NaN height (a joint never planted) is never down
        down = (feet[..., 1] - np.asarray(heights) < spec.height_threshold) & (
            speed < SLIP_SPEEDS * spec.speed_threshold
        )
    return np.maximum(labels, down)


def fix_feet_features(
    raw: np.ndarray, profile: SkeletonProfile, fps: float, heights: np.ndarray | None = None
) -> np.ndarray:
    """`fix_feet` on feature windows (..., F, D) in data units, pinning `set_down`'s contacts: only the
    rotation channels of the joints and frames the IK moved change. The others keep their channels as
    sampled: encoding them again would orthonormalise their 6D rotations, the same pose but other
    numbers (the evaluator reads the numbers)."""
    raw = np.asarray(raw, dtype=np.float32)
    skeleton, spec = profile.canonical_skeleton, profile.contacts
    layout = FeatureLayout(skeleton.num_joints)
    out = raw.copy()
    for index in np.ndindex(raw.shape[:-2]):
        motion = decode(raw[index], skeleton, 1.0 / fps)
        fixed = fix_feet(motion, set_down(motion, raw[index][:, layout.contacts], spec, heights), spec)
        moved = np.abs(fixed.rotations - motion.rotations).max(axis=(-2, -1)) > 0  # (F, J)
        sixd = encode(fixed, profile)[:, layout.rotations].reshape(len(moved), -1, 6)
        window = out[index][:, layout.rotations].reshape(sixd.shape)
        window[moved] = sixd[moved]
        out[index][:, layout.rotations] = window.reshape(len(moved), -1)
    return out


# ---------------------------------------------------------------- grounding (vertical)


FK_FRAMES = 4096  # frames put through forward kinematics at a time: a long clip's FK in bounded memory


def _feet_heights(raw: torch.Tensor, skeleton: Skeleton, spec: ContactSpec) -> torch.Tensor:
    """World heights (..., F, 4) of the contact joints of raw features (..., F, D).

    Heights do not depend on where the root is or which way it heads (the root height is a channel of
    its own and heading turns about the vertical), so a long clip is taken FK_FRAMES frames at a time.
    """
    offsets = torch.from_numpy(skeleton.offsets).to(raw.dtype)
    feet = [skeleton.index(name) for name in spec.joints]
    return torch.cat(
        [
            features_to_positions(raw[..., start : start + FK_FRAMES, :], offsets, skeleton.parents)[
                ..., feet, 1
            ]
            for start in range(0, raw.shape[-2], FK_FRAMES)
        ],
        dim=-2,
    )


def planted_heights(clips: list[np.ndarray], skeleton: Skeleton, spec: ContactSpec) -> np.ndarray:
    """(4,) median height of each contact joint over the frames real clips label it planted.

    NaN for a joint the clips never plant (`ground` then leaves it out).
    """
    heights, planted = [], []
    layout = FeatureLayout(skeleton.num_joints)
    for raw in clips:
        raw = torch.from_numpy(np.asarray(raw, dtype=np.float64))
        heights.append(_feet_heights(raw, skeleton, spec))
        planted.append(raw[:, layout.contacts] > 0.5)
    heights, planted = torch.cat(heights), torch.cat(planted)
    return np.array(
        [float(heights[planted[:, j], j].median()) if planted[:, j].any() else np.nan for j in range(4)]
    )


def ground_shifts(raw: np.ndarray, skeleton: Skeleton, spec: ContactSpec, heights: np.ndarray) -> np.ndarray:
    """(...,) vertical shift per clip of raw features (..., F, D) that puts its planted feet where real
    ones stand: the median, over its planted frames and joints (the clip's own contact labels), of how
    far each planted joint is from that joint's planted height in the training data (`planted_heights`);
    0 for a clip with no planted frame."""
    raw = np.asarray(raw, dtype=np.float32)
    layout = FeatureLayout(skeleton.num_joints)
    feet = _feet_heights(torch.from_numpy(raw).double(), skeleton, spec).numpy()
    planted = raw[..., layout.contacts] > 0.5
    gap = np.where(planted, np.asarray(heights)[None] - feet, np.nan)  # (..., F, 4)
    flat = gap.reshape(*gap.shape[:-2], -1)
    has = np.isfinite(flat).any(-1)
    shift = np.zeros(flat.shape[:-1])
    shift[has] = np.nanmedian(flat[has], axis=-1)
    return shift


def ground_tolerance(
    clips: list[np.ndarray], skeleton: Skeleton, spec: ContactSpec, heights: np.ndarray, window: int
) -> float:
    """How far real clips' own planted feet stand from `heights` by `ground_shifts`' measure: the 95th
    percentile of its size over the real clips' windows (non-overlapping, `window` frames). A generated
    clip no further off than that stands as a real one does; shifting it anyway only adds the measure's
    noise (on the turns folder it put more swinging feet under the contact height)."""
    windows = [
        np.asarray(clip[start : start + window], dtype=np.float32)
        for clip in clips
        for start in range(0, len(clip) - window + 1, window)
    ]
    if not windows:
        return 0.0
    sizes = np.abs(ground_shifts(np.stack(windows), skeleton, spec, heights))
    return float(np.quantile(sizes, 0.95))


def ground(
    raw: np.ndarray, skeleton: Skeleton, spec: ContactSpec, heights: np.ndarray, tolerance: float = 0.0
) -> np.ndarray:
    """Raw features (..., F, D) lifted or lowered so their planted feet stand where real ones do.

    One vertical shift per clip (`ground_shifts`), less `tolerance` (`ground_tolerance`: a clip is moved
    only by how much further off it is than real clips are). Only the root height changes; a clip with no
    planted frame is left as it is.
    """
    raw = np.asarray(raw, dtype=np.float32)
    layout = FeatureLayout(skeleton.num_joints)
    shift = ground_shifts(raw, skeleton, spec, heights)
    shift = np.sign(shift) * np.maximum(np.abs(shift) - tolerance, 0.0)
    out = raw.copy()
    out[..., layout.root_height] += shift[..., None, None].astype(np.float32)
    return out
