"""argparse types shared by the command line and the benchmarks: finite numbers in a range, whole numbers,
lists of them; a bad value is said in one line that names the option."""

from __future__ import annotations

import argparse
import math

from walkdiff.common.errors import WalkdiffError


def number(low: float | None = None, high: float | None = None, *, above: bool = False, below: bool = False):
    """An argparse type: a finite number in [low, high]; `above`/`below` leave out the bound itself."""
    left, right = "(" if above else "[", ")" if below else "]"
    span = (
        f" in {left}{'-inf' if low is None else f'{low:g}'}, {'inf' if high is None else f'{high:g}'}{right}"
    )

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        inside = math.isfinite(value) and (
            (low is None or value > low or (value == low and not above))
            and (high is None or value < high or (value == high and not below))
        )
        if not inside:
            raise argparse.ArgumentTypeError(f"expected a finite number{span}, got {text!r}")
        return value

    parse.__name__ = "number"
    return parse


def count(low: int):
    """An argparse type: a whole number >= low."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = low - 1
        if value < low:
            raise argparse.ArgumentTypeError(f"expected a whole number >= {low}, got {text!r}")
        return value

    parse.__name__ = "count"
    return parse


def counts(low: int):
    """An argparse type: whole numbers >= low, separated by commas ("1,2")."""
    one = count(low)

    def parse(text: str) -> list[int]:
        try:
            return sorted({one(part) for part in text.split(",")})
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(
                f"expected whole numbers >= {low} separated by commas, got {text!r}"
            ) from None

    parse.__name__ = "counts"
    return parse


class UsageError(WalkdiffError):
    """A bad command line: said in one line with a pointer to the command's --help, not the whole usage."""


class Parser(argparse.ArgumentParser):
    def error(self, message: str):
        raise UsageError(f"{message}; see `{self.prog} --help`")
