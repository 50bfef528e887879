"""Keys of `sample(keys=...)` and `walkdiff sample --keys`: poses, root positions and headings a clip
passes through, read from a BVH of key poses, a JSON file or Python dicts, and turned into the
constraint the masked sampler keeps (styled/editing.py)."""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import FeatureLayout, encode, start_pose
from walkdiff.motion.skeleton import Motion
from walkdiff.styled.editing import Constraint, RootKey


@dataclass
class Key:
    """One key of `sample(keys=...)`: at `frame`, a pose (a one-frame canonical clip, which places the
    root too), or a root position (x, z canonical) and/or heading (radians)."""

    frame: int
    pose: Motion | None = None
    position: tuple[float, float] | None = None
    heading: float | None = None
    where: str = "keys"


def keys_constraint(keys: list[Key], frames: int, profile: SkeletonProfile) -> Constraint:
    """The constraint of keys over a clip of `frames` frames (each key checked to lie inside it)."""
    layout = FeatureLayout(profile.canonical_skeleton.num_joints)
    known = np.zeros((frames, layout.dim), np.float32)
    mask = np.zeros((frames, layout.dim), bool)
    root_keys: dict[int, RootKey] = {}
    for key in sorted(keys, key=lambda k: k.frame):
        if not 0 <= key.frame < frames:
            raise WalkdiffError(
                f"{key.where}: key at frame {key.frame} is outside the {frames}-frame clip (frames 0 to "
                f"{frames - 1}); give a frame inside it or a longer --frames"
            )
        if key.frame in root_keys:
            raise WalkdiffError(f"{key.where}: two keys at frame {key.frame}; give one key per frame")
        position, heading = key.position, key.heading
        if key.pose is not None:
            features = encode(key.pose, profile)[0]
            for channels in (layout.root_height, layout.rotations):
                known[key.frame, channels], mask[key.frame, channels] = features[channels], True
            here, facing = start_pose(key.pose, profile)
            position = tuple(here) if position is None else position
            heading = facing if heading is None else heading
        root_keys[key.frame] = RootKey(key.frame, position, heading)
    return Constraint(known, mask, list(root_keys.values()))


def read_keys(spec, profile: SkeletonProfile, frames: int) -> list[Key]:
    """Keys from what a user gave: a BVH of key poses on the model's skeleton, `FILE.bvh@F0,F1,...` with
    their frame numbers (without them: spread evenly over the clip), a JSON file
    ({"keys": [{"frame": 30, "root": [x, y, z], "heading": 90, "pose": "pose.bvh", "pose_frame": 0}]}:
    the root in the file's axes and units, the heading in degrees counter-clockwise seen from above, 0
    facing the way an unkeyed clip starts), or a list of such dicts (Python)."""
    if isinstance(spec, list | tuple):
        return [_json_key(k, i, profile, "keys") for i, k in enumerate(spec)]
    text = os.fspath(spec)
    path, _, numbers = text.partition("@") if text.lower().endswith(".json") is False else (text, "", "")
    path = Path(path)
    if not path.is_file():
        raise WalkdiffError("--keys: no such file (expected a BVH of key poses or a JSON of keys)", path=path)
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(path.read_text())
        except (ValueError, UnicodeDecodeError) as error:
            raise WalkdiffError(f"--keys: not JSON ({error})", path=path) from None
        entries = data.get("keys") if isinstance(data, dict) else data
        if not isinstance(entries, list) or not entries:
            raise WalkdiffError(
                '--keys: expected {"keys": [{"frame": N, ...}, ...]} with at least one key', path=path
            )
        return [_json_key(k, i, profile, str(path), path.parent) for i, k in enumerate(entries)]
    poses = _poses(path, profile)
    if numbers:
        try:
            at = [int(n) for n in numbers.split(",")]
        except ValueError:
            raise WalkdiffError(
                f"--keys: expected FILE.bvh@F0,F1,... with whole frame numbers, got {numbers!r}"
            ) from None
        if len(at) != poses.num_frames:
            raise WalkdiffError(
                f"--keys: {len(at)} frame numbers for the file's {poses.num_frames} key poses", path=path
            )
    else:
        count = poses.num_frames
        at = [0] if count == 1 else [round(i * (frames - 1) / (count - 1)) for i in range(count)]
    return [Key(f, poses.slice(i, i + 1), where=f"{path} key {i}") for i, f in enumerate(at)]


def _poses(path: Path, profile: SkeletonProfile) -> Motion:
    motion = read_bvh(path)
    profile.check(motion.skeleton, path)
    return profile.to_canonical(motion)


def _json_key(entry, index: int, profile: SkeletonProfile, where: str, folder: Path | None = None) -> Key:
    where = f"{where}: key {index}"
    if (
        not isinstance(entry, dict)
        or not isinstance(entry.get("frame"), int)
        or isinstance(entry.get("frame"), bool)
    ):
        raise WalkdiffError(f'{where}: expected {{"frame": N, ...}} with a whole frame number, got {entry!r}')
    unknown = set(entry) - {"frame", "root", "heading", "pose", "pose_frame"}
    if unknown:
        raise WalkdiffError(
            f"{where}: unknown field {sorted(unknown)[0]!r} (expected frame, root, heading, pose, pose_frame)"
        )
    key = Key(entry["frame"], where=where)
    if "root" in entry:
        root = entry["root"]
        if not (isinstance(root, list) and len(root) == 3 and all(isinstance(v, int | float) for v in root)):
            raise WalkdiffError(
                f"{where}: root: expected [x, y, z] in the file's axes and units, got {root!r}"
            )
        canonical = profile.turn @ np.asarray(root, np.float64)
        key.position = (float(canonical[0]), float(canonical[2]))
    if "heading" in entry:
        heading = entry["heading"]
        if not isinstance(heading, int | float) or isinstance(heading, bool) or not math.isfinite(heading):
            raise WalkdiffError(f"{where}: heading: expected degrees, got {heading!r}")
        key.heading = math.radians(heading)
    if "pose" in entry:
        path = Path(entry["pose"]) if folder is None else folder / entry["pose"]
        if not path.is_file():
            raise WalkdiffError(f"{where}: pose: no such BVH file", path=path)
        poses = _poses(path, profile)
        at = entry.get("pose_frame", 0)
        if not isinstance(at, int) or not 0 <= at < poses.num_frames:
            raise WalkdiffError(
                f"{where}: pose_frame: expected a frame in 0 to {poses.num_frames - 1}, got {at!r}"
            )
        key.pose = poses.slice(at, at + 1)
    if key.pose is None and key.position is None and key.heading is None:
        raise WalkdiffError(f"{where}: a key needs a pose, a root position or a heading")
    return key
