"""Walking that follows a path (`walkdiff walk`, `PathFollower`) and how well it does (`bench walk` measures).

Path-following error: the mean distance of the generated root (x, z) from the path polyline over all
frames, as a percentage of the distance walked (the length of the path covered). Style accuracy: the
evaluator's style recognition on the generated walk cut into the evaluator's windows.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError, command, python_api
from walkdiff.common.files import check_free, output_folder, output_set, write_atomic, write_json
from walkdiff.common.memory import WALK_BYTES_PER_FRAME, check_frames
from walkdiff.common.progress import progress, step_hook
from walkdiff.diffusion import SamplerChoice
from walkdiff.models.pipeline import Generated, Pipeline, specs_first
from walkdiff.models.style_examples import MATCH_CLIPS, clip_statistics, clips_record
from walkdiff.models.style_labels import DEFAULT_TRANSITION, StyleTimeline, parse_timeline, plot_timeline
from walkdiff.models.style_spec import Style
from walkdiff.models.style_statistics import StyleStatistics
from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.path import Polyline, checked_polyline, frames_for, read_path
from walkdiff.motion.representation import decode
from walkdiff.motion.skeleton import Motion
from walkdiff.motion.take import Take
from walkdiff.motion.target_rig import TargetRig
from walkdiff.preview.render import PREVIEW_SECONDS, Marks, PreviewCap, render_gif


def load_walker(path: str | Path, device: str | torch.device = "cpu"):
    from walkdiff.models.path_walker import PathWalker

    return PathWalker.from_trained(path, "path-walker", device)


def walk_paths(
    model,
    path: Polyline,
    styles: list[int],
    speed: float | None,
    seed: int,
    frames: int | None = None,
    sampler: SamplerChoice | None = None,
    match: StyleStatistics | None = None,
) -> tuple[np.ndarray, tuple[np.ndarray, float], np.ndarray]:
    """Raw features (B, F, D), the start pose, and the speeds used (B,): one walk per style id (or one walk
    of a `StyleTimeline`), each frame drawn by `sampler` (default DDPM); refused before any work where
    the path is too long for memory, with a progress bar over the frames. `match`: example clips'
    statistics every walk is moved to (`clip_statistics`)."""
    style_at, timeline = None, styles if isinstance(styles, StyleTimeline) else None
    style = torch.tensor(styles) if timeline is None else timeline.at(0.0)[None]
    known = model.style_speed.cpu()
    if timeline is None:
        speeds = known[style] if speed is None else torch.full((len(styles),), float(speed))
    else:  # each frame's style, and its speed: the given one or the styles' own, mixed as they are
        fps, keys = model.spec["fps"], timeline.weights @ known
        speeds = keys.mean()[None] if speed is None else torch.full((1,), float(speed))
        speeds = speeds if speed is not None or (keys > 0).all() else keys.min()[None]

        def style_at(f: int) -> tuple[torch.Tensor, torch.Tensor]:
            weights = timeline.at(f / fps)
            return weights[None], speeds if speed is not None else (weights @ known)[None]

    if (speeds <= 0).any():
        raise WalkdiffError("the checkpoint has no walking speed for a style; give --speed")
    frames = frames or max(frames_for(path, float(s), model.spec["fps"]) for s in speeds)
    check_frames("--path", frames, WALK_BYTES_PER_FRAME, len(style))
    generator = torch.Generator(device=model.device).manual_seed(seed)
    with progress(desc="walking", unit="frame") as bar:
        raw, start = model.generate(
            path, style, speeds, frames, generator, step_hook(bar), sampler, style_at=style_at, match=match
        )
    return raw, start, speeds.numpy()


def to_motion(model, raw: np.ndarray, start: tuple[np.ndarray, float]) -> Motion:
    fps = model.spec["fps"]
    return decode(raw, model.skeleton, 1.0 / fps, start_position=start[0], start_heading=start[1])


def path_in_metres(path: Polyline | str | os.PathLike | list | np.ndarray) -> tuple[Polyline, float | None]:
    """A path as the walker's users give it, in metres: a Polyline, (x, z) points, or a path file (and
    the file's speed in m/s, None if it gives none)."""
    if isinstance(path, Polyline):
        return path, None
    if isinstance(path, str | os.PathLike):
        return read_path(path)
    return checked_polyline(path.tolist() if isinstance(path, np.ndarray) else path), None


@dataclass(frozen=True)
class WalkRequest:
    """What to walk, checked against the model before any path is read: the style as asked and its
    file-name label (a timeline, when it changes), the speed asked (m/s; None: the path file's or the
    style's), the sampler, the example clips' statistics and the rig."""

    spec: Style
    label: str
    timeline: StyleTimeline | None
    speed: float | None
    sampler: SamplerChoice
    match: StyleStatistics | None
    rig: TargetRig | None


class PathFollower(Pipeline):
    """A trained PathWalker: `follow` walks a style along a path and returns the walk as a `Take` on the
    training files' skeleton, writing nothing; `walkdiff walk` writes the same walk for the same seed."""

    @classmethod
    def load(cls, ckpt: str | Path, device: str = "cpu") -> PathFollower:
        return cls(load_walker(ckpt, device))

    @property
    def styles(self) -> tuple[str, ...]:
        return tuple(self.model.spec["styles"])

    @python_api
    def follow(
        self, path: Polyline | str | os.PathLike | list | np.ndarray, style, speed=None, seed=0, **options
    ) -> Generated:
        """`style` walking along `path` ((x, z) points or a Polyline in metres, or a path file) at `speed`
        m/s: by default the file's, else the style's own pace in the training data. `style` may be a
        timeline ('neutral@0,old@4s' or [(0, 'neutral'), (4, 'old')], ramped over `transition` s).
        `options`, as `request` takes them: the sampler (sampler, steps, eta), `to` (+ `to_map`), a rig to
        play it on (its root path is then the walk's scaled by the legs' length ratio), `transition`, and
        `style_clips`: example clips whose pose statistics the walk takes on as well, at `match_clips`
        (docs/walking.md). The result reads as its one take."""
        return self.walk(self.request(style, speed, **options), path, seed)

    @python_api
    def stream(self, style, speed: float | None = None, seed: int = 0, **options) -> PathStream:
        """A walk along a path whose points arrive over time (`PathStream`: feed it (x, z) points in
        metres): one style (no timeline), at `speed` m/s (None: the style's own); `options` as
        `request`'s, no rig (the live poses are on the model's skeleton)."""
        return PathStream(self, self.request(style, speed, **options), seed)

    @python_api
    def request(
        self,
        style,
        speed: float | None = None,
        sampler: str | SamplerChoice | dict = "ddpm",
        steps: int | None = None,
        eta: float = 0.0,
        to: TargetRig | str | os.PathLike | Motion | None = None,
        to_map=None,
        transition: float = DEFAULT_TRANSITION,
        style_clips=None,
        match_clips: float = MATCH_CLIPS,
    ) -> WalkRequest:
        """What `follow` will walk, checked against the model before any path is read."""
        spec = Style.of(style, style_clips, match_clips, transition)
        choice = SamplerChoice.of(sampler, steps, eta).unguided()
        rig = TargetRig.of(to, to_map)
        if spec.labels is None:
            raise WalkdiffError("no style given: pass --style NAME (the walker's style is a label's)")
        self.check(spec.labels, speed)
        match = clip_statistics(self.model, spec.clips, spec.match)
        timeline = parse_timeline(self.model, spec.labels, spec.transition)
        label = spec.labels if timeline is None else timeline.label
        return WalkRequest(spec, label, timeline, speed, choice, match, rig)

    def walk(self, request: WalkRequest, path, seed: int = 0) -> Generated:
        """`follow`'s work on a checked request: the take, and what the manifest records of it."""
        metres, file_speed = path_in_metres(path)
        started = time.perf_counter()
        speed = file_speed if request.speed is None else request.speed
        motion, speed_m_s = self.walk_along(
            metres, request.spec.labels, speed, seed, request.sampler, request.spec.transition, request.match
        )
        elapsed = time.perf_counter() - started
        take, scale = self.take(motion), 1.0  # on a rig: the model's path times the legs' ratio in metres
        if request.rig is not None:
            scale = request.rig.retargeter(take.motion, take.profile).metric_leg_ratio
            take = take.retarget(request.rig)
        clips = request.spec.clips
        settings = {
            "style": request.spec.labels,
            "style_clips": clips_record(clips),
            "match_clips": request.spec.match if clips else None,
            "path": str(path) if isinstance(path, str | os.PathLike) else "points",
            "path_length_m": metres.length,
            "speed_m_s": speed_m_s,
            "seed": seed,
            "sampler": request.sampler.label(self.model.diffusion),
            "frames": motion.num_frames,
            "seconds": motion.num_frames / motion.fps,
            "generation_seconds": round(elapsed, 2),
            "path_error_m": path_error(
                metres, motion.root_positions[:, [0, 2]] * self.model.profile.metres_per_unit
            ),
            "timeline": None if request.timeline is None else request.timeline.record(),
        }
        timing = {"generation_seconds": round(elapsed, 2)}
        extra = {"metres": metres, "scale": scale, "timeline": request.timeline}
        return Generated(
            [take], settings, timing, seed=seed, rig=request.rig, label=request.label, extra=extra
        )

    def controller(self, style=None, speed: float | None = None, seed: int = 0, **options):
        """A `WalkController` (walkdiff/autoregressive/controller.py): `step(direction, speed)` makes the
        next frame of `characters` walkers starting as `style` (a name, a mix or weights; None: the
        model's first style with a known speed) at `speed` m/s (None: the style's own). Default sampler
        DDIM 10 steps, eta 1 (docs/live-control.md); `options`: sampler, steps, eta, characters,
        transition, turn_rate, heading_assist, foot_lock, positions, headings, record, style_clips and
        match_clips (example clips whose posture and swing the walkers take on)."""
        from walkdiff.autoregressive.controller import controller

        return controller(self.model, style, speed, seed, **options)

    def check(self, style: str, speed: float | None) -> int:
        """The style's index (-1 for a timeline), once the style and the speed (m/s, None: the style's
        own) are valid."""
        if speed is not None and not 0 < speed < math.inf:
            raise WalkdiffError(f"--speed must be a positive number of metres per second, got {speed}")
        if parse_timeline(self.model, style) is not None:
            return -1
        if style not in self.styles:
            raise WalkdiffError(f"unknown style {style!r}; valid: {', '.join(self.styles)}")
        return self.styles.index(style)

    def walk_along(
        self,
        metres: Polyline,
        style: str,
        speed: float | None,
        seed: int,
        choice: SamplerChoice,
        transition: float = DEFAULT_TRANSITION,
        match: StyleStatistics | None = None,
    ) -> tuple[Motion, float]:
        """The canonical walk of `style` along a path in metres at `speed` m/s (None: the style's own),
        and the speed it walked at in m/s."""
        timeline = parse_timeline(self.model, style, transition)
        index = self.check(style, speed) if timeline is None else timeline
        unit = self.model.profile.metres_per_unit
        polyline = Polyline.of(metres.points / unit)  # the model walks in its data's units
        speed = None if speed is None else speed / unit
        styles = [index] if timeline is None else timeline
        raw, start, speeds = walk_paths(
            self.model, polyline, styles, speed, seed, sampler=choice, match=match
        )
        return to_motion(self.model, raw[0], start), float(speeds[0]) * unit


class PathStream:
    """`PathFollower.stream`'s: a walk along a path whose points arrive over time. `feed` (x, z) points in
    metres, `run` the frames the path so far allows, `frames` hands those over (on the training files'
    skeleton), `close` at the path's end; `take` is the whole walk made."""

    def __init__(self, follower: PathFollower, request: WalkRequest, seed: int = 0):
        from walkdiff.autoregressive.streaming import WalkStream

        if request.timeline is not None:
            raise WalkdiffError("--style: a timeline (STYLE@SECONDS) is not for --stream; give one style")
        if request.rig is not None:
            raise WalkdiffError(
                "--to does not work with a stream (the live poses are on the model's skeleton); retarget "
                "the walk it makes"
            )
        model = self.model = follower.model
        self.follower, self.request = follower, request
        index = follower.styles.index(request.label)
        self.unit = unit = model.profile.metres_per_unit
        units_per_s = float(model.style_speed[index]) if request.speed is None else request.speed / unit
        if not units_per_s > 0:
            raise WalkdiffError("the checkpoint has no walking speed for this style; give --speed")
        self.speed_m_s = units_per_s * unit
        sampler, match = request.sampler, request.match
        self.walker = WalkStream(model, index, units_per_s, seed, sampler=sampler, match=match)
        self.raws: list[np.ndarray] = []

    @property
    def points(self) -> int:
        """The path points taken so far."""
        return len(self.walker.points)

    @property
    def path_length_m(self) -> float:
        return 0.0 if self.walker.path is None else self.walker.path.length * self.unit

    def header(self) -> dict:
        return {
            "fps": self.model.spec["fps"], "joints": self.model.profile.skeleton.names,
            "units_per_metre": 1 / self.unit,
        }  # fmt: skip

    def feed(self, points) -> None:
        """Path points (n, 2) in metres; a WalkdiffError for the first the walk cannot take (those
        before it are taken)."""
        self.walker.feed(np.asarray(points, dtype=np.float64).reshape(-1, 2) / self.unit)

    def run(self) -> None:
        self.walker.batch.run()

    def close(self) -> None:
        self.walker.close()

    def frames(self) -> tuple[int, Motion | None]:
        """The frames made since the last call, on the training files' skeleton (None: none), and the
        number of the first."""
        made, first = self.walker.take(), len(self.raws)
        if not len(made):
            return first, None
        self.raws.extend(made)
        return first, self.model.to_file(to_motion(self.model, made, self.walker.roots[first]))

    def take(self) -> Take | None:
        """The walk made so far (None: no frame)."""
        if not self.raws:
            return None
        return self.follower.take(to_motion(self.model, np.stack(self.raws), self.walker.start))


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


START_COLOR, END_COLOR = "#1a9850", "#d7191c"


def plot_paths(out: str | Path, panels: list[tuple[str, Polyline, list[tuple[str, np.ndarray]]]]) -> Path:
    """Top-down plot per path, in metres: the requested path (start and end marked, arrows along it) and
    each walk's root trajectory.

    Drawn in walkdiff's one axis convention (`walkdiff.preview.render`): seen from above, x to the right and z
    towards the viewer, that is down the page, as the GIF's camera sees the ground.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    width = max(8.0, 4.5 * len(panels))  # >= 880 px at 110 dpi
    fig, axes = plt.subplots(1, len(panels), figsize=(width, 6.0), squeeze=False)
    for ax, (title, path, walks) in zip(axes[0], panels, strict=True):
        points = path.points
        ax.plot(points[:, 0], points[:, 1], color="black", lw=4, alpha=0.25, label="requested path")
        for s in np.linspace(0, path.length, 7)[1:-1]:  # direction arrows along the path
            at, ahead = path.at(np.array(s)), path.at(np.array(s + 1e-3 * path.length))
            arrow = {"arrowstyle": "-|>", "color": "0.35", "lw": 0, "mutation_scale": 18}
            ax.annotate("", xy=tuple(ahead), xytext=tuple(at), arrowprops=arrow)
        for label, xz in walks:
            ax.plot(xz[:, 0], xz[:, 1], lw=1.5, label=f"{label} (root)")
        ax.plot(*points[0], "o", color=START_COLOR, ms=10, label="start")
        ax.plot(*points[-1], "s", color=END_COLOR, ms=10, label="end")
        ax.set_aspect("equal", adjustable="datalim")  # a straight path keeps a readable panel width
        ax.invert_yaxis()  # z towards the viewer: down the page, as in the GIF
        ax.grid(True, color="0.9")
        ax.set_title(title)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("z (m), towards the viewer")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=9, loc="lower center", ncol=min(len(labels), 6))
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    written = write_atomic(out, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)
    return written


def render_walk(gif: Path, take: Take, path: Polyline, cap: PreviewCap, title: str | None = None):
    """The walk's GIF and MP4, with the requested path (in the take's units) drawn on the ground."""
    motion = take.canonical()
    skeleton = motion.skeleton  # without the static joints above the body
    positions = motion_world_positions(motion.slice(0, cap.frames(motion.num_frames, motion.fps)))
    return render_gif(
        gif, [positions], skeleton.parents, motion.fps, names=skeleton.names, cap=cap, video=True,
        marks=Marks.of(take.profile), paths=[path.points], titles=None if title is None else [title],
    )  # fmt: skip


@command
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
    **request,
) -> dict:
    """`walkdiff walk`: `PathFollower.follow`'s walk as a BVH (+ a GIF of its first `preview_seconds` and
    a top-down plot) and its manifest; a timeline `style` also writes its weights' plot. `request`: the
    sampler, rig and style clips, as `PathFollower.request` takes them."""
    request = specs_first(request)
    cap = PreviewCap(preview_seconds) if gif else None
    follower = PathFollower.load(ckpt)
    request = follower.request(style, speed, **request)  # before the path file is read
    read_path(path)
    out = output_folder(out)
    stem = f"{request.label}_{Path(path).stem}"
    bvh = out / f"{stem}.bvh"
    written = [bvh, out / f"{stem}_path.png", out / f"{stem}.json"]
    written += [out / f"{stem}_timeline.png"] if request.timeline is not None else []
    check_free(written + ([bvh.with_suffix(".gif"), bvh.with_suffix(".mp4")] if gif else []), overwrite)

    # Refused here (a path too long for memory, a style without a speed) before the folder exists.
    result = follower.walk(request, path, seed)
    take, extra = result.take, result.extra
    with output_set(out):
        files = _write_walk(out, stem, take, extra["metres"], request.label, cap, extra["scale"])
        if request.timeline is not None:
            seconds = take.num_frames / take.fps
            timeline_png = out / f"{stem}_timeline.png"
            files.append(plot_timeline(timeline_png, request.timeline, list(follower.styles), seconds))
        manifest = {
            "checkpoint": str(ckpt),
            **result.settings,
            "retarget": None if result.rig is None else result.rig.record(),
            "files": [str(f) for f in files],
            "preview": None if cap is None else cap.describe(take.num_frames, take.fps),
        }
        write_json(out / f"{stem}.json", manifest)
    return manifest


def _write_walk(
    out: Path, stem: str, take: Take, metres: Polyline, style: str, cap: PreviewCap | None, scale: float = 1.0
) -> list[Path]:
    """A walk's BVH (on the training files' skeleton or a --to rig's), its top-down plot in metres and,
    unless `cap` is None, its GIF and MP4. On a rig of other proportions the walk's path is the model's
    scaled by the legs' length ratio (`scale`, in metres): the plot and preview show the requested path
    scaled the same way."""
    unit, canonical = take.metres_per_unit, take.canonical()
    bvh = out / f"{stem}.bvh"
    root_xz = canonical.root_positions[:, [0, 2]]
    write_bvh(bvh, take.motion)
    requested = Polyline.of(metres.points * scale)
    files = [bvh, plot_paths(out / f"{stem}_path.png", [(stem, requested, [(style, root_xz * unit)])])]
    if cap is not None:
        gif = render_walk(out / f"{stem}.gif", take, Polyline.of(requested.points / unit), cap)
        files += [gif, gif.with_suffix(".mp4")]
    return files


def path_points(chunks, where: str):
    """Path points (x, z) from JSON lines, `{"x": .., "z": ..}` each, as their bytes arrive: per chunk,
    (line number, point) for each of its complete lines (blank lines skipped). A bad line is a
    WalkdiffError naming it, raised once the points before it have been given."""
    import json

    pending, number = b"", 0
    for data in chunks:
        lines = (pending + data).split(b"\n")
        pending, points = lines.pop(), []
        try:
            for line in lines:
                number += 1
                if line.strip():
                    points.append((number, _point(line, where, number, json)))
        except WalkdiffError as error:
            yield points  # the walk goes as far as the good points take it
            raise error
        yield points
    if pending.strip():
        yield [(number + 1, _point(pending, where, number + 1, json))]


def _feed(live: PathStream, points: list[tuple[int, list[float]]], where: str) -> None:
    """(line number, point in metres) pairs to a PathStream; a point it refuses (one the walk to which
    would not fit in memory) is named by its line."""
    before = live.points
    try:
        live.feed([point for _, point in points])
    except WalkdiffError as error:
        line = points[min(live.points - before, len(points) - 1)][0]
        raise WalkdiffError(error.reason, path=where, line=line) from None


def _point(line: bytes, where: str, number: int, json) -> list[float]:
    try:
        data = json.loads(line)
    except (UnicodeDecodeError, json.JSONDecodeError):
        data = None
    if (
        not isinstance(data, dict)
        or set(data) != {"x", "z"}
        or not all(isinstance(v, int | float) and math.isfinite(v) for v in data.values())
    ):
        text = line.decode("utf-8", "replace").strip()[:60]
        raise WalkdiffError(
            f'expected a JSON object {{"x": metres, "z": metres}}, got {text!r}', path=where, line=number
        )
    return [float(data["x"]), float(data["z"])]


@command
def walk_stream(
    ckpt: str, style: str, path: str, out: str, idle: float = 2.0, overwrite: bool = False, **options
) -> dict:
    """`walkdiff walk --stream`: `PathFollower.stream`'s walk along a path whose points arrive as JSON
    lines (stdin, or a file still being written), one JSON line per frame on stdout as soon as the path
    ahead allows, the BVH at the end. `options`: speed, seed and what `PathFollower.request` takes."""
    import sys

    from walkdiff.autoregressive.streaming import StreamEnd, emit, read_growing, read_pipe, stopped

    live = PathFollower.load(ckpt).stream(style, **specs_first(options))
    out = output_folder(out)
    bvh = out / f"{live.request.label}_{'stdin' if path == '-' else Path(path).stem}.bvh"
    check_free([bvh], overwrite)
    chunks = read_pipe(sys.stdin.buffer) if path == "-" else read_growing(path, idle)
    emit(live.header() | {
        "root": "position of the first joint, in the BVH's units and axes",
        "rotation": "local to the parent joint, quaternion [x, y, z, w], on the BVH's skeleton and axes",
    })  # fmt: skip
    started, fps = time.perf_counter(), live.model.spec["fps"]

    def send(arrived: float) -> None:
        first, motion = live.frames()
        if motion is None:
            return
        quaternions = _quaternions(motion.rotations).round(5)
        latency = round(1000 * (time.perf_counter() - arrived), 1)
        for i in range(motion.num_frames):
            emit({
                "frame": first + i, "time": round((first + i) / fps, 4), "latency_ms": latency,
                "root": motion.positions[i, 0].round(4).tolist(), "rotations": quaternions[i].tolist(),
            })  # fmt: skip

    end = StreamEnd()  # bad input midway or Ctrl-C: the frames made so far are written, then it stops
    with end.watch():
        for points in path_points(chunks, path):
            arrived = time.perf_counter()
            _feed(live, points, path)
            live.run()
            send(arrived)
        live.close()
    end.finish(live.run)
    send(time.perf_counter())
    take = live.take()
    if take is not None:
        write_bvh(bvh, take.motion)
    frames = 0 if take is None else take.num_frames
    if end.error is not None:
        raise stopped(end.error, frames, [bvh] if frames else [])
    summary = {
        "done": True, "frames": frames, "path_length_m": live.path_length_m, "speed_m_s": live.speed_m_s,
        "wall_s": round(time.perf_counter() - started, 3),
        "style_clips": clips_record(live.request.spec.clips) or None, "files": [str(bvh)],
    }  # fmt: skip
    emit(summary)
    return summary


def _quaternions(rotations: np.ndarray) -> np.ndarray:
    import roma

    return roma.rotmat_to_unitquat(torch.from_numpy(rotations)).numpy()


# ---------------------------------------------------------------- benchmark
