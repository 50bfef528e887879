"""The SMPL body's 24-joint tree, and walkdiff `Skeleton`s on it with bone offsets measured from data.

SMPL numbers its joints breadth-first-ish (pelvis, left_hip, right_hip, spine1, ...); walkdiff stores
joints depth-first, the order a BVH file lists them (see walkdiff/motion/skeleton.py), so that a clip
written to BVH and read back keeps its joint order. `BVH_ORDER[k]` is the SMPL index of walkdiff joint k.

SMPL's rest pose is Y-up and faces +Z, left is +X: the root's forward axis is +Z, as for Xia's CMU
skeleton, so the feature representation needs no other setting.
"""

from __future__ import annotations

import numpy as np
import torch

from walkdiff.motion.kinematics import forward_kinematics
from walkdiff.motion.skeleton import Skeleton

SMPL_NAMES = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_hand", "right_hand",
)  # fmt: skip
SMPL_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)
NUM_JOINTS = len(SMPL_NAMES)

ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
JOINT_CHANNELS = ("Zrotation", "Yrotation", "Xrotation")
# A leaf's End Site continues its incoming bone by this fraction: BVH viewers only draw a leaf's own
# bone when it has an End Site, and SMPL has no joint beyond the head, hands and feet.
END_SITE_FRACTION = 0.5


def _depth_first(parents: tuple[int, ...]) -> tuple[int, ...]:
    order: list[int] = []

    def visit(joint: int) -> None:
        order.append(joint)
        for child in (j for j, p in enumerate(parents) if p == joint):
            visit(child)

    visit(0)
    return tuple(order)


BVH_ORDER = _depth_first(SMPL_PARENTS)
_POSITION_IN_BVH = {smpl: k for k, smpl in enumerate(BVH_ORDER)}
NAMES = [SMPL_NAMES[j] for j in BVH_ORDER]
PARENTS = np.array([-1] + [_POSITION_IN_BVH[SMPL_PARENTS[j]] for j in BVH_ORDER[1:]])


def to_bvh_order(smpl_array: np.ndarray, axis: int = 0) -> np.ndarray:
    """An array indexed by SMPL joint along `axis`, re-indexed in walkdiff's (depth-first) joint order."""
    return np.take(smpl_array, BVH_ORDER, axis=axis)


def smpl_skeleton(offsets: np.ndarray) -> Skeleton:
    """A walkdiff skeleton from (24, 3) bone offsets in SMPL joint order (the root's is ignored)."""
    offsets = to_bvh_order(np.asarray(offsets, dtype=np.float64)).copy()
    offsets[0] = 0.0  # the root's translation is its per-frame position
    leaves = [j for j in range(NUM_JOINTS) if j not in PARENTS]
    return Skeleton(
        names=list(NAMES),
        parents=PARENTS.copy(),
        offsets=offsets,
        channels=[ROOT_CHANNELS] + [JOINT_CHANNELS] * (NUM_JOINTS - 1),
        end_sites={j: END_SITE_FRACTION * offsets[j] for j in leaves},
    )


def rest_offsets(local_rotations: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bone offsets (24, 3) that explain world joint positions under given local rotations, SMPL order.

    With R_p(t) the world rotation of joint j's parent at frame t, FK puts j at
    p_j(t) = p_p(t) + R_p(t) offset_j, so every frame gives offset_j = R_p(t)^T (p_j(t) - p_p(t)).
    The offsets are the mean of these over the frames (least squares, since R_p is orthogonal); the
    second result is the largest distance (per frame and joint) between `joints` and the FK positions
    with those offsets: 0 up to rounding when the joints were made by SMPL from these rotations.

    Args:
        local_rotations: (F, 24, 3, 3) local rotations (SMPL order), the root's in world axes.
        joints: (F, 24, 3) world joint positions, SMPL order.
    """
    rotations = torch.as_tensor(local_rotations, dtype=torch.float64)
    positions = torch.as_tensor(joints, dtype=torch.float64)
    _, world = forward_kinematics(rotations, torch.zeros_like(positions), SMPL_PARENTS, return_rotations=True)
    parents = list(SMPL_PARENTS[1:])
    bones = positions[:, 1:] - positions[:, parents]
    local_bones = (world[:, parents].transpose(-1, -2) @ bones.unsqueeze(-1)).squeeze(-1)
    offsets = torch.cat([torch.zeros(1, 3, dtype=torch.float64), local_bones.mean(dim=0)])
    translations = offsets.expand_as(positions).clone()
    translations[:, 0] = positions[:, 0]
    fk_positions = forward_kinematics(rotations, translations, SMPL_PARENTS)
    residual = torch.linalg.norm(fk_positions - positions, dim=-1).max()
    return offsets.numpy(), float(residual)
