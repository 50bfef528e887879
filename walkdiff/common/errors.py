"""The one error type walkdiff raises for bad user input (files, fields, options)."""

from __future__ import annotations

import functools
import re
from contextvars import ContextVar
from pathlib import Path

# Set while a command runs: its errors keep the command line's spelling.
_COMMAND: ContextVar[bool] = ContextVar("walkdiff_command", default=False)
# Command-line options whose Python parameter is not simply the option's name with '_' for '-'.
PYTHON_NAMES = {"--style-clip": "style_clips", "--input": "motion", "--target-map": "to_map"}


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

    def in_python(self) -> WalkdiffError:
        """The same error with each command-line option named as the Python API's parameter (`--frames`
        -> `frames`): the messages are written once, in the spelling of the command line."""
        spelled = re.sub(
            r"(?<![\w-])--([a-z][a-z0-9-]*)",
            lambda m: PYTHON_NAMES.get(m[0], m[1].replace("-", "_")),
            self.reason,
        )
        where = str(self).removesuffix(self.reason)
        self.reason, self.args = spelled, (where + spelled,)
        return self


def python_api(method):
    """A method of the Python API: its WalkdiffErrors name parameters, not command-line options."""

    @functools.wraps(method)
    def call(*args, **kwargs):
        try:
            return method(*args, **kwargs)
        except WalkdiffError as error:
            if not _COMMAND.get():
                error.in_python()
            raise

    return call


def command(function):
    """A command's function: the API calls it makes say their errors with the command line's options."""

    @functools.wraps(function)
    def call(*args, **kwargs):
        token = _COMMAND.set(True)
        try:
            return function(*args, **kwargs)
        finally:
            _COMMAND.reset(token)

    return call
