"""Speech-driven gestures with a trained DiffMotion: synthesis, smoothing, metrics and commands.

Metrics (all on world positions of the modelled joints, root and other joints in the neutral pose, so
generated and real motion are compared on the same footing):

- L1: mean over frames and joints of |x - x'| + |y - y'| + |z - z'| against the ground truth.
- PCK: the fraction of joints closer than `pck_threshold` metres (0.1 m; converted to the skeleton's units
  with its profile) to the truth.
- Beat consistency: motion beats B_m are the local minima of the mean joint speed, audio beats B_a the
  onsets; BC = 1/|B_m| sum_{b in B_m} exp(-min_{a in B_a} (b - a)^2 / (2 sigma^2)), sigma = 0.1 s.
- Diversity: samples of the same audio cut into clips of equal length; the mean L1 over all pairs of
  clips (DiffMotion's protocol).
- Jerk: mean norm of the third difference of positions times fps^3 (walkdiff.metrics.Jitter).
- Seconds per frame of generation.

Each metric of the generated samples comes with a 95% percentile-bootstrap interval over the samples
(`BOOTSTRAP` resamples), so samplers and settings can be told apart from the spread of the samples.
"""

from __future__ import annotations

import inspect
import itertools
import math
import os
import time
import warnings
from dataclasses import dataclass
from itertools import chain
from pathlib import Path

import numpy as np
import torch
from scipy.signal import argrelmin

from walkdiff.common.checkpoints import read_checkpoint
from walkdiff.common.errors import WalkdiffError, command, python_api
from walkdiff.common.files import check_free, output_folder, output_set, write_json
from walkdiff.common.memory import GESTURE_BYTES_PER_FRAME, check_frames
from walkdiff.common.progress import progress, step_hook
from walkdiff.data.speech import SpeechDataModule, decode_poses, log_mel, onset_times, read_wav, wav_seconds
from walkdiff.diffusion import SamplerChoice
from walkdiff.metrics import Jitter
from walkdiff.models.pipeline import Generated, Pipeline, specs_first
from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.filters import savgol
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.skeleton import Motion
from walkdiff.motion.take import Take
from walkdiff.motion.target_rig import TargetRig
from walkdiff.preview.render import DEFAULT_PREVIEW, PREVIEW_SECONDS, PreviewCap, render_gif

SMOOTH_WINDOW, SMOOTH_ORDER = 31, 4  # DiffMotion's Savitzky–Golay settings
BEAT_SIGMA = 0.1  # seconds
SHIFT_SECONDS = 2.0  # the audio-blind baseline of beat consistency
BOOTSTRAP = 1000  # resamples of the samples behind each metric's interval


# ---------------------------------------------------------------- model and synthesis


def load_model(path: str | Path, device: str | torch.device = "cpu"):
    from walkdiff.models.diffmotion import DiffMotion

    model = DiffMotion.from_trained(path, "DiffMotion", device)
    if model.neutral is None:
        raise WalkdiffError("the checkpoint has no neutral pose; was it saved by `walkdiff fit`?", path=path)
    return model


def synthesize(
    model,
    audio: np.ndarray,
    streams: int = 1,
    seed: int = 0,
    smooth: bool = False,
    sampler: SamplerChoice | None = None,
) -> np.ndarray:
    """(streams, F, D) pose features for (F, M) log-mel audio, the streams batched, each frame drawn by
    `sampler` (default DDPM over all trained steps); optionally smoothed. A bar counts the frames."""
    generator = torch.Generator(device=model.device).manual_seed(seed)
    with progress(desc="gestures", unit="frame") as bar:
        poses = model.generate(torch.from_numpy(audio), generator, streams, step_hook(bar), sampler)
        poses = poses.cpu().numpy()
    return savgol(poses, SMOOTH_WINDOW, SMOOTH_ORDER, axis=1) if smooth else poses


def to_motion(model, features: np.ndarray) -> Motion:
    """(F, D) features -> a canonical clip (Y up) of the model's body; `model.to_file` writes it."""
    spec = model.spec
    joints = [model.skeleton.index(n) for n in spec["joints"]]
    return decode_poses(features, model.skeleton, joints, spec["rotation"], model.neutral, 1.0 / spec["fps"])


def joint_positions(model, features: np.ndarray) -> np.ndarray:
    """(F, J, 3) world positions of the modelled joints."""
    joints = [model.skeleton.index(n) for n in model.spec["joints"]]
    return motion_world_positions(to_motion(model, features))[:, joints]


@dataclass(frozen=True)
class GestureRequest:
    """What to make, checked before any audio is read: how many clips, from which seed, smoothed or not,
    by which sampler, on which rig."""

    num: int
    seed: int
    smooth: bool
    sampler: SamplerChoice
    rig: TargetRig | None

    def names(self, out: Path, stem: str) -> tuple[list[str], list[Path]]:
        """Each clip's title and BVH file (`write_takes` names them the same), for `gesture` and its
        stream."""
        titles = [f"seed{self.seed}" if self.num == 1 else f"seed{self.seed}_{k}" for k in range(self.num)]
        return titles, [out / (f"{stem}.bvh" if self.num == 1 else f"{stem}_{t}.bvh") for t in titles]


class GestureGenerator(Pipeline):
    """A trained DiffMotion: `gesture` makes gestures for speech and returns them as `Take`s on the
    training files' skeleton, writing nothing; `stream` makes them as the speech arrives; `walkdiff
    gesture` (with --stream) writes the same clips for the same seed."""

    @classmethod
    def load(cls, ckpt: str | Path, device: str = "cpu") -> GestureGenerator:
        return cls(load_model(ckpt, device))

    @python_api
    def request(
        self,
        num: int = 1,
        seed: int = 0,
        smooth: bool = False,
        sampler: str | SamplerChoice | dict = "ddpm",
        steps: int | None = None,
        eta: float = 0.0,
        to: TargetRig | str | os.PathLike | None = None,
        to_map=None,
        samples: int | None = None,
    ) -> GestureRequest:
        """`num` clips from `seed`; `smooth`: DiffMotion's Savitzky-Golay filter (the command's --smooth);
        the sampler (a name with `steps` and `eta`, or a SamplerChoice); `to` (+ `to_map`): a rig to play
        them on (`Take.retarget`). `samples`: `num`'s old name (deprecated)."""
        if samples is not None:
            warnings.warn("gesture: samples= is deprecated; use num=", DeprecationWarning, stacklevel=3)
            num = samples
        choice = SamplerChoice.of(sampler, steps, eta).unguided()
        rig = TargetRig.of(to, to_map)
        if isinstance(num, bool) or not isinstance(num, int) or num < 1:
            raise WalkdiffError(f"--num must be a whole number >= 1, got {num!r}")
        return GestureRequest(num, seed, bool(smooth), choice, rig)

    @python_api
    def gesture(self, audio: str | os.PathLike | np.ndarray, rate: int | None = None, **options) -> Generated:
        """Gesture clips, one frame per 1/fps of the speech: a WAV file, or samples (N,) or (N,
        channels) at `rate` Hz. `options`: what `request` takes (num, seed, smooth, sampler, steps, eta,
        to, to_map). The result reads as the list of its takes; its `settings` are what `walkdiff
        gesture` prints."""
        return self.make(self.request(**options), audio, rate)

    def make(self, request: GestureRequest, audio, rate: int | None = None) -> Generated:
        """`gesture`'s work on a checked request."""
        sound, rate = self.listen(audio, rate, request.num)
        mel = log_mel(sound, rate, self.fps, self.model.spec["audio_dim"])
        started = time.perf_counter()
        clips = synthesize(self.model, mel, request.num, request.seed, request.smooth, request.sampler)
        per_frame = (time.perf_counter() - started) / len(mel)
        settings = {
            "frames": len(mel),
            "seconds": len(mel) / self.fps,
            "streams": request.num,
            "sampler": request.sampler.label(self.model.diffusion),
            "seconds_per_frame": per_frame,
        }
        takes = [self.take(to_motion(self.model, clip), request.rig) for clip in clips]
        timing = {"seconds_per_frame": per_frame}
        extra = {"audio": (sound, rate)}
        return Generated(takes, settings, timing, seed=request.seed, rig=request.rig, extra=extra)

    @python_api
    def stream(self, rate: int | None = None, **options) -> SpeechStreams:
        """Gestures as the speech arrives (`SpeechStreams`: feed it mono samples at `rate` Hz, default
        the model's training audio's): `options` as `request`'s, no rig (the live poses are on the
        model's skeleton)."""
        return SpeechStreams(self, self.request(**options), rate)

    def listen(
        self, audio: str | os.PathLike | np.ndarray, rate: int | None = None, streams: int = 1
    ) -> tuple[np.ndarray, int]:
        """Mono samples and their rate, refused where `streams` clips for them would not fit in memory
        (a WAV file from its header, before its samples are read)."""
        from_file = isinstance(audio, str | os.PathLike)
        if from_file and rate is not None:
            raise WalkdiffError("rate is for samples given as an array; a WAV file gives its own", path=audio)
        sound = None if from_file else mono_samples(audio, rate)
        seconds = wav_seconds(audio) if from_file else len(sound) / rate
        # One frame per hop and one more, as log_mel's centred frames.
        check_frames("--audio", math.floor(seconds * self.fps) + 1, GESTURE_BYTES_PER_FRAME, streams)
        return read_wav(audio) if from_file else (sound, int(rate))


def mono_samples(audio: np.ndarray, rate: int | None) -> np.ndarray:
    """Speech given as samples (N,) or (N, channels) at `rate` Hz, made what read_wav gives: mono float32."""
    if isinstance(rate, bool) or not isinstance(rate, int | np.integer) or rate <= 0:
        raise WalkdiffError(f"rate: samples given as an array need their rate in whole Hz > 0, got {rate!r}")
    sound = np.asarray(audio, dtype=np.float32)
    sound = sound.mean(axis=1) if sound.ndim == 2 else sound
    if sound.ndim != 1 or not len(sound):
        raise WalkdiffError(f"audio: expected samples (N,) or (N, channels), got shape {np.shape(audio)}")
    if not np.isfinite(sound).all():
        raise WalkdiffError("audio: samples that are not finite numbers; expected audio in [-1, 1]")
    return sound


class SpeechStreams:
    """`GestureGenerator.stream`'s: the request's `num` gesture streams of one speech whose samples arrive
    over time. `feed` samples, `run` the frames they allow, `frames` hands those over (the poses as
    rotations on the file's skeleton), `close` at the end of the speech; `takes` are the clips made,
    smoothed as asked (the live frames never are: they could not wait for the filter's frames ahead)."""

    def __init__(self, generator: GestureGenerator, request: GestureRequest, rate: int | None = None):
        from walkdiff.autoregressive.streaming import GestureBatch, GestureStream

        if request.rig is not None:
            raise WalkdiffError(
                "--to does not work with a stream (the live poses are on the model's skeleton); retarget "
                "the clips it makes"
            )
        model, spec = generator.model, generator.model.spec
        self.generator, self.model, self.request = generator, model, request
        self.joints = list(spec["joints"])
        self.batch = GestureBatch(model, request.seed, request.sampler)
        self.streams = [GestureStream(model, rate, batch=self.batch) for _ in range(request.num)]
        self.rate = self.streams[0].rate
        self.poses: list[list[np.ndarray]] = [[] for _ in range(request.num)]

    def header(self) -> dict:
        spec = self.model.spec
        return {
            "fps": spec["fps"], "rate": self.rate, "streams": self.request.num, "joints": self.joints,
            "rotation": "local to the parent joint, quaternion [x, y, z, w], on the BVH's skeleton and axes",
            "lookahead_s": round(self.streams[0].features.needed(spec["lookahead"]) / self.rate, 4),
        }  # fmt: skip

    def feed(self, samples: np.ndarray) -> None:
        for stream in self.streams:
            stream.feed(samples)

    def run(self) -> None:
        self.batch.run()

    def close(self) -> None:
        for stream in self.streams:
            stream.close()

    def frames(self) -> list[dict]:
        """The frames made since the last call: stream, frame, time, the audio time it waited for and
        the rotations (J, 4) of the modelled joints."""
        lines, fps = [], self.model.spec["fps"]
        for k, stream in enumerate(self.streams):
            made = stream.take()
            if not len(made):
                continue
            first = len(self.poses[k])
            self.poses[k].extend(made)
            quaternions = file_quaternions(self.model, made, self.joints).round(5)
            for i, q in enumerate(quaternions):
                t = first + i
                lines.append({
                    "stream": k, "frame": t, "time": round(t / fps, 4),
                    "audio_time": round(stream.waited[t], 4), "rotations": q.tolist(),
                })  # fmt: skip
        return lines

    def takes(self) -> list[Take]:
        """The clips made, as long as the shortest (streams stopped by Ctrl-C within a batch's frame);
        none when no frame was made."""
        made = min(len(p) for p in self.poses)
        if not made:
            return []
        clips = [np.stack(p[:made]) for p in self.poses]
        if self.request.smooth:
            clips = [savgol(c, SMOOTH_WINDOW, SMOOTH_ORDER, axis=0) for c in clips]
        return [self.generator.take(to_motion(self.model, clip)) for clip in clips]


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


def file_quaternions(model, poses: np.ndarray, joints: list[str]) -> np.ndarray:
    """(F, len(joints), 4) local rotations of `joints` as unit quaternions (x, y, z, w) on the file's
    skeleton and axes (what the BVH holds), for (F, D) features of `model`."""
    import roma

    motion = model.to_file(to_motion(model, poses))
    index = [motion.skeleton.index(name) for name in joints]
    return roma.rotmat_to_unitquat(torch.from_numpy(motion.rotations[:, index])).numpy()


@command
def gesture_stream(
    ckpt: str,
    audio: str,
    out: str,
    rate: int | None = None,
    idle: float = 2.0,
    seconds: float | None = None,
    overwrite: bool = False,
    **options,
) -> dict:
    """`walkdiff gesture --stream`: `GestureGenerator.stream`'s poses as the audio arrives (raw s16le PCM
    on stdin, or a WAV that is still being written), one JSON line per frame on stdout, the BVH(s)
    written at the end. `options`: what `GestureGenerator.request` takes."""
    from walkdiff.autoregressive.streaming import StreamEnd, emit, speech_input, stopped

    generator = GestureGenerator.load(ckpt)
    request = generator.request(**specs_first(options))
    decoder = speech_input(audio, rate, generator.model.spec.get("sample_rate"))
    stem, out = ("stdin" if audio == "-" else Path(audio).stem), output_folder(out)
    _, targets = request.names(out, stem)
    check_free(targets, overwrite)
    chunks = decoder.chunks(idle)  # opened once the outputs are free
    live, received, started = None, 0, time.perf_counter()

    def send(arrived: float) -> None:
        latency = round(1000 * (time.perf_counter() - arrived), 1)
        for line in live.frames():
            emit(line | {"latency_ms": latency})

    end = StreamEnd()  # bad input midway or Ctrl-C: the frames made so far are written, then it stops
    with end.watch():
        for data in chain([b""], chunks):  # stdin's rate is known before any byte: its header first
            arrived, samples = time.perf_counter(), decoder.decode(data)
            if live is None and decoder.rate is not None:
                live = SpeechStreams(generator, request, decoder.rate)
                emit(live.header())
            if live is not None:
                limit = None if seconds is None else round(seconds * live.rate)
                samples = samples if limit is None else samples[: max(limit - received, 0)]
                received += len(samples)
                live.feed(samples)
                live.run()
                send(arrived)
                if limit is not None and received >= limit:
                    break
        else:
            decoder.end()
        if live is not None:
            live.close()
    takes = []
    if live is not None:
        end.finish(live.run)
        send(time.perf_counter())
        takes = live.takes()
    if takes:
        with output_set(out):  # all or none
            for path, take in zip(targets, takes, strict=True):
                write_bvh(path, take.motion)
    made = takes[0].num_frames if takes else 0
    if end.error is not None:
        raise stopped(end.error, made, targets if made else [])
    summary = {
        "done": True, "frames": made, "seconds": received / live.rate, "streams": request.num,
        "wall_s": round(time.perf_counter() - started, 3), "files": [str(t) for t in targets],
    }  # fmt: skip
    emit(summary)
    return summary


# ---------------------------------------------------------------- metrics


def l1_distance(pred: np.ndarray, truth: np.ndarray) -> float:
    """Mean over frames and joints of the L1 norm of the position error; (F, J, 3) each."""
    return float(np.abs(pred - truth).sum(axis=-1).mean())


def pck(pred: np.ndarray, truth: np.ndarray, threshold: float) -> float:
    """Fraction of (frame, joint) positions within `threshold` (Euclidean) of the truth."""
    return float((np.linalg.norm(pred - truth, axis=-1) < threshold).mean())


def motion_beats(positions: np.ndarray, fps: float) -> np.ndarray:
    """Times (s) of the local minima of the mean joint speed; positions (F, J, 3)."""
    speed = np.linalg.norm(np.diff(positions, axis=0), axis=-1).mean(axis=-1)
    return (argrelmin(speed)[0] + 0.5) / fps  # speed i lies between frames i and i + 1


def beat_consistency(beats: np.ndarray, onsets: np.ndarray, sigma: float = BEAT_SIGMA) -> float:
    """Mean over motion beats of exp(-d^2 / (2 sigma^2)), d the distance to the nearest audio onset."""
    if len(beats) == 0 or len(onsets) == 0:
        return 0.0
    distance = np.abs(np.asarray(beats)[:, None] - np.asarray(onsets)[None]).min(axis=1)
    return float(np.exp(-(distance**2) / (2 * sigma**2)).mean())


def shift_beats(beats: np.ndarray, seconds: float, duration: float) -> np.ndarray:
    """Beats of the motion rolled by `seconds` against its audio (circularly, so none are lost)."""
    return np.sort((np.asarray(beats) + seconds) % duration)


def diversity(samples: np.ndarray, clip_frames: int) -> float:
    """Mean L1 between all pairs of equal clips cut from the samples (S, F, J, 3) of one audio."""
    count = samples.shape[1] // clip_frames
    clips = samples[:, : count * clip_frames].reshape(-1, clip_frames, *samples.shape[2:])
    if len(clips) < 2:
        raise WalkdiffError(f"diversity needs at least two {clip_frames}-frame clips, got {len(clips)}")
    return float(
        np.mean([l1_distance(clips[i], clips[j]) for i, j in itertools.combinations(range(len(clips)), 2)])
    )


def mean_jerk(positions: np.ndarray, fps: float) -> float:
    """Mean jerk magnitude of (F, J, 3) or (S, F, J, 3) positions."""
    metric = Jitter(fps)
    metric.update(torch.from_numpy(positions.reshape(-1, *positions.shape[-3:])))
    return float(metric.compute())


# ---------------------------------------------------------------- evaluation


def evaluate_gesture(
    ckpt: str,
    out: str,
    samples: int = 5,
    seed: int = 0,
    clip_seconds: float = 2.0,
    pck_threshold: float = 0.1,
    root: str | None = None,
    sampler: str = "ddpm",
    steps: int | None = None,
    eta: float = 0.0,
    to: str | None = None,
    to_map: str | None = None,
) -> dict:
    """`walkdiff evaluate-gesture`: every metric on the held-out part of each take, with 95% intervals
    over the samples, into report.json; the per-take BVH and previews played by `to` (+ `to_map`) when
    given (the metrics are on the model's skeleton)."""
    choice = SamplerChoice(sampler, steps, eta)
    rig = TargetRig.of(to, to_map)
    if samples < 1:
        raise WalkdiffError(f"--samples must be >= 1, got {samples}")
    if not 0 < pck_threshold < np.inf:
        raise WalkdiffError(f"--pck-threshold must be a positive distance in metres, got {pck_threshold}")
    model = load_model(ckpt)
    pck_units = pck_threshold / model.profile.metres_per_unit
    checkpoint = read_checkpoint(ckpt, "gesture model", mmap=False)
    settings = dict(checkpoint.get("datamodule_hyper_parameters") or {})
    settings |= {"root": root} if root is not None else {}
    accepted = inspect.signature(SpeechDataModule).parameters  # LightningCLI adds _class_path
    settings = {k: v for k, v in settings.items() if k in accepted}
    data = SpeechDataModule(**settings)
    fps = model.spec["fps"]
    out_dir = Path(out)
    rows = []
    for take in progress(data.load_takes(), desc="takes", unit="take"):
        begin, end = data.split_frames(take, "test")
        truth_features = data.poses(take)[begin:end]
        wav, rate = read_wav(take.wav)
        onsets = onset_times(wav[int(begin / fps * rate) : int(end / fps * rate)], rate)
        start = time.perf_counter()
        raw = synthesize(model, take.audio[begin:end], samples, seed, sampler=choice)
        elapsed = time.perf_counter() - start
        smooth = savgol(raw, SMOOTH_WINDOW, SMOOTH_ORDER, axis=1)
        truth = joint_positions(model, truth_features)
        duration, clip = (end - begin) / fps, round(clip_seconds * fps)
        row = {"take": take.name, "frames": end - begin, "seconds": duration, "onsets": len(onsets)}
        row["truth"] = _beat_row(truth, onsets, fps, duration) | {"jerk": mean_jerk(truth, fps)}
        resamples = np.random.default_rng(seed).integers(0, samples, (BOOTSTRAP, samples))
        for name, clips in (("generated", raw), ("smoothed", smooth)):
            positions = np.stack([joint_positions(model, c) for c in clips])
            beats = [_beat_row(p, onsets, fps, duration) for p in positions]
            per_sample = {
                "l1": [l1_distance(p, truth) for p in positions],
                "pck": [pck(p, truth, pck_units) for p in positions],
                "bc": [b["bc"] for b in beats],
                "bc_shifted": [b["bc_shifted"] for b in beats],
                "jerk": [mean_jerk(p, fps) for p in positions],
            }
            row[name] = {key: float(np.mean(values)) for key, values in per_sample.items()}
            row[name] |= beat_gain(beats)
            row[name]["diversity"] = None
            if samples * ((end - begin) // clip) >= 2:
                row[name]["diversity"] = diversity(positions, clip)
                row[name]["diversity_ci95"] = diversity_interval(positions, clip, resamples)
            for key, values in per_sample.items():
                row[name][f"{key}_ci95"] = mean_interval(np.asarray(values), resamples)
            row[name]["jerk_over_truth"] = row[name]["jerk"] / row["truth"]["jerk"]
        row["seconds_per_frame"] = elapsed / (end - begin)  # all `samples` streams generated together
        _, row["preview"] = write_clips(
            out_dir / take.name,
            take.name,
            model,
            [truth_features, smooth[0], raw[0]],
            ["truth", "smoothed", "generated"],
            rig=rig,
        )
        rows.append(row)
    report = {
        "checkpoint": str(ckpt),
        "sampler": choice.label(model.diffusion),
        "samples": samples,
        "bootstrap": BOOTSTRAP,
        "seed": seed,
        "retarget": None if rig is None else rig.record(),
        "pck_threshold_m": pck_threshold,
        "beat_sigma_s": BEAT_SIGMA,
        "shift_s": SHIFT_SECONDS,
        "clip_seconds": clip_seconds,
        "takes": rows,
    }
    write_json(out_dir / "report.json", report)
    return report


def mean_interval(values: np.ndarray, resamples: np.ndarray) -> list[float] | None:
    """95% percentile-bootstrap interval of the mean of per-sample `values` (S,); resamples (R, S) of
    sample indices. None for a single sample."""
    if len(values) < 2:
        return None
    return [float(q) for q in np.percentile(values[resamples].mean(axis=1), [2.5, 97.5])]


def diversity_interval(samples: np.ndarray, clip_frames: int, resamples: np.ndarray) -> list[float] | None:
    """95% percentile-bootstrap interval of `diversity` over the samples (S, F, J, 3): a resample counts
    each pair of clips as often as their samples were drawn together, never a clip against itself."""
    count = samples.shape[1] // clip_frames
    if len(samples) < 2 or count < 1:
        return None
    clips = samples[:, : count * clip_frames].reshape(-1, clip_frames, *samples.shape[2:])
    distance = np.zeros((len(clips), len(clips)))
    for i, j in itertools.combinations(range(len(clips)), 2):
        distance[i, j] = distance[j, i] = l1_distance(clips[i], clips[j])
    owner = np.repeat(np.arange(len(samples)), count)  # the sample of each clip
    values = []
    for draw in resamples:
        drawn = np.bincount(draw, minlength=len(samples))[owner].astype(float)
        weight = np.outer(drawn, drawn)
        np.fill_diagonal(weight, 0.0)
        if weight.sum() > 0:  # a draw of one sample cut into one clip has no pair
            values.append((weight * distance).sum() / weight.sum())
    return [float(q) for q in np.percentile(values, [2.5, 97.5])] if values else None


def _beat_row(positions: np.ndarray, onsets: np.ndarray, fps: float, duration: float) -> dict:
    beats = motion_beats(positions, fps)
    return {
        "bc": beat_consistency(beats, onsets),
        "bc_shifted": beat_consistency(shift_beats(beats, SHIFT_SECONDS, duration), onsets),
        "beats": len(beats),
    }


def beat_gain(beats: list[dict]) -> dict:
    """How much the timing with its own audio beats the 2-s shift, per sample (paired): mean and 95% CI."""
    gain = np.array([b["bc"] - b["bc_shifted"] for b in beats])
    half = 1.96 * gain.std(ddof=1) / np.sqrt(len(gain)) if len(gain) > 1 else float("nan")
    return {
        "bc_gain": float(gain.mean()),
        "bc_gain_ci95": [float(gain.mean() - half), float(gain.mean() + half)],
        "bc_gain_positive_share": float((gain > 0).mean()),
    }


# ---------------------------------------------------------------- training callback
