"""`walkdiff bench walk`: a walker over benchmark paths, how closely it follows them and whether its style is
recognised."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.files import write_json
from walkdiff.evaluation.scorer import load_evaluator
from walkdiff.motion.path import Polyline, frames_for
from walkdiff.walker.follow import load_walker, path_error, to_motion, walk_paths
from walkdiff.walker.plots import plot_paths


def benchmark_paths(scale: float) -> dict[str, Polyline]:
    """Paths of every kind of turn, sized by `scale` (a walking speed times one second)."""
    u = np.linspace(0, 1, 200)
    return {
        "straight": Polyline.of(np.stack([np.zeros(2), [0.0, 8 * scale]])),
        "circle": Polyline.of(
            2 * scale * np.stack([1 - np.cos(2 * np.pi * u), np.sin(2 * np.pi * u)], axis=-1)
        ),
        "s_curve": Polyline.of(np.stack([1.5 * scale * np.sin(2 * np.pi * u), 9 * scale * u], axis=-1)),
        "square": Polyline.of(3 * scale * np.array([[0, 0], [0, 1], [1, 1], [1, 0], [0, 0]], dtype=float)),
    }


def style_accuracy(scorer, raws: list[np.ndarray], styles: list[int], window: int) -> float:
    """The evaluator's style recognition over non-overlapping windows of each walk."""
    windows, labels = [], []
    for raw, style in zip(raws, styles, strict=True):
        for begin in range(0, raw.shape[0] - window + 1, window):
            windows.append(raw[begin : begin + window])
            labels.append(style)
    positions = scorer.raw_positions(torch.from_numpy(np.stack(windows)).double()).float()
    logits = scorer.classify(positions)[0]
    return float((logits.argmax(-1).cpu() == torch.tensor(labels)).double().mean())


def bench_walk(out: str, ckpt: str, evaluator: str, seed: int = 0) -> dict:
    """Every style along every test path: path-following error, style accuracy, a plot of the paths."""
    model = load_walker(ckpt)
    scorer = load_evaluator(evaluator)
    styles = list(range(len(model.spec["styles"])))
    scale = float(model.style_speed.mean())
    unit = model.profile.metres_per_unit  # the plot is in metres
    rows, panels = {}, []
    for name, polyline in benchmark_paths(scale).items():
        started = time.perf_counter()
        raw, start, speeds = walk_paths(model, polyline, styles, None, seed)
        elapsed = time.perf_counter() - started
        walks, errors, scored = [], [], []
        for style, features, speed in zip(styles, raw, speeds, strict=True):
            # Each style walks at its own pace: its walk is scored until it is due at the path's end.
            frames = frames_for(polyline, float(speed), model.spec["fps"])
            scored.append(features[:frames])
            root_xz = to_motion(model, features[:frames], start).root_positions[:, [0, 2]]
            errors.append(path_error(polyline, root_xz))
            walks.append((model.spec["styles"][style], root_xz * unit))
        rows[name] = {
            "length": polyline.length,
            "frames": raw.shape[1],
            "error_percent": float(np.mean([e["error_percent"] for e in errors])),
            "worst_error_percent": float(np.max([e["error_percent"] for e in errors])),
            "max_distance": float(np.max([e["max_distance"] for e in errors])),
            "path_covered_percent": float(np.mean([e["path_covered_percent"] for e in errors])),
            "style_accuracy": style_accuracy(scorer, scored, styles, scorer.spec["window"]),
            "seconds_per_frame_8_streams": elapsed / raw.shape[1],
        }
        panels.append((name, Polyline.of(polyline.points * unit), walks))
    plot = plot_paths(Path(out).with_suffix(".png"), panels)
    result = {
        "checkpoint": ckpt,
        "evaluator": evaluator,
        "seed": seed,
        "paths": rows,
        "error_percent": float(np.mean([r["error_percent"] for r in rows.values()])),
        "style_accuracy": float(np.mean([r["style_accuracy"] for r in rows.values()])),
        "plot": str(plot),
    }
    write_json(out, result)
    return result
