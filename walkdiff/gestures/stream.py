"""DiffMotion gestures from speech that is still arriving: `GestureStream`s of a `GestureBatch`
(streams/batch.py), and the speech's bytes decoded as they come (raw PCM on stdin, a WAV being written)."""

from __future__ import annotations

import struct
import sys
from collections.abc import Iterator

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.data.speech import LogMelStream
from walkdiff.diffusion import SamplerChoice
from walkdiff.streams.batch import Stream, StreamBatch
from walkdiff.streams.inputs import read_growing, read_pipe


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
