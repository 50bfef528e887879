"""Progress bars for long work: one style (tqdm, with rate and ETA, on stderr) for every command.

tqdm comes with Lightning, whose training bar uses it too. `WALKDIFF_PROGRESS=0` turns the bars off;
when stderr is not a terminal (a log file, CI) they redraw at most every 10 s instead of 10 times a second.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable

from tqdm import tqdm


def progress(
    iterable: Iterable | None = None, *, total: int | None = None, desc: str, unit: str = "it"
) -> tqdm:
    """A bar over `iterable` (or updated by hand up to `total`): `for x in progress(xs, desc="clips")`."""
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
        disable=os.environ.get("WALKDIFF_PROGRESS", "1") == "0",
    )
