"""`walkdiff retarget SRC --to TARGET --out OUT`: a BVH clip played by another rig, written as that rig's
BVH (its skeleton, channels, axes and units) or as `.glb`. `walkdiff convert` runs here too: its steps are
`motion/conversion.py`'s, and with --to the clip (resampled, mirrored) is played on a rig the same way.

TARGET is a BVH of the user's rig (its first frame is the pose it is aligned on: export the rig
standing, in its bind pose or any standing frame) or the name of a built-in rig (`walkdiff.retarget.rigs`).
"""

from __future__ import annotations

from pathlib import Path

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import read_config
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.conversion import check_convert, read_for_convert, write_converted
from walkdiff.motion.gltf import write_glb
from walkdiff.retarget.retargeter import Retargeter
from walkdiff.retarget.take import Take
from walkdiff.retarget.target_rig import TargetRig, rig_clip


def retarget_file(
    source: str,
    target: str,
    out: str,
    *,
    feet: str = "follow",
    source_map: str | None = None,
    target_map: str | None = None,
    reference_frame: int | None = None,
    overwrite: bool = False,
    force: bool = False,
) -> str:
    """Retarget the clip `source` onto `target` and write `out` (.bvh or .glb); returns the report.
    `force`: also a source or target that does not stand like a biped."""
    suffix = Path(out).suffix.lower()
    if suffix not in (".bvh", ".glb"):
        raise WalkdiffError("expected an output ending in .bvh or .glb (binary glTF)", path=out)
    if Path(out).exists() and not overwrite:
        raise WalkdiffError("the output exists; pass --overwrite to replace it", path=out)
    if Path(source).resolve() == Path(out).resolve():
        raise WalkdiffError("the output is the input: write to another file", path=out)
    rig, named = rig_clip(target)  # a wrong --to is said before the clip is read
    clip = read_bvh(source)
    maps = {
        name: read_config(path, option) if path else None
        for name, path, option in (
            ("source", source_map, "--source-map"),
            ("target", target_map, "--target-map"),
        )
    }
    retargeter = Retargeter(
        clip, rig, maps["source"], maps["target"], reference_frame, feet=feet, force=force
    )
    result = retargeter(clip)
    if suffix == ".glb":  # glTF is Y-up in metres: the target's canonical clip, scaled
        profile = retargeter.target_profile
        write_glb(out, profile.to_canonical(result.motion), profile.metres_per_unit)
    else:
        write_bvh(out, result.motion)
    lines = [
        f"wrote {out}: {result.motion.num_frames} frames at {result.motion.fps:g} fps on {named} "
        f"({result.motion.skeleton.num_joints} joints), legs {result.leg_ratio:.3f}x the source's"
    ]
    lines += [f"  {line}" for line in retargeter.describe()]  # its notes too, each once
    return "\n".join(lines)


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
    """`walkdiff convert`: BVH -> (resample) -> (mirror) -> features -> BVH on the same skeleton, placed
    where it started (or glTF); with `to`, (resample) -> (mirror) -> played by that rig (`TargetRig`) on
    its skeleton."""
    check_convert(source, target, fps, overwrite)
    rig = TargetRig.of(to, to_map)  # a wrong --to is said before the clip is read
    motion, found, canonical = read_for_convert(source, profile, fps, mirror_sides)
    if rig is None:
        return write_converted(source, target, motion, found, canonical, mirror_sides)
    take = Take(found.to_file(canonical), found).retarget(rig)
    if Path(target).suffix.lower() == ".glb":
        take.to_glb(target, overwrite=True)  # the no-overwrite check came first
    else:
        take.to_bvh(target, overwrite=True)
    ratio = rig.record()["leg_ratio"][0]
    mirrored = " (mirrored)" if mirror_sides else ""
    return (
        f"wrote {target}: {take.num_frames} frames at {take.fps:g} fps on {rig.named} "
        f"({take.skeleton.num_joints} joints), legs {ratio:.3f}x the source's{mirrored}"
    )
