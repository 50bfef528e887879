"""How many threads torch computes with: the cores this process may run on, not the machine's.

torch's default is the machine's core count. In a container, under `taskset`, or on a shared machine
limited by a cgroup quota, that oversubscribes the cores the process really has, and torch slows many
times over (a generator measured 5.9 s a batch with too many threads, 1.1 s with one, on a busy host).
`walkdiff --threads N` (or WALKDIFF_THREADS) chooses; OMP_NUM_THREADS set by the user is respected.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from walkdiff.common.errors import WalkdiffError

CGROUP_CPU_MAX = Path("/sys/fs/cgroup/cpu.max")  # cgroup v2: "QUOTA PERIOD" or "max PERIOD"


def available_cores() -> int:
    """Cores this process may use: its CPU affinity, capped by a cgroup v2 CPU quota when one is set."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows: no affinity call
        cores = os.cpu_count() or 1
    try:
        quota, period = CGROUP_CPU_MAX.read_text().split()[:2]
        if quota != "max":
            cores = min(cores, max(1, math.ceil(int(quota) / int(period))))
    except (OSError, ValueError):
        pass
    return max(1, cores)


def parse_threads(value: str, where: str) -> int:
    try:
        threads = int(value)
    except ValueError:
        threads = 0
    if threads < 1:
        raise WalkdiffError(f"{where}: expected a whole number of threads of at least 1, got {value!r}")
    return threads


def choose_threads(flag: str | None) -> tuple[int, str]:
    """(threads, why): the --threads flag, else WALKDIFF_THREADS, else OMP_NUM_THREADS, else the cores
    available to this process."""
    if flag is not None:
        return parse_threads(flag, "--threads"), "--threads"
    for variable in ("WALKDIFF_THREADS", "OMP_NUM_THREADS"):
        if os.environ.get(variable):
            return parse_threads(os.environ[variable], variable), variable
    return available_cores(), "the cores available to this process"


CHOSEN: list[str] = []  # what the command chose and why, said by `fit` once training starts


def apply_threads(threads: int, why: str = "") -> None:
    """Set torch's intra-op threads: through the environment when torch is not imported yet (importing it
    costs a second that commands without torch should not pay), directly when it is."""
    CHOSEN[:] = [f"torch computes with {threads} thread{'s' * (threads > 1)} ({why}; --threads N to change)"]
    os.environ["OMP_NUM_THREADS"] = str(threads)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(threads)


@contextmanager
def single_thread() -> Iterator[None]:
    """Torch on one thread for a while: for work made of many small tensor operations (a few joints at a
    time), where other threads only add waiting, most of all on a machine busy with other work."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)
