"""Style from an example clip that no code describes: matching the sample's pose statistics to the clip's.

A style code places an example among the styles the encoder was trained on, so a style never seen in
training lands on the nearest seen one (measured: `walkdiff bench style`, unseen styles). What an
example clip does carry, seen or not, is the statistics of its features: the mean of each channel is its
posture (a raised chest, a bent back) and speed, the spread of each channel over a window is how far and
how fast its joints swing. Holden et al. (2016) restyled motion by matching such second-order statistics
of an example, and AdaIN (Huang and Belongie 2017; Aberman et al. 2020 for motion) by moving the mean and
spread of each channel to the example's; here the same move is made on the denoiser's clean estimate at
every sampling step, so the network keeps making a whole, consistent body around it.

The channels matched are the pose and the root's speed and height (`FeatureLayout`); the turning rate is
the path's and the contact flags are the feet's timing, so neither is touched. Statistics are of
normalised features, taken per window of the model and averaged over the example's windows.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from walkdiff.diffusion.gaussian import GaussianDiffusion, extract
from walkdiff.motion.representation import FeatureLayout

MAX_SCALE = 3.0  # a channel's spread is scaled by at most this (or 1/this): a still channel is not blown up


def matched_channels(dim: int, root_speed: bool = True) -> torch.Tensor:
    """(D,) 1 on the channels whose statistics carry style: root speed and height, and the pose
    (`root_speed` False: not the speed, where a path and a commanded pace set it)."""
    layout = FeatureLayout.from_dim(dim)
    mask = torch.zeros(dim)
    for block in (layout.root_vel, layout.root_height, layout.rotations)[0 if root_speed else 1 :]:
        mask[block] = 1.0
    return mask


def moved_output(
    diffusion: GaussianDiffusion, out: torch.Tensor, x: torch.Tensor, t: torch.Tensor, delta: torch.Tensor
) -> torch.Tensor:
    """A network output (eps, x0 or v) whose clean estimate is moved by `delta`, in the network's terms."""
    # x0 = sqrt(1 / abar) x_t - sqrt(1 / abar - 1) eps = sqrt(abar) x_t - sqrt(1 - abar) v
    per_unit = {
        "x0": None,
        "eps": diffusion.sqrt_recipm1_alphas_cumprod,
        "v": diffusion.sqrt_one_minus_alphas_cumprod,
    }[diffusion.prediction]
    return out + delta if per_unit is None else out - delta / extract(per_unit, t, x)


@dataclass(frozen=True)
class StyleStatistics:
    """Per-channel mean and spread (D,) of normalised feature windows, or (B, D) one per sample of a batch,
    and how strongly to match them (a weight, () or (B,), in [0, 1]; 1 moves the sample's statistics all
    the way)."""

    mean: torch.Tensor
    spread: torch.Tensor
    strength: torch.Tensor

    @classmethod
    def of(cls, windows: torch.Tensor) -> StyleStatistics:
        """The statistics of windows (N, F, D): the mean over every frame, the root mean square of each
        window's spread over its frames."""
        mean = windows.mean(dim=(0, 1))
        spread = windows.var(dim=1, correction=0).mean(dim=0).sqrt()
        return cls(mean, spread, torch.ones(()))

    @classmethod
    def mixed(cls, weighted: list[tuple[StyleStatistics, float]], strength: float) -> StyleStatistics:
        """The weighted mean of several examples' statistics (variances averaged), matched at `strength`."""
        total = sum(w for _, w in weighted)
        mean = sum(w * s.mean for s, w in weighted) / total
        spread = (sum(w * s.spread.square() for s, w in weighted) / total).sqrt()
        return cls(mean, spread, torch.tensor(float(strength)))

    @classmethod
    def stack(cls, each: list[StyleStatistics]) -> StyleStatistics:
        """One statistics per sample of a batch, in order."""
        return cls(
            *(torch.stack([getattr(s, name) for s in each]) for name in ("mean", "spread", "strength"))
        )

    def towards(self, other: StyleStatistics, share: float) -> StyleStatistics:
        """`share` of the way from these to `other` (variances and strengths interpolated): a style ramp.
        A side matched at strength 0 has no statistics to leave or reach, so only the strength ramps."""
        start = self if float(self.strength) > 0 else replace(other, strength=self.strength)
        end = other if float(other.strength) > 0 else replace(self, strength=other.strength)
        return StyleStatistics(
            start.mean + share * (end.mean - start.mean),
            (start.spread.square() + share * (end.spread.square() - start.spread.square())).sqrt(),
            start.strength + share * (end.strength - start.strength),
        )

    def rows(self, start: int, stop: int) -> StyleStatistics:
        """The statistics of samples [start, stop) of a batch's."""
        return StyleStatistics(self.mean[start:stop], self.spread[start:stop], self.strength[start:stop])

    def shift(self, x0: torch.Tensor) -> torch.Tensor:
        """How far (B, F, D) to move clean windows x0 (B, F, D) so each channel's mean and spread over the
        window meet these, on the matched channels, times the strength."""
        mask = matched_channels(x0.shape[-1]).to(x0)
        mean, spread = x0.mean(dim=1, keepdim=True), x0.std(dim=1, keepdim=True, correction=0)
        scale = (self.spread.to(x0)[..., None, :] / spread.clamp_min(1e-6)).clamp(1 / MAX_SCALE, MAX_SCALE)
        moved = (x0 - mean) * scale + self.mean.to(x0)[..., None, :]
        strength = self.strength.to(x0).reshape(*self.strength.shape, 1, 1)
        return strength * mask * (moved - x0)

    def guide(self, model_fn, diffusion: GaussianDiffusion):
        """A sampler's model_fn (x_t, t) -> output whose clean estimate is moved to these statistics; the
        output stays in the network's own terms (eps, x0 or v)."""

        def matched(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
            out = model_fn(x, t)
            return moved_output(diffusion, out, x, t, self.shift(diffusion.predict_x0(out, x, t)))

        return matched


class RunningMatch:
    """The same matching for a model that makes one frame at a time (the path walker): it has no window
    to take a mean and a spread over, so its own recent frames stand in, a running mean and variance of
    the network's clean frames over about `span` frames (before they are moved: the moves do not feed
    the statistics they are measured by). Each row of a batch keeps its own. The root's speed is left to
    the path and the commanded pace. `target` may be one statistics for every row, or one per row (B, D)
    with strengths (B,), and may be replaced between frames (a live controller's ramps)."""

    def __init__(self, target: StyleStatistics, span: int, diffusion: GaussianDiffusion, last_step: int):
        self.target, self.diffusion, self.last_step = target, diffusion, last_step
        self.rate = 1.0 / max(1, span)
        self.mean: torch.Tensor | None = None  # (B, D)
        self.variance: torch.Tensor | None = None

    def shift(self, x0: torch.Tensor) -> torch.Tensor:
        """How far (B, D) to move the clean frames x0 (B, D)."""
        if self.mean is None:  # the first frame: no spread to measure yet, its mean moved alone
            mean, scale = x0, 1.0
        else:
            mean, spread = self.mean, self.variance.sqrt().clamp_min(1e-6)
            scale = (self.target.spread.to(x0) / spread).clamp(1 / MAX_SCALE, MAX_SCALE)
        moved = (x0 - mean) * scale + self.target.mean.to(x0)
        mask = matched_channels(x0.shape[-1], root_speed=False).to(x0)
        strength = self.target.strength.to(x0)
        return strength.reshape(*strength.shape, 1) * mask * (moved - x0)

    def record(self, x0: torch.Tensor) -> None:
        """A frame made: its clean estimate (B, D) joins the running statistics."""
        if self.mean is None:
            self.mean, self.variance = x0.clone(), self.target.spread.to(x0).square().expand_as(x0).clone()
            return
        deviation = x0 - self.mean
        self.mean = self.mean + self.rate * deviation
        self.variance = (1 - self.rate) * (self.variance + self.rate * deviation.square())

    def guide(self, model_fn):
        """A frame sampler's model_fn with each clean estimate moved; the last step's joins the record."""
        diffusion = self.diffusion

        def matched(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
            out = model_fn(x, t)
            x0 = diffusion.predict_x0(out, x, t)
            delta = self.shift(x0)
            if int(t[0]) == self.last_step:
                self.record(x0)
            return moved_output(diffusion, out, x, t, delta)

        return matched
