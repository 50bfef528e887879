"""`walkdiff inspect` and `walkdiff convert`: look at any BVH file, or push it through the representation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import read_config
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.gltf import write_glb
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.mirror import mirror
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.profile_detection import NO_FEET
from walkdiff.motion.representation import decode, encode, foot_contacts, start_pose
from walkdiff.motion.resample import resample
from walkdiff.motion.skeleton import Motion


def suspicious(motion: Motion, world: np.ndarray, height: float) -> list[str]:
    """Things worth a second look before training on a canonical (Y-up) clip of a body `height` tall."""
    notes = []
    if motion.num_frames < 10:
        notes.append(f"very short clip ({motion.num_frames} frames)")
    if not 10 <= motion.fps <= 250:
        notes.append(f"unusual frame rate {motion.fps:.2f} fps")
    if np.ptp(world[0, :, 1]) < 1e-6:
        notes.append("all joints at one height in frame 0: no rest pose offsets?")
    if motion.num_frames > 1:
        speed = np.linalg.norm(np.diff(world, axis=0), axis=-1) * motion.fps  # (F-1, J)
        limit = 20 * max(height, 1e-6)  # 20 body heights per second is no human motion
        jumps = np.flatnonzero(speed.max(axis=1) > limit)
        if jumps.size:
            notes.append(
                f"{jumps.size} frame-to-frame jumps faster than {limit:.4g} units/s "
                f"(first at frame {jumps[0] + 1}): a cut or a glitch"
            )
    lowest = world[..., 1].min()
    if lowest < -0.05 * height:
        notes.append(f"a joint goes {-lowest:.4g} units below the floor (up = 0): floor not at 0?")
    return notes


def file_profile(motion: Motion, profile: str | None, path: str | Path) -> SkeletonProfile:
    """The profile of the clip read from `path`, with the overrides of a YAML/JSON file (`--profile`)."""
    overrides = read_config(profile, "--profile") if profile else {}
    return SkeletonProfile.detect(motion, overrides, path)


def inspect_file(path: str, profile: str | None = None) -> str:
    motion = read_bvh(path)
    skeleton = motion.skeleton
    found = file_profile(motion, profile, path)
    canonical = found.to_canonical(motion)
    world = motion_world_positions(canonical)
    contacts = foot_contacts(canonical, found.contacts) if found.feet else None
    root = canonical.root_positions
    walked = np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=1).sum()
    first = ", ".join(skeleton.names[:6]) + (", ..." if skeleton.num_joints > 6 else "")
    positioned = [skeleton.names[j] for j in range(skeleton.num_joints) if skeleton.position_order(j)]
    lines = [
        f"file:      {path}",
        f"joints:    {skeleton.num_joints} ({first}); {len(found.body)} modelled (the root and below)",
        f"end sites: {len(skeleton.end_sites)}",
        f"channels:  {sum(len(c) for c in skeleton.channels)} per frame; position channels on "
        + ", ".join(positioned[:5])
        + (" ..." if len(positioned) > 5 else ""),
        f"frames:    {motion.num_frames} at {motion.fps:.2f} fps ({motion.duration:.2f} s)",
        *found.describe(),
        f"root path: {walked:.4g} units ({walked * found.metres_per_unit:.2f} m)",
        "contacts:  "
        + (
            ", ".join(
                f"{name} {ratio:.0%}"
                for name, ratio in zip(("left heel", "left toe", "right heel", "right toe"), contacts.mean(0))
            )
            + " of frames"
            if contacts is not None
            else "none (no feet)"
        ),
    ]
    notes = list(found.notes) + suspicious(canonical, world, found.body_height)
    lines.append("suspicious: " + ("none" if not notes else ""))
    lines += [f"  - {n}" for n in notes]
    return "\n".join(lines)


def convert_file(
    source: str,
    target: str,
    *,
    fps: float | None = None,
    mirror_sides: bool = False,
    profile: str | None = None,
    overwrite: bool = False,
) -> str:
    """BVH -> (resample) -> (mirror) -> features -> BVH on the same skeleton, placed where it started."""
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise WalkdiffError(f"--fps: expected a positive frame rate, got {fps}")
    if Path(target).suffix.lower() not in (".bvh", ".glb"):
        raise WalkdiffError("expected an output ending in .bvh or .glb (binary glTF)", path=target)
    if Path(source).resolve() == Path(target).resolve():
        raise WalkdiffError("the output is the input: write to another file", path=target)
    if Path(target).exists() and not overwrite:
        raise WalkdiffError("the output exists; pass --overwrite to replace it", path=target)
    motion = read_bvh(source)
    found = file_profile(motion, profile, source)
    canonical = found.to_canonical(motion)
    if fps is not None:
        canonical = resample(canonical, fps)
    if mirror_sides:
        if not found.can_mirror:
            raise WalkdiffError(
                "--mirror: no left/right joint pairs found by name; name them in --profile (mirror_pairs)",
                path=source,
            )
        canonical = mirror(canonical, found.body_pairs)
    mirrored = " (mirrored)" if mirror_sides else ""
    if Path(target).suffix.lower() == ".glb":  # glTF is Y-up in metres: the canonical clip, scaled
        write_glb(target, canonical, found.metres_per_unit)
        frames = f"{canonical.num_frames} frames at {canonical.fps:g} fps"
        return f"wrote {target}: {frames}, glTF (Y up, metres){mirrored}"
    if not found.feet:  # the features' contact labels need them; glTF takes the clip as it is
        raise WalkdiffError(
            f"converting to BVH goes through the features: {NO_FEET} (or write .glb)", path=source
        )
    features = encode(canonical, found)
    position, heading = start_pose(canonical, found)
    out = found.to_file(decode(features, canonical.skeleton, canonical.frame_time, position, heading))
    write_bvh(target, out)
    return f"wrote {target}: {out.num_frames} frames at {out.fps:g} fps{mirrored}"
