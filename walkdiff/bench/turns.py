"""`walkdiff bench turns`: labels that name a side turn that way.

A content label that names a side (`walk-turn-left`, `walk_rturn_s1`; `walkdiff.data.laterality`) must
turn to it: a clip sampled with a left label turns to the body's left (its heading, summed over the
clip, grows to the left), a right label to the right; a transfer of a turning test clip into another
style, conditioned on the clip's own content label, keeps the clip's direction of turn. With mirrored
training copies whose labels were not swapped, both would fail silently: each label would learn both
directions (issue 32).

Rows, per lateral label (and per style inside it): the share of sampled clips turning the label's way
(target 95%), their median turn in degrees; the share of transfers keeping the source's direction
(target 95%); and what the model learned from: the share of the training windows of the label (mirrored
copies included, as training sees them) that turn its way, and of its whole training clips. Per label
that names no side (`walk`), the median absolute turn of a window sampled beside that of its training
windows: a plain walk should not drift more than real plain walks do.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from walkdiff.bench.measure import machine
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import strict_json, write_json
from walkdiff.common.progress import progress
from walkdiff.data.laterality import side_of
from walkdiff.motion.representation import FeatureLayout, encode

HEADING = FeatureLayout.heading_vel.start  # radians per frame, positive to the body's left
TARGET = 0.95
SIGN = {"left": 1.0, "right": -1.0}


def turn_degrees(features: np.ndarray) -> float:
    """Degrees a clip turns to the body's left (negative: right), from its features (F, D)."""
    return float(np.degrees(np.asarray(features)[:, HEADING].sum()))


def take_features(take) -> np.ndarray:
    """A `Take`'s features (F, D) on its model's skeleton, as training encodes clips."""
    return encode(take.canonical(), take.profile)


def window_turns(features: np.ndarray, window: int) -> list[float]:
    """Degrees turned by each window of a clip's features (F, D), windows half a window apart."""
    starts = range(0, len(features) - window + 1, max(1, window // 2))
    return [turn_degrees(features[s : s + window]) for s in starts]


def _share(turns: list[float], side: str) -> float:
    return float(np.mean([SIGN[side] * t > 0 for t in turns])) if turns else float("nan")


def _row(turns: list[float], side: str) -> dict:
    return {
        "share": round(_share(turns, side), 4),
        "count": len(turns),
        "median_deg": round(float(np.median(turns)), 1) if turns else None,
    }


def bench_turns(
    ckpt: str | Path,
    out: str | Path,
    num: int = 8,
    frames: int | None = None,
    seed: int = 0,
    sampler: str = "ddim",
    steps: int | None = None,
    strength: float = 0.6,
    root: str | None = None,
) -> dict:
    """Every lateral content label of a styled generator `ckpt` measured (see the module docstring):
    `num` clips of `frames` frames (default two windows) per label and style, transfers of the test
    split's clips of those labels into every other style at `strength`. Writes the JSON `out`."""
    from walkdiff.api import load
    from walkdiff.common.checkpoints import read_checkpoint
    from walkdiff.data.datamodule import MotionDataModule, data_settings

    started = time.perf_counter()
    model = load(ckpt)
    if not hasattr(model, "transfer"):
        raise WalkdiffError("bench turns: expected a styled generator checkpoint", path=ckpt)
    lateral = {c: side_of(c) for c in model.contents if side_of(c) in SIGN}
    if not lateral:
        raise WalkdiffError(
            f"bench turns: no content label names a side (labels: {', '.join(model.contents)}); "
            "train on clips labelled e.g. walk-turn-left / walk-turn-right",
            path=ckpt,
        )
    spec = model.model.spec
    window = int(spec["window"])
    frames = frames or 2 * window
    data = MotionDataModule(**data_settings(read_checkpoint(ckpt, "generator", mmap=False), root=root))
    groups = data.source.groups
    result: dict = {
        "benchmark": "turns",
        "checkpoint": str(ckpt),
        "settings": {
            "num": num,
            "frames": frames,
            "fps": spec["fps"],
            "sampler": sampler,
            "steps": steps,
            "seed": seed,
            "strength": strength,
        },
        "targets": {
            "sampled": f">= {TARGET:.0%} of clips turn the label's way",
            "transfers": f">= {TARGET:.0%} keep the source's direction",
        },
        "labels": {},
    }
    train = [(info, f) for info, _, f in data.split_features("train", mirrored=True)]
    result["no_side"] = {}
    for content in model.contents:
        own = [f for info, f in train if groups[info.content] == content]
        sampled = {
            style: [
                take_features(t)
                for t in model.sample(style, content, num=num, frames=frames, seed=seed, sampler=sampler,
                                      steps=steps)
            ]
            for style in progress(model.styles, desc=f"sample {content}", unit="style")
        }  # fmt: skip
        side = lateral.get(content)
        if side is None:
            result["no_side"][content] = _straight_row(own, sampled, window)
            continue
        windows = [t for f in own for t in window_turns(f, window)]
        row = {
            "side": side,
            "training_windows": _row(windows, side),
            "training_clips": _row([turn_degrees(f) for f in own], side),
            "sampled": {
                style: _row([turn_degrees(f) for f in clips], side) for style, clips in sampled.items()
            },
        }
        pooled = [turn_degrees(f) for clips in sampled.values() for f in clips]
        row["sampled_all"] = {**_row(pooled, side), "pass": _share(pooled, side) >= TARGET}
        row["transfers"] = _transfers(model, data, content, groups, strength, seed, sampler, steps)
        result["labels"][content] = row
    result["machine"] = machine()
    result["seconds"] = round(time.perf_counter() - started, 1)
    write_json(out, strict_json(result))
    return result


def _straight_row(training: list[np.ndarray], sampled: dict, window: int) -> dict:
    """A label that names no side should not turn more than its training windows do: the median absolute
    turn of a window, sampled and in training."""
    real = [abs(t) for f in training for t in window_turns(f, window)]
    made = [abs(t) for clips in sampled.values() for f in clips for t in window_turns(f, window)]
    return {
        "sampled_window_abs_deg": round(float(np.median(made)), 1) if made else None,
        "training_window_abs_deg": round(float(np.median(real)), 1) if real else None,
        "sampled_windows": len(made),
        "training_windows": len(real),
    }


def _transfers(model, data, content: str, groups, strength, seed, sampler, steps) -> dict:
    """Each test clip of `content` into every other style: does it turn as the source does?"""
    kept, rows = [], []
    tests = [(info, f) for info, _, f in data.split_features("test") if groups[info.content] == content]
    for info, features in progress(tests, desc=f"transfer {content}", unit="clip"):
        source = turn_degrees(features)
        own = model.styles[info.style] if model.styles else None
        for style in model.styles:
            if style == own:
                continue
            take = model.transfer(
                info.path, style, content, strength=strength, seed=seed, sampler=sampler, steps=steps
            )
            turned = turn_degrees(take_features(take))
            kept.append(np.sign(turned) == np.sign(source))
            rows.append({"clip": info.name, "style": style, "source_deg": round(source, 1),
                         "transfer_deg": round(turned, 1)})  # fmt: skip
    share = float(np.mean(kept)) if kept else float("nan")
    return {"share_kept": round(share, 4), "count": len(kept), "pass": bool(kept) and share >= TARGET,
            "rows": rows}  # fmt: skip


def format_turns(result: dict) -> list[str]:
    lines = [f"bench turns: {result['checkpoint']} ({result['seconds']} s)"]
    for content, row in result["labels"].items():
        sampled, moved, side = row["sampled_all"], row["transfers"], row["side"]
        lines.append(
            f"  {content} ({side}): sampled {sampled['share']:.1%} of {sampled['count']} turn {side}"
            f" (median {sampled['median_deg']} deg){'' if sampled['pass'] else ' !'}; transfers keep the"
            f" turn {moved['share_kept']:.1%} of {moved['count']}{'' if moved['pass'] else ' !'}; training"
            f" windows {row['training_windows']['share']:.1%}, clips {row['training_clips']['share']:.1%}"
        )
    for content, row in result["no_side"].items():
        lines.append(
            f"  {content} (no side): median turn of a window {row['sampled_window_abs_deg']} deg sampled,"
            f" {row['training_window_abs_deg']} deg in training"
        )
    return lines
