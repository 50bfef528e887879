"""Walking that follows a path (`walkdiff walk`) and how well it does (`walkdiff bench walk`).

Path-following error: the mean distance of the generated root (x, z) from the path polyline over all
frames, as a percentage of the distance walked (the length of the path covered). Style accuracy: the
evaluator's style recognition on the generated walk cut into the evaluator's windows.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import torch

from walkdiff.diffusion import SamplerChoice
from walkdiff.errors import WalkdiffError
from walkdiff.files import check_free, output_folder, write_atomic, write_json
from walkdiff.memory import WALK_BYTES_PER_FRAME, check_frames
from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.path import Polyline, read_path
from walkdiff.motion.representation import decode
from walkdiff.motion.skeleton import Motion
from walkdiff.progress import progress, step_hook
from walkdiff.render import PREVIEW_SECONDS, PreviewCap, render_gif


def load_walker(path: str | Path, device: str | torch.device = "cpu"):
    from walkdiff.models.path_walker import PathWalker

    return PathWalker.from_trained(path, "path-walker", device)


def frames_for(path: Polyline, speed: float, fps: float) -> int:
    """Frames to walk the whole path at `speed`."""
    # A hair of tolerance: speeds are float32 tensors and paths converted from metres, so a walk of a
    # whole number of frames may come out a millionth of a frame longer.
    return max(2, math.ceil(path.length / speed * fps - 1e-4) + 1)


def walk_paths(
    model,
    path: Polyline,
    styles: list[int],
    speed: float | None,
    seed: int,
    frames: int | None = None,
    sampler: SamplerChoice | None = None,
) -> tuple[np.ndarray, tuple[np.ndarray, float], np.ndarray]:
    """Raw features (B, F, D), the start pose, and the speeds used (B,): one walk per style id, each frame
    drawn by `sampler` (default DDPM); refused before any work where the path is too long for memory,
    with a progress bar over the frames."""
    style = torch.tensor(styles)
    speeds = model.style_speed[style].cpu() if speed is None else torch.full((len(styles),), float(speed))
    if (speeds <= 0).any():
        raise WalkdiffError("the checkpoint has no walking speed for a style; give --speed")
    frames = frames or max(frames_for(path, float(s), model.spec["fps"]) for s in speeds)
    check_frames("--path", frames, WALK_BYTES_PER_FRAME, len(styles))
    generator = torch.Generator(device=model.device).manual_seed(seed)
    with progress(desc="walking", unit="frame") as bar:
        raw, start = model.generate(path, style, speeds, frames, generator, step_hook(bar), sampler)
    return raw, start, speeds.numpy()


def to_motion(model, raw: np.ndarray, start: tuple[np.ndarray, float]) -> Motion:
    fps = model.spec["fps"]
    return decode(raw, model.skeleton, 1.0 / fps, start_position=start[0], start_heading=start[1])


def path_error(path: Polyline, root_xz: np.ndarray) -> dict[str, float]:
    """How far a root trajectory (F, 2) strays from the path, and how much of the path it covers."""
    distance = path.distance(root_xz)
    covered, _ = path.project(root_xz[-1:])
    walked = float(np.linalg.norm(np.diff(root_xz, axis=0), axis=1).sum())
    return {
        "mean_distance": float(distance.mean()),
        "max_distance": float(distance.max()),
        "distance_walked": walked,
        "error_percent": float(100 * distance.mean() / max(walked, 1e-9)),
        "path_covered_percent": float(100 * covered[0] / path.length),
    }


def plot_paths(out: str | Path, panels: list[tuple[str, Polyline, list[tuple[str, np.ndarray]]]]) -> Path:
    """Top-down plot per path: the path and each walk's root trajectory."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 4), squeeze=False)
    for ax, (title, path, walks) in zip(axes[0], panels, strict=True):
        ax.plot(path.points[:, 0], path.points[:, 1], color="black", lw=3, alpha=0.3, label="path")
        for label, xz in walks:
            ax.plot(xz[:, 0], xz[:, 1], lw=1, label=label)
        ax.set_aspect("equal", adjustable="datalim")  # a straight path keeps a readable panel width
        ax.set_title(title)
        ax.set_xlabel("x")
        ax.set_ylabel("z")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="center right")
    fig.tight_layout(rect=(0, 0, 0.9, 1))
    written = write_atomic(out, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)
    return written


def walk(
    ckpt: str,
    style: str,
    path: str,
    out: str,
    speed: float | None = None,
    seed: int = 0,
    gif: bool = True,
    preview_seconds: float = PREVIEW_SECONDS,
    overwrite: bool = False,
    sampler: str = "ddpm",
    steps: int | None = None,
    eta: float = 0.0,
) -> dict:
    """`walkdiff walk`: a BVH (+ a GIF of its first `preview_seconds` and a top-down plot) of the style
    walking along the path file, each frame drawn by the sampler (`SamplerChoice`)."""
    choice = SamplerChoice(sampler, steps, eta)
    cap = PreviewCap(preview_seconds) if gif else None
    model = load_walker(ckpt)
    styles = list(model.spec["styles"])
    if style not in styles:
        raise WalkdiffError(f"unknown style {style!r}; valid: {', '.join(styles)}")
    if speed is not None and not 0 < speed < math.inf:
        raise WalkdiffError(f"--speed must be a positive number of metres per second, got {speed}")
    metres, file_speed = read_path(path)
    unit = model.profile.metres_per_unit
    polyline = Polyline.of(metres.points / unit)  # the model walks in its data's units
    speed = speed or file_speed
    speed = None if speed is None else speed / unit
    out = output_folder(out)
    stem = f"{style}_{Path(path).stem}"
    bvh = out / f"{stem}.bvh"
    written = [bvh, out / f"{stem}_path.png", out / f"{stem}.json"]
    check_free(written + ([bvh.with_suffix(".gif"), bvh.with_suffix(".mp4")] if gif else []), overwrite)
    out.mkdir(parents=True, exist_ok=True)

    started = time.perf_counter()
    raw, start, speeds = walk_paths(model, polyline, [styles.index(style)], speed, seed, sampler=choice)
    elapsed = time.perf_counter() - started
    motion = to_motion(model, raw[0], start)
    root_xz = motion.root_positions[:, [0, 2]]
    write_bvh(bvh, model.to_file(motion))
    files = [bvh, plot_paths(out / f"{stem}_path.png", [(stem, metres, [(style, root_xz * unit)])])]
    if cap is not None:
        skeleton = model.skeleton
        positions = motion_world_positions(motion.slice(0, cap.frames(motion.num_frames, motion.fps)))
        gif = render_gif(
            out / f"{stem}.gif", [positions], skeleton.parents, motion.fps, names=skeleton.names, cap=cap,
            video=True,
        )  # fmt: skip
        files += [gif, gif.with_suffix(".mp4")]
    manifest = {
        "checkpoint": str(ckpt),
        "style": style,
        "path": str(path),
        "path_length_m": metres.length,
        "speed_m_s": float(speeds[0]) * unit,
        "seed": seed,
        "sampler": choice.label(model.diffusion),
        "frames": motion.num_frames,
        "seconds": motion.num_frames / motion.fps,
        "generation_seconds": round(elapsed, 2),
        "path_error_m": path_error(metres, root_xz * unit),
        "files": [str(f) for f in files],
        "preview": None if cap is None else cap.describe(motion.num_frames, motion.fps),
    }
    write_json(out / f"{stem}.json", manifest)
    return manifest


# ---------------------------------------------------------------- benchmark


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
    from walkdiff.evaluation import load_evaluator

    model = load_walker(ckpt)
    scorer = load_evaluator(evaluator)
    styles = list(range(len(model.spec["styles"])))
    scale = float(model.style_speed.mean())
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
            walks.append((model.spec["styles"][style], root_xz))
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
        panels.append((name, polyline, walks))
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
