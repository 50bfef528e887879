"""Metrics of a set of clips with 95% intervals by bootstrap over clips (`walkdiff score`).

Windows cut from one clip are correlated, so a set is resampled by clip, never by window. Every metric is
a function of per-clip sums (counts, feature sums and outer products, kernel sums, contact and jerk
sums), so a resample is a vector of clip weights (how often each clip was drawn) and costs a few small
matrix products, not a new pass over the windows.

KID is the unbiased squared MMD with torchmetrics' polynomial kernel k(x, y) = (x.y / E + 1)^3 (the
estimator of torchmetrics' `KernelInceptionDistance`, computed once over all windows instead of averaged
over random subsets): unlike FMD its expectation does not depend on the number of windows, so sets of
different sizes compare. FMD is biased upwards for small sets (its covariance estimate is noisy).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor
from torchmetrics.image.kid import poly_kernel

from walkdiff.metrics.distribution import random_pairs
from walkdiff.metrics.protocol import BOUNDS, PROPORTION

KERNEL_CHUNK = 2048  # windows per block of the kernel matrix


def kernel_sums(x: Tensor, y: Tensor, x_groups: Tensor, num_groups: int) -> Tensor:
    """(num_groups, len(y)) sums over each group's rows of k(x, y), computed in blocks."""
    out = torch.zeros(num_groups, y.shape[0], dtype=torch.float64)
    for i in range(0, x.shape[0], KERNEL_CHUNK):
        block = poly_kernel(x[i : i + KERNEL_CHUNK].double(), y.double())
        out.index_add_(0, x_groups[i : i + KERNEL_CHUNK], block)
    return out


def _self_kernel(x: Tensor) -> Tensor:
    """k(x_i, x_i) of every row, as `poly_kernel` defines k."""
    return ((x * x).sum(-1) / x.shape[1] + 1).pow(3)


@dataclass
class Reference:
    """The real windows every set is measured against: their feature moments and kernel sums."""

    features: Tensor  # (M, E) float64
    mean: Tensor
    cov: Tensor
    kernel_within: float  # mean of k(y, y') over pairs of different windows
    cov_sqrt: Tensor = field(init=False)  # the symmetric square root of `cov`

    def __post_init__(self) -> None:
        values, vectors = torch.linalg.eigh(self.cov)
        self.cov_sqrt = (vectors * values.clamp(min=0).sqrt()) @ vectors.T

    def frechet(self, mean: Tensor, cov: Tensor) -> float:
        """Fréchet distance of a Gaussian to this one: |mu - mu_r|^2 + Tr(S + S_r) - 2 Tr((S_r S)^1/2).

        The eigenvalues of S_r S are those of the symmetric S_r^1/2 S S_r^1/2, whose `eigvalsh` is exact
        and a hundred times faster than the general eigen-solver of torchmetrics' FID, run per resample.
        """
        inner = torch.linalg.eigvalsh(self.cov_sqrt @ cov @ self.cov_sqrt).clamp(min=0).sqrt().sum()
        return float((mean - self.mean).square().sum() + cov.trace() + self.cov.trace() - 2 * inner)

    @classmethod
    def of(cls, features: Tensor) -> Reference:
        y = features.double()
        m = y.shape[0]
        total = kernel_sums(y, y, torch.zeros(m, dtype=torch.long), 1).sum()
        self_sum = _self_kernel(y).sum()
        return cls(y, y.mean(0), torch.cov(y.T), float((total - self_sum) / (m * (m - 1))))


@dataclass
class ClipStatistics:
    """Per-clip sums of one set of scored windows; `metrics(weights)` gives every metric of a resample."""

    windows: Tensor  # (C,) windows per clip
    features: Tensor  # (N, E) float64, the windows' evaluator features
    clip: Tensor  # (N,) clip index of each window
    feature_sum: Tensor  # (C, E)
    feature_outer: Tensor  # (C, E, E)
    kernel_within: Tensor  # (C, C) sums of k over window pairs of clips c and d
    kernel_self: Tensor  # (C,) sums of k(x, x)
    kernel_reference: Tensor  # (C,) sums of k(x, y) over the reference windows
    correct: dict[str, Tensor]  # name -> (C,) correctly recognised windows
    contact_steps: Tensor
    skating_steps: Tensor
    speed_sum: Tensor
    jerk_sum: Tensor
    jerk_count: Tensor
    reference: Reference

    @property
    def num_clips(self) -> int:
        return self.windows.shape[0]

    @classmethod
    def of(
        cls,
        features: Tensor,
        clip: Tensor,
        reference: Reference,
        correct: dict[str, Tensor],
        skating: tuple[Tensor, Tensor, Tensor],
        jerk: tuple[Tensor, Tensor],
    ) -> ClipStatistics:
        """`clip` (N,) numbers windows 0..C-1; `correct` maps names to (N,) bools; `skating` is per-window
        (contact steps, skating steps, speed sum) and `jerk` per-window (jerk sum, count)."""
        x = features.double()
        c = int(clip.max()) + 1
        if (torch.diff(clip) < 0).any():
            raise ValueError("windows must be given clip after clip (clip indices in order)")

        def per_clip(values: Tensor) -> Tensor:
            return torch.zeros(c, *values.shape[1:], dtype=torch.float64).index_add_(0, clip, values.double())

        within = kernel_sums(x, x, clip, c)  # (C, N)
        within = torch.zeros(c, c, dtype=torch.float64).index_add_(1, clip, within)
        return cls(
            windows=per_clip(torch.ones(len(clip))),
            features=x,
            clip=clip,
            feature_sum=per_clip(x),
            feature_outer=per_clip(x[:, :, None] * x[:, None, :]),
            kernel_within=within,
            kernel_self=per_clip(_self_kernel(x)),
            kernel_reference=kernel_sums(x, reference.features, clip, c).sum(1),
            correct={name: per_clip(value) for name, value in correct.items()},
            contact_steps=per_clip(skating[0]),
            skating_steps=per_clip(skating[1]),
            speed_sum=per_clip(skating[2]),
            jerk_sum=per_clip(jerk[0]),
            jerk_count=per_clip(jerk[1]),
            reference=reference,
        )

    def metrics(self, weights: Tensor, seed: int = 0) -> dict[str, float]:
        """Every metric of the multiset of clips where clip c appears weights[c] times."""
        w = weights.double()
        n = float(w @ self.windows)
        ref = self.reference
        values = {name: float(w @ hits) / n for name, hits in self.correct.items()}

        mean = (w @ self.feature_sum) / n
        second = torch.einsum("c,cij->ij", w, self.feature_outer)
        cov = (second - n * torch.outer(mean, mean)) / max(n - 1, 1)
        values["fmd"] = ref.frechet(mean, cov)

        # Pairs of different windows, leaving out pairs between two draws of one clip: their identical
        # windows would count as pairs of a real set's distinct windows and bias KID upwards.
        same = torch.diagonal(self.kernel_within)
        counts = self.windows
        pair_sum = w @ self.kernel_within @ w - w.square() @ same + w @ (same - self.kernel_self)
        pair_count = (w @ counts) ** 2 - w.square() @ counts.square() + w @ (counts * (counts - 1))
        m = ref.features.shape[0]
        cross = float(w @ self.kernel_reference) / (n * m)
        values["kid"] = float(pair_sum / pair_count) + ref.kernel_within - 2 * cross

        # Diversity as `metrics.Diversity` draws it: 200 random pairs of the resample's windows.
        rows = self._rows(weights.long())
        first, second = random_pairs(len(rows), 200, torch.Generator().manual_seed(seed))
        values["diversity"] = float(
            (self.features[rows[first]] - self.features[rows[second]]).norm(dim=1).mean()
        )

        contact = float(w @ self.contact_steps)
        values["skate_ratio"] = float(w @ self.skating_steps) / contact if contact else float("nan")
        values["slide_speed"] = float(w @ self.speed_sum) / contact if contact else float("nan")
        values["jitter"] = float(w @ self.jerk_sum) / float(w @ self.jerk_count)
        return values

    def _rows(self, weights: Tensor) -> Tensor:
        """Window indices of the multiset of clips (windows are stored clip after clip)."""
        counts = self.windows.long()
        offsets = torch.cumsum(counts, 0) - counts
        drawn = torch.repeat_interleave(torch.arange(self.num_clips), weights)
        lengths = counts[drawn]
        begins = torch.cumsum(lengths, 0) - lengths
        return torch.repeat_interleave(offsets[drawn] - begins, lengths) + torch.arange(int(lengths.sum()))

    def bootstrap(self, resamples: int, seed: int = 0) -> dict[str, dict[str, float]]:
        """{metric: {value, low, high, n}}: the value on the set and a 95% interval from `resamples`
        resamples of its clips (`resample_weights`).

        A share (accuracy, skate ratio) gets the 2.5-97.5 percentile range of its resamples: each lies in
        [0, 1], so the range does too. Any other metric gets that range moved by the resamples' bias (their
        mean minus the value): a resample holds fewer distinct clips than the set, which alone raises FMD,
        so a plain percentile range may not even hold the value; the moved range is cut to the metric's
        range (`BOUNDS`).
        """
        # Small eigen-problems gain nothing from threads, and on a busy machine every thread barrier
        # of the solver waits for a descheduled thread (measured: 0.24 s instead of 0.6 ms a solve).
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            point = self.metrics(torch.ones(self.num_clips), seed)
            draws = [self.metrics(w, seed) for w in resample_weights(self.num_clips, resamples, seed)]
        finally:
            torch.set_num_threads(threads)
        out = {}
        for name, value in point.items():
            samples = np.array([d[name] for d in draws], dtype=np.float64)
            low, high = interval(samples, value, BOUNDS.get(name))
            out[name] = {"value": value, "low": low, "high": high, "n": self.num_clips}
        return out

    def share(self, name: str, weights: Tensor) -> float:
        """A per-window quantity of `correct` (a share, or a mean distance) over the resample `weights`."""
        return float(weights.double() @ self.correct[name]) / float(weights.double() @ self.windows)


def resample_weights(num_clips: int, resamples: int, seed: int = 0) -> Iterator[Tensor]:
    """Clip weights of `resamples` bootstrap resamples (how often each clip was drawn); the same for every
    set of `num_clips` clips and `seed`, so sets whose clips correspond are resampled in pairs."""
    generator = torch.Generator().manual_seed(seed)
    for _ in range(resamples):
        picks = torch.randint(num_clips, (num_clips,), generator=generator)
        yield torch.bincount(picks, minlength=num_clips).double()


def interval(samples: np.ndarray, value: float, bounds: tuple[float, float] | None) -> tuple[float, float]:
    """The 95% interval of `value` from its bootstrap `samples` (see `ClipStatistics.bootstrap`)."""
    samples = samples[np.isfinite(samples)]
    if not samples.size or not np.isfinite(value):
        return float("nan"), float("nan")
    low, high = np.percentile(samples, [2.5, 97.5])
    if bounds != PROPORTION:
        bias = samples.mean() - value
        low, high = low - bias, high - bias
    if bounds is not None:
        low, high = np.clip([low, high], *bounds)
    return float(low), float(high)
