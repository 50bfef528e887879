"""Labels that know left from right: what a mirrored training copy is labelled.

Mirroring a clip (`data.mirror`) swaps its left and right sides: a left turn becomes a right turn, a
left-handed punch a right-handed one, a clockwise circle an anticlockwise one. A label that names a side
must swap with it, or the mirrored copies teach the model that `walk-turn-left` turns both ways.

A label is *lateral* when one of its tokens names a side. Tokens are the runs of letters (and the digits
that follow them) between separators (`_`, `-`, space, `.`, ...) and at camelCase boundaries, so
`walkTurnLeft` is walk / Turn / Left and `walk_l1` is walk / l1. Sides, in any case:

- `left` / `right`, and `l` / `r` as a whole token (`punch_l`, `Walk-L`; not `walk_l1`, `stroll`,
  `bright`, `upright`: those are not tokens that name a side);
- a side glued to a motion word, before or after it: `lturn` / `rturn`, `LTurn`, `leftturn`, `turnleft`,
  `rstep`, `lkick` (the words in `_GLUED`);
- the sense of a rotation: `cw` / `ccw`, `clockwise` / `counterclockwise` (or `anticlockwise`).

Its *partner* is the label with every side swapped, spelled as the label spells it (`walk_lturn_s1` ->
`walk_rturn_s1`, `Turn-Left` -> `Turn-Right`), else the one label of the same kind (style or content)
that says the same with sides swapped in another spelling (`turn_left` -> `turn_R`).

`data.mirror_labels` ({label: partner}) overrides what the names say: a partner of the same kind, the
label itself (not lateral: its copies keep it) or null (no partner: its copies are left out). A pair given
one way holds both ways.

A lateral label without a partner among the labels (`walk-turn-left` but no `walk-turn-right`) drops the
mirrored copies of its clips from training, with a warning that names it and the fix: a copy labelled
with itself would be a right turn called left, and a label that no clip has cannot be trained on or
scored. The clips themselves train as they are; only their mirrored copies are left out.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace

from walkdiff.common.errors import WalkdiffError
from walkdiff.data.clips import ClipInfo

OPTION = "data.mirror_labels"
KINDS = ("style", "content")
# Tokens: a capitalised or lower-case word, or an upper-case run (not the capital of a next word), each
# with the digits that follow it; or digits alone.
_TOKEN = re.compile(r"[A-Z]?[a-z]+[0-9]*|[A-Z]+[0-9]*(?![a-z])|[0-9]+")
_SIDES = {"left": "right", "right": "left", "l": "r", "r": "l"}
_SENSES = {
    "cw": "ccw", "ccw": "cw", "clockwise": "counterclockwise", "counterclockwise": "clockwise",
    "anticlockwise": "clockwise",
}  # fmt: skip
_CANONICAL = {
    "left": "left", "l": "left", "right": "right", "r": "right", "cw": "cw", "clockwise": "cw",
    "ccw": "ccw", "counterclockwise": "ccw", "anticlockwise": "ccw",
}  # fmt: skip
_OPPOSITE = {"left": "right", "right": "left", "cw": "ccw", "ccw": "cw"}
# Motion words a side may be glued to (`lturn`, `turnleft`).
_GLUED = (
    "turn", "turns", "turning", "step", "steps", "side", "sidestep", "kick", "punch", "hook", "jab", "hand",
    "foot", "leg", "arm", "spin", "pivot", "curve", "circle", "hop", "lean", "strafe", "cross", "swing",
)  # fmt: skip
_GLUED_SIDE = re.compile(rf"^(?:(left|right|l|r)({'|'.join(_GLUED)})|({'|'.join(_GLUED)})(left|right|l|r))$")


def _cased(word: str, like: str) -> str:
    """`word` in the case of `like`: UPPER, Capitalised or lower."""
    if like.isupper() and (len(like) > 1 or len(word) == 1):
        return word.upper()
    if like[:1].isupper():
        return word[:1].upper() + word[1:]
    return word


def _token_side(token: str) -> tuple[str, int, int] | None:
    """(side word as written, start, end) inside `token` when it names a side, else None."""
    lower = token.lower()
    if lower in _SIDES or lower in _SENSES:
        return token, 0, len(token)
    match = _GLUED_SIDE.match(lower)
    if match is None:
        return None
    group = 1 if match.group(1) else 4
    start, end = match.span(group)
    return token[start:end], start, end


def _swap_word(word: str) -> str:
    lower = word.lower()
    opposite = _SIDES.get(lower) or _SENSES[lower]
    return _cased(opposite, word)


def lateral_tokens(label: str) -> list[str]:
    """The side words of `label` as written (empty: not lateral), e.g. ['lturn'] -> ['l']."""
    return [side[0] for m in _TOKEN.finditer(label) if (side := _token_side(m.group())) is not None]


def side_of(label: str) -> str | None:
    """The side a label names, "left" or "right" (a sense of rotation as seen from above: clockwise is
    to the right), or None when it names none or both."""
    sides = {_CANONICAL[word.lower()] for word in lateral_tokens(label)}
    sides = {{"cw": "right", "ccw": "left"}.get(side, side) for side in sides}
    return sides.pop() if len(sides) == 1 else None


def mirrored_name(label: str) -> str | None:
    """`label` with every side swapped in its own spelling, or None when it names no side."""
    out, last, lateral = [], 0, False
    for match in _TOKEN.finditer(label):
        side = _token_side(match.group())
        if side is None:
            continue
        word, start, end = side
        at = match.start() + start
        out += [label[last:at], _swap_word(word)]
        last, lateral = match.start() + end, True
    return "".join(out) + label[last:] if lateral else None


def _canonical(label: str, mirror: bool = False) -> tuple[str, ...]:
    """Lower-case tokens with sides spelled one way (`lturn` -> left, turn); sides swapped if `mirror`."""
    tokens: list[str] = []
    for match in _TOKEN.finditer(label):
        token = match.group().lower()
        side = _token_side(token)
        if side is None:
            tokens.append(token)
            continue
        word, start, end = side
        canonical = _CANONICAL[word]
        canonical = _OPPOSITE[canonical] if mirror else canonical
        rest = token[:start] + token[end:]
        tokens += [canonical, rest] if start == 0 and rest else [rest, canonical] if rest else [canonical]
    return tuple(tokens)


def find_partner(label: str, names: tuple[str, ...]) -> tuple[str | None, str]:
    """(partner among `names` or None, the name looked for) of a lateral label (see the module docstring)."""
    spelled = mirrored_name(label)
    assert spelled is not None, f"{label!r} is not lateral"
    if spelled in names:
        return spelled, spelled
    wanted = _canonical(label, mirror=True)
    found = [n for n in names if n != label and _canonical(n) == wanted]
    if len(found) > 1:
        raise WalkdiffError(
            f"{OPTION}: the mirrored copies of {label!r} could be labelled {' or '.join(map(repr, found))}: "
            f"name its partner, e.g. {OPTION}: {{{label}: {found[0]}}}"
        )
    return (found[0] if found else None), spelled


@dataclass(frozen=True)
class LabelSwap:
    """What the mirrored copies of one lateral label (or one given in data.mirror_labels) are labelled."""

    kind: str  # style or content
    label: str
    partner: str | None  # None: no partner, its mirrored copies are left out
    given: bool  # from data.mirror_labels, not from the name
    looked_for: str = ""  # the partner's name the label's own spelling gives (for the advice)
    unselected: bool = False  # the partner is a label, but not among data.contents

    def describe(self) -> str:
        how = f" ({OPTION})" if self.given else ""
        if self.partner == self.label:
            return f"{self.kind} {self.label}: kept ({OPTION}: not lateral)"
        if self.partner is not None:
            return f"{self.kind} {self.label} -> {self.partner}{how}"
        if self.given:
            return f"{self.kind} {self.label}: no partner ({OPTION}): its mirrored copies are left out"
        where = (
            f"{self.kind} {self.looked_for!r} is not in data.contents"
            if self.unselected
            else f"no {self.kind} {self.looked_for!r} among the labels"
        )
        return (
            f"{self.kind} {self.label}: {where}: its mirrored copies are left out (a mirrored "
            f"{self.label} is not a {self.label}); {self.fix()}"
        )

    def fix(self) -> str:
        return (
            f"name its partner with {OPTION} {{{self.label}: PARTNER}} (data scan: --mirror-labels "
            f"{self.label}=PARTNER), or {{{self.label}: {self.label}}} if it is not lateral"
        )


@dataclass(frozen=True)
class MirrorLabels:
    """Label index -> the mirrored copy's label index (None: no copy), per kind; the lateral labels."""

    styles: tuple[int | None, ...]
    contents: tuple[int | None, ...]
    swaps: tuple[LabelSwap, ...]

    @classmethod
    def unchanged(cls, styles: int, contents: int) -> MirrorLabels:
        """Every label kept (no mirroring, or nothing lateral)."""
        return cls(tuple(range(styles)), tuple(range(contents)), ())

    def mirrored(self, clip: ClipInfo) -> ClipInfo | None:
        """The labels of `clip`'s mirrored copy, or None when the copy is left out."""
        style, content = self.styles[clip.style], self.contents[clip.content]
        if style is None or content is None:
            return None
        if (style, content) == (clip.style, clip.content):
            return clip
        return replace(clip, style=style, content=content)

    @property
    def swapped(self) -> tuple[LabelSwap, ...]:
        return tuple(s for s in self.swaps if s.partner not in (None, s.label))

    @property
    def unpaired(self) -> tuple[LabelSwap, ...]:
        """Lateral labels found from their names without a partner (given ones are not warned about)."""
        return tuple(s for s in self.swaps if s.partner is None and not s.given)

    def describe(self) -> list[str]:
        """One line per lateral label (a pair that swaps both ways: one line, `a <-> b`)."""
        partner = {(s.kind, s.label): s.partner for s in self.swaps}
        lines, done = [], set()
        for s in self.swaps:
            if (s.kind, s.label) in done:
                continue
            back = s.partner not in (None, s.label) and partner.get((s.kind, s.partner)) == s.label
            if back:
                done.add((s.kind, s.partner))
                lines.append(s.describe().replace(" -> ", " <-> ", 1))
            else:
                lines.append(s.describe())
        return lines

    def warning(self) -> str | None:
        """What `fit` warns about: lateral labels whose mirrored copies are left out, and the fix."""
        if not self.unpaired:
            return None
        listing = "; ".join(s.describe() for s in self.unpaired)
        return f"data.mirror: mirrored copies left out of training: {listing}"


def mirror_labels(
    styles: tuple[str, ...],
    contents: tuple[str, ...],
    given: dict | None = None,
    selected: tuple[str, ...] | None = None,
) -> MirrorLabels:
    """The labels of mirrored copies (see the module docstring). `selected`: the contents trained on
    (data.contents); a content partner outside them counts as none."""
    names = {"style": tuple(styles), "content": tuple(contents)}
    chosen = {"style": tuple(styles), "content": tuple(selected if selected is not None else contents)}
    given = _check_given(given, names)
    maps: dict[str, list[int | None]] = {}
    swaps: list[LabelSwap] = []
    for kind in KINDS:
        labels = names[kind]
        out: list[int | None] = list(range(len(labels)))
        for i, label in enumerate(labels):
            if label in given[kind]:
                partner = given[kind][label]
                swap = LabelSwap(kind, label, partner, given=True, looked_for=partner or "")
            elif mirrored_name(label) is not None:
                partner, looked_for = find_partner(label, chosen[kind])
                outside = partner is None and find_partner(label, labels)[0] is not None
                swap = LabelSwap(kind, label, partner, False, looked_for, unselected=outside)
            else:
                continue
            swaps.append(swap)
            out[i] = None if swap.partner is None else labels.index(swap.partner)
        maps[kind] = out
    return MirrorLabels(tuple(maps["style"]), tuple(maps["content"]), tuple(swaps))


def _check_given(given, names: dict[str, tuple[str, ...]]) -> dict[str, dict[str, str | None]]:
    """data.mirror_labels as {kind: {label: partner}}, both ways, or a WalkdiffError naming the entry."""
    out: dict[str, dict[str, str | None]] = {kind: {} for kind in KINDS}
    if given is None:
        return out
    expected = (
        "expected a mapping {label: mirrored label}, the label itself (not lateral) or null (no partner)"
    )
    if not isinstance(given, dict):
        raise WalkdiffError(f"{OPTION}: {expected}, got {type(given).__name__}")
    known = ", ".join(dict.fromkeys(names["style"] + names["content"]))
    for label, partner in given.items():
        if not isinstance(label, str) or not (partner is None or isinstance(partner, str)):
            raise WalkdiffError(f"{OPTION}: {label!r}: {partner!r}: {expected}")
        kinds = [kind for kind in KINDS if label in names[kind]]
        if not kinds:
            raise WalkdiffError(
                f"{OPTION}: unknown label {label!r}: expected a style or content label: {known}"
            )
        for kind in kinds:
            if partner is not None and partner not in names[kind]:
                raise WalkdiffError(
                    f"{OPTION}: {label!r} is a {kind} label and {partner!r} is not: expected one of "
                    f"{', '.join(names[kind])}, or null (no partner)"
                )
            out[kind][label] = partner
    return {kind: _both_ways(mapping, kind) for kind, mapping in out.items()}


def _both_ways(explicit: dict[str, str | None], kind: str) -> dict[str, str | None]:
    """label -> partner and partner -> label; a label mapped two ways is an error."""
    out = dict(explicit)
    for label, partner in explicit.items():
        if partner is None or partner == label:
            continue
        if out.get(partner, label) != label:
            raise WalkdiffError(
                f"{OPTION}: {kind} {partner!r} would be mirrored to both {out[partner]!r} and {label!r}: "
                "mirroring twice must give the label back"
            )
        out[partner] = label
    return out
