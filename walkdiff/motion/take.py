"""Generated motion in hand: what walkdiff's Python API returns instead of writing files.

A `Take` is the clip a command would write, kept in memory: on the training files' skeleton, axes and
units (exactly the BVH `walkdiff sample` writes), with the skeleton profile that turns it back into
walkdiff's canonical Y-up body for glTF. Nothing is written until `to_bvh` or `to_glb` is called, and
neither replaces a file unless told to.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import check_free
from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.gltf import write_glb
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.skeleton import Motion, Skeleton
from walkdiff.motion.target_rig import TargetRig

# How the no-overwrite error names the way out, in Python.
OVERWRITE = "overwrite=True"


@dataclass(frozen=True, eq=False, repr=False)
class Take:
    """One clip: `motion` (local rotations and translations) on the training files' skeleton, and the
    `profile` of that skeleton (axes, units, root and feet)."""

    motion: Motion
    profile: SkeletonProfile

    @classmethod
    def from_canonical(cls, motion: Motion, profile: SkeletonProfile) -> Take:
        """A clip as the models make it (canonical: Y up, the body below the root) in the files' form."""
        return cls(profile.to_file(motion), profile)

    @property
    def fps(self) -> float:
        return self.motion.fps

    @property
    def skeleton(self) -> Skeleton:
        return self.motion.skeleton

    @property
    def num_frames(self) -> int:
        return self.motion.num_frames

    @property
    def positions(self) -> np.ndarray:
        """World positions (F, J, 3) of every joint of the file skeleton, in the files' units and axes."""
        return motion_world_positions(self.motion)

    @property
    def metres_per_unit(self) -> float:
        """The files' unit in metres, to read `positions` in metres."""
        return self.profile.metres_per_unit

    def canonical(self) -> Motion:
        """The clip in walkdiff's canonical form (Y up, the body below the root), in the files' units."""
        return self.profile.to_canonical(self.motion)

    def to_bvh(self, path: str | Path, overwrite: bool = False) -> Path:
        """The clip as a BVH file (what the commands write), refusing to replace one unless `overwrite`."""
        path = Path(path)
        check_free([path], overwrite, OVERWRITE)
        write_bvh(path, self.motion)
        return path

    def to_glb(self, path: str | Path, overwrite: bool = False) -> Path:
        """The clip as binary glTF, Y up in metres as glTF requires, refusing to replace a file unless
        `overwrite`."""
        path = Path(path)
        check_free([path], overwrite, OVERWRITE)
        return write_glb(path, self.canonical(), self.profile.metres_per_unit)

    def retarget(
        self, to: TargetRig | str | Path | Motion | Skeleton, target_map: dict | str | Path | None = None
    ) -> Take:
        """This clip played by another humanoid rig, on that rig's skeleton, axes and units: `to` is a
        built-in rig's name (mixamo, unreal, smpl), a BVH of the rig (its first frame is the pose it is
        aligned on), or a `TargetRig` (made once, it prepares once for many takes); `target_map` overrides
        the rig's humanoid map (role: joint)."""
        if to is None:
            raise WalkdiffError(
                "retarget: expected a rig (mixamo, unreal, smpl, a BVH or a TargetRig), got None"
            )
        if isinstance(to, TargetRig) and target_map is not None:
            raise WalkdiffError("retarget: give target_map to the TargetRig, not beside it")
        rig = TargetRig.of(to, target_map)
        result = rig.play(self.motion, self.profile)
        return Take(result.motion, rig.retargeter(self.motion).target_profile)

    def __repr__(self) -> str:
        return f"Take({self.num_frames} frames at {self.fps:g} fps, {self.skeleton.num_joints} joints)"
