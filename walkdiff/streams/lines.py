"""What a stream command prints: a JSON line per frame as soon as it is made, and how its input ended
(as it should, with bad input midway or by Ctrl-C)."""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from walkdiff.common.errors import WalkdiffError


def emit(line: dict) -> None:
    """One JSON line on stdout, flushed: a live consumer reads it as soon as it is made. One write of the
    line and its newline: Ctrl-C between print's two writes left a line without its end, and the
    interrupted stream's summary then joined it."""
    sys.stdout.write(json.dumps(line, separators=(",", ":")) + "\n")
    sys.stdout.flush()


class Interrupted(KeyboardInterrupt):
    """Ctrl-C on a stream, raised once what it made is written: its message says where (the command
    line prints it on one line and exits 130)."""


class StreamEnd:
    """How a stream command's input ended: as it should, with bad input midway (`error`, a WalkdiffError)
    or by Ctrl-C (`error`, a KeyboardInterrupt). Every stream command reads its input inside `watch()`,
    makes its last frames with `finish`, writes the frames made (atomically: a complete file or none),
    then raises `stopped(end.error, ...)` if the input did not end as it should."""

    def __init__(self) -> None:
        self.error: WalkdiffError | KeyboardInterrupt | None = None

    @property
    def interrupted(self) -> bool:
        return isinstance(self.error, KeyboardInterrupt)

    @contextmanager
    def watch(self) -> Iterator[None]:
        """Bad input or Ctrl-C inside stops the input there; the frames made before it are kept."""
        try:
            yield
        except (WalkdiffError, KeyboardInterrupt) as error:
            self.error = error

    def finish(self, make) -> None:
        """`make()` the frames the input allows, unless Ctrl-C came (the user wants out, not more
        frames); a Ctrl-C during it stops it, keeping what it made."""
        if self.interrupted:
            return
        try:
            make()
        except KeyboardInterrupt as error:
            self.error = error


def stopped(error: WalkdiffError | KeyboardInterrupt, frames: int, files: list[Path]) -> Exception:
    """A stream whose input went bad or was interrupted: its last JSON line says so, with the frames made
    before and the files they were written to; the error to raise names the input's fault (or Ctrl-C) and
    where those frames are."""
    if isinstance(error, KeyboardInterrupt):
        emit({"done": False, "frames": frames, "interrupted": True, "files": [str(f) for f in files]})
        if not files:
            return Interrupted(f"{frames} frames made, nothing written")
        return Interrupted(f"the {frames} frames made so far are in {', '.join(str(f) for f in files)}")
    emit({"done": False, "frames": frames, "error": str(error), "files": [str(f) for f in files]})
    if not files:
        return error
    kept = f"the {frames} frames made before it are in {', '.join(str(f) for f in files)}"
    return WalkdiffError(f"{error.reason}; {kept}", path=error.path, line=error.line)


def pump(
    end: StreamEnd,
    arrivals: Iterable[tuple[float, object]],
    feed: Callable,
    run: Callable[[], object],
    send: Callable[[float], None],
    close: Callable[[], None],
) -> None:
    """A stream command's input as it arrives: each (arrival time, input) is fed, the frames it allows
    made and sent (`send(arrived)`), and the input closed at its end. Bad input midway or Ctrl-C stops it
    there (`end` says which); the frames the input so far allows are made and sent all the same, unless
    Ctrl-C asked to get out."""
    with end.watch():
        for arrived, given in arrivals:
            feed(given)
            run()
            send(arrived)
        close()
    end.finish(run)
    send(time.perf_counter())


def finished(end: StreamEnd, frames: int, written: list[Path], **summary) -> dict:
    """The last line of a stream command whose frames are `written`: its summary when the input ended as
    it should, else `stopped`'s line and error (those files hold the frames made before)."""
    if end.error is not None:
        raise stopped(end.error, frames, written if frames else [])
    summary = {"done": True, "frames": frames, **summary}
    emit(summary)
    return summary


def sender(live) -> Callable[[float], None]:
    """`pump`'s `send` for a stream whose `frames()` hands over its new frames as dicts: each printed as a
    JSON line with its latency, the milliseconds from the input's arrival to the line."""

    def send(arrived: float) -> None:
        lines = live.frames()
        latency = round(1000 * (time.perf_counter() - arrived), 1)
        for line in lines:
            emit(line | {"latency_ms": latency})

    return send
