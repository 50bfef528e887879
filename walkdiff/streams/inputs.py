"""Inputs that arrive over time: a pipe's bytes as they come, a file's as it is written."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

from walkdiff.common.errors import WalkdiffError


def read_pipe(stream) -> Iterator[bytes]:
    """The bytes of a pipe (standard input's binary buffer) as they come, until end of file."""
    read = getattr(stream, "read1", stream.read)  # read1: what is there, without waiting for a full block
    while data := read(1 << 14):
        yield data


def read_growing(path: str | Path, idle: float, poll: float = 0.02) -> Iterator[bytes]:
    """The bytes of a file that is still being written, until it has not grown for `idle` seconds."""
    path = Path(path)
    if not path.is_file():  # now, not at the first read
        raise WalkdiffError("file not found", path=path)
    return _follow(path, idle, poll)


def _follow(path: Path, idle: float, poll: float) -> Iterator[bytes]:
    with path.open("rb") as f:
        quiet_since = time.monotonic()
        while True:
            data = f.read(1 << 16)
            if data:
                quiet_since = time.monotonic()
                yield data
            elif time.monotonic() - quiet_since >= idle:
                return
            else:
                time.sleep(poll)
