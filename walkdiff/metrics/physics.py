"""Physical plausibility of motions in world joint positions (Y up): foot skating and jitter.

Both metrics keep float64 sums and counts reduced by 'sum', so they are exact under DDP.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torch import Tensor
from torchmetrics import Metric

from walkdiff.common.errors import WalkdiffError


def _check_positions(name: str, positions: Tensor, min_frames: int) -> None:
    if positions.ndim != 4 or positions.shape[-1] != 3 or positions.shape[1] < min_frames:
        raise WalkdiffError(
            f"{name} expects joint positions (B, F, J, 3) with F >= {min_frames}, "
            f"got {tuple(positions.shape)}"
        )


def skating_sums(
    positions: Tensor, contacts: Tensor, foot_joints: Sequence[int], fps: float, speed_threshold: float
) -> tuple[Tensor, Tensor, Tensor]:
    """Per window (B,): contact steps, skating steps and the sum of horizontal foot speeds over contact
    steps (see `FootSkating`)."""
    feet = positions[:, :, list(foot_joints)].double()
    step = feet[:, 1:] - feet[:, :-1]
    # Horizontal speed in a Y-up world: (B, F-1, n_feet).
    speed = step[..., [0, 2]].norm(dim=-1) * fps
    in_contact = contacts.double() > 0.5
    in_contact = in_contact[:, 1:] & in_contact[:, :-1]
    return (
        in_contact.sum(dim=(1, 2)).double(),
        (in_contact & (speed > speed_threshold)).sum(dim=(1, 2)).double(),
        (speed * in_contact).sum(dim=(1, 2)),
    )


def jerk_sums(positions: Tensor, fps: float) -> tuple[Tensor, Tensor]:
    """Per window (B,): the sum of jerk magnitudes (third difference times fps^3) and their count."""
    magnitude = (torch.diff(positions.double(), n=3, dim=1) * fps**3).norm(dim=-1)
    return magnitude.sum(dim=(1, 2)), torch.full(
        (positions.shape[0],), magnitude[0].numel(), dtype=torch.float64
    )


class FootSkating(Metric):
    """Foot sliding while in contact: ``compute()`` gives ``{"skate_ratio", "slide_speed"}``.

    A step between frames t and t+1 counts as a contact step for a foot when the foot is labelled in contact
    at both frames (lift-off and touch-down steps move legitimately). Over the contact steps:
    ``skate_ratio`` is the share whose horizontal (XZ) foot speed exceeds ``speed_threshold`` and
    ``slide_speed`` the mean horizontal foot speed, both in the units of the positions per second. Both are
    NaN when no contact step was seen.
    """

    is_differentiable = False
    higher_is_better = False
    full_state_update = False

    def __init__(self, foot_joints: Sequence[int], fps: float, speed_threshold: float, **kwargs: Any):
        super().__init__(**kwargs)
        if len(foot_joints) == 0 or fps <= 0 or speed_threshold < 0:
            raise WalkdiffError(
                "FootSkating needs foot joint indices, fps > 0 and speed_threshold >= 0, got "
                f"{list(foot_joints)}, {fps}, {speed_threshold}"
            )
        self.foot_joints = list(foot_joints)
        self.fps = fps
        self.speed_threshold = speed_threshold
        self.add_state("contact_steps", default=torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("skating_steps", default=torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("speed_sum", default=torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")

    def update(self, positions: Tensor, contacts: Tensor) -> None:
        """Add world joint positions (B, F, J, 3) and foot contacts (B, F, n_feet) (bool or probabilities)."""
        _check_positions("FootSkating", positions, min_frames=2)
        b, f, j, _ = positions.shape
        n_feet = len(self.foot_joints)
        if contacts.shape != (b, f, n_feet):
            raise WalkdiffError(
                f"FootSkating expects contacts ({b}, {f}, {n_feet}), got {tuple(contacts.shape)}"
            )
        if max(self.foot_joints) >= j:
            raise WalkdiffError(
                f"FootSkating foot joints {self.foot_joints} do not fit positions with {j} joints"
            )
        contact, skating, speed = skating_sums(
            positions, contacts, self.foot_joints, self.fps, self.speed_threshold
        )
        self.contact_steps += contact.sum()
        self.skating_steps += skating.sum()
        self.speed_sum += speed.sum()

    def compute(self) -> dict[str, Tensor]:
        return {
            "skate_ratio": self.skating_steps / self.contact_steps,
            "slide_speed": self.speed_sum / self.contact_steps,
        }


class Jitter(Metric):
    """Mean jerk magnitude: norm of the third finite difference of joint positions times fps^3.

    Averaged over all joints and all frames of all sequences; units of the positions per second cubed.
    """

    is_differentiable = False
    higher_is_better = False
    full_state_update = False

    def __init__(self, fps: float, **kwargs: Any):
        super().__init__(**kwargs)
        if fps <= 0:
            raise WalkdiffError(f"Jitter needs fps > 0, got {fps}")
        self.fps = fps
        self.add_state("jerk_sum", default=torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("count", default=torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")

    def update(self, positions: Tensor) -> None:
        """Add world joint positions (B, F, J, 3), F >= 4."""
        _check_positions("Jitter", positions, min_frames=4)
        jerk, count = jerk_sums(positions, self.fps)
        self.jerk_sum += jerk.sum()
        self.count += count.sum()

    def compute(self) -> Tensor:
        return self.jerk_sum / self.count
