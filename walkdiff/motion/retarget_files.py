"""`walkdiff retarget SRC --to TARGET --out OUT`: a BVH clip played by another rig, written as that rig's
BVH (its skeleton, channels, axes and units) or as `.glb`.

TARGET is a BVH of the user's rig (its first frame is the pose it is aligned on: export the rig
standing, in its bind pose or any standing frame) or the name of a built-in rig (`walkdiff.motion.rigs`).
"""

from __future__ import annotations

from pathlib import Path

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import read_config
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.gltf import write_glb
from walkdiff.motion.retarget import Retargeter
from walkdiff.motion.target_rig import rig_clip


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
