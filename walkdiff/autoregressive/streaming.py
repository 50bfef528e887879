"""Streaming: gestures from speech that is still arriving, walking along a path that is still being drawn.

A stream owns what its control needs (the audio features so far, or the path so far) and says when its
next frame is ready; a batch of streams of one model carries their LSTM state and previous poses
(`FrameStreams`) and, per frame, runs one forward for all the streams that have a frame ready:

    batch = GestureBatch(model, seed=0)
    a, b = GestureStream(model, batch=batch), GestureStream(model, batch=batch)
    a.feed(pcm_a); b.feed(pcm_b); batch.run()      # every frame that became ready, batched
    poses_a, poses_b = a.take(), b.take()

or, for one stream, `GestureStream(model, rate, seed).push(pcm)` -> the poses made. A gesture frame t
needs audio frames up to t + lookahead, and mel frame k needs the samples before (k + 1) * hop (its
window is centred on k * hop and two hops long); `finish` pads the end as the offline path does. A
walker's frame t needs the path up to where its control reads it (`WalkStream.ready`).

Reproducibility: a single stream with seed s makes the poses `walkdiff gesture --seed s` (or `walk`)
makes from the whole input, up to float rounding of the audio encoding. Streams of a batch share one
random generator, drawn in one go for the streams advanced together: streams that advance in lockstep
(the same audio at the same time, as `--streams N`) equal the offline batch, to the same rounding; streams at
different points of their input are valid samples whose noise depends on which frames were batched.
"""

from __future__ import annotations

import json
import math
import struct
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.memory import WALK_BYTES_PER_FRAME, check_frames
from walkdiff.data.speech import LogMelStream
from walkdiff.diffusion import SamplerChoice
from walkdiff.models.path_walker import advance_root, path_control, path_start
from walkdiff.motion.path import Polyline, frames_for, frames_for_length


class StreamBatch:
    """Streams of one model, advanced together a frame at a time; subclasses encode their controls."""

    def __init__(self, model, seed: int = 0, sampler: SamplerChoice | None = None):
        self.model = model
        self.generator = torch.Generator(device=model.device).manual_seed(seed)
        self.frames = model.start_streams(0, sampler)  # sampler: default DDPM over all trained steps
        self.streams: list = []

    def join(self, stream) -> int:
        """A new stream at its start; its row."""
        if self.frames.tables.guide is not None and self.streams:  # its running statistics are one batch's
            raise WalkdiffError("a stream batch that matches example clips holds one stream")
        with torch.inference_mode():
            self.frames.add(1)
        self.streams.append(stream)
        return len(self.streams) - 1

    def encode(self, ready: list) -> torch.Tensor:
        """The encoded controls (R, control_hidden) of the streams `ready` for their next frame."""
        raise NotImplementedError

    def step(self) -> int:
        """One frame for every stream with one ready, in one forward; how many streams advanced."""
        ready = [s for s in self.streams if s.ready()]
        if not ready:
            return 0
        every = len(ready) == len(self.streams)
        rows = None if every else torch.tensor([s.row for s in ready], device=self.model.device)
        with torch.inference_mode():
            x = self.model.advance(self.frames, self.encode(ready), self.generator, rows)
            poses = self.model.normalizer.denormalize(x).cpu().numpy()
        for stream, pose in zip(ready, poses):
            stream.receive(pose)
        return len(ready)

    def run(self) -> int:
        """Every frame that is ready, a frame at a time (streams behind others catch up); frames made."""
        made = 0
        while advanced := self.step():
            made += advanced
        return made


class Stream:
    """One stream of a `StreamBatch`: its input is fed (`feed`, `close`: audio or path points), and what
    its batch then makes is handed over (`made`, one frame per row, in the model's feature units)."""

    batch: StreamBatch
    made: list[np.ndarray]

    def push(self, data) -> np.ndarray:
        """Input in -> the frames (n, D) that became computable."""
        self.feed(data)
        self.batch.run()
        return self.take()

    def finish(self) -> np.ndarray:
        """The end of the input -> the remaining frames."""
        self.close()
        self.batch.run()
        return self.take()

    def take(self) -> np.ndarray:
        """The frames made since the last take, (n, D)."""
        made, self.made = self.made, []
        return np.stack(made) if made else np.zeros((0, self.batch.model.spec["feature_dim"]), np.float32)


class GestureBatch(StreamBatch):
    def encode(self, ready: list) -> torch.Tensor:
        windows = torch.from_numpy(np.stack([s.control() for s in ready])).to(self.model.device)
        return self.model.encoder.audio(windows)


class GestureStream(Stream):
    """DiffMotion gestures from mono audio pushed in pieces of any size (float samples in [-1, 1]).

    `rate` defaults to the sample rate of the model's training audio (recorded in checkpoints since
    streaming came); it must be a whole number of samples per motion frame.
    """

    def __init__(
        self,
        model,
        rate: int | None = None,
        seed: int = 0,
        batch: GestureBatch | None = None,
        sampler: SamplerChoice | None = None,
    ):
        spec = model.spec
        rate = rate or spec.get("sample_rate")
        if rate is None:
            raise WalkdiffError("the checkpoint does not record its audio's sample rate: give the rate")
        self.rate, self.fps = int(rate), spec["fps"]
        self.past, self.lookahead, self.window = spec["past"], spec["lookahead"], model.window
        self.features = LogMelStream(self.rate, self.fps, spec["audio_dim"], where=f"{self.rate} Hz audio")
        normalizer = model.audio_normalizer
        self.mean, self.std = normalizer.mean.cpu().numpy(), normalizer.std.cpu().numpy()
        self.padded: list[np.ndarray] = []  # normalised audio frames from `first` - past on, edges repeated
        self.first = 0  # the frame of padded[0] is first - past (older ones are dropped)
        self.frame = 0  # the next frame to make
        self.total: int | None = None  # frames in all, once the audio has ended
        self.made: list[np.ndarray] = []
        self.waited: list[float] = []  # per frame made: the audio time (s) it waited for
        self.batch = batch or GestureBatch(model, seed, sampler)
        self.row = self.batch.join(self)

    def feed(self, samples: np.ndarray) -> None:
        """Audio, without making frames (`GestureBatch.run` makes them for all streams at once)."""
        self._append(self.features.push(samples))

    def close(self) -> None:
        """The audio has ended: the last frames are made with the last audio frame repeated, as offline."""
        if self.features.received == 0:
            raise WalkdiffError("no audio arrived: expected at least one sample")
        self._append(self.features.finish())
        self.total = self.features.frames
        self.padded += [self.padded[-1]] * self.lookahead

    def ready(self) -> bool:
        if self.total is not None:
            return self.frame < self.total
        return len(self.padded) >= self.frame - self.first + self.window

    def control(self) -> np.ndarray:
        """The flattened control window (window * M,) of the next frame, as `DiffMotion.control_windows`."""
        start = self.frame - self.first
        return np.concatenate(self.padded[start : start + self.window])

    def receive(self, pose: np.ndarray) -> None:
        needed = min(self.features.needed(self.frame + self.lookahead), self.features.received)
        self.waited.append(needed / self.rate)
        self.made.append(pose)
        self.frame += 1
        drop = self.frame - self.first - 1
        if drop > 256:  # keep the list short on long streams
            del self.padded[:drop]
            self.first += drop

    def _append(self, mel: np.ndarray) -> None:
        if len(mel) == 0:
            return
        normalized = ((mel - self.mean) / self.std).astype(np.float32)
        if not self.padded:
            self.padded = [normalized[0]] * self.past
        self.padded.extend(normalized)


class WalkBatch(StreamBatch):
    """Walker streams; with `match` (example clips' statistics), one stream whose frames are moved to them
    as `walk --style-clip` moves a whole walk's (`RunningMatch`)."""

    def __init__(self, model, seed: int = 0, sampler: SamplerChoice | None = None, match=None):
        super().__init__(model, seed, sampler)
        if match is not None:
            model.match_streams(self.frames, match, sampler)

    def encode(self, ready: list) -> torch.Tensor:
        control = torch.cat([s.control() for s in ready]).to(self.model.device)
        style = torch.tensor([s.style for s in ready], device=self.model.device)
        return self.model.encode_control(control[:, None], style)[:, 0]


class WalkStream(Stream):
    """A PathWalker walking a path whose points (x, z in the model's units) arrive over time.

    A frame is made once the path reaches past where its control reads it: the walker's closest path
    point is searched within `reach` of the last one, and the control's points lie up to pace[-1]
    beyond it, so a path longer than progress + reach + pace[-1] gives the controls the whole path
    gives. The walk lasts, as `walkdiff walk`, the frames it takes to cover the path at `speed`.
    `match`: example clips' statistics its frames are moved to (in a batch of its own, `WalkBatch`).
    """

    def __init__(
        self,
        model,
        style: int,
        speed: float,
        seed: int = 0,
        batch: WalkBatch | None = None,
        sampler: SamplerChoice | None = None,
        match=None,
    ):
        if not 0 < speed < math.inf:
            raise WalkdiffError(f"the walking speed must be a positive number, got {speed}")
        self.model, self.style, self.speed = model, int(style), float(speed)
        self.pace = model.pace(torch.tensor([speed]))
        self.reach = 2 * float(self.pace[:, -1].max()) + 1.0  # as PathWalker.generate
        self.points: list[np.ndarray] = []
        self.path: Polyline | None = None
        self.closed = False
        self.frame = 0
        self.start: tuple[np.ndarray, float] | None = None
        self.position = self.heading = self.progress = None
        self.made: list[np.ndarray] = []
        self.roots: list[tuple[np.ndarray, float]] = []  # per frame made: root (x, z) and heading there
        self.batch = batch or WalkBatch(model, seed, sampler, match)
        self.row = self.batch.join(self)

    def feed(self, points) -> None:
        """More path points (n, 2), appended to the path. The first point that is not finite, or makes the
        path longer than a walk that fits in memory (`check_frames`, as `walkdiff walk` caps a path file),
        is refused with those after it: a WalkdiffError, the points before it appended."""
        if self.closed:
            raise WalkdiffError("path points arrived after the end of the path")
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        previous = np.asarray(self.points[-1:] or points[:1]).reshape(-1, 2)
        with np.errstate(over="ignore", invalid="ignore"):  # refused below
            steps = np.linalg.norm(np.diff(np.concatenate([previous, points]), axis=0), axis=1)
            ends = (0.0 if self.path is None else self.path.length) + np.cumsum(steps)
        refusal = None
        # Arc lengths only grow, and a non-finite point makes every later one non-finite: the last point
        # passes only if all do.
        if len(points) and self._refusal(points[-1], ends[-1]) is not None:
            keep = next(k for k in range(len(points)) if self._refusal(points[k], ends[k]) is not None)
            refusal, points = self._refusal(points[keep], ends[keep]), points[:keep]
        self._append(points)
        if refusal is not None:
            raise refusal

    def _refusal(self, point: np.ndarray, end: float) -> WalkdiffError | None:
        """Why the path cannot take `point`, which makes it `end` long; None if it can."""
        if not np.isfinite(point).all():
            return WalkdiffError(f"expected a path point of finite numbers, got {point.tolist()}")
        if not np.isfinite(end):
            return WalkdiffError("the path up to this point is too long: its length overflows")
        try:
            frames = frames_for_length(end, self.speed, self.model.spec["fps"])
            check_frames("the path up to this point", frames, WALK_BYTES_PER_FRAME)
        except WalkdiffError as error:
            return error
        return None

    def _append(self, points: np.ndarray) -> None:
        self.points.extend(points)
        if len(self.points) >= 2:
            self.path = Polyline.of(self.points)
        if self.start is None and self.path is not None and self.path.length > 0:
            self.start = path_start(self.path)
            self.position = self.start[0][None].copy()
            self.heading = np.array([self.start[1]])
            self.progress = np.zeros(1)

    def close(self) -> None:
        if self.start is None:
            raise WalkdiffError("the path has no length: expected at least two distinct points")
        self.closed = True

    @property
    def frames(self) -> int:
        """Frames to walk the path known so far (all of it once closed)."""
        return frames_for(self.path, self.speed, self.model.spec["fps"])

    def ready(self) -> bool:
        if self.start is None or self.frame >= self.frames:
            return False
        return self.closed or self.path.length > self.progress[0] + self.reach + self.pace[0, -1]

    def control(self) -> torch.Tensor:
        control, self.progress = path_control(
            self.path, self.position, self.heading, self.progress, self.pace, self.reach
        )
        return control

    def receive(self, pose: np.ndarray) -> None:
        self.roots.append((self.position[0].copy(), float(self.heading[0])))
        self.made.append(pose)
        raw = pose.astype(np.float64)[None]
        self.position, self.heading = advance_root(self.position, self.heading, raw, self.model.layout)
        self.frame += 1


# ---------------------------------------------------------------- inputs that arrive over time


def read_pipe(stream) -> Iterator[bytes]:
    """The bytes of a pipe (standard input's binary buffer) as they come, until end of file."""
    read = getattr(stream, "read1", stream.read)  # read1: what is there, without waiting for a full block
    while data := read(1 << 14):
        yield data


def read_growing(path: str | Path, idle: float, poll: float = 0.02) -> Iterator[bytes]:
    """The bytes of a file that is still being written, until it has not grown for `idle` seconds."""
    path = Path(path)
    if not path.is_file():  # now, not at the first read
        raise WalkdiffError("file not found", path=path)
    return _follow(path, idle, poll)


def _follow(path: Path, idle: float, poll: float) -> Iterator[bytes]:
    with path.open("rb") as f:
        quiet_since = time.monotonic()
        while True:
            data = f.read(1 << 16)
            if data:
                quiet_since = time.monotonic()
                yield data
            elif time.monotonic() - quiet_since >= idle:
                return
            else:
                time.sleep(poll)


def speech_input(audio: str, rate: int | None, trained_rate: int | None) -> PcmDecoder | WavDecoder:
    """The decoder of speech given as `--audio`: raw s16le PCM on stdin ('-', at `rate`, default the
    rate of the model's training audio `trained_rate`) or a WAV file still being written (its own rate)."""
    if audio == "-":
        rate = rate or trained_rate
        if rate is None:
            raise WalkdiffError(
                "--rate: the checkpoint does not record the sample rate of its training audio; give the rate "
                "of the PCM on stdin"
            )
        return PcmDecoder("--audio -", rate)
    if rate is not None:
        raise WalkdiffError("--rate is for raw PCM on stdin (--audio -); a WAV file gives its own rate")
    return WavDecoder(audio, trained_rate)


class PcmDecoder:
    """Raw s16le PCM bytes (mono) at `rate` Hz from stdin -> float samples in [-1, 1), as soundfile reads
    16-bit WAVs."""

    def __init__(self, where: str, rate: int | None = None):
        self.where, self.left, self.bytes, self.rate = where, b"", 0, rate

    def chunks(self, idle: float) -> Iterator[bytes]:
        """Standard input's bytes as they come (`idle` is for files)."""
        return read_pipe(sys.stdin.buffer)

    def decode(self, data: bytes) -> np.ndarray:
        data = self.left + data
        self.bytes += len(data) - len(self.left)
        whole = len(data) - len(data) % 2
        self.left = data[whole:]
        return np.frombuffer(data[:whole], dtype="<i2").astype(np.float32) / np.float32(32768)

    def end(self) -> None:
        if self.left:
            raise WalkdiffError(
                f"{self.where}: {self.bytes} bytes, an odd number: expected s16le samples (2 bytes each)"
            )


class WavDecoder:
    """A WAV file's bytes as they arrive -> float mono samples (channels averaged, as `read_wav`).

    The header is read from the first bytes; its sizes are not trusted (a file still being written
    has placeholders there). 16-bit PCM and 32-bit float samples.
    """

    def __init__(self, where: str, rate: int | None):
        self.where, self.expected_rate = where, rate
        self.head = b""
        self.rate: int | None = None
        self.channels = self.width = 0
        self.left = b""
        self.floating = False
        self.decoded = 0  # samples given so far
        self.bad: WalkdiffError | None = None  # raised at the next call, once the samples before it are out

    def chunks(self, idle: float) -> Iterator[bytes]:
        """The file's bytes as they are written, until it has not grown for `idle` seconds."""
        return read_growing(self.where, idle)

    def decode(self, data: bytes) -> np.ndarray:
        if self.bad is not None:
            raise self.bad
        if self.rate is None:
            self.head += data
            data = self._header()
            if self.rate is None:
                return np.zeros(0, np.float32)
        data = self.left + data
        frame = self.channels * self.width
        whole = len(data) - len(data) % frame
        self.left = data[whole:]
        kind = "<f4" if self.floating else "<i2"
        samples = np.frombuffer(data[:whole], dtype=kind).reshape(-1, self.channels).astype(np.float32)
        if not self.floating:
            samples /= np.float32(32768)
        elif not np.isfinite(samples).all():
            first = int(np.argmin(np.isfinite(samples).all(axis=1)))
            at = (self.decoded + first) / self.rate
            self.bad = WalkdiffError(
                f"{self.where}: a sample that is not a finite number at {at:.3f} s; expected audio in [-1, 1]"
            )
            samples = samples[:first]
        self.decoded += len(samples)
        return samples.mean(axis=1)

    def end(self) -> None:
        if self.bad is not None:
            raise self.bad
        if self.rate is None:
            raise WalkdiffError(f"{self.where}: no WAV header with a 'data' chunk arrived")

    def _header(self) -> bytes:
        """Parse the RIFF header once its 'data' chunk has begun; the bytes after it."""
        head = self.head
        if len(head) >= 12 and (head[:4] != b"RIFF" or head[8:12] != b"WAVE"):
            raise WalkdiffError(f"{self.where}: not a WAV file (expected a RIFF/WAVE header)")
        at, fmt = 12, None
        while at + 8 <= len(head):
            name, size = head[at : at + 4], struct.unpack("<I", head[at + 4 : at + 8])[0]
            if name == b"data":
                if fmt is None:
                    raise WalkdiffError(f"{self.where}: the WAV's 'data' chunk comes before its 'fmt ' chunk")
                self._format(fmt)
                return head[at + 8 :]
            if at + 8 + size > len(head):
                return b""
            if name == b"fmt ":
                fmt = head[at + 8 : at + 8 + size]
            at += 8 + size + size % 2
        if len(head) > 1 << 20:
            raise WalkdiffError(f"{self.where}: no 'data' chunk in the first MB of the WAV")
        return b""

    def _format(self, fmt: bytes) -> None:
        tag, channels, rate, _, _, bits = struct.unpack("<HHIIHH", fmt[:16])
        if tag == 0xFFFE and len(fmt) >= 26:  # WAVE_FORMAT_EXTENSIBLE: the real tag opens the subformat
            tag = struct.unpack("<H", fmt[24:26])[0]
        if (tag, bits) not in ((1, 16), (3, 32)) or channels < 1:
            raise WalkdiffError(
                f"{self.where}: a WAV of format {tag} with {bits}-bit samples; expected 16-bit PCM or "
                "32-bit float"
            )
        if self.expected_rate is not None and rate != self.expected_rate:
            raise WalkdiffError(
                f"{self.where}: {rate} Hz; the model was trained on {self.expected_rate} Hz audio: "
                f"resample it (e.g. ffmpeg -ar {self.expected_rate})"
            )
        self.rate, self.channels, self.width, self.floating = rate, channels, bits // 8, tag == 3


def emit(line: dict) -> None:
    """One JSON line on stdout, flushed: a live consumer reads it as soon as it is made. One write of the
    line and its newline: Ctrl-C between print's two writes left a line without its end, and the
    interrupted stream's summary then joined it."""
    sys.stdout.write(json.dumps(line, separators=(",", ":")) + "\n")
    sys.stdout.flush()


class Interrupted(KeyboardInterrupt):
    """Ctrl-C on a stream, raised once what it made is written: its message says where (the command
    line prints it on one line and exits 130)."""


class StreamEnd:
    """How a stream command's input ended: as it should, with bad input midway (`error`, a WalkdiffError)
    or by Ctrl-C (`error`, a KeyboardInterrupt). Every stream command reads its input inside `watch()`,
    makes its last frames with `finish`, writes the frames made (atomically: a complete file or none),
    then raises `stopped(end.error, ...)` if the input did not end as it should."""

    def __init__(self) -> None:
        self.error: WalkdiffError | KeyboardInterrupt | None = None

    @property
    def interrupted(self) -> bool:
        return isinstance(self.error, KeyboardInterrupt)

    @contextmanager
    def watch(self) -> Iterator[None]:
        """Bad input or Ctrl-C inside stops the input there; the frames made before it are kept."""
        try:
            yield
        except (WalkdiffError, KeyboardInterrupt) as error:
            self.error = error

    def finish(self, make) -> None:
        """`make()` the frames the input allows, unless Ctrl-C came (the user wants out, not more
        frames); a Ctrl-C during it stops it, keeping what it made."""
        if self.interrupted:
            return
        try:
            make()
        except KeyboardInterrupt as error:
            self.error = error


def stopped(error: WalkdiffError | KeyboardInterrupt, frames: int, files: list[Path]) -> Exception:
    """A stream whose input went bad or was interrupted: its last JSON line says so, with the frames made
    before and the files they were written to; the error to raise names the input's fault (or Ctrl-C) and
    where those frames are."""
    if isinstance(error, KeyboardInterrupt):
        emit({"done": False, "frames": frames, "interrupted": True, "files": [str(f) for f in files]})
        if not files:
            return Interrupted(f"{frames} frames made, nothing written")
        return Interrupted(f"the {frames} frames made so far are in {', '.join(str(f) for f in files)}")
    emit({"done": False, "frames": frames, "error": str(error), "files": [str(f) for f in files]})
    if not files:
        return error
    kept = f"the {frames} frames made before it are in {', '.join(str(f) for f in files)}"
    return WalkdiffError(f"{error.reason}; {kept}", path=error.path, line=error.line)
