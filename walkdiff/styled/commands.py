"""`walkdiff sample` and `walkdiff transfer`: the styled generator's clips written as BVH, previews and a
manifest or report.

The clips are what `StyledGenerator` (styled/pipeline.py) returns to Python for the same seed and
settings; this module adds the files: names from the style label, no overwriting unasked, GIF and MP4
previews of the first seconds, and the JSON that records how they were made. A command's files are
written all or none (`output_set`): a run that fails midway leaves no clip without its manifest.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from walkdiff.common.errors import command
from walkdiff.common.files import check_free, output_folder, output_set, write_json
from walkdiff.models.pipeline import Generated, specs_first
from walkdiff.models.style_labels import plot_timeline
from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.preview.render import PREVIEW_SECONDS, Marks, PreviewCap, render_gif
from walkdiff.retarget.take import Take
from walkdiff.styled.generation import short_note
from walkdiff.styled.pipeline import StyledGenerator, check_sample_size


def write_clip(
    path: Path, take: Take, title: str, cap: PreviewCap | None, others: tuple[tuple[Take, str], ...] = ()
) -> None:
    """A clip as BVH on its skeleton (the training files' or the --to rig's); the GIF and MP4 previews
    (unless `cap` is None) show the clips' canonical (Y-up) form, first seconds only."""
    write_bvh(path, take.motion)
    if cap is not None:
        clips = [(t.canonical(), name) for t, name in (*others, (take, title))]
        shown = cap.frames(max(m.num_frames for m, _ in clips), take.fps, len(clips))
        skeleton = clips[-1][0].skeleton  # canonical: without the static joints above the body
        render_gif(
            path.with_suffix(".gif"),
            [motion_world_positions(m.slice(0, shown)) for m, _ in clips],
            skeleton.parents,
            take.fps,
            names=skeleton.names,
            titles=[t for _, t in clips],
            cap=cap,
            video=True,
            marks=Marks.of(take.profile),
        )


@command
def sample(
    ckpt: str | Path,
    out: str | Path,
    style=None,
    num: int = 8,
    frames: int = 300,
    seed: int = 0,
    ground: bool = True,
    fix_feet: bool | None = None,
    gif: bool = True,
    preview_seconds: float = PREVIEW_SECONDS,
    overwrite: bool = False,
    device: str = "cpu",
    keys=None,
    **request,
) -> dict:
    """`walkdiff sample`: `StyledGenerator.sample`'s clips as BVH (+ GIF previews of their first
    `preview_seconds`) and `manifest.json` in `out`; returns the manifest. `request`: the style, content,
    sampler, windows and rig, as `StyledGenerator.request` takes them; `keys`: what the clips pass
    through (styled/keys.py `read_keys`)."""
    check_sample_size(num, frames)
    request = specs_first(request)
    cap = PreviewCap(preview_seconds) if gif else None
    generator = StyledGenerator.load(ckpt, device)
    request = generator.request(style, unstyled=keys is not None, **request)
    out = output_folder(out)
    stem = f"{request.label}_{request.content_name}"
    bvh = [out / f"{stem}_{i:03d}.bvh" for i in range(num)]
    previews = [p.with_suffix(suffix) for p in bvh for suffix in (".gif", ".mp4")] if gif else []
    timeline_png = out / f"{stem}_timeline.png"
    extra = [timeline_png] if request.timeline is not None else []
    check_free([*bvh, *previews, *extra, out / "manifest.json"], overwrite)

    short = short_note(frames, generator.model.spec["window"], generator.fps)
    if short is not None:
        print(f"walkdiff: note: {short}", file=sys.stderr)
    if keys is None:
        result = generator.make(request, num, frames, seed, ground, fix_feet)
    else:
        result = generator.keyed(request, keys, num, frames, seed, ground, fix_feet)
    started = time.perf_counter()
    with output_set(out):
        for path, take in zip(bvh, result.takes, strict=True):
            write_clip(path, take, f"{request.label} {request.content_name}", cap)
        if request.timeline is not None:
            plot_timeline(timeline_png, request.timeline, list(generator.styles), frames / generator.fps)
        files = {"files": [p.name for p in bvh]}
        if keys is not None:
            files["keys"] = {"source": str(keys), "kept_error_body_heights": result.extra["kept_error"],
                             "root_key_error_body_heights": result.extra["root_key_error"]}  # fmt: skip
        result.timing["write_s"] = round(time.perf_counter() - started, 3)
        return _record(
            out / "manifest.json", {"command": "sample", "checkpoint": str(ckpt)}, result, files, cap
        )


@command
def transfer(
    ckpt: str | Path,
    input: str | Path,
    out: str | Path,
    style=None,
    strength: float = 0.6,
    keep_trajectory: bool = False,
    seed: int = 0,
    ground: bool = True,
    fix_feet: bool | None = None,
    gif: bool = True,
    preview_seconds: float = PREVIEW_SECONDS,
    overwrite: bool = False,
    device: str = "cpu",
    **request,
) -> dict:
    """`walkdiff transfer`: `StyledGenerator.transfer`'s clip as `out/<input>_to_<style>.bvh`, a GIF beside
    the source (of their first `preview_seconds`) and a JSON report."""
    request = specs_first(request)
    cap = PreviewCap(preview_seconds) if gif else None
    generator = StyledGenerator.load(ckpt, device)
    request = generator.request(style, **request)
    input = Path(input)
    out = output_folder(out)
    target = out / f"{input.stem}_to_{request.label}.bvh"
    previews = [target.with_suffix(".gif"), target.with_suffix(".mp4")] if gif else []
    check_free([target, target.with_suffix(".json"), *previews], overwrite)

    result = generator.restyle(request, input, strength, keep_trajectory, seed, ground, fix_feet)
    for note in result.warnings:
        print(f"walkdiff: warning: {note}", file=sys.stderr)
    with output_set(out):
        write_clip(target, result.take, request.label, cap, others=((result.extra["source"], "source"),))
        head = {"command": "transfer", "checkpoint": str(ckpt), "input": str(input)}
        found = {"root_path_error": result.extra["root_path_error"], "warnings": result.warnings}
        return _record(target.with_suffix(".json"), head, result, {"file": target.name}, cap, found)


def _record(path: Path, head: dict, result: Generated, files: dict, cap, found: dict | None = None) -> dict:
    """The manifest (sample) or report (transfer) of a command: how its files were made, as JSON."""
    panels = 1 if head["command"] == "sample" else 2  # transfer's preview shows the source beside
    report = {
        **head,
        "settings": result.settings,
        "seed": result.seed,
        "retarget": None if result.rig is None else result.rig.record(),
        **files,
        "preview": None
        if cap is None
        else cap.describe(result.settings["frames"], result.settings["fps"], panels),
        **(found or {}),
        "timing": result.timing,
    }
    write_json(path, report)
    return report
