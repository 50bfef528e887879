"""Convention-free motion features: what the evaluators read, computed from world joint positions only.

Two BVH files whose joints pass through the same world positions get the same features, whatever their
rotation convention (twists, Euler orders, rest poses), root layout or channel order. Per frame, with
J the body's joints, D = 6J + 1 numbers, lengths in body heights and rates per second:

    positions   (3J)  every joint relative to the root's ground point, in the heading frame
    velocities  (3J)  every joint's world velocity (the root's planar velocity included), in the
                      heading frame of the frame
    turning     (1)   heading rate (rad/s)

The heading is found from the body, not from a joint's rotation: the horizontal direction at right angles
to the line from the left to the right joints of the body's mirrored chains (hips and shoulders), as the
rest of the field does for positional representations. Rates are forward differences times the frame
rate (the last frame repeats the one before), so clips at any frame rate, resampled to the evaluator's,
give features on one scale.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.kinematics import forward_kinematics
from walkdiff.motion.profile import SkeletonProfile

# A left/right pair marks the heading only when its joints stand this far apart (body heights) at
# rest: CMU's hip joints sit on the root itself, their children are the first usable pair.
MIN_PAIR_SEPARATION = 0.05


@dataclass(frozen=True)
class BodyFrame:
    """What the features need of a skeleton: joint names, the root, the heading pairs, the body height."""

    names: tuple[str, ...]
    root: int
    left: tuple[int, ...]
    right: tuple[int, ...]
    height: float  # units of the positions given to `features`

    @classmethod
    def of(cls, profile: SkeletonProfile) -> BodyFrame:
        """The frame of a profile's canonical skeleton (root first, Y up, file units)."""
        skeleton = profile.canonical_skeleton
        names = list(skeleton.names)
        rest = forward_kinematics(
            torch.eye(3, dtype=torch.float64).expand(len(names), 3, 3),
            torch.tensor(skeleton.offsets),
            skeleton.parents,
        ).numpy()

        def ancestors(j: int) -> set[int]:
            out = set()
            while skeleton.parents[j] >= 0:
                j = int(skeleton.parents[j])
                out.add(j)
            return out

        pairs = sorted(
            ((names.index(a), names.index(b)) for a, b in profile.body_pairs),
            key=lambda p: (len(ancestors(p[0])), p),
        )
        left, right, taken = [], [], set()
        for a, b in pairs:
            apart = np.linalg.norm(rest[a] - rest[b]) >= MIN_PAIR_SEPARATION * profile.body_height
            if apart and not (ancestors(a) | ancestors(b)) & taken:
                left.append(a)
                right.append(b)
                taken |= {a, b}
        if not left:
            raise WalkdiffError(
                "skeleton profile: no left/right joint pairs to find the body's heading from; name them "
                "with the profile's mirror_pairs (e.g. [[LeftUpLeg, RightUpLeg], [LeftArm, RightArm]])"
            )
        return cls(tuple(names), 0, tuple(left), tuple(right), float(profile.body_height))

    @property
    def dim(self) -> int:
        return 6 * len(self.names) + 1

    def heading(self, positions: torch.Tensor) -> torch.Tensor:
        """(..., J, 3) positions -> (...,) yaw angles; 0 faces +Z, as `representation.yaw_matrix`."""
        across = (positions[..., self.right, :] - positions[..., self.left, :]).sum(dim=-2)
        # forward = up x (right - left), with up = +Y: (z, 0, -x)
        return torch.atan2(across[..., 2], -across[..., 0])

    def features(self, positions: torch.Tensor, fps: float) -> torch.Tensor:
        """World positions (..., F, J, 3) in canonical axes (Y up) -> features (..., F, 6J + 1)."""
        if positions.shape[-2:] != (len(self.names), 3) or positions.shape[-3] < 1:
            raise WalkdiffError(
                f"body features expect positions (..., frames, {len(self.names)}, 3), "
                f"got {tuple(positions.shape)}"
            )
        heading = self.heading(positions)
        cos, sin = torch.cos(heading)[..., None], torch.sin(heading)[..., None]

        def to_heading(v: torch.Tensor) -> torch.Tensor:  # the inverse yaw, on (..., F, J, 3)
            x, y, z = v.unbind(-1)
            return torch.stack([cos * x - sin * z, y, sin * x + cos * z], dim=-1)

        ground = positions[..., self.root : self.root + 1, :] * positions.new_tensor([1.0, 0.0, 1.0])
        local = to_heading(positions - ground)
        step = _per_step(positions[..., 1:, :, :] - positions[..., :-1, :, :], axis=-3)
        velocity = to_heading(step) * fps
        turn = _per_step(_wrap(heading[..., 1:] - heading[..., :-1]), axis=-1) * fps
        flat = torch.cat([local.flatten(-2), velocity.flatten(-2)], dim=-1) / self.height
        return torch.cat([flat, turn.unsqueeze(-1)], dim=-1)


def _wrap(angle: torch.Tensor) -> torch.Tensor:
    return torch.pi - torch.remainder(torch.pi - angle, 2 * torch.pi)


def _per_step(values: torch.Tensor, axis: int) -> torch.Tensor:
    """F - 1 values along the frame `axis` -> F, the last repeated (zeros for a one-frame clip)."""
    if values.shape[axis] == 0:
        shape = list(values.shape)
        shape[axis] = 1
        return values.new_zeros(shape)
    last = values.narrow(axis, values.shape[axis] - 1, 1)
    return torch.cat([values, last], dim=axis)


def resample_positions(positions: np.ndarray, fps: float, target_fps: float) -> np.ndarray:
    """(F, J, 3) positions at `fps` -> the same span at `target_fps`, by linear interpolation in time.

    Positions have no convention to respect, so interpolation needs no rotation maths.
    """
    if abs(fps - target_fps) <= 1e-6 * target_fps:
        return positions
    frames = positions.shape[0]
    count = int(np.floor((frames - 1) * target_fps / fps + 1e-9)) + 1
    t = np.arange(count) * fps / target_fps
    lower = np.minimum(np.floor(t).astype(int), frames - 1)
    upper = np.minimum(lower + 1, frames - 1)
    w = (t - lower)[:, None, None]
    return (1 - w) * positions[lower] + w * positions[upper]
