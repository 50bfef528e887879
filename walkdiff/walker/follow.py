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

from walkdiff.common.errors import WalkdiffError, python_api
from walkdiff.common.memory import WALK_BYTES_PER_FRAME, check_frames
from walkdiff.common.progress import progress, step_hook
from walkdiff.diffusion import SamplerChoice
from walkdiff.models.pipeline import Generated, Pipeline
from walkdiff.models.style_examples import MATCH_CLIPS, clip_statistics, clips_record
from walkdiff.models.style_labels import DEFAULT_TRANSITION, StyleTimeline, parse_timeline
from walkdiff.models.style_spec import Style
from walkdiff.models.style_statistics import StyleStatistics
from walkdiff.motion.path import Polyline, checked_polyline, frames_for, read_path
from walkdiff.motion.representation import decode
from walkdiff.motion.rotations import matrix_to_quaternion
from walkdiff.motion.skeleton import Motion
from walkdiff.retarget.take import Take
from walkdiff.retarget.target_rig import TargetRig


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
    def stream(
        self,
        style,
        speed: float | None = None,
        seed: int = 0,
        runtime: str = "torch",
        onnx: str | os.PathLike | None = None,
        **options,
    ) -> PathStream:
        """A walk along a path whose points arrive over time (`PathStream`: feed it (x, z) points in
        metres): one style (no timeline), at `speed` m/s (None: the style's own); `options` as
        `request`'s, no rig (the live poses are on the model's skeleton). `runtime` 'onnx': the frames
        made by ONNX Runtime, the same for the same seed (the frame exported for the request's sampler,
        or the graph `walkdiff export --format onnx` wrote into the folder `onnx`); no example clips."""
        return PathStream(self, self.request(style, speed, **options), seed, runtime, onnx)

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
        """A `WalkController` (walkdiff/walker/controller.py): `step(direction, speed)` makes the
        next frame of `characters` walkers starting as `style` (a name, a mix or weights; None: the
        model's first style with a known speed) at `speed` m/s (None: the style's own). Default sampler
        DDIM 10 steps, eta 1 (docs/live-control.md); `options`: sampler, steps, eta, characters,
        transition, turn_rate, heading_assist, foot_lock, positions, headings, record, style_clips and
        match_clips (example clips whose posture and swing the walkers take on)."""
        from walkdiff.walker.controller import controller

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

    def __init__(
        self,
        follower: PathFollower,
        request: WalkRequest,
        seed: int = 0,
        runtime: str = "torch",
        onnx: str | os.PathLike | None = None,
    ):
        from walkdiff.export.runtime import frame_runtime
        from walkdiff.walker.stream import WalkStream

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
        frames = frame_runtime(model, runtime, sampler, onnx=onnx)  # the model itself, or ONNX Runtime
        self.runtime = runtime
        self.walker = WalkStream(frames, index, units_per_s, seed, sampler=sampler, match=match)
        self.raws: list[np.ndarray] = []

    @property
    def points(self) -> int:
        """The path points taken so far."""
        return len(self.walker.points)

    @property
    def path_length_m(self) -> float:
        return 0.0 if self.walker.path is None else self.walker.path.length * self.unit

    def header(self) -> dict:
        """What the frames hand over, as the first line of `walkdiff walk --stream` says it."""
        return {
            "fps": self.model.spec["fps"], "joints": self.model.profile.skeleton.names,
            "units_per_metre": 1 / self.unit,
            "root": "position of the first joint, in the BVH's units and axes",
            "rotation": "local to the parent joint, quaternion [x, y, z, w], on the BVH's skeleton and axes",
        }  # fmt: skip

    def feed(self, points) -> None:
        """Path points (n, 2) in metres; a WalkdiffError for the first the walk cannot take (those
        before it are taken)."""
        self.walker.feed(np.asarray(points, dtype=np.float64).reshape(-1, 2) / self.unit)

    def run(self) -> None:
        self.walker.batch.run()

    def close(self) -> None:
        self.walker.close()

    def frames(self) -> list[dict]:
        """The frames made since the last call: frame, time, the root's position and the local rotations
        as quaternions, on the training files' skeleton (as the `header` says)."""
        made, first = self.walker.take(), len(self.raws)
        if not len(made):
            return []
        self.raws.extend(made)
        motion = self.model.to_file(to_motion(self.model, made, self.walker.roots[first]))
        quaternions = matrix_to_quaternion(torch.from_numpy(motion.rotations)).numpy().round(5)
        fps = self.model.spec["fps"]
        return [
            {
                "frame": first + i, "time": round((first + i) / fps, 4),
                "root": motion.positions[i, 0].round(4).tolist(), "rotations": quaternions[i].tolist(),
            }
            for i in range(motion.num_frames)
        ]  # fmt: skip

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
