"""World joint positions of predicted motion for training losses, in units any skeleton shares.

The styled GAN-DDPM and the path walker both add terms on the motion their network predicts, through
differentiable forward kinematics of the raw features (the root integrated, then the skeleton).
Velocities are measured in multiples of the profile's contact speed threshold (0.326 leg lengths/s) and
lengths in contact heights (0.0326 leg lengths), so a term means the same on a skeleton in centimetres or
in metres, long-legged or not: a foot that slides at the threshold speed costs 1.
"""

from __future__ import annotations

import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import features_to_positions

# How sharply "near the ground" falls off above the contact height, in contact heights.
LOW_FOOT_SOFTNESS = 0.1


def at_least_float32(x: torch.Tensor) -> torch.Tensor:
    return x.to(torch.promote_types(x.dtype, torch.float32))


class BodyTerms:
    """Positions, velocities and foot quantities of raw features on one skeleton profile at one fps."""

    def __init__(self, profile: SkeletonProfile | None, fps: float):
        if profile is None:
            raise WalkdiffError("the position losses need the skeleton: train through `walkdiff fit`")
        self.profile = profile
        self.skeleton = profile.canonical_skeleton
        self.contacts = profile.contacts
        self.fps = fps
        self.feet = [self.skeleton.index(name) for name in self.contacts.joints]

    def positions(self, raw: torch.Tensor) -> torch.Tensor:
        """World joint positions (..., F, J, 3) of raw features (..., F, D)."""
        raw = at_least_float32(raw)
        offsets = torch.as_tensor(self.skeleton.offsets, dtype=raw.dtype, device=raw.device)
        # In float32 under bf16 autocast too: FK chains every bone's rotation, and the velocity and foot
        # terms difference neighbouring frames, which bf16's 3 digits would drown.
        with torch.autocast(raw.device.type, enabled=False):
            return features_to_positions(raw, offsets, self.skeleton.parents)

    def velocities(self, positions: torch.Tensor) -> torch.Tensor:
        """Joint velocities (..., F-1, J, 3) of positions, in contact speed thresholds."""
        return torch.diff(positions, dim=-3) * (self.fps / self.contacts.speed_threshold)

    def in_heights(self, lengths: torch.Tensor) -> torch.Tensor:
        """Lengths in contact heights: the same numbers in any units."""
        return lengths / self.contacts.height_threshold

    def pose(self, positions: torch.Tensor) -> torch.Tensor:
        """Joint positions relative to the root (..., F, J, 3), in contact heights."""
        return self.in_heights(positions - positions[..., :1, :])

    def foot_slide(self, velocity_hat: torch.Tensor, planted: torch.Tensor) -> torch.Tensor:
        """Squared horizontal foot speed (..., F-1, feet) of predicted velocities where `planted`
        (..., F-1, feet) is 1: MDM's foot-contact term before its mean."""
        return velocity_hat[..., self.feet, :][..., [0, 2]].pow(2).sum(dim=-1) * planted

    def low_foot_slide(
        self, positions_hat: torch.Tensor, velocity_hat: torch.Tensor, floor: torch.Tensor
    ) -> torch.Tensor:
        """How far beyond the contact speed threshold (..., F-1, feet) predicted feet slide horizontally over
        steps where the predicted foot itself is near the ground (below one contact height above `floor`,
        (feet,) in data units, at both ends): the geometric rule the skating metric counts by. Linear
        beyond the threshold, so the rare fast real foot near the floor (a landing) does not dominate;
        soft in height, so a sliding foot just at the contact height is pushed up as well as slowed down.
        A NaN floor (a joint never planted) is never near it."""
        height = self.in_heights(positions_hat[..., self.feet, 1] - floor)
        low = torch.sigmoid((1 - height.nan_to_num(nan=float("inf"))) / LOW_FOOT_SOFTNESS)
        low = low[..., 1:, :] * low[..., :-1, :]
        speed = velocity_hat[..., self.feet, :][..., [0, 2]].norm(dim=-1)
        return torch.relu(speed - 1) * low

    def foot_velocity_error(self, velocity_hat: torch.Tensor, velocity: torch.Tensor) -> torch.Tensor:
        """Predicted minus real velocities of the feet (..., F-1, feet, 3), in contact speed thresholds: all
        frames, not only planted ones, so a foot that reaches the ground still fast is penalised as well."""
        return velocity_hat[..., self.feet, :] - velocity[..., self.feet, :]

    def foot_height_error(self, positions_hat: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
        """Predicted minus real world heights of the feet (..., F, feet), in contact heights."""
        return self.in_heights(positions_hat[..., self.feet, 1] - positions[..., self.feet, 1])
