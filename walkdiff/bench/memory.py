"""`walkdiff bench memory`: peak memory of the generating commands, each run in its own process, beside the
estimates they refuse frame counts by."""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from walkdiff.bench.measure import machine, report
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_json
from walkdiff.common.progress import progress

# Runs a walkdiff command and, as it exits, writes the peak resident memory of its own address space
# (VmHWM). The rusage of a child is no measure: Linux carries the high-water mark of the process that
# forked it across exec, so a child of a big process (a test session) reports at least that one's size.
_PEAK_WRAPPER = """\
import atexit, sys
from pathlib import Path
report = Path(sys.argv.pop(1))
def write_peak():
    status = Path("/proc/self/status").read_text().splitlines()
    report.write_text(next(line.split()[1] for line in status if line.startswith("VmHWM:")))
atexit.register(write_peak)
from walkdiff.cli.main import main
sys.argv[0] = "walkdiff"
sys.exit(main(sys.argv[1:]))
"""


def peak_rss(args: list[str], env: dict | None = None) -> tuple[int, float, float]:
    """Run `walkdiff ARGS` in a subprocess: (its exit code, its peak resident memory in bytes, seconds)."""
    import subprocess

    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "peak"
        child = subprocess.run(
            [sys.executable, "-c", _PEAK_WRAPPER, str(report), *args],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        )  # fmt: skip
        if child.returncode != 0 or not report.exists():
            raise WalkdiffError(
                f"benchmark run failed ({child.returncode}): walkdiff {' '.join(args)}\n"
                + child.stderr.decode()[-2000:]
            )
        peak = int(report.read_text()) * 1024  # kB
    return child.returncode, peak, time.perf_counter() - started


def bench_memory(
    out: str,
    ckpt: str,
    frames: tuple[int, ...] = (300, 10_000, 100_000),
    walker: str | None = None,
    gesture: str | None = None,
    audio: str | None = None,
    seconds: tuple[int, ...] = (10, 120),
) -> dict:
    """Peak memory of `walkdiff sample --frames N --num 1` (GIF included) for each N, each in its own
    process, beside the estimate `walkdiff.common.memory` refuses frame counts by; with `walker`, of `walkdiff
    walk` along straight paths of each of `seconds`; with `gesture` and `audio`, of `walkdiff gesture`
    on the WAV repeated to each of `seconds`.

    The windows are denoised with DDIM over one step: memory does not depend on the sampler or its steps
    (one window is denoised at a time), and 100,000 frames of DDPM would take hours.
    """

    from walkdiff.common.memory import SAMPLE_BYTES_PER_FRAME, check_frames, memory_limit
    from walkdiff.styled.generation import load_generator

    style = load_generator(ckpt).spec["styles"][0]
    env = os.environ | {"WALKDIFF_PROGRESS": "0"}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        extra = {}
        if walker is not None:
            extra["walk"] = [_walk_memory(walker, s, Path(tmp), env) for s in seconds]
        if gesture is not None:
            if audio is None:
                raise WalkdiffError("bench memory: --gesture needs --audio (a speech WAV to repeat)")
            extra["gesture"] = [_gesture_memory(gesture, audio, s, Path(tmp), env) for s in seconds]
        for n in progress(frames, desc="bench memory", unit="run"):
            estimate = check_frames("--frames", n, SAMPLE_BYTES_PER_FRAME)
            command = [
                "sample", "--ckpt", str(ckpt), "--out", f"{tmp}/{n}",
                "--style", style, "--num", "1", "--frames", str(n), "--sampler", "ddim", "--steps", "1",
            ]  # fmt: skip
            _, peak, seconds = peak_rss(command, env)
            manifest = json.loads((Path(tmp) / str(n) / "manifest.json").read_text())
            gif = next((Path(tmp) / str(n)).glob("*.gif"))
            rows.append(
                {
                    "command": f"walkdiff sample --frames {n} --num 1 --sampler ddim --steps 1",
                    "frames": n,
                    "peak_rss_mb": round(peak / 1e6, 1),
                    "estimate_mb": round(estimate / 1e6, 1),
                    "seconds": round(seconds, 1),
                    "gif_mb": round(gif.stat().st_size / 1e6, 2),
                    "preview": manifest["preview"]["note"],
                }
            )
    result = {
        "benchmark": "memory",
        "ckpt": ckpt,
        "limit_mb": round(memory_limit() / 1e6),
        "sample": rows,
        **extra,
        "machine": machine(),
    }
    report(out, result)
    return result


def _walk_memory(ckpt: str, seconds: int, tmp: Path, env: dict) -> dict:
    """Peak memory of `walkdiff walk` along a straight path walked in `seconds` at 1.2 m/s."""
    from walkdiff.common.memory import WALK_BYTES_PER_FRAME, check_frames
    from walkdiff.walker.follow import load_walker

    model = load_walker(ckpt)
    path = tmp / f"straight_{seconds}s.json"
    write_json(path, {"points": [[0, 0], [0, 1.2 * seconds]], "speed": 1.2})
    frames = round(seconds * model.spec["fps"]) + 1
    style = model.spec["styles"][0]
    command = [
        "walk",
        "--ckpt",
        ckpt,
        "--style",
        style,
        "--path",
        str(path),
        "--out",
        str(tmp / path.stem),
    ]
    _, peak, spent = peak_rss(command, env)
    return {
        "command": f"walkdiff walk --path <straight, {seconds} s at 1.2 m/s>",
        "frames": frames,
        "peak_rss_mb": round(peak / 1e6, 1),
        "estimate_mb": round(check_frames("--path", frames, WALK_BYTES_PER_FRAME) / 1e6, 1),
        "seconds": round(spent, 1),
    }


def _gesture_memory(ckpt: str, audio: str, seconds: int, tmp: Path, env: dict) -> dict:
    """Peak memory of `walkdiff gesture` on `audio` repeated (or cut) to `seconds`."""
    import soundfile

    from walkdiff.common.memory import GESTURE_BYTES_PER_FRAME, check_frames
    from walkdiff.data.speech import read_wav
    from walkdiff.gestures.generator import load_model

    samples, rate = read_wav(audio)
    long = np.resize(samples, seconds * rate)  # repeated end to end
    wav = tmp / f"speech_{seconds}s.wav"
    soundfile.write(str(wav), long, rate)
    fps = load_model(ckpt).spec["fps"]
    command = ["gesture", "--ckpt", ckpt, "--audio", str(wav), "--out", str(tmp / wav.stem)]
    _, peak, spent = peak_rss(command, env)
    return {
        "command": f"walkdiff gesture --audio <{seconds} s of speech>",
        "frames": round(seconds * fps),
        "peak_rss_mb": round(peak / 1e6, 1),
        "estimate_mb": round(check_frames("--audio", round(seconds * fps), GESTURE_BYTES_PER_FRAME) / 1e6, 1),
        "seconds": round(spent, 1),
    }
