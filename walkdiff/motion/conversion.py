"""`walkdiff inspect` and `walkdiff convert`: look at any BVH file, or push it through the representation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import read_config
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.gltf import write_glb
from walkdiff.motion.humanoid import humanoid_map
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.mirror import mirror
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.profile_detection import NO_FEET, translation_off_offsets
from walkdiff.motion.representation import decode, encode, foot_contacts, start_pose
from walkdiff.motion.resample import resample
from walkdiff.motion.skeleton import Motion
from walkdiff.motion.take import Take
from walkdiff.motion.target_rig import TargetRig

ROUND_TRIP = 1e-3  # of the body height: how far `convert` may move a joint before it refuses to write


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
    lines += _humanoid_lines(motion)
    return "\n".join(lines)


def _humanoid_lines(motion: Motion) -> list[str]:
    """The humanoid map `walkdiff retarget` would use, or why there is none."""
    try:
        hmap = humanoid_map(motion)
    except WalkdiffError as error:  # not a humanoid (or not one we recognise): inspect still reports
        return [f"humanoid:  none ({error}); retargeting needs a map (--source-map/--target-map)"]
    return ["humanoid map (what `walkdiff retarget` uses):"] + [
        f"  {line}" for line in hmap.describe(motion.skeleton)
    ]


def convert_file(
    source: str,
    target: str,
    *,
    fps: float | None = None,
    mirror_sides: bool = False,
    profile: str | None = None,
    overwrite: bool = False,
    to: str | None = None,
    to_map: str | None = None,
) -> str:
    """BVH -> (resample) -> (mirror) -> features -> BVH on the same skeleton, placed where it started; or,
    with `to`, (resample) -> (mirror) -> played by that rig (`TargetRig`) on its skeleton."""
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise WalkdiffError(f"--fps: expected a positive frame rate, got {fps}")
    if Path(target).suffix.lower() not in (".bvh", ".glb"):
        raise WalkdiffError("expected an output ending in .bvh or .glb (binary glTF)", path=target)
    if Path(source).resolve() == Path(target).resolve():
        raise WalkdiffError("the output is the input: write to another file", path=target)
    if Path(target).exists() and not overwrite:
        raise WalkdiffError("the output exists; pass --overwrite to replace it", path=target)
    rig = TargetRig.of(to, to_map)  # a wrong --to is said before the clip is read
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
    if rig is not None:
        return _write_retargeted(target, Take(found.to_file(canonical), found).retarget(rig), rig) + mirrored
    if Path(target).suffix.lower() == ".glb":  # glTF is Y-up in metres: the canonical clip, scaled
        write_glb(target, canonical, found.metres_per_unit)
        frames = f"{canonical.num_frames} frames at {canonical.fps:g} fps"
        return f"wrote {target}: {frames}, glTF (Y up, metres){mirrored}"
    if not found.feet:  # the features' contact labels need them; glTF takes the clip as it is
        raise WalkdiffError(
            f"converting to BVH goes through the features: {NO_FEET} (or write .glb)", path=source
        )
    layout = found.to_file(found.to_canonical(motion))  # the input's own frames, before any resampling
    check_round_trip(motion, layout, found, source, "through the profile's layout")
    features = encode(canonical, found)
    position, heading = start_pose(canonical, found)
    decoded = decode(features, canonical.skeleton, canonical.frame_time, position, heading)
    check_round_trip(canonical, decoded, found, source, "through the features")
    out = found.to_file(decoded)
    write_bvh(target, out)
    rebuilt = f"; {', '.join(found.carriers)} given the root's path again" if found.carriers else ""
    return f"wrote {target}: {out.num_frames} frames at {out.fps:g} fps{mirrored}{rebuilt}"


def _write_retargeted(target: str, take: Take, rig: TargetRig) -> str:
    if Path(target).suffix.lower() == ".glb":
        take.to_glb(target, overwrite=True)  # the no-overwrite check came first
    else:
        take.to_bvh(target, overwrite=True)
    ratio = rig.record()["leg_ratio"][0]
    return (
        f"wrote {target}: {take.num_frames} frames at {take.fps:g} fps on {rig.named} "
        f"({take.skeleton.num_joints} joints), legs {ratio:.3f}x the source's"
    )


def check_round_trip(reference: Motion, back: Motion, found: SkeletonProfile, source, what: str) -> None:
    """A WalkdiffError, nothing written, when `back` (on `reference`'s skeleton) puts a joint farther than
    ROUND_TRIP body heights from where `reference` has it. Joints that carry part of the root's path
    (`SkeletonProfile.carriers`) are left out: export gives them the path again, not their own."""
    names = reference.skeleton.names
    error = np.linalg.norm(motion_world_positions(reference) - motion_world_positions(back), axis=-1)
    error[:, [names.index(n) for n in found.carriers if n in names]] = 0.0
    frame, joint = np.unravel_index(int(np.argmax(error)), error.shape)
    worst = float(error[frame, joint])
    if worst <= ROUND_TRIP * found.body_height:
        return
    root = reference.skeleton.index(found.root) if found.root in names else 0
    lost = translation_off_offsets(reference, root, ROUND_TRIP * found.body_height)
    why = (
        f": translation on {', '.join(repr(names[j]) for j, _ in lost[:4])} below the root {found.root!r}, "
        "which the features do not keep (set profile.root to the joint that carries it)"
        if lost
        else f": joints outside the body ({found.root!r} and below) move, and export keeps their first frame"
        if joint not in found.body and what.startswith("through the profile")
        else ""
    )  # fmt: skip
    raise WalkdiffError(
        f"convert would write {names[joint]!r} {worst:.4g} {found.units} "
        f"({worst / found.body_height:.2%} of the body height) from where the input has it at frame "
        f"{frame} ({what}){why}; nothing written",
        path=source,
    )
