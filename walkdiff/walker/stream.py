"""A path walker walking a path that is still being drawn: `WalkStream`s of a `WalkBatch`
(streams/batch.py)."""

from __future__ import annotations

import math

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.memory import WALK_BYTES_PER_FRAME, check_frames
from walkdiff.diffusion import SamplerChoice
from walkdiff.models.path_walker import advance_root, path_control, path_start
from walkdiff.motion.path import Polyline, frames_for, frames_for_length
from walkdiff.streams.batch import Stream, StreamBatch


class WalkBatch(StreamBatch):
    """Walker streams; with `match` (example clips' statistics), one stream whose frames are moved to them
    as `walk --style-clip` moves a whole walk's (`RunningMatch`)."""

    def __init__(self, model, seed: int = 0, sampler: SamplerChoice | None = None, match=None):
        super().__init__(model, seed, sampler)
        if match is not None:
            model.match_streams(self.frames, match, sampler)

    def encode(self, rows: np.ndarray) -> torch.Tensor:
        ready = [self.streams[row] for row in rows.tolist()]
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
