"""`walkdiff bench stream`: latency of live gestures and walking with input arriving in real time, and how
many streams keep real time batched."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from walkdiff.bench.gesture import gesture_model
from walkdiff.bench.measure import machine, median_seconds, percentiles, report
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.progress import progress


def _stream_walker(ckpt: str | None, speed: float):
    """A PathWalker: the checkpoint, or untrained of conf/walk_xia.yaml's size on a Xia-sized body.

    Untrained weights sample poses at random, and a root that jumps anywhere outruns a path drawn at
    walking pace; its normaliser is set to walk straight on at `speed` (units/s) whatever it samples,
    so it waits for the path as a trained walker does (speed does not depend on the weights).
    """
    from walkdiff.models.path_walker import PathWalker

    if ckpt is not None:
        from walkdiff.walker.follow import load_walker

        return load_walker(ckpt)
    spec = dict(
        dataset="xia", feature_dim=8 + 6 * 31, num_joints=31, window=24, fps=30.0,
        styles=tuple(f"style{i}" for i in range(8)), contents=("walk",),
    )  # fmt: skip
    walker = PathWalker(spec, **_shipped_walker()).eval()
    layout, normalizer = walker.layout, walker.normalizer
    for part in (layout.root_vel, layout.heading_vel):
        normalizer.std[part] = 1e-4
    normalizer.mean[layout.root_vel] = torch.tensor([0.0, speed / spec["fps"]])  # forward is +z
    walker.style_speed.fill_(speed)
    return walker


def _shipped_walker() -> dict:
    """The model settings of conf/walk_xia.yaml (the repository's), so the untrained walker has its size."""
    from omegaconf import OmegaConf

    config = Path(__file__).resolve().parents[2] / "conf" / "walk_xia.yaml"
    if not config.is_file():
        raise WalkdiffError(
            f"bench stream without --walker sizes the walker as {config} does; run it from the "
            "repository, or give --walker"
        )
    return dict(OmegaConf.to_container(OmegaConf.load(config).model.init_args))


def _realtime_latency(push, arrivals: list[float], frame_times) -> tuple[list[float], list[float], float]:
    """Push inputs at their arrival times (s after now, real-time pace): per frame made, the wall time
    from the arrival of the input that completed it, and from its own moment (`frame_times(t)` s in);
    and the CPU seconds of this process per frame (on a busy machine, what a free core would take)."""
    latency, since_moment, made = [], [], 0
    start, cpu = time.perf_counter(), time.process_time()
    for i, arrival in enumerate(arrivals):
        wait = start + arrival - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        count = push(i)
        done = time.perf_counter()
        for t in range(made, made + count):
            latency.append(done - (start + arrival))
            since_moment.append(done - (start + frame_times(t)))
        made += count
    return latency, since_moment, (time.process_time() - cpu) / max(made, 1)


def _most_streams(make_batch, fps: float, frames: int, most: int, desc: str) -> tuple[int, dict]:
    """Streams batched in lockstep, doubled (then bisected) until a frame of all of them takes longer than
    1 / fps: the most that keep real time, and the seconds per frame measured at each count."""
    timed: dict[int, float] = {}
    cpu: dict[int, float] = {}

    def seconds_per_frame(n: int) -> float:
        step = make_batch(n)
        step()  # warm-up
        started = time.process_time()
        timed[n] = median_seconds(step, frames)
        cpu[n] = (time.process_time() - started) / frames
        return timed[n]

    good, bad, n = 0, None, 1
    with progress(desc=desc, unit="count") as bar:
        while n <= most:
            bar.update(1)
            if seconds_per_frame(n) > 1 / fps:
                bad = n
                break
            good, n = n, 2 * n
        while bad is not None and bad - good > max(1, good // 8):  # to within an eighth
            bar.update(1)
            middle = (good + bad) // 2
            good, bad = (middle, bad) if seconds_per_frame(middle) <= 1 / fps else (good, middle)
    return good, {
        "seconds_per_frame_by_streams": {str(k): round(v, 4) for k, v in sorted(timed.items())},
        "cpu_seconds_per_frame_by_streams": {str(k): round(v, 4) for k, v in sorted(cpu.items())},
    }


def _sustained(make_batch, fps: float, frames: int, most: int, threads: tuple[int, ...]) -> dict:
    """`_most_streams` at each torch thread count, and the best of them."""
    rows = {}
    for count in threads:
        torch.set_num_threads(count)
        good, timed = _most_streams(
            make_batch, fps, frames, most, f"bench stream: streams, {count} thread(s)"
        )
        rows[str(count)] = {"realtime_streams": good, **timed}
    best = max(rows, key=lambda k: rows[k]["realtime_streams"])
    return {"realtime_streams": rows[best]["realtime_streams"], "best_threads": int(best), "by_threads": rows}


def bench_stream(
    out: str,
    ckpt: str | None = None,
    walker: str | None = None,
    seconds: float = 6.0,
    chunk_ms: float = 20.0,
    rate: int = 16000,
    frames: int = 6,
    most: int = 256,
    seed: int = 0,
    threads: tuple[int, ...] = (1, 2),
    sampler: str = "ddpm",
    steps: int | None = None,
    eta: float = 0.0,
    runtime: str = "torch",
) -> dict:
    """Streaming: latency from audio in to pose out with audio arriving in real time, the streams kept
    in real time batched; the same for the path walker (a path drawn while walking). Latency is timed
    with one torch thread (as fast as two for one stream on a quiet machine, far faster on a busy one);
    the streams kept in real time at each of `threads`. `runtime` onnx: the frames made by ONNX Runtime
    (`OnnxFrames`, on the same thread counts)."""
    before = torch.get_num_threads()
    try:
        from walkdiff.diffusion import SamplerChoice

        choice = SamplerChoice(sampler, steps, eta)
        return _bench_stream(
            out, ckpt, walker, seconds, chunk_ms, rate, frames, most, seed, threads, choice, runtime
        )
    finally:
        torch.set_num_threads(before)


def _bench_stream(
    out, ckpt, walker, seconds, chunk_ms, rate, frames, most, seed, threads, sampler, runtime
) -> dict:
    torch.set_num_threads(1)
    from walkdiff.export.runtime import frame_runtime
    from walkdiff.gestures.stream import GestureBatch, GestureStream
    from walkdiff.walker.stream import WalkBatch, WalkStream

    model = frame_runtime(gesture_model(ckpt).eval(), runtime, sampler)  # the checkpoint, or ZEGGS-sized
    rate = model.spec.get("sample_rate") or rate
    fps, rng = model.spec["fps"], np.random.default_rng(seed)
    audio = rng.normal(0, 0.1, round(seconds * rate)).astype(np.float32)
    chunk = max(1, round(chunk_ms / 1000 * rate))
    GestureStream(model, rate, seed, sampler=sampler).push(audio[:rate])  # warm-up
    stream = GestureStream(model, rate, seed, sampler=sampler)
    pieces = [audio[i : i + chunk] for i in range(0, len(audio), chunk)]
    arrivals = [min((i + 1) * chunk, len(audio)) / rate for i in range(len(pieces))]
    latency, since_moment, cpu_per_frame = _realtime_latency(
        lambda i: len(stream.push(pieces[i])), arrivals, lambda t: t / fps
    )
    lookahead_ms = 1000 * stream.features.needed(model.spec["lookahead"]) / rate
    if not latency:
        raise WalkdiffError(
            f"--seconds {seconds:g}: no pose before the audio ended; give more than the "
            f"model's look-ahead of {lookahead_ms / 1000:g} s"
        )

    hop, first = stream.features.hop, (model.spec["lookahead"] + 1) * stream.features.hop
    steady = rng.normal(0, 0.1, first + (frames + 2) * hop).astype(np.float32)

    def gesture_batch(n: int):
        batch = GestureBatch(model, seed, sampler)
        streams = [GestureStream(model, rate, batch=batch) for _ in range(n)]
        for s in streams:  # audio up to the first frame's look-ahead: then each hop makes a frame
            s.feed(steady[:first])
        at = [first]

        def step():
            for s in streams:
                s.feed(steady[at[0] : at[0] + hop])
            at[0] += hop
            if batch.step() != n:
                raise RuntimeError("a stream fell out of lockstep")

        return step

    sustained = _sustained(gesture_batch, fps, frames, most, threads)
    torch.set_num_threads(1)
    result = {
        "benchmark": "stream", "runtime": runtime, "checkpoint": ckpt, "seed": seed,
        "gesture": {
            "sampler": sampler.label(model.diffusion), "fps": fps, "rate": rate, "chunk_ms": chunk_ms,
            "audio_seconds": seconds,
            "lookahead_ms": round(lookahead_ms, 1),
            "latency_chunk_to_pose": percentiles(latency),
            "latency_audio_to_pose": percentiles(since_moment),
            "target_audio_to_pose_ms": round(lookahead_ms + 50, 1),
            "latency_threads": 1, "latency_cpu_ms_per_frame": round(1000 * cpu_per_frame, 1), **sustained,
        },
    }  # fmt: skip

    walk = frame_runtime(_stream_walker(walker, 12.0), runtime, sampler)  # Xia units/s: ~0.7 m/s
    wfps, speed = walk.spec["fps"], float(walk.style_speed.max())
    step = speed / wfps  # one path point per frame time, as far as the walker goes in it
    u = np.arange(round(seconds * wfps) + 200) * step
    points = np.stack([3 * speed * np.sin(u / (4 * speed)), u], axis=-1)  # a gentle S, drawn as walked
    walking = WalkStream(walk, 0, speed, seed, sampler=sampler)
    lead = int(np.ceil((walking.reach + walking.pace[0, -1]) / step)) + 2  # the path ahead it needs first
    WalkStream(walk, 0, speed, seed, sampler=sampler).push(points[: lead + 10])  # warm-up
    walking.push(points[:lead])  # the frames the lead allows at once, untimed: then a frame per point
    arrivals = [i / wfps for i in range(round(seconds * wfps))]
    w_latency, _, w_cpu_per_frame = _realtime_latency(
        lambda i: len(walking.push(points[lead + i : lead + i + 1])), arrivals, lambda t: t / wfps
    )

    def walk_batch(n: int):
        batch = WalkBatch(walk, seed, sampler)
        walkers = [WalkStream(walk, k % len(walk.spec["styles"]), speed, batch=batch) for k in range(n)]
        for w in walkers:
            w.feed(points)  # far ahead of them: every frame is ready

        def step():
            if batch.step() != n:
                raise RuntimeError("a walker fell out of lockstep")

        return step

    w_sustained = _sustained(walk_batch, wfps, frames, most, threads)
    result["walk"] = {
        "checkpoint": walker, "fps": wfps, "speed_units_s": speed, "path_lead_points": lead,
        "latency_point_to_pose": percentiles(w_latency), "frames_measured": len(w_latency),
        "latency_threads": 1, "latency_cpu_ms_per_frame": round(1000 * w_cpu_per_frame, 1), **w_sustained,
    }  # fmt: skip
    result["machine"] = machine()
    report(out, result)
    return result
