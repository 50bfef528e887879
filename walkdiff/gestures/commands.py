"""`walkdiff gesture` and `walkdiff gesture --stream`: `GestureGenerator`'s clips written as BVH and previews,
or printed as JSON lines as the speech arrives."""

from __future__ import annotations

import time
from itertools import chain
from pathlib import Path

import numpy as np

from walkdiff.common.errors import command
from walkdiff.common.files import check_free, output_folder, output_set
from walkdiff.gestures.generator import GestureGenerator, SpeechStreams, to_motion
from walkdiff.gestures.stream import speech_input
from walkdiff.models.pipeline import Pipeline, specs_first
from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.preview.render import DEFAULT_PREVIEW, PREVIEW_SECONDS, PreviewCap, render_gif
from walkdiff.retarget.take import Take
from walkdiff.retarget.target_rig import TargetRig
from walkdiff.streams.lines import StreamEnd, emit, finished, pump, sender


def write_clips(
    out: Path,
    stem: str,
    model,
    clips: list[np.ndarray],
    titles: list[str],
    cap: PreviewCap = DEFAULT_PREVIEW,
    audio: tuple[np.ndarray, int] | None = None,
    rig: TargetRig | None = None,
) -> tuple[list[Path], dict]:
    """`write_takes` of clips of features, on the training files' skeleton or played by `rig`."""
    takes = [Pipeline(model).take(to_motion(model, clip), rig) for clip in clips]
    return write_takes(out, stem, takes, titles, model.spec["fps"], cap, audio)


def write_takes(
    out: Path,
    stem: str,
    takes: list[Take],
    titles: list[str],
    fps: float,
    cap: PreviewCap = DEFAULT_PREVIEW,
    audio: tuple[np.ndarray, int] | None = None,
) -> tuple[list[Path], dict]:
    """One BVH per take (made at `fps`), and a GIF and an MP4 (with `audio`, the speech, as its sound) of
    the first seconds of all of them side by side; the files and what the preview shows."""
    out.mkdir(parents=True, exist_ok=True)
    frames = max(t.num_frames for t in takes)
    shown = cap.frames(frames, fps, len(takes))
    files, positions = [], []
    for take, title in zip(takes, titles, strict=True):
        path = out / (f"{stem}.bvh" if len(takes) == 1 else f"{stem}_{title}.bvh")
        write_bvh(path, take.motion)
        files.append(path)
        canonical = take.canonical()
        positions.append(motion_world_positions(canonical.slice(0, shown)))
    gif = out / f"{stem}.gif"
    skeleton = canonical.skeleton  # without the static joints above the body
    render_gif(
        gif, positions, skeleton.parents, fps, names=skeleton.names, titles=titles, cap=cap, video=True,
        audio=audio,
    )  # fmt: skip
    return files + [gif, gif.with_suffix(".mp4")], cap.describe(frames, fps, len(takes))


@command
def gesture(
    ckpt: str,
    audio: str,
    out: str,
    preview_seconds: float = PREVIEW_SECONDS,
    overwrite: bool = False,
    **options,
) -> dict:
    """`walkdiff gesture`: `GestureGenerator.gesture`'s clips as BVH(s) and a GIF (of their first
    `preview_seconds`) for a WAV file. `options`: what `GestureGenerator.request` takes."""
    options = specs_first(options)
    cap = PreviewCap(preview_seconds)
    generator = GestureGenerator.load(ckpt)
    request = generator.request(**options)
    stem, out = Path(audio).stem, output_folder(out)
    titles, targets = request.names(out, stem)
    check_free([*targets, Path(out) / f"{stem}.gif", Path(out) / f"{stem}.mp4"], overwrite)
    result = generator.make(request, audio)
    with output_set(out):  # all or none: no BVH without the others and the preview
        speech = result.extra["audio"]
        files, preview = write_takes(Path(out), stem, result.takes, titles, generator.fps, cap, speech)
    return {
        **result.settings,
        "retarget": None if result.rig is None else result.rig.record(),
        "files": [str(f) for f in files],
        "preview": preview,
    }


@command
def gesture_stream(
    ckpt: str,
    audio: str,
    out: str,
    rate: int | None = None,
    idle: float = 2.0,
    seconds: float | None = None,
    overwrite: bool = False,
    runtime: str = "torch",
    onnx: str | None = None,
    **options,
) -> dict:
    """`walkdiff gesture --stream`: `GestureGenerator.stream`'s poses as the audio arrives (raw s16le PCM
    on stdin, or a WAV that is still being written), one JSON line per frame on stdout, the BVH(s)
    written at the end, made by `runtime` (torch, or onnx: ONNX Runtime, from the graph in the folder
    `onnx` if given). `options`: what `GestureGenerator.request` takes."""
    generator = GestureGenerator.load(ckpt)
    request = generator.request(**specs_first(options))
    decoder = speech_input(audio, rate, generator.model.spec.get("sample_rate"))
    stem, out = ("stdin" if audio == "-" else Path(audio).stem), output_folder(out)
    _, targets = request.names(out, stem)
    check_free(targets, overwrite)
    live, started = SpeechStreams(generator, request, None, runtime, onnx), time.perf_counter()
    arrivals = speech_arrivals(decoder, decoder.chunks(idle), live, seconds)  # opened once outputs are free
    end = StreamEnd()  # bad input midway or Ctrl-C: the frames made so far are written, then it stops
    pump(end, arrivals, live.feed, live.run, sender(live), live.close)
    takes = live.takes()
    if takes:
        with output_set(out):  # all or none
            for path, take in zip(targets, takes, strict=True):
                write_bvh(path, take.motion)
    return finished(
        end, takes[0].num_frames if takes else 0, targets, seconds=live.received / (live.rate or 1),
        streams=request.num, runtime=runtime, wall_s=round(time.perf_counter() - started, 3),
        files=[str(t) for t in targets],
    )  # fmt: skip


def speech_arrivals(decoder, chunks, live: SpeechStreams, seconds: float | None):
    """(arrival time, samples) of the speech as its bytes come, the first `seconds` of it at most; the
    streams start (and their header line is printed) once its rate is known: stdin's before any byte,
    a WAV's with its header."""
    for data in chain([b""], chunks):
        arrived, samples = time.perf_counter(), decoder.decode(data)
        if live.rate is None and decoder.rate is not None:
            live.start(decoder.rate)
            emit(live.header())
        if live.rate is None:
            continue
        limit = None if seconds is None else round(seconds * live.rate)
        yield arrived, samples if limit is None else samples[: max(limit - live.received, 0)]
        if limit is not None and live.received >= limit:
            return
    decoder.end()
