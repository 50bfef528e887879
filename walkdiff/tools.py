"""`walkdiff inspect` and `walkdiff convert`: look at one BVH file, or push it through the representation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from walkdiff.data.datasets import dataset_module
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.mirror import mirror
from walkdiff.motion.representation import decode, encode, foot_contacts, start_pose
from walkdiff.motion.resample import resample
from walkdiff.motion.skeleton import Motion


def suspicious(motion: Motion, world: np.ndarray) -> list[str]:
    """Things worth a second look before training on a clip."""
    notes = []
    if motion.num_frames < 10:
        notes.append(f"very short clip ({motion.num_frames} frames)")
    if not 10 <= motion.fps <= 250:
        notes.append(f"unusual frame rate {motion.fps:.2f} fps")
    height = np.ptp(world[0, :, 1])
    if height < 1e-6:
        notes.append("all joints at one height in frame 0: no rest pose offsets?")
    if motion.num_frames > 1:
        speed = np.linalg.norm(np.diff(world, axis=0), axis=-1) * motion.fps  # (F-1, J)
        limit = 20 * max(height, 1e-6)  # 20 body heights per second is no human motion
        jumps = np.flatnonzero(speed.max(axis=1) > limit)
        if jumps.size:
            notes.append(
                f"{jumps.size} frame-to-frame jumps faster than {limit:.0f} units/s "
                f"(first at frame {jumps[0] + 1}): a cut or a glitch"
            )
    lowest = world[..., 1].min()
    if lowest < -0.05 * height:
        notes.append(f"a joint goes {-lowest:.2f} units below y=0 (floor not at 0?)")
    return notes


def inspect_file(path: str, dataset: str = "xia") -> str:
    motion = read_bvh(path)
    skeleton = motion.skeleton
    world = motion_world_positions(motion)
    contacts = foot_contacts(motion, dataset_module(dataset).CONTACTS)
    root = motion.root_positions
    walked = np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=1).sum()
    first = ", ".join(skeleton.names[:6]) + (", ..." if skeleton.num_joints > 6 else "")
    lines = [
        f"file:      {path}",
        f"joints:    {skeleton.num_joints} ({first})",
        f"end sites: {len(skeleton.end_sites)}",
        f"channels:  {sum(len(c) for c in skeleton.channels)} per frame",
        f"frames:    {motion.num_frames} at {motion.fps:.2f} fps ({motion.duration:.2f} s)",
        f"height:    {np.ptp(world[0, :, 1]):.2f} units (frame 0), root path {walked:.2f} units",
        "contacts:  "
        + ", ".join(
            f"{name} {ratio:.0%}"
            for name, ratio in zip(("left heel", "left toe", "right heel", "right toe"), contacts.mean(0))
        )
        + f" of frames ({dataset} thresholds)",
    ]
    notes = suspicious(motion, world)
    lines.append("suspicious: " + ("none" if not notes else ""))
    lines += [f"  - {n}" for n in notes]
    return "\n".join(lines)


def convert_file(
    source: str, target: str, *, fps: float | None = None, mirror_sides: bool = False, dataset: str = "xia"
) -> str:
    """BVH -> (resample) -> (mirror) -> features -> BVH on the same skeleton, placed where it started."""
    motion = read_bvh(source)
    if fps is not None:
        motion = resample(motion, fps)
    if mirror_sides:
        motion = mirror(motion)
    features = encode(motion, dataset_module(dataset).CONTACTS)
    position, heading = start_pose(motion)
    out = decode(features, motion.skeleton, motion.frame_time, position, heading)
    Path(target).parent.mkdir(parents=True, exist_ok=True)
    write_bvh(target, out)
    return (
        f"wrote {target}: {out.num_frames} frames at {out.fps:g} fps{' (mirrored)' if mirror_sides else ''}"
    )
