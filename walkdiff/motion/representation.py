"""Motion <-> per-frame feature vectors, and the per-channel normaliser that models train on.

Features are made from canonical clips (`walkdiff.motion.profile`: the body below the root joint, Y up,
the ground the XZ plane, in the file's units), so every skeleton, axis convention and root layout
gives the same kind of vector. One frame is D = 4 + 6J + 4 numbers:

    root_vel     (2)   root displacement to the next frame, x and z in the heading frame of this frame
    root_height  (1)   root y
    heading_vel  (1)   heading change to the next frame, wrapped to (-pi, pi]
    rotations    (6J)  6D local rotation of every joint (first two matrix columns); the root's is taken
                       relative to its heading, so the features do not depend on where the clip faces
    contacts     (4)   left heel, left toe, right heel, right toe in {0, 1}

The heading is the yaw of the root: its forward axis (a local axis found by the skeleton profile, +Z
for the CMU skeleton of Xia) turned into the world and projected on the ground. Velocities are forward
differences, so the last frame has no next frame: it repeats the previous frame's values (zeros for a
one-frame clip), and decoding never reads them. Features are computed in float64 and returned as float32.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import roma
import torch
from torch import nn

from walkdiff.motion.kinematics import forward_kinematics, motion_world_positions
from walkdiff.motion.profile import ContactSpec, SkeletonProfile
from walkdiff.motion.rotations import matrix_to_6d, sixd_to_matrix
from walkdiff.motion.skeleton import Motion, Skeleton


@dataclass(frozen=True)
class FeatureLayout:
    """Where each block of a feature vector lies, from the joint count alone."""

    num_joints: int

    root_vel = slice(0, 2)
    root_height = slice(2, 3)
    heading_vel = slice(3, 4)

    @property
    def rotations(self) -> slice:
        return slice(4, 4 + 6 * self.num_joints)

    @property
    def contacts(self) -> slice:
        return slice(4 + 6 * self.num_joints, 8 + 6 * self.num_joints)

    @property
    def dim(self) -> int:
        return 8 + 6 * self.num_joints

    @classmethod
    def from_dim(cls, dim: int) -> FeatureLayout:
        if dim < 14 or (dim - 8) % 6:
            raise ValueError(f"a feature dimension is 8 + 6 * joints, got {dim}")
        return cls((dim - 8) // 6)


def yaw_matrix(heading: torch.Tensor) -> torch.Tensor:
    """(...,) angles -> (..., 3, 3) rotations about +Y; yaw_matrix(h) turns +Z to (sin h, 0, cos h)."""
    return roma.rotvec_to_rotmat(heading.unsqueeze(-1) * heading.new_tensor([0.0, 1.0, 0.0]))


def root_heading(root_rotations: torch.Tensor, forward: Sequence[float]) -> torch.Tensor:
    """(..., 3, 3) root world rotations -> (...,) heading angles (yaw of the forward axis)."""
    direction = root_rotations @ root_rotations.new_tensor(forward)
    return torch.atan2(direction[..., 0], direction[..., 2])


def start_pose(motion: Motion, profile: SkeletonProfile) -> tuple[np.ndarray, float]:
    """Root (x, z) and heading at frame 0 of a canonical clip: pass them to `decode` to put a decoded
    clip back in place."""
    heading = root_heading(torch.tensor(motion.rotations[0, 0]), profile.forward)
    return motion.root_positions[0, [0, 2]].copy(), float(heading)


def _wrap(angle: torch.Tensor) -> torch.Tensor:
    """Angles to (-pi, pi]."""
    return torch.pi - torch.remainder(torch.pi - angle, 2 * torch.pi)


def _per_step(values: torch.Tensor) -> torch.Tensor:
    """Values of frames 0..F-2 (one per step to the next frame) -> F frames, the last one repeated."""
    if values.shape[0] == 0:
        return torch.zeros(1, *values.shape[1:], dtype=values.dtype)
    return torch.cat([values, values[-1:]])


def contact_state(feet: np.ndarray, fps: float, spec: ContactSpec) -> tuple[np.ndarray, np.ndarray]:
    """World positions (F, n, 3) of contact joints -> (low, slow) booleans (F, n): within the contact
    height of the joint's own floor, and slower than the contact speed. In contact: both."""
    feet = torch.as_tensor(feet, dtype=torch.float64)
    speed = _per_step(torch.linalg.norm(feet[1:] - feet[:-1], dim=-1)) * fps
    height = feet[..., 1] - torch.quantile(feet[..., 1], spec.floor_percentile / 100, dim=0)
    return (height < spec.height_threshold).numpy(), (speed < spec.speed_threshold).numpy()


def foot_contacts(motion: Motion, spec: ContactSpec) -> np.ndarray:
    """(F, 4) float {0, 1}: left heel, left toe, right heel, right toe (see `ContactSpec`)."""
    joints = [motion.skeleton.index(name) for name in spec.joints]
    low, slow = contact_state(motion_world_positions(motion)[:, joints], motion.fps, spec)
    return (low & slow).astype(np.float64)


def encode(motion: Motion, profile: SkeletonProfile) -> np.ndarray:
    """(F, 8 + 6J) float32 features of a canonical clip (`SkeletonProfile.to_canonical`)."""
    rotations = torch.tensor(motion.rotations)
    root = torch.tensor(motion.root_positions)
    heading = root_heading(rotations[:, 0], profile.forward)
    to_heading = yaw_matrix(heading).transpose(-1, -2)

    local = rotations.clone()
    local[:, 0] = to_heading @ rotations[:, 0]
    step = _per_step((to_heading[:-1] @ (root[1:] - root[:-1]).unsqueeze(-1)).squeeze(-1))
    heading_vel = _per_step(_wrap(heading[1:] - heading[:-1]))
    contacts = torch.from_numpy(foot_contacts(motion, profile.contacts))

    features = torch.cat(
        [
            step[:, [0, 2]],
            root[:, 1:2],
            heading_vel[:, None],
            matrix_to_6d(local).reshape(motion.num_frames, -1),
            contacts,
        ],
        dim=-1,
    )
    return features.numpy().astype(np.float32)


def root_trajectory(
    features: torch.Tensor,
    start_position: Sequence[float] | torch.Tensor | None = None,
    start_heading: float | torch.Tensor = 0.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Headings (..., F) and root positions (..., F, 3) by summing the per-frame changes; differentiable."""
    layout = FeatureLayout.from_dim(features.shape[-1])
    zero = torch.zeros_like(features[..., :1, 0])
    start_heading = torch.as_tensor(start_heading, dtype=features.dtype, device=features.device)
    turns = torch.cumsum(features[..., :-1, layout.heading_vel.start], dim=-1)
    heading = start_heading.unsqueeze(-1) + torch.cat([zero, turns], dim=-1)

    vel = features[..., layout.root_vel]
    local_step = torch.stack([vel[..., 0], torch.zeros_like(vel[..., 0]), vel[..., 1]], dim=-1)
    world_step = (yaw_matrix(heading) @ local_step.unsqueeze(-1)).squeeze(-1)
    travelled = torch.cumsum(world_step[..., :-1, :], dim=-2)
    xz = torch.cat([torch.zeros_like(world_step[..., :1, :]), travelled], dim=-2)[..., [0, 2]]
    if start_position is not None:
        xz = xz + torch.as_tensor(start_position, dtype=features.dtype, device=features.device).unsqueeze(-2)
    height = features[..., layout.root_height]
    return heading, torch.stack([xz[..., 0], height[..., 0], xz[..., 1]], dim=-1)


def decode_root(
    features: torch.Tensor,
    start_position: Sequence[float] | torch.Tensor | None = None,
    start_heading: float | torch.Tensor = 0.0,
) -> torch.Tensor:
    """Root world positions (..., F, 3) from features (..., F, D); differentiable.

    The root starts at `start_position` (x, z), by default the origin, facing `start_heading`.
    """
    return root_trajectory(features, start_position, start_heading)[1]


def _local_rotations(features: torch.Tensor, heading: torch.Tensor) -> torch.Tensor:
    """(..., F, J, 3, 3) local rotations with the root put back on its heading."""
    layout = FeatureLayout.from_dim(features.shape[-1])
    sixd = features[..., layout.rotations].unflatten(-1, (layout.num_joints, 6))
    rotations = sixd_to_matrix(sixd)
    root = yaw_matrix(heading) @ rotations[..., 0, :, :]
    return torch.cat([root.unsqueeze(-3), rotations[..., 1:, :, :]], dim=-3)


def features_to_positions(
    features: torch.Tensor,
    skeleton_offsets: torch.Tensor,
    parents: Sequence[int] | np.ndarray,
    start_position: Sequence[float] | torch.Tensor | None = None,
    start_heading: float | torch.Tensor = 0.0,
) -> torch.Tensor:
    """World joint positions (..., F, J, 3) from features (..., F, D) and offsets (J, 3); differentiable."""
    heading, root = root_trajectory(features, start_position, start_heading)
    rotations = _local_rotations(features, heading)
    offsets = skeleton_offsets.to(features.dtype).expand(*root.shape[:-1], -1, 3)
    positions = torch.cat([root.unsqueeze(-2), offsets[..., 1:, :]], dim=-2)
    return forward_kinematics(rotations, positions, parents)


DECODE_FRAMES = 4096


def decode(
    features: np.ndarray,
    skeleton: Skeleton,
    frame_time: float,
    start_position: Sequence[float] | None = None,
    start_heading: float = 0.0,
) -> Motion:
    """A clip on `skeleton` from (F, D) features (contacts are not used).

    Joints other than the root get their bone offsets: translation channels of non-root joints are
    not part of the features.
    """
    x = torch.tensor(np.asarray(features), dtype=torch.float64)
    if x.ndim != 2 or x.shape[1] != FeatureLayout(skeleton.num_joints).dim:
        raise ValueError(
            f"expected features (frames, {FeatureLayout(skeleton.num_joints).dim}) for "
            f"{skeleton.num_joints} joints, got {tuple(x.shape)}"
        )
    heading, root = root_trajectory(x, start_position, start_heading)
    positions = np.repeat(skeleton.offsets[None], x.shape[0], axis=0)
    positions[:, 0] = root.numpy()
    # Rotations are per frame: made DECODE_FRAMES at a time, a long clip's temporaries stay small.
    rotations = np.empty((x.shape[0], skeleton.num_joints, 3, 3))
    for start in range(0, x.shape[0], DECODE_FRAMES):
        stop = start + DECODE_FRAMES
        rotations[start:stop] = _local_rotations(x[start:stop], heading[start:stop]).numpy()
    return Motion(skeleton, rotations, positions, frame_time)


class Normalizer(nn.Module):
    """Per-channel standardisation with statistics of the training split, saved with the model.

    Every channel is standardised, contacts included: the diffusion noise is N(0, I) on every channel,
    so all channels should share its scale, and losses on contacts are taken after `denormalize`.
    A channel whose std is below `eps` (e.g. a joint that never rotates) is only centred: dividing by
    a tiny std would blow a model's small errors up on the way back.
    """

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, dim: int):
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("std", torch.ones(dim))

    @classmethod
    def fit(cls, features: np.ndarray | Sequence[np.ndarray], eps: float = 1e-4) -> Normalizer:
        """Statistics over all frames of (F, D) arrays (or one array)."""
        if isinstance(features, np.ndarray):
            frames = features.reshape(-1, features.shape[-1]).astype(np.float64)
        else:
            frames = np.concatenate([np.asarray(f, dtype=np.float64) for f in features], axis=0)
        normalizer = cls(frames.shape[-1])
        std = frames.std(axis=0)
        normalizer.mean.copy_(torch.from_numpy(frames.mean(axis=0)))
        normalizer.std.copy_(torch.from_numpy(np.where(std < eps, 1.0, std)))
        return normalizer

    def normalize(self, x: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
        if isinstance(x, torch.Tensor):
            return (x - self.mean.to(x)) / self.std.to(x)
        return ((x - self.mean.cpu().numpy()) / self.std.cpu().numpy()).astype(np.float32)

    def denormalize(self, x: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
        if isinstance(x, torch.Tensor):
            return x * self.std.to(x) + self.mean.to(x)
        return (x * self.std.cpu().numpy() + self.mean.cpu().numpy()).astype(np.float32)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.normalize(x)
