"""Speech-driven gestures with a trained DiffMotion: `GestureGenerator` makes them for a whole recording
(`gesture`) or as the speech arrives (`stream`), returning `Take`s and writing nothing."""

from __future__ import annotations

import math
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError, python_api
from walkdiff.common.memory import GESTURE_BYTES_PER_FRAME, check_frames
from walkdiff.common.progress import progress, step_hook
from walkdiff.data.speech import decode_poses, log_mel, read_wav, wav_seconds
from walkdiff.diffusion import SamplerChoice
from walkdiff.models.pipeline import Generated, Pipeline
from walkdiff.motion.filters import savgol
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.rotations import matrix_to_quaternion
from walkdiff.motion.skeleton import Motion
from walkdiff.retarget.take import Take
from walkdiff.retarget.target_rig import TargetRig

SMOOTH_WINDOW, SMOOTH_ORDER = 31, 4  # DiffMotion's Savitzky–Golay settings


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
    def stream(
        self,
        rate: int | None = None,
        runtime: str = "torch",
        onnx: str | os.PathLike | None = None,
        **options,
    ) -> SpeechStreams:
        """Gestures as the speech arrives (`SpeechStreams`: feed it mono samples at `rate` Hz, default
        the model's training audio's): `options` as `request`'s, no rig (the live poses are on the
        model's skeleton). `runtime` 'onnx': the frames made by ONNX Runtime, the same for the same seed
        (the frame exported for the request's sampler, or the graph `walkdiff export --format onnx`
        wrote into the folder `onnx`)."""
        request = self.request(**options)
        rate = rate or self.model.spec.get("sample_rate")
        if rate is None:
            raise WalkdiffError("the checkpoint does not record its audio's sample rate: give the rate")
        return SpeechStreams(self, request, rate, runtime, onnx)

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
    over time at `rate` Hz (None: not known yet, `start` once it is). `feed` samples, `run` the frames
    they allow, `frames` hands those over (the poses as rotations on the file's skeleton), `close` at the
    end of the speech; `takes` are the clips made, smoothed as asked (the live frames never are: they
    could not wait for the filter's frames ahead). `runtime` 'onnx' (+ `onnx`, a folder of an exported
    graph): the frames made by ONNX Runtime, as `GestureGenerator.stream` says."""

    def __init__(
        self,
        generator: GestureGenerator,
        request: GestureRequest,
        rate: int | None = None,
        runtime: str = "torch",
        onnx: str | os.PathLike | None = None,
    ):
        from walkdiff.export.runtime import frame_runtime
        from walkdiff.gestures.stream import GestureBatch

        if request.rig is not None:
            raise WalkdiffError(
                "--to does not work with a stream (the live poses are on the model's skeleton); retarget "
                "the clips it makes"
            )
        model, spec = generator.model, generator.model.spec
        self.generator, self.model, self.request = generator, model, request
        self.joints = list(spec["joints"])
        self.runtime = runtime
        self.runner = frame_runtime(model, runtime, request.sampler, onnx=onnx)  # the model, or ONNX Runtime
        self.batch = GestureBatch(self.runner, request.seed, request.sampler)
        self.streams: list = []
        self.poses: list[list[np.ndarray]] = [[] for _ in range(request.num)]
        self.rate, self.received = None, 0  # samples fed
        if rate is not None:
            self.start(rate)

    def start(self, rate: int) -> None:
        """The streams, once the speech's sample rate is known."""
        from walkdiff.gestures.stream import GestureStream

        self.streams = [GestureStream(self.runner, rate, batch=self.batch) for _ in range(self.request.num)]
        self.rate = self.streams[0].rate

    def header(self) -> dict:
        spec = self.model.spec
        return {
            "fps": spec["fps"], "rate": self.rate, "streams": self.request.num, "joints": self.joints,
            "rotation": "local to the parent joint, quaternion [x, y, z, w], on the BVH's skeleton and axes",
            "lookahead_s": round(self.streams[0].features.needed(spec["lookahead"]) / self.rate, 4),
        }  # fmt: skip

    def feed(self, samples: np.ndarray) -> None:
        self.received += len(samples)
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
        if not self.streams or not made:
            return []
        clips = [np.stack(p[:made]) for p in self.poses]
        if self.request.smooth:
            clips = [savgol(c, SMOOTH_WINDOW, SMOOTH_ORDER, axis=0) for c in clips]
        return [self.generator.take(to_motion(self.model, clip)) for clip in clips]


def file_quaternions(model, poses: np.ndarray, joints: list[str]) -> np.ndarray:
    """(F, len(joints), 4) local rotations of `joints` as unit quaternions (x, y, z, w) on the file's
    skeleton and axes (what the BVH holds), for (F, D) features of `model`."""
    motion = model.to_file(to_motion(model, poses))
    index = [motion.skeleton.index(name) for name in joints]
    return matrix_to_quaternion(torch.from_numpy(motion.rotations[:, index])).numpy()
