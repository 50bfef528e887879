"""The one error type walkdiff raises for bad user input (files, fields, options)."""

from __future__ import annotations

from pathlib import Path


class WalkdiffError(Exception):
    """Bad input, with where it was found and what was expected.

    The message always names the source (a file or a config field) and, when known, the line,
    so that a user can go straight to the problem.
    """

    def __init__(self, message: str, *, path: str | Path | None = None, line: int | None = None):
        self.path = None if path is None else str(path)
        self.line = line
        self.reason = message
        where = ""
        if self.path is not None:
            where = self.path if line is None else f"{self.path}:{line}"
            where += ": "
        super().__init__(where + message)
