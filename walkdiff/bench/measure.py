"""What every benchmark shares: the machine it ran on, its report, and timings taken as medians."""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.files import strict_json, write_json


def machine() -> dict:
    return {
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "platform": platform.platform(),
    }


def report(out: str | Path, result: dict) -> None:
    """Write a benchmark's JSON (atomically) and show it."""
    write_json(out, result)
    print(json.dumps(strict_json(result), indent=2))


def median_seconds(fn, repeats: int) -> float:
    """Median seconds of `fn` over `repeats` runs."""
    return interleaved_medians([fn], repeats)[0]


def interleaved_medians(fns: list, repeats: int) -> list[float]:
    """Median seconds of each of `fns`, run in turn `repeats` times: timings that are to be compared
    share the machine's slow and fast moments."""
    times = [[] for _ in fns]
    for _ in range(repeats):
        for fn, spent in zip(fns, times, strict=True):
            start = time.perf_counter()
            fn()
            spent.append(time.perf_counter() - start)
    return [statistics.median(spent) for spent in times]


def percentiles(values: list[float]) -> dict:
    """Median and 95th percentile of latencies in seconds, in milliseconds."""
    values = np.asarray(values) * 1000
    return {
        "median_ms": round(float(np.median(values)), 1),
        "p95_ms": round(float(np.percentile(values, 95)), 1),
    }
