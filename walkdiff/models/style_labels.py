"""Styles as users write them: a name, a mix (`angry:0.7,old:0.3`), or a timeline, style that changes
over time (`--style neutral@0,old@4s,proud+angry@8s --transition 1`), for every model with style labels.

A timeline's key is a style (a name, or a mix written with '+': `angry:0.7+old:0.3`) from a time on. Its
conditioning is mixing weights over the training styles (which a model with a style encoder turns into
codes), interpolated linearly between two keys over `transition` seconds centred on the later key. The
window generator denoises every window under the weights at its middle frame (neighbouring windows
differ little and the held overlap carries the motion across); the path walker takes them frame by frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_atomic

DEFAULT_TRANSITION = 1.0  # seconds


def parse_style(model, text: str) -> tuple[torch.Tensor, str]:
    """A style id, or mixing weights from 'angry:0.7,old:0.3' (scaled to sum 1), and a file-name label."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if len(parts) == 1 and ":" not in parts[0]:
        return style_ids(model, parts)[0], parts[0]
    names, weights = [], []
    for part in parts:
        name, _, weight = part.partition(":")
        try:
            value = float(weight) if weight else float("nan")
        except ValueError:
            value = float("nan")
        if not np.isfinite(value) or value <= 0:
            raise WalkdiffError(f"--style: expected NAME or NAME:WEIGHT,... with weights > 0, got {text!r}")
        names.append(name.strip())
        weights.append(value)
    ids = style_ids(model, names)
    mix = torch.zeros(len(model.spec["styles"]), device=model.device)
    mix.index_add_(0, ids, torch.tensor(weights, device=model.device))
    mix /= mix.sum()
    label = "+".join(f"{n}{round(100 * w / sum(weights))}" for n, w in zip(names, weights, strict=True))
    return mix, label


def style_ids(model, names: list[str]) -> torch.Tensor:
    """The ids of style names in the model's vocabulary (`spec["styles"]`), or an error listing it."""
    vocabulary = list(model.spec["styles"])
    unknown = [n for n in names if n not in vocabulary]
    if unknown:
        raise WalkdiffError(f"unknown style {', '.join(unknown)}; valid: {', '.join(vocabulary)}")
    return torch.tensor([vocabulary.index(n) for n in names], device=model.device)


def eased(share: float) -> float:
    """How far along a style change is at `share` of its ramp (0 to 1), eased in and out (smoothstep):
    the change starts and ends at rate 0, so the conditioning's rate of change never jumps, where a linear
    ramp starts at full rate (live-control.md: seams at style switches)."""
    share = min(max(share, 0.0), 1.0)
    return share * share * (3 - 2 * share)


@dataclass(frozen=True)
class StyleTimeline:
    """Keys (seconds, mixing weights over the styles (S,)), the first at 0, and the transition length."""

    times: tuple[float, ...]
    weights: torch.Tensor  # (keys, S)
    names: tuple[str, ...]
    transition: float

    def at(self, seconds: float) -> torch.Tensor:
        """The mixing weights (S,) at a time: a key's from its time on, ramped (`eased`) from the previous
        key's over the transition centred on it."""
        out = self.weights[0]
        for k in range(1, len(self.times)):
            share = (seconds - self.times[k]) / self.transition + 0.5 if self.transition > 0 else 1.0
            if share <= 0:
                break
            share = eased(share)
            out = (1 - share) * self.weights[k - 1] + share * self.weights[k]
        return out

    @property
    def label(self) -> str:
        return "timeline-" + "-".join(n.replace(":", "").replace("+", "_") for n in self.names)

    def record(self) -> dict:
        keys = [{"at_s": t, "style": n} for t, n in zip(self.times, self.names, strict=True)]
        return {"keys": keys, "transition_s": self.transition}

    def check_length(self, seconds: float) -> None:
        late = [f"{n}@{t:g}s" for n, t in zip(self.names, self.times, strict=True) if t >= seconds]
        if late:
            raise WalkdiffError(
                f"--style: {', '.join(late)} starts after the clip ends ({seconds:.2f} s); give more --frames"
            )


def parse_timeline(model, text: str, transition: float = DEFAULT_TRANSITION) -> StyleTimeline | None:
    """`text` as a timeline when it has keys (`STYLE@SECONDS,...`); None for a plain style or mix."""
    if "@" not in text:
        return None
    if not (math.isfinite(transition) and transition >= 0):
        raise WalkdiffError(f"--transition: expected seconds >= 0, got {transition}")
    times, weights, names = [], [], []
    for key in (k.strip() for k in text.split(",")):
        spec, at, when = key.rpartition("@")
        seconds = _seconds(when, key) if at else math.nan
        if not spec or not np.isfinite(seconds) or (times and seconds <= times[-1]):
            raise WalkdiffError(
                f"--style: expected a timeline STYLE@SECONDS,... with times rising from 0 (e.g. "
                f"neutral@0,old@4s; a mix as angry:0.7+old:0.3@8s), got {key!r} in {text!r}"
            )
        style, _ = parse_style(model, spec.replace("+", ","))
        if not style.is_floating_point():
            style = torch.nn.functional.one_hot(style, len(model.spec["styles"])).float()
        times.append(seconds)
        weights.append(style)
        names.append(spec)
    if times[0] != 0:
        raise WalkdiffError(f"--style: the timeline's first key must be at 0, got {names[0]}@{times[0]:g}s")
    spacing = min(np.diff(times), default=math.inf)
    return StyleTimeline(tuple(times), torch.stack(weights), tuple(names), min(transition, spacing))


def _seconds(text: str, key: str) -> float:
    text = text.strip().removesuffix("s")
    try:
        return float(text)
    except ValueError:
        return math.nan


def plot_timeline(path: Path, timeline: StyleTimeline, styles: list[str], seconds: float) -> Path:
    """A PNG of each style's weight over the clip: what the preview's walker was asked to be when."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grid = np.linspace(0, seconds, 200)
    weights = torch.stack([timeline.at(float(t)) for t in grid]).numpy()
    figure, axes = plt.subplots(figsize=(6, 2.2), dpi=100)
    shown = [s for s in range(len(styles)) if weights[:, s].any()]
    for k, s in enumerate(shown):  # line styles tell apart styles that share a weight
        axes.plot(grid, weights[:, s], label=styles[s], ls=("-", "--", "-.", ":")[k % 4], lw=1.8)
    for t in timeline.times[1:]:
        axes.axvline(t, color="grey", lw=0.5, ls=":")
    axes.set(xlabel="seconds", ylabel="weight", ylim=(-0.05, 1.05), xlim=(0, seconds))
    axes.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    figure.tight_layout()
    written = write_atomic(path, lambda f: figure.savefig(f, format="png"))
    plt.close(figure)
    return written
