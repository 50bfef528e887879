"""2-D paths on the ground plane (x, z): reading them from JSON, arc length, projection, distance.

A path file is JSON, either a list of points `[[x, z], ...]` or an object
`{"points": [[x, z], ...], "speed": 1.4}` with an optional walking speed, in metres and metres per
second whatever the skeleton: the walker converts them with its skeleton profile's units. x and z are
the two ground axes (the profile turns any up axis to y).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_json


@dataclass
class Polyline:
    """A path as a polyline: `points` (N, 2) and the arc length `s` (N,) at each of them."""

    points: np.ndarray
    s: np.ndarray

    @classmethod
    def of(cls, points) -> Polyline:
        points = np.asarray(points, dtype=np.float64)
        with np.errstate(over="ignore"):  # points too far apart make an infinite length, refused by callers
            keep = np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-9])
            points = points[keep]  # repeated points would give zero-length segments
            s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
        return cls(points, s)

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def at(self, s: np.ndarray) -> np.ndarray:
        """Points (..., 2) at arc lengths `s` (...), clamped to the ends."""
        s = np.clip(s, 0.0, self.length)
        return np.stack([np.interp(s, self.s, self.points[:, k]) for k in range(2)], axis=-1)

    def direction(self, s: float) -> np.ndarray:
        """Unit tangent at arc length `s`."""
        i = int(np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.s) - 2))
        d = self.points[i + 1] - self.points[i]
        return d / np.linalg.norm(d)

    def project(self, xz: np.ndarray, near: np.ndarray | None = None, reach: float = math.inf):
        """Closest points to `xz` (B, 2): (arc lengths (B,), distances (B,)).

        With `near` (B,), only the part of the path within `reach` of those arc lengths is searched,
        so a walker on a path that crosses itself keeps to its own stretch.
        """
        a, b = self.points[:-1], self.points[1:]  # segments (S, 2)
        ab = b - a
        rel = xz[:, None, :] - a[None]  # (B, S, 2)
        u = np.clip((rel * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)  # (B, S)
        closest = a[None] + u[..., None] * ab[None]
        distance = np.linalg.norm(xz[:, None, :] - closest, axis=-1)
        s = self.s[:-1][None] + u * np.linalg.norm(ab, axis=-1)[None]
        if near is not None:
            distance = np.where(np.abs(s - near[:, None]) <= reach, distance, np.inf)
        best = distance.argmin(axis=1)
        rows = np.arange(len(xz))
        return s[rows, best], distance[rows, best]

    def distance(self, xz: np.ndarray) -> np.ndarray:
        """Distance of each point (..., 2) to the path."""
        flat = xz.reshape(-1, 2)
        return self.project(flat)[1].reshape(xz.shape[:-1])


def read_path(path: str | Path) -> tuple[Polyline, float | None]:
    """A path file -> (polyline, speed or None); errors name the file and the field."""
    path = Path(path)
    if not path.is_file():
        raise WalkdiffError("path file not found", path=path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        line = getattr(error, "lineno", None)
        raise WalkdiffError(f"not valid JSON ({error})", path=path, line=line) from None
    speed = None
    if isinstance(data, dict):
        unknown = set(data) - {"points", "speed"}
        if unknown or "points" not in data:
            raise WalkdiffError(
                f"expected an object with 'points' (and optionally 'speed'), got keys {sorted(data)}",
                path=path,
            )
        speed = data.get("speed")
        if speed is not None and (not isinstance(speed, int | float) or not 0 < speed < math.inf):
            raise WalkdiffError(f"'speed' must be a positive number (m/s), got {speed!r}", path=path)
        data = data["points"]
    return checked_polyline(data, path), None if speed is None else float(speed)


def checked_polyline(points, path: str | Path | None = None) -> Polyline:
    """A path from its points [[x, z], ...] (a JSON list, or pairs from Python), or a WalkdiffError
    naming the point that is wrong and `path`, the file they came from."""
    if not isinstance(points, list | tuple) or len(points) < 2:
        raise WalkdiffError("'points' must be a list of at least 2 [x, z] pairs", path=path)
    for i, point in enumerate(points):
        if (
            not isinstance(point, list | tuple)
            or len(point) != 2
            or not all(isinstance(v, int | float) and math.isfinite(v) for v in point)
        ):
            raise WalkdiffError(
                f"points[{i}] must be a pair of finite numbers [x, z], got {point!r}", path=path
            )
    polyline = Polyline.of(points)
    if polyline.length <= 0:
        raise WalkdiffError("the path has no length: all its points coincide", path=path)
    if not math.isfinite(polyline.length):
        raise WalkdiffError("the path's length overflows: expected coordinates in metres", path=path)
    return polyline


def write_path(path: str | Path, points: np.ndarray, speed: float | None = None) -> None:
    data = {"points": np.asarray(points).round(4).tolist()} | ({} if speed is None else {"speed": speed})
    write_json(path, data)


def frames_for(path: Polyline, speed: float, fps: float) -> int:
    """Frames to walk the whole path at `speed`."""
    return frames_for_length(path.length, speed, fps)


def frames_for_length(length: float, speed: float, fps: float) -> int:
    """Frames to walk `length` at `speed`, both ends included."""
    # A hair of tolerance: speeds are float32 tensors and paths converted from metres, so a walk of a
    # whole number of frames may come out a millionth of a frame longer.
    return max(2, math.ceil(length / speed * fps - 1e-4) + 1)
