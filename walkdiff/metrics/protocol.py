"""Aggregation of an evaluation repeated several times (e.g. 20 repetitions of 1000 samples).

The papers' tables give "mean ± 1.96·σ/√n" over the repetitions. σ is the population standard deviation
(``np.std`` with ddof=0), as in the Action2Motion, ACTOR and MDM evaluation code, so the numbers compare.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from walkdiff.common.errors import WalkdiffError


def summarize(values: Sequence[float]) -> dict[str, float]:
    """Mean, population std, 95% confidence half-width 1.96·std/√n and n of repeated measurements."""
    if len(values) == 0:
        raise WalkdiffError("summarize needs at least one value (number of repetitions >= 1)")
    array = np.asarray(values, dtype=np.float64)
    std = float(array.std())
    n = len(array)
    return {"mean": float(array.mean()), "std": std, "ci95": 1.96 * std / math.sqrt(n), "n": n}


def summarize_runs(runs: Sequence[Mapping[str, float]]) -> dict[str, dict[str, float]]:
    """Summarise each metric over repetitions given as one ``{metric: value}`` mapping per repetition."""
    if len(runs) == 0:
        raise WalkdiffError("summarize_runs needs at least one repetition")
    names = list(runs[0])
    for i, run in enumerate(runs):
        if set(run) != set(names):
            raise WalkdiffError(f"repetition {i} has metrics {sorted(run)}, expected {sorted(names)}")
    return {name: summarize([run[name] for run in runs]) for name in names}


def format_summary(summary: Mapping[str, float], decimals: int = 2) -> str:
    """Table cell "mean ± ci95", e.g. "12.34 ± 0.56"."""
    return f"{summary['mean']:.{decimals}f} ± {summary['ci95']:.{decimals}f}"
