"""Aggregation of an evaluation repeated several times (e.g. 20 repetitions of 1000 samples).

The papers' tables give "mean ± 1.96·σ/√n" over the repetitions. σ is the population standard deviation
(``np.std`` with ddof=0), as in the Action2Motion, ACTOR and MDM evaluation code, so the numbers compare.
An interval never leaves its metric's range (`BOUNDS`): an accuracy of 0.95 ± 0.07 is 0.95 [0.88, 1.00].
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from walkdiff.common.errors import WalkdiffError

PROPORTION = (0.0, 1.0)
NON_NEGATIVE = (0.0, math.inf)
# The range of every bounded metric, which no interval of it may leave (KID is unbiased: it can be < 0).
BOUNDS = {
    "style_acc": PROPORTION,
    "content_acc": PROPORTION,
    "target_style_acc": PROPORTION,
    "content_kept": PROPORTION,
    "skate_ratio": PROPORTION,
    "fmd": NON_NEGATIVE,
    "diversity": NON_NEGATIVE,
    "multimodality": NON_NEGATIVE,
    "slide_speed": NON_NEGATIVE,
    "jitter": NON_NEGATIVE,
    "content_distance": NON_NEGATIVE,
}


def summarize(values: Sequence[float], bounds: tuple[float, float] | None = None) -> dict[str, float]:
    """Mean, population std, 95% confidence half-width 1.96·std/√n, n, and the interval's ends (low,
    high: mean ∓ ci95 cut to `bounds`) of repeated measurements."""
    if len(values) == 0:
        raise WalkdiffError("summarize needs at least one value (number of repetitions >= 1)")
    array = np.asarray(values, dtype=np.float64)
    std = float(array.std())
    n = len(array)
    mean, ci95 = float(array.mean()), 1.96 * std / math.sqrt(n)
    low, high = bounds or (-math.inf, math.inf)
    return {
        "mean": mean,
        "std": std,
        "ci95": ci95,
        "n": n,
        "low": min(max(mean - ci95, low), high),
        "high": max(min(mean + ci95, high), low),
    }


def summarize_runs(
    runs: Sequence[Mapping[str, float]], bounds: Mapping[str, tuple[float, float]] = BOUNDS
) -> dict[str, dict[str, float]]:
    """Summarise each metric over repetitions given as one ``{metric: value}`` mapping per repetition;
    the intervals of the metrics named in `bounds` stay in their ranges."""
    if len(runs) == 0:
        raise WalkdiffError("summarize_runs needs at least one repetition")
    names = list(runs[0])
    for i, run in enumerate(runs):
        if set(run) != set(names):
            raise WalkdiffError(f"repetition {i} has metrics {sorted(run)}, expected {sorted(names)}")
    return {name: summarize([run[name] for run in runs], bounds.get(name)) for name in names}


def format_summary(summary: Mapping[str, float], decimals: int = 2) -> str:
    """Table cell "mean ± ci95", e.g. "12.34 ± 0.56"; "mean [low, high]" where the interval was cut to
    its metric's range, e.g. "0.95 [0.88, 1.00]"."""
    mean, ci95 = summary["mean"], summary["ci95"]
    low, high = summary.get("low", mean - ci95), summary.get("high", mean + ci95)
    if low > mean - ci95 or high < mean + ci95:
        return f"{mean:.{decimals}f} [{low:.{decimals}f}, {high:.{decimals}f}]"
    return f"{mean:.{decimals}f} ± {ci95:.{decimals}f}"
