"""Streams of one frame model advanced together: gestures from speech that is still arriving (gestures/
stream.py), walking along a path that is still being drawn (walker/stream.py).

A stream takes in what its control needs (audio, or path points) and its batch knows when its next frame
is ready (a walk stream keeps its path; a gesture batch keeps all its streams' audio features, computed
together); a batch of streams of one model carries their LSTM state and previous poses (`FrameStreams`)
and, per frame, runs one forward for all the streams that have a frame ready:

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

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion import SamplerChoice


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

    def encode(self, rows: np.ndarray) -> torch.Tensor:
        """The encoded controls (R, control_hidden) of the streams at `rows` for their next frame."""
        raise NotImplementedError

    def ready(self) -> np.ndarray:
        """The rows of the streams with a frame ready, in order."""
        return np.flatnonzero([s.ready() for s in self.streams])

    def step(self) -> int:
        """One frame for every stream with one ready, in one forward; how many streams advanced."""
        ready = self.ready()
        if not len(ready):
            return 0
        every = len(ready) == len(self.streams)
        rows = None if every else torch.from_numpy(ready).to(self.model.device)
        with torch.inference_mode():
            x = self.model.advance(self.frames, self.encode(ready), self.generator, rows)
            poses = self.model.normalizer.denormalize(x).cpu().numpy()
        self.advanced(ready, poses)
        return len(ready)

    def advanced(self, ready: np.ndarray, poses: np.ndarray) -> None:
        """The streams at rows `ready` made their frames `poses` (R, D)."""
        streams = self.streams
        for row, pose in zip(ready.tolist(), poses):
            streams[row].receive(pose)

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
