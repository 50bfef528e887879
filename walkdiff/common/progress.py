"""Progress bars for long work: one style (tqdm, with rate and ETA, on stderr) for every command.

tqdm comes with Lightning, whose training bar uses it too. `WALKDIFF_PROGRESS=0` turns the bars off;
when stderr is not a terminal (a log file, CI) they redraw at most every 10 s instead of 10 times a second.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterable

from tqdm import tqdm


def progress(
    iterable: Iterable | None = None,
    *,
    total: int | None = None,
    desc: str,
    unit: str = "it",
    show: bool = True,
) -> tqdm:
    """A bar over `iterable` (or updated by hand up to `total`): `for x in progress(xs, desc="clips")`.
    `show=False` hides it (work too short to need one)."""
    terminal = sys.stderr.isatty()
    return tqdm(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        file=sys.stderr,
        dynamic_ncols=True,
        leave=terminal,
        mininterval=0.1 if terminal else 10.0,
        disable=not show or os.environ.get("WALKDIFF_PROGRESS", "1") == "0",
    )


def say(line: str) -> None:
    """A line on stderr, above a bar that is running (a plain print would land at the end of the bar's)."""
    tqdm.write(line, file=sys.stderr)
    sys.stderr.flush()


def step_hook(bar: tqdm, runs: int = 1) -> Callable[[int, int], None]:
    """A sampler's `progress` hook, hook(steps_done, steps_total), that advances `bar` one step at a time
    over `runs` sampler runs: the bar's total, `runs` times one run's steps, is set at the first step, so
    a caller need not know how many steps its sampler takes."""

    def hook(done: int, total: int) -> None:
        if bar.total is None:
            bar.total = runs * total
            bar.refresh()
        bar.update(1)

    return hook


def duration(seconds: float) -> str:
    """A duration as people say it: '45 s', '12 min', '2.5 h'."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"
