"""`walkdiff bench gesture`: DiffMotion's seconds per frame, one stream and many batched."""

from __future__ import annotations

import os

import numpy as np
import torch

from walkdiff.bench.measure import interleaved_medians, machine, report
from walkdiff.common.progress import progress


def gesture_model(ckpt: str | None):
    """The DiffMotion checkpoint, or an untrained one of the ZEGGS config's size (N = 100).

    Speed depends on the architecture and the sampler only, so untrained weights time as trained ones.
    """
    from walkdiff.models.diffmotion import DiffMotion

    if ckpt is not None:
        from walkdiff.gestures.generator import load_model

        return load_model(ckpt).eval()
    spec = dict(
        dataset="zeggs", feature_dim=45, num_joints=15, window=120, fps=20.0,
        joints=tuple(map(str, range(15))), rotation="expmap", audio_dim=27, past=10, lookahead=20,
    )  # fmt: skip
    return DiffMotion(spec).eval()


def bench_gesture(
    out: str,
    ckpt: str | None = None,
    frames: int = 40,
    repeats: int = 5,
    sampler: str = "ddim",
    steps: int | None = 10,
    eta: float = 1.0,
    streams: tuple[int, ...] = (16, 64, 128),
    runtime: str = "torch",
) -> dict:
    """DiffMotion generation speed: seconds per frame of one stream with DDPM over all N steps and with
    the few-step `sampler`, each plain (the eps module and `run_steps`) and fused (`FusedEps`); frames per
    second of `streams` streams batched (few-step, fused) and which of them keep up with the model's fps.

    Timings that are compared are interleaved rounds, `repeats` of them, reported as medians.
    `runtime` onnx: the few-step frame exported and run by ONNX Runtime (on torch's thread count) instead.
    """
    from walkdiff.diffusion import SamplerChoice

    few = SamplerChoice(sampler, steps, eta)
    model = gesture_model(ckpt)
    if runtime == "onnx":
        return _bench_onnx(out, ckpt, model, few, frames, repeats, streams)
    fps, n = model.spec["fps"], model.diffusion.num_timesteps
    audio = torch.randn(frames, model.spec["audio_dim"])
    settings = {
        f"{label}_{kind}": (choice, kind == "fused")
        for choice, label in (
            (SamplerChoice(), f"ddpm{n}"),
            (few, few.label(model.diffusion).replace("-", "")),
        )
        for kind in ("plain", "fused")
    }
    result = {
        "benchmark": "gesture",
        "checkpoint": ckpt,
        "frames_timed": frames,
        "repeats": repeats,
        "fps": fps,
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
    }
    batch_rounds = max(1, repeats // 2)
    bar = progress(
        total=len(settings) * repeats + len(streams) * batch_rounds, desc="bench gesture", unit="run"
    )

    def counted(fn):  # a timed run that then advances the bar (microseconds, inside the timing)
        return lambda: (fn(), bar.update(1))

    with bar:
        for choice, fused in settings.values():  # warm-up
            model.generate(audio[:3], sampler=choice, fused=fused)
        runs = [
            counted(lambda choice=choice, fused=fused: model.generate(audio, sampler=choice, fused=fused))
            for choice, fused in settings.values()
        ]
        one = interleaved_medians(runs, repeats)
        result["seconds_per_frame_1_stream"] = {name: round(t / frames, 5) for name, t in zip(settings, one)}
        result["lstm_step_ms"] = _lstm_step_ms(model, repeats)
        batched = interleaved_medians(
            [counted(lambda s=s: model.generate(audio, streams=s, sampler=few)) for s in streams],
            batch_rounds,
        )
    result["sampler_batched"] = few.label(model.diffusion)
    result["frames_per_second_batched"] = {str(s): round(s * frames / t, 1) for s, t in zip(streams, batched)}
    realtime = [s for s, t in zip(streams, batched) if t / frames <= 1 / fps]
    result["realtime_streams"] = max(realtime, default=0)  # the most measured streams that keep up
    result["realtime_streams_estimate"] = int(max(s * frames / t for s, t in zip(streams, batched)) // fps)
    result["target"] = {"seconds_per_frame_1_stream": 0.005, "realtime_streams": 64}
    result["machine"] = machine()
    report(out, result)
    return result


def _bench_onnx(out, ckpt, model, few, frames: int, repeats: int, streams: tuple[int, ...]) -> dict:
    """`bench_gesture` on ONNX Runtime: a frame of one stream (the generation loop, noise drawn as torch
    draws it, and the graph's run alone, as an engine calls it), and `streams` streams batched."""
    from walkdiff.export.runtime import OnnxFrames

    threads = torch.get_num_threads()
    frames_model = OnnxFrames(model, few, threads)
    fps, label = model.spec["fps"], few.label(model.diffusion)
    audio = torch.randn(frames, model.spec["audio_dim"])

    def generate(count: int = 1, length: int = frames) -> None:
        frames_model.generate(audio[:length], streams=count, sampler=few)

    state = frames_model.start_streams(1)
    window = np.zeros((1, model.window * model.spec["audio_dim"]), np.float32)
    noise = frames_model.noise(1, None)
    rounds = 50

    def graph() -> None:
        for _ in range(rounds):
            frames_model.run(window, state.previous, state.h, state.c, noise)

    bar = progress(total=2 * repeats + len(streams) * max(1, repeats // 2), desc="bench gesture", unit="run")
    with bar:
        generate(1, 3), graph()  # warm-up
        timed = [lambda: (generate(), bar.update(1)), lambda: (graph(), bar.update(1))]
        loop, alone = interleaved_medians(timed, repeats)
        batched = interleaved_medians(
            [lambda s=s: (generate(s), bar.update(1)) for s in streams], max(1, repeats // 2)
        )
    realtime = [s for s, t in zip(streams, batched) if t / frames <= 1 / fps]
    result = {
        "benchmark": "gesture", "runtime": "onnx", "checkpoint": ckpt, "sampler": label,
        "frames_timed": frames, "repeats": repeats, "fps": fps, "threads": threads,
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "ms_per_frame_1_stream": round(1e3 * loop / frames, 4),
        "ms_per_frame_graph_alone": round(1e3 * alone / rounds, 4),
        "frames_per_second_batched": {str(s): round(s * frames / t, 1) for s, t in zip(streams, batched)},
        "realtime_streams": max(realtime, default=0),
        "realtime_streams_estimate": int(max(s * frames / t for s, t in zip(streams, batched)) // fps),
        "target": {"ms_per_frame_1_stream": 1.0, "realtime_streams": 256},
        "machine": machine(),
    }  # fmt: skip
    report(out, result)
    return result


def _lstm_step_ms(model, repeats: int) -> dict:
    """Milliseconds of one encoder step of one stream: nn.LSTM against the addmm form generation uses."""
    encoder = model.encoder
    x = torch.randn(1, 1, encoder.lstm.input_size)
    rounds = 50
    with torch.inference_mode():
        state = encoder.step(x[:, 0], None)[1]

        def lstm() -> None:
            for _ in range(rounds):
                encoder.lstm(x, state)

        def addmm() -> None:
            for _ in range(rounds):
                encoder.step(x[:, 0], state)

        lstm(), addmm()
        times = interleaved_medians([lstm, addmm], repeats)
    return {"nn_lstm": round(1e3 * times[0] / rounds, 4), "addmm": round(1e3 * times[1] / rounds, 4)}
