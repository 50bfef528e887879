"""Skeleton hierarchy and motion clips: plain numpy containers, no file format, no Lightning.

Conventions used throughout walkdiff:
- joints are stored in BVH (depth-first) order, so every parent index is smaller than its child's;
- `parents[0] == -1` (the root);
- rotations are local rotation matrices (parent <- child), float64;
- `Motion.positions` holds each joint's local translation per frame: the root's world position, the
  channel-driven translation of any other joint that has position channels, and the bone offset of
  every joint that does not.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")


@dataclass
class Skeleton:
    names: list[str]
    parents: np.ndarray  # (J,) int, -1 for the root
    offsets: np.ndarray  # (J, 3) float64 rest translation of each joint in its parent's frame
    channels: list[tuple[str, ...]]  # per joint, BVH channel names in file order
    end_sites: dict[int, np.ndarray] = field(default_factory=dict)  # joint index -> End Site offset (3,)

    def __post_init__(self) -> None:
        self.parents = np.asarray(self.parents, dtype=np.int64)
        self.offsets = np.asarray(self.offsets, dtype=np.float64)

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"joint {name!r} not in skeleton ({', '.join(self.names)})") from None

    def rotation_order(self, joint: int) -> str:
        """Rotation axes in file order, e.g. 'ZYX' for `Zrotation Yrotation Xrotation` ('' if none)."""
        return "".join(c[0] for c in self.channels[joint] if c in ROTATION_CHANNELS)

    def position_order(self, joint: int) -> str:
        return "".join(c[0] for c in self.channels[joint] if c in POSITION_CHANNELS)

    def children(self, joint: int) -> list[int]:
        return [j for j, p in enumerate(self.parents) if p == joint]

    def same_hierarchy(self, other: Skeleton) -> bool:
        return self.names == other.names and np.array_equal(self.parents, other.parents)


@dataclass
class Motion:
    skeleton: Skeleton
    rotations: np.ndarray  # (F, J, 3, 3) float64 local rotation matrices
    positions: np.ndarray  # (F, J, 3) float64 local translations (see module docstring)
    frame_time: float  # seconds per frame

    def __post_init__(self) -> None:
        self.rotations = np.asarray(self.rotations, dtype=np.float64)
        self.positions = np.asarray(self.positions, dtype=np.float64)

    @property
    def num_frames(self) -> int:
        return self.rotations.shape[0]

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    @property
    def duration(self) -> float:
        return self.num_frames * self.frame_time

    @property
    def root_positions(self) -> np.ndarray:
        return self.positions[:, 0]

    def slice(self, start: int, stop: int) -> Motion:
        return replace(self, rotations=self.rotations[start:stop], positions=self.positions[start:stop])


def skeleton_to_dict(skeleton: Skeleton) -> dict:
    """Plain-python form (JSON / checkpoint friendly)."""
    return {
        "names": list(skeleton.names),
        "parents": skeleton.parents.tolist(),
        "offsets": skeleton.offsets.tolist(),
        "channels": [list(c) for c in skeleton.channels],
        "end_sites": {str(j): np.asarray(o).tolist() for j, o in skeleton.end_sites.items()},
    }


def skeleton_from_dict(data: dict) -> Skeleton:
    return Skeleton(
        names=list(data["names"]),
        parents=np.asarray(data["parents"]),
        offsets=np.asarray(data["offsets"]),
        channels=[tuple(c) for c in data["channels"]],
        end_sites={int(j): np.asarray(o, dtype=np.float64) for j, o in data["end_sites"].items()},
    )
