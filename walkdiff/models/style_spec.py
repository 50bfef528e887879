"""A style request as Python speaks it, read once: labels, example clips, or a timeline of them.

The command line gives text (`--style angry:0.7,old:0.3`, `--style-clip a.bvh:0.7`); Python gives a name,
a dict or list of weighted names, a list of (seconds, style) keys, and clips as paths, `Motion`s or
`Take`s with weights. Both become one `Style`, whose labels are the text the model's parsers read
(models/style_labels.py), so the two routes make the same motion for the same request.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

from walkdiff.common.errors import WalkdiffError
from walkdiff.models.style_examples import MATCH_CLIPS, parse_style_clips
from walkdiff.models.style_labels import DEFAULT_TRANSITION

STYLE_FORMS = (
    "a name ('old'), a mix ({'old': 0.7, 'proud': 0.3}, [('old', 0.7), ...] or 'old:0.7,proud:0.3') or a "
    "timeline ([(0, 'neutral'), (4, 'old')] or 'neutral@0,old@4s')"
)


@dataclass(frozen=True)
class Style:
    """What style to make. `labels`: the trained styles as text (a name, a mix or a timeline); `clips`:
    example clips with their weights; `match`: how far the clips' pose statistics are matched (0: their
    code alone); `transition`: seconds a timeline's change is ramped over."""

    labels: str | None = None
    clips: tuple[tuple[object, float], ...] = ()
    match: float = MATCH_CLIPS
    transition: float = DEFAULT_TRANSITION

    def __post_init__(self) -> None:  # read once, whatever form it came in
        object.__setattr__(self, "labels", labels_text(self.labels))
        object.__setattr__(self, "clips", tuple(parse_style_clips(self.clips)) if self.clips else ())

    @classmethod
    def of(
        cls,
        style=None,
        style_clips=None,
        match_clips: float = MATCH_CLIPS,
        transition: float = DEFAULT_TRANSITION,
    ) -> Style:
        """The spec from what a caller gave (a Style itself, then alone)."""
        if isinstance(style, Style):
            if style_clips or (match_clips, transition) != (MATCH_CLIPS, DEFAULT_TRANSITION):
                raise WalkdiffError("style: give style_clips, match_clips and transition inside the Style")
            return style
        return cls(style, style_clips or (), match_clips, transition)

    @property
    def timeline(self) -> bool:
        return self.labels is not None and "@" in self.labels


def labels_text(style) -> str | None:
    """A style as the text the label parsers read: 'old', 'old:0.7,proud:0.3' or 'neutral@0,old@4'."""
    if style is None or isinstance(style, str):
        return style
    if isinstance(style, dict):
        return ",".join(_weighted(name, weight) for name, weight in style.items())
    if (
        isinstance(style, list | tuple)
        and style
        and all(isinstance(i, list | tuple) and len(i) == 2 for i in style)
    ):
        if all(isinstance(i[0], numbers.Real) and not isinstance(i[0], bool) for i in style):
            return ",".join(f"{_key(key)}@{float(at)!r}" for at, key in style)
        if all(isinstance(i[0], str) for i in style):
            return ",".join(_weighted(name, weight) for name, weight in style)
    if isinstance(style, list | tuple) and style and all(isinstance(i, str) for i in style):
        return style[0] if len(style) == 1 else ",".join(_weighted(name, 1.0) for name in style)
    raise WalkdiffError(f"style: expected {STYLE_FORMS}, got {style!r}")


def _weighted(name, weight) -> str:
    if not isinstance(name, str) or not isinstance(weight, numbers.Real) or isinstance(weight, bool):
        raise WalkdiffError(f"style: expected names with numeric weights, got {name!r}: {weight!r}")
    return f"{name}:{float(weight)!r}"


def _key(style) -> str:
    """A timeline key's style: a name, or a mix written with '+' (as on the command line)."""
    return labels_text(style).replace(",", "+")
