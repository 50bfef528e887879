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

import numpy as np

from walkdiff.common.files import check_free, output_folder, output_set, write_json
from walkdiff.models.style_examples import MATCH_CLIPS
from walkdiff.models.style_labels import DEFAULT_TRANSITION, plot_timeline
from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.skeleton import Motion
from walkdiff.motion.take import Take
from walkdiff.motion.target_rig import TargetRig
from walkdiff.preview.render import PREVIEW_SECONDS, Marks, PreviewCap, render_gif
from walkdiff.styled.generation import Sampling, noised_steps, short_note
from walkdiff.styled.pipeline import StyledGenerator, check_sample_size


def _write_clip(
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


def sample(
    ckpt: str | Path,
    out: str | Path,
    style: str | None = None,
    content: str = "walk",
    num: int = 8,
    frames: int = 300,
    seed: int = 0,
    sampler: str = "ddpm",
    steps: int | None = None,
    eta: float = 0.0,
    guidance: float = 1.0,
    overlap: int | None = None,
    blend: int | None = None,
    ground: bool = True,
    fix_feet: bool | None = None,
    gif: bool = True,
    preview_seconds: float = PREVIEW_SECONDS,
    overwrite: bool = False,
    device: str = "cpu",
    to: str | None = None,
    to_map: str | None = None,
    style_clips: str | None = None,
    transition: float = DEFAULT_TRANSITION,
    match_clips: float = MATCH_CLIPS,
) -> dict:
    """`walkdiff sample`: `num` clips as BVH (+ GIF previews of their first `preview_seconds`) and
    `manifest.json` in `out`; returns the manifest. `to`: a rig to play them on (`TargetRig`)."""
    check_sample_size(num, frames)
    rig = None if to is None else TargetRig(to, to_map)
    sampling = Sampling(sampler, steps, eta, guidance)
    cap = PreviewCap(preview_seconds) if gif else None
    generator = StyledGenerator.load(ckpt, device)
    model = generator.model
    request = generator.request(
        style, content, sampling, overlap, blend, style_clips, transition, match_clips
    )
    out = output_folder(out)
    names = [f"{request.label}_{content}_{i:03d}" for i in range(num)]
    manifest_path = out / "manifest.json"
    bvh = [out / f"{n}.bvh" for n in names]
    previews = [p.with_suffix(suffix) for p in bvh for suffix in (".gif", ".mp4")] if gif else []
    timeline_png = out / f"{request.label}_{content}_timeline.png"
    extra = [timeline_png] if request.timeline is not None else []
    check_free(bvh + previews + extra + [manifest_path], overwrite)

    short = short_note(frames, model.spec["window"], generator.fps)
    if short is not None:
        print(f"walkdiff: note: {short}", file=sys.stderr)
    started = time.perf_counter()
    clips = generator.generate(request, num, frames, seed, ground, fix_feet)
    generated = time.perf_counter() - started
    with output_set(out):
        for path, clip in zip(bvh, clips, strict=True):
            _write_clip(path, generator.take(clip, rig), f"{request.label} {content}", cap)
        if request.timeline is not None:
            plot_timeline(timeline_png, request.timeline, list(generator.styles), frames / generator.fps)
        manifest = {
            "command": "sample",
            "checkpoint": str(ckpt),
            "settings": {
                "style": style,
                "style_clips": [e.record() for e in request.examples],
                "match_clips": match_clips if request.examples else None,
                "timeline": None if request.timeline is None else request.timeline.record(),
                "content": content,
                "num": num,
                "frames": frames,
                "fps": model.spec["fps"],
                **request.sampling.record(),
                "overlap": request.overlap,
                "blend": request.blend,
                "ground": ground,
                "fix_feet": request.pins_feet(fix_feet),
                "distilled_jumps": model.jumps(sampler, steps, eta) is not None,
            },
            "seed": seed,
            "retarget": None if rig is None else rig.record(),
            "files": [p.name for p in bvh],
            "preview": None if cap is None else cap.describe(frames, model.spec["fps"]),
            "timing": {
                "generate_s": round(generated, 3),
                "write_s": round(time.perf_counter() - started - generated, 3),
                "generated_frames_per_s": round(num * frames / generated, 1),
            },
        }
        write_json(manifest_path, manifest)
    return manifest


def transfer(
    ckpt: str | Path,
    input: str | Path,
    out: str | Path,
    style: str | None = None,
    content: str = "walk",
    strength: float = 0.6,
    keep_trajectory: bool = False,
    seed: int = 0,
    sampler: str = "ddpm",
    steps: int | None = None,
    eta: float = 0.0,
    guidance: float = 1.0,
    overlap: int | None = None,
    blend: int | None = None,
    ground: bool = True,
    fix_feet: bool | None = None,
    gif: bool = True,
    preview_seconds: float = PREVIEW_SECONDS,
    overwrite: bool = False,
    device: str = "cpu",
    to: str | None = None,
    to_map: str | None = None,
    style_clips: str | None = None,
    match_clips: float = MATCH_CLIPS,
) -> dict:
    """`walkdiff transfer`: `out/<input>_to_<style>.bvh`, a GIF beside the source (of their first
    `preview_seconds`) and a JSON report. `to`: a rig to play the result on (the preview shows the
    source on it too)."""
    rig = None if to is None else TargetRig(to, to_map)
    sampling = Sampling(sampler, steps, eta, guidance)
    cap = PreviewCap(preview_seconds) if gif else None
    generator = StyledGenerator.load(ckpt, device)
    model = generator.model
    request = generator.request(
        style, content, sampling, overlap, blend, style_clips, match_clips=match_clips
    )
    noised_steps(model, strength, sampling)  # bad strength fails before any work
    input = Path(input)
    motion = generator.source(input)
    out = output_folder(out)
    target = out / f"{input.stem}_to_{request.label}.bvh"
    report_path = target.with_suffix(".json")
    previews = [target.with_suffix(".gif"), target.with_suffix(".mp4")] if gif else []
    check_free([target, report_path, *previews], overwrite)
    short = generator.window_note(motion, input)
    if short is not None:
        print(f"walkdiff: warning: {short}", file=sys.stderr)

    started = time.perf_counter()
    result = generator.restyled(request, motion, strength, keep_trajectory, seed, ground, fix_feet)
    elapsed = time.perf_counter() - started
    with output_set(out):
        source = generator.take(motion, rig)
        _write_clip(target, generator.take(result, rig), request.label, cap, others=((source, "source"),))
        report = {
            "command": "transfer",
            "checkpoint": str(ckpt),
            "input": str(input),
            "settings": {
                "style": style,
                "style_clips": [e.record() for e in request.examples],
                "match_clips": match_clips if request.examples else None,
                "content": content,
                "strength": strength,
                "keep_trajectory": keep_trajectory,
                "frames": motion.num_frames,
                "fps": model.spec["fps"],
                **request.sampling.record(),
                "overlap": request.overlap,
                "blend": request.blend,
                "ground": ground,
                "fix_feet": request.pins_feet(fix_feet),
            },
            "seed": seed,
            "retarget": None if rig is None else rig.record(),
            "file": target.name,
            "preview": None if cap is None else cap.describe(motion.num_frames, model.spec["fps"], panels=2),
            "root_path_error": root_path_error(motion, result),
            "warnings": [] if short is None else [short],
            "timing": {"restyle_s": round(elapsed, 3)},
        }
        write_json(report_path, report)
    return report


def root_path_error(source: Motion, result: Motion) -> dict[str, float]:
    """Mean horizontal distance between the two root paths, absolute and relative to the distance walked."""
    a, b = source.root_positions[:, [0, 2]], result.root_positions[:, [0, 2]]
    walked = float(np.linalg.norm(np.diff(a, axis=0), axis=1).sum())
    error = float(np.linalg.norm(a - b, axis=1).mean())
    return {"mean": error, "walked": walked, "relative": error / walked if walked > 0 else float("nan")}
