"""HumanAct12 (Guo et al. 2020, Action2Motion) as distributed in `humanact12poses.pkl`: 12 actions, no styles.

The file (see README.md, section "HumanAct12") is a pickled dict of three lists, one entry per clip:
`poses` (T, 72) SMPL axis-angle rotations (24 joints, the pelvis's in world axes), `joints3D` (T, 24, 3)
joint positions in metres, and `y` the action id 0-11. Clips are at 20 fps, the rate Action2Motion and
ACTOR use for this set.

A clip becomes a `Motion` on the 24-joint SMPL tree (walkdiff.motion.smpl):
- rotations: the axis-angle poses as matrices;
- root position: the pelvis of `joints3D`;
- bone offsets: per clip, the rest-frame bone vectors that, under the poses, best reproduce `joints3D`
  (`rest_offsets`: the mean over frames of R_parent(t)^T (p_joint(t) - p_parent(t))). When `joints3D`
  were made by SMPL from these poses that is exact, and the clip's FK gives `joints3D` back;
- axes: walkdiff is Y-up. The file's up axis is found from the data (the signed world axis closest to
  the mean pelvis -> neck direction over all clips) and turned onto +Y; `load_clip(..., up=...)` names
  it instead. The clip is lifted so that its lowest joint over the clip touches y = 0.

HumanAct12 has no test split. The published protocol compares generated motion with the real data
itself, so `test` holds every selected clip; `val` is a deterministic 10% of each action's clips (at
least one when the action has two or more), `train` the rest.
"""

from __future__ import annotations

import functools
import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import roma
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.data.clips import ClipInfo, ContentSelection, deterministic_order
from walkdiff.motion.skeleton import Motion
from walkdiff.motion.smpl import BVH_ORDER, NUM_JOINTS, SMPL_NAMES, rest_offsets, smpl_skeleton

FILE_NAME = "humanact12poses.pkl"
FPS = 20.0
STYLES = ("none",)
GROUPS = (
    "warm_up", "walk", "run", "jump", "drink", "lift_dumbbell", "sit", "eat", "turn_steering_wheel",
    "phone", "boxing", "throw",
)  # fmt: skip
VAL_FRACTION = 0.1

# SMPL's ankles stand for the heels and its 'foot' joints for the toes (the balls of the feet): the
# skeleton profile finds them by name. The joints are in metres.
PROFILE = {"units": "m"}

SCHEMA = (
    f"expected a pickled dict with keys poses (per clip: T x 72 SMPL axis-angle), joints3D (T x 24 x 3) "
    f"and y (action id 0-{len(GROUPS) - 1}), as in {FILE_NAME} of Action2Motion / ACTOR"
)

# Rotations that turn a signed world axis onto +Y (the smallest turn; any would keep the motion rigid).
UP_ROTATIONS = {
    "+y": np.eye(3),
    "-y": np.diag([1.0, -1.0, -1.0]),
    "+z": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "-z": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
    "+x": np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]),
    "-x": np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]]),
}


@dataclass(frozen=True)
class PklData:
    poses: list[np.ndarray]  # per clip (T, 24, 3) axis-angle
    joints: list[np.ndarray]  # per clip (T, 24, 3)
    actions: list[int]
    up: str  # the file's up axis found from the data, a key of UP_ROTATIONS


def read_pkl(path: str | Path) -> PklData:
    """The checked contents of a humanact12poses.pkl, read once per version of the file."""
    path = Path(path)
    try:
        stat = path.stat()
    except OSError as e:
        raise WalkdiffError(f"cannot read the HumanAct12 file ({e.strerror}); {SCHEMA}", path=path) from None
    return _read_pkl(path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=2)
def _read_pkl(path: Path, mtime_ns: int, size: int) -> PklData:
    """Cached on (path, mtime, size): every clip of the data set lives in this one file."""
    try:
        with path.open("rb") as f:
            data = pickle.load(f)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError, ValueError) as e:
        raise WalkdiffError(f"cannot unpickle the file ({e}); {SCHEMA}", path=path) from None
    if not isinstance(data, dict):
        raise WalkdiffError(f"found a {type(data).__name__}; {SCHEMA}", path=path)
    for key in ("poses", "joints3D", "y"):
        if key not in data:
            raise WalkdiffError(f"missing key {key!r}; {SCHEMA}", path=path)
        if not isinstance(data[key], (list, tuple, np.ndarray)):
            raise WalkdiffError(
                f"{key} is of type {type(data[key]).__name__}: expected a list, one entry per clip", path=path
            )
    counts = {key: len(data[key]) for key in ("poses", "joints3D", "y")}
    if len(set(counts.values())) != 1 or counts["y"] == 0:
        listing = ", ".join(f"{key} {n}" for key, n in counts.items())
        raise WalkdiffError(
            f"clip counts {listing}: expected the same number (> 0) in each; {SCHEMA}", path=path
        )

    poses, joints, actions = [], [], []
    for i, (pose, joint, action) in enumerate(zip(data["poses"], data["joints3D"], data["y"])):
        pose, joint = np.asarray(pose, dtype=np.float64), np.asarray(joint, dtype=np.float64)
        if pose.ndim != 2 or pose.shape[1] != 3 * NUM_JOINTS or pose.shape[0] < 1:
            raise WalkdiffError(
                f"poses[{i}] has shape {pose.shape}: expected (T, 72), T >= 1 frames of 24 SMPL "
                "axis-angle rotations",
                path=path,
            )
        frames = pose.shape[0]
        if joint.shape != (frames, NUM_JOINTS, 3):
            raise WalkdiffError(
                f"joints3D[{i}] has shape {joint.shape}: expected ({frames}, 24, 3), the frames of "
                f"poses[{i}] times 24 SMPL joints",
                path=path,
            )
        if not (np.isfinite(pose).all() and np.isfinite(joint).all()):
            raise WalkdiffError(f"clip {i}: poses or joints3D hold NaN or infinite values", path=path)
        if not (np.ndim(action) == 0 and float(action).is_integer() and 0 <= action < len(GROUPS)):
            raise WalkdiffError(f"y[{i}] is {action!r}: expected an action id 0-{len(GROUPS) - 1}", path=path)
        poses.append(pose.reshape(frames, NUM_JOINTS, 3))
        joints.append(joint)
        actions.append(int(action))
    return PklData(poses, joints, actions, _find_up(joints))


def _find_up(joints: list[np.ndarray]) -> str:
    """The signed world axis closest to the mean pelvis -> neck direction over all frames."""
    neck, pelvis = SMPL_NAMES.index("neck"), SMPL_NAMES.index("pelvis")
    direction = sum((j[:, neck] - j[:, pelvis]).sum(axis=0) for j in joints)
    axis = int(np.argmax(np.abs(direction)))
    return ("+" if direction[axis] >= 0 else "-") + "xyz"[axis]


def clip_name(item: int) -> str:
    return f"humanact12_{item:04d}"


def list_clips(folder: Path) -> list[ClipInfo]:
    path = Path(folder) / FILE_NAME
    if not path.is_file():
        raise WalkdiffError(
            f"{FILE_NAME} not found; get it with Action2Motion's or ACTOR's HumanAct12Poses download "
            "(README.md, section 'HumanAct12') and put it in this folder",
            path=path,
        )
    data = read_pkl(path)
    return [
        ClipInfo(path=path, name=clip_name(i), style=0, content=action, item=i)
        for i, action in enumerate(data.actions)
    ]


def split_clips(clips: list[ClipInfo], selection: ContentSelection) -> dict[str, list[ClipInfo]]:
    """Per selected action: a hash-ranked 10% (at least one of two or more) for val, the rest for train;
    test is every selected clip, as the protocol scores against the real data itself."""
    splits: dict[str, list[ClipInfo]] = {"train": [], "val": [], "test": []}
    for action, name in enumerate(GROUPS):
        if name not in selection.names:
            continue
        ranked = deterministic_order([c for c in clips if c.content == action])
        n_val = max(1, round(VAL_FRACTION * len(ranked))) if len(ranked) >= 2 else 0
        splits["val"] += ranked[:n_val]
        splits["train"] += ranked[n_val:]
        splits["test"] += ranked
    return splits


def load_clip(path: str | Path, item: int, up: str = "auto") -> Motion:
    """Clip `item` of a humanact12poses.pkl as a Y-up Motion; `up`: the file's up axis ('+y', '-z', ...)
    or 'auto' to find it from the data."""
    data = read_pkl(path)
    if not 0 <= item < len(data.actions):
        raise WalkdiffError(f"clip {item} asked for; the file has clips 0-{len(data.actions) - 1}", path=path)
    up = data.up if up == "auto" else up
    if up not in UP_ROTATIONS:
        raise WalkdiffError(f"up axis {up!r}: expected 'auto' or one of {', '.join(UP_ROTATIONS)}")
    to_y_up = UP_ROTATIONS[up]

    rotations = roma.rotvec_to_rotmat(torch.from_numpy(data.poses[item])).numpy()
    rotations[:, 0] = to_y_up @ rotations[:, 0]  # only the root's rotation is in world axes
    joints = data.joints[item] @ to_y_up.T
    joints[..., 1] -= joints[..., 1].min()
    offsets, _ = rest_offsets(rotations, joints)

    skeleton = smpl_skeleton(offsets)
    positions = np.repeat(skeleton.offsets[None], joints.shape[0], axis=0)
    positions[:, 0] = joints[:, 0]
    return Motion(skeleton, rotations[:, BVH_ORDER], positions, 1.0 / FPS)


def load(clip: ClipInfo) -> Motion:
    return load_clip(clip.path, clip.item)
