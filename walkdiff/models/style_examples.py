"""Style from example clips (`--style-clip FILE[:WEIGHT],...`, `style_clips=`), alone or mixed with labels.

A model trained with a style encoder (`model.style_code_dim > 0`, models/style_encoder.py) turns each
clip into a unit code: the clip is read as `transfer` reads its input (the model's skeleton, any frame
rate), cut into windows half a window apart, and the direction of the mean of their codes is its code.
A request's style is then the direction of the weighted sum of the labels' stored codes (the `--style`
part counts as weight 1) and the clips' codes (weight 1 each unless given). The clips' windows also give
their pose statistics, which sampling matches (`--match-clips`, models/style_statistics.py) in proportion
to the clips' share of the weight.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from walkdiff.common.errors import WalkdiffError
from walkdiff.models.pipeline import Pipeline
from walkdiff.models.style_statistics import StyleStatistics
from walkdiff.motion.representation import encode
from walkdiff.motion.skeleton import Motion

# How far a sample's pose statistics are moved to its example clips' (models/style_statistics.py): all the
# way, because a code alone gives a style never seen in training as the nearest seen one (bench style).
MATCH_CLIPS = 1.0


@dataclass(frozen=True)
class StyleExample:
    """One example clip: where it came from, its weight, and its code once encoded."""

    source: str
    weight: float
    code: tuple[float, ...] = ()

    def record(self) -> dict:
        return {"clip": self.source, "weight": self.weight, "code": [round(c, 5) for c in self.code]}


def clip_name(clip) -> str:
    """How errors and manifests name an example clip: its path, or what it is."""
    return str(clip) if isinstance(clip, str | os.PathLike) else "the example clip"


def check_match_clips(value: float) -> None:
    """--match-clips is a share in [0, 1]."""
    if not (np.isfinite(value) and 0 <= value <= 1):
        raise WalkdiffError(f"--match-clips must be in [0, 1] (0: the clips' code alone), got {value:g}")


def parse_style_clips(text: str | list) -> list[tuple[str | Motion, float]]:
    """'a.bvh:0.7,b.bvh' (or a list of paths, Motions, or (clip, weight) pairs) -> [(clip, weight)]."""
    items = text.split(",") if isinstance(text, str) else list(text)
    out = []
    for item in items:
        if isinstance(item, tuple):
            clip, weight = item
        elif isinstance(item, str | os.PathLike):
            clip, weight = _path_and_weight(str(item).strip())
        else:
            clip, weight = item, 1.0
        if not (np.isfinite(weight) and weight > 0):
            raise WalkdiffError(f"--style-clip: expected FILE or FILE:WEIGHT with weights > 0, got {item!r}")
        out.append((clip, float(weight)))
    if not out:
        raise WalkdiffError("--style-clip: expected one or more BVH files (FILE[:WEIGHT],...)")
    return out


def _path_and_weight(item: str) -> tuple[str, float]:
    path, _, weight = item.rpartition(":")
    if path and not Path(item).exists():
        try:
            return path, float(weight)
        except ValueError:
            pass
    return item, 1.0


def example_windows(model, motion: Motion, where: str) -> torch.Tensor:
    """Normalised windows (N, window, D) of a canonical clip at the model's fps, half a window apart."""
    window = model.spec["window"]
    if motion.num_frames < window:
        fps = model.spec["fps"]
        raise WalkdiffError(
            f"--style-clip: {motion.num_frames} frames at the model's {fps:g} fps; a style example needs at "
            f"least one {window}-frame window ({window / fps:.2f} s)",
            path=where,
        )
    features = model.normalizer.normalize(torch.from_numpy(encode(motion, model.profile)))
    starts = range(0, motion.num_frames - window + 1, max(1, window // 2))
    return torch.stack([features[s : s + window] for s in starts]).float().to(model.device)


def mixed_code(weighted: list[tuple[torch.Tensor, float]]) -> torch.Tensor:
    """The direction of the weighted sum of codes (code_dim,)."""
    total = sum(w * code for code, w in weighted)
    return F.normalize(total, dim=0)


def label_code(model, style: torch.Tensor) -> torch.Tensor:
    """The stored code (code_dim,) of a style id or mixing weights (what sampling by label uses)."""
    return model.ema.module.style.as_codes(style[None])[0]


def clips_record(style_clips) -> list[dict]:
    """What a manifest records of example clips: each one's path (or "a Motion") and weight; [] for none."""
    if not style_clips:
        return []
    return [
        {"clip": str(c) if isinstance(c, str | os.PathLike) else "a Motion", "weight": w}
        for c, w in parse_style_clips(style_clips)
    ]


def clip_statistics(model, style_clips, match_clips: float = MATCH_CLIPS) -> StyleStatistics | None:
    """The example clips' pose statistics ('a.bvh:0.7,b.bvh', or a list of paths, Motions or (clip,
    weight) pairs), weighted, matched at `match_clips`; None without clips. For a model with no style
    encoder (the path walker) the clips give posture and swing, its style is still the label's."""
    if not style_clips:
        return None
    check_match_clips(match_clips)
    weighted = []
    for clip, weight in parse_style_clips(style_clips):
        where = clip_name(clip)
        windows = example_windows(model, Pipeline(model).source(clip, "--style-clip"), where)
        weighted.append((StyleStatistics.of(windows), weight))
    return StyleStatistics.mixed(weighted, match_clips)
