"""`walkdiff walk` and `walkdiff walk --stream`: `PathFollower`'s walks written as BVH, a plot, previews and
a manifest, or printed as JSON lines as the path arrives."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

from walkdiff.common.errors import WalkdiffError, command
from walkdiff.common.files import check_free, output_folder, output_set, write_json
from walkdiff.models.pipeline import specs_first
from walkdiff.models.style_examples import clips_record
from walkdiff.models.style_labels import plot_timeline
from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.path import Polyline, read_path
from walkdiff.preview.render import PREVIEW_SECONDS, PreviewCap
from walkdiff.retarget.take import Take
from walkdiff.streams.inputs import read_growing, read_pipe
from walkdiff.streams.lines import StreamEnd, emit, finished, pump, sender
from walkdiff.walker.follow import PathFollower, PathStream
from walkdiff.walker.plots import plot_paths, render_walk


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
    live = PathFollower.load(ckpt).stream(style, **specs_first(options))
    out = output_folder(out)
    bvh = out / f"{live.request.label}_{'stdin' if path == '-' else Path(path).stem}.bvh"
    check_free([bvh], overwrite)
    chunks = read_pipe(sys.stdin.buffer) if path == "-" else read_growing(path, idle)
    emit(live.header())
    started, end = time.perf_counter(), StreamEnd()  # bad input midway or Ctrl-C: the frames so far are kept
    arrivals = ((time.perf_counter(), points) for points in path_points(chunks, path))
    pump(end, arrivals, lambda points: _feed(live, points, path), live.run, sender(live), live.close)
    take = live.take()
    if take is not None:
        write_bvh(bvh, take.motion)
    return finished(
        end, 0 if take is None else take.num_frames, [bvh], path_length_m=live.path_length_m,
        speed_m_s=live.speed_m_s, runtime=live.runtime, wall_s=round(time.perf_counter() - started, 3),
        style_clips=clips_record(live.request.spec.clips) or None, files=[str(bvh)],
    )  # fmt: skip
