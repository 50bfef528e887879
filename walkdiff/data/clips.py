"""What every dataset module shares: clip labels, content selection and deterministic ordering."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

from walkdiff.common.errors import WalkdiffError


@dataclass(frozen=True)
class ClipInfo:
    path: Path
    name: str
    style: int  # index into the dataset's STYLES (0 when the dataset has no styles)
    content: int  # index into the dataset's GROUPS (content group or action)
    item: int = -1  # index inside a multi-clip file (HumanAct12's pkl); -1 for one file per clip


@dataclass(frozen=True)
class ContentSelection:
    """The content groups a run trains on: 'all', one group name, or a list of names."""

    names: tuple[str, ...]

    @classmethod
    def parse(cls, value: str | list[str] | tuple[str, ...], groups: tuple[str, ...]) -> ContentSelection:
        if isinstance(value, str):
            value = list(groups) if value == "all" else [v.strip() for v in value.split(",")]
        unknown = [v for v in value if v not in groups]
        if unknown or not value:
            raise WalkdiffError(
                f"data.contents: unknown content {', '.join(unknown) or '(empty)'}; "
                f"expected 'all' or names from {', '.join(groups)}"
            )
        return cls(tuple(g for g in groups if g in value))


def deterministic_order(clips: list[ClipInfo]) -> list[ClipInfo]:
    """Clips ranked by a hash of their name: stable across machines, file systems and file order."""
    return sorted(clips, key=lambda c: hashlib.sha1(c.name.encode()).hexdigest())
