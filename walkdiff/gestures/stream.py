"""DiffMotion gestures from speech that is still arriving: `GestureStream`s of a `GestureBatch`
(streams/batch.py), and the speech's bytes decoded as they come (raw PCM on stdin, a WAV being written)."""

from __future__ import annotations

import struct
import sys
from collections.abc import Iterator

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.data.speech import LogMelBatch, samples_per_frame
from walkdiff.diffusion import SamplerChoice
from walkdiff.streams.batch import Stream, StreamBatch
from walkdiff.streams.inputs import read_growing, read_pipe


class GestureBatch(StreamBatch):
    """Gesture streams of one model. Their audio features are kept here for all of them: a stream's
    samples go to its row of a `LogMelBatch` (one per sample rate), and each step first computes the
    frames all the streams' samples completed, at once, and keeps them normalised in one array
    (`history`, a row per stream) from which the control windows of the ready streams are gathered."""

    def __init__(self, model, seed: int = 0, sampler: SamplerChoice | None = None):
        super().__init__(model, seed, sampler)
        spec = model.spec
        self.fps, self.bands = spec["fps"], spec["audio_dim"]
        self.past, self.lookahead, self.window = spec["past"], spec["lookahead"], model.window
        normalizer = model.audio_normalizer
        self.mean, self.std = normalizer.mean.cpu().numpy(), normalizer.std.cpu().numpy()
        self.mels: dict[int, tuple[LogMelBatch, list[int]]] = {}  # rate -> features, each of its rows' row
        # Per stream row: normalised audio frames from frame `first` - past on (the first frame repeated
        # `past` times before it, the last `lookahead` times after it once the audio has ended, as
        # offline), `have` of them; frames made so far (`done`); frames in all once ended (else -1).
        self.history = np.zeros((0, 4 * self.window, self.bands), np.float32)
        self.first = np.zeros(0, np.int64)
        self.have = np.zeros(0, np.int64)
        self.done = np.zeros(0, np.int64)
        self.total = np.zeros(0, np.int64)
        self.ending: list[int] = []  # rows whose audio ended since the last step (padded once computed)

    def join(self, stream: GestureStream) -> int:
        if stream.rate not in self.mels:
            where = f"{stream.rate} Hz audio"
            self.mels[stream.rate] = (LogMelBatch(stream.rate, self.fps, self.bands, where), [])
        features, rows = self.mels[stream.rate]
        row = super().join(stream)
        stream.features, stream.feature_row = features, features.add()
        rows.append(row)
        if row == len(self.history):  # room for more rows, by doubling: joining n streams copies O(n) rows
            grown = np.zeros((max(1, 2 * row), *self.history.shape[1:]), np.float32)
            grown[:row] = self.history
            self.history = grown
            self.first, self.have, self.done, self.total = (
                np.resize(a, len(grown)) for a in (self.first, self.have, self.done, self.total)
            )
        self.first[row] = self.have[row] = self.done[row] = 0
        self.total[row] = -1
        return row

    def end(self, row: int, frames: int) -> None:
        """The audio of the stream at `row` has ended after `frames` frames."""
        self.total[row] = frames
        self.ending.append(row)

    def ready(self) -> np.ndarray:
        self._features()
        n = len(self.streams)
        done, total = self.done[:n], self.total[:n]
        whole = self.have[:n] - (done - self.first[:n]) >= self.window  # the next frame's window is in
        return np.flatnonzero(np.where(total >= 0, done < total, whole))

    def encode(self, rows: np.ndarray) -> torch.Tensor:
        start = self.done[rows] - self.first[rows]
        windows = self.history[rows[:, None], start[:, None] + np.arange(self.window)]  # (R, window, M)
        windows = torch.from_numpy(windows.reshape(len(rows), -1)).to(self.model.device)
        return self.model.encoder.audio(windows)

    def advanced(self, ready: np.ndarray, poses: np.ndarray) -> None:
        super().advanced(ready, poses)
        self.done[ready] += 1

    def _features(self) -> None:
        """The audio frames the streams' samples completed since the last step, into `history`."""
        for features, feature_rows in self.mels.values():
            at, frame, mel = features.compute()
            if not len(at):
                continue
            rows = np.asarray(feature_rows)[at]
            normalized = ((mel - self.mean) / self.std).astype(np.float32)
            self._room(rows, frame + self.past)
            spot = self.past + frame - self.first[rows]
            self.history[rows, spot] = normalized
            starts = frame == 0
            if starts.any():
                self.history[rows[starts], : self.past] = normalized[starts][:, None]
            np.maximum.at(self.have, rows, spot + 1)
        for row in self.ending:
            end = self.total[row] + self.past + self.lookahead
            self._room(np.array([row]), np.array([end - 1]))
            have = self.have[row]
            self.history[row, have : have + self.lookahead] = self.history[row, have - 1]
            self.have[row] += self.lookahead
        self.ending = []

    def _room(self, rows: np.ndarray, last: np.ndarray) -> None:
        """Room in `history` for entry `last` (counted from the stream's start, padding included) of each
        row `rows`: the frames before the next frame's window dropped, then the array widened if still
        needed."""
        over = last - self.first[rows] >= self.history.shape[1]
        if not over.any():
            return
        for row, end in zip(rows[over].tolist(), last[over].tolist()):
            drop = int(self.done[row] - self.first[row])
            if end - self.first[row] < self.history.shape[1] or drop == 0:
                continue
            keep = int(self.have[row]) - drop
            self.history[row, :keep] = self.history[row, drop : drop + keep]
            self.first[row] += drop
            self.have[row] = keep
        width = int((last - self.first[rows]).max()) + 1
        if width > self.history.shape[1]:
            width = max(width, 2 * self.history.shape[1])
            wider = np.zeros((len(self.history), width, self.bands), np.float32)
            wider[:, : self.history.shape[1]] = self.history
            self.history = wider


class GestureStream(Stream):
    """DiffMotion gestures from mono audio pushed in pieces of any size (float samples in [-1, 1]).

    `rate` defaults to the sample rate of the model's training audio (recorded in checkpoints since
    streaming came); it must be a whole number of samples per motion frame. Its audio features are
    computed and kept by its batch (`GestureBatch`), with those of the batch's other streams.
    """

    features: LogMelBatch  # its batch's features of audio at its rate (its row: `feature_row`)
    feature_row: int

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
        self.rate, self.fps, self.lookahead = int(rate), spec["fps"], spec["lookahead"]
        samples_per_frame(self.rate, self.fps, f"{self.rate} Hz audio")  # refused before joining a batch
        self.made: list[np.ndarray] = []
        self.waited: list[float] = []  # per frame made: the audio time (s) it waited for
        self.batch = batch or GestureBatch(model, seed, sampler)
        self.row = self.batch.join(self)

    @property
    def received(self) -> int:
        """Samples fed so far."""
        return self.features.received[self.feature_row]

    @property
    def frame(self) -> int:
        """The next frame to make."""
        return int(self.batch.done[self.row])

    def feed(self, samples: np.ndarray) -> None:
        """Audio, without making frames (`GestureBatch.run` makes them for all streams at once)."""
        self.features.push(self.feature_row, samples)

    def close(self) -> None:
        """The audio has ended: the last frames are made with the last audio frame repeated, as offline."""
        if self.received == 0:
            raise WalkdiffError("no audio arrived: expected at least one sample")
        self.features.finish(self.feature_row)
        self.batch.end(self.row, self.features.frames[self.feature_row])

    def ready(self) -> bool:
        return self.row in self.batch.ready()

    def control(self) -> np.ndarray:
        """The flattened control window (window * M,) of the next frame, as `DiffMotion.control_windows`."""
        batch = self.batch
        batch.ready()
        start = self.frame - int(batch.first[self.row])
        return batch.history[self.row, start : start + batch.window].reshape(-1)

    def receive(self, pose: np.ndarray) -> None:
        needed = min(self.features.needed(self.frame + self.lookahead), self.received)
        self.waited.append(needed / self.rate)
        self.made.append(pose)


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
