"""The rig a command or a `Take` plays its motion on (`--to TARGET`, `to=`): a built-in rig by name, a
BVH of the user's rig, or a clip or skeleton in memory.

A `TargetRig` is made once per command and prepares one `Retargeter` per source skeleton it meets,
so eight sampled clips cost one preparation (the per-rig work is most of a short clip's time).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import read_config
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.humanoid import HumanoidMap
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.skeleton import Motion, Skeleton
from walkdiff.retarget.retargeter import Retargeter, RetargetResult
from walkdiff.retarget.rigs import RIGS, rig


def rig_clip(target: str | os.PathLike) -> tuple[Motion, str]:
    """(the target rig as a clip whose frame 0 is its reference pose, how it was named)."""
    if str(target).lower() in RIGS:
        return rig(str(target)), f"built-in rig {str(target).lower()}"
    path = Path(target)
    if path.suffix.lower() != ".bvh" or not path.is_file():
        raise WalkdiffError(
            f"--to: expected a BVH file of your rig or a built-in rig ({', '.join(RIGS)})", path=str(target)
        )
    return read_bvh(path), str(path)


class TargetRig:
    """A rig to play clips on. `to`: a built-in rig's name, the path of a BVH of the rig (its first frame
    is its reference pose), a `Motion` (the same) or a `Skeleton` (its rest pose is). `target_map`: humanoid
    map overrides (a dict, a YAML/JSON file or a `HumanoidMap`); `feet`: follow, pin or off (`Retargeter`)."""

    def __init__(
        self,
        to: str | os.PathLike | Motion | Skeleton,
        target_map: HumanoidMap | dict | str | os.PathLike | None = None,
        feet: str = "follow",
    ):
        if isinstance(to, Motion | Skeleton):
            self.target, self.named = to, f"a {type(to).__name__.lower()} of {to_joints(to)} joints"
        elif isinstance(to, str | os.PathLike):
            self.target, self.named = rig_clip(to)
        else:
            raise WalkdiffError(
                f"to: expected a rig name, a BVH path, a Motion or a Skeleton, got {type(to).__name__}"
            )
        if isinstance(target_map, str | os.PathLike):
            target_map = read_config(target_map, "--to-map")
        self.target_map, self.feet = target_map, feet
        self._prepared: list[Retargeter] = []

    @classmethod
    def of(
        cls,
        to: TargetRig | str | os.PathLike | Motion | Skeleton | None,
        to_map: HumanoidMap | dict | str | os.PathLike | None = None,
    ) -> TargetRig | None:
        """The rig spec from what a caller gave (`to=` and `to_map=` of the API, --to and --to-map of the
        commands): itself when it is a TargetRig (then with its own map); None stays None."""
        if to is None or isinstance(to, TargetRig):
            if to_map is not None:
                raise WalkdiffError(
                    "--to-map needs --to (a rig name or BVH), not " + ("a TargetRig" if to else "none")
                )
            return to
        return cls(to, to_map)

    def retargeter(self, source: Motion, profile: SkeletonProfile | None = None) -> Retargeter:
        """The prepared retargeter for clips of `source`'s skeleton (made on first use)."""
        for prepared in self._prepared:
            if _same_skeleton(prepared.source_skeleton, source.skeleton):
                return prepared
        frame = 0 if isinstance(self.target, Motion) else None
        prepared = Retargeter(
            source, self.target, None, self.target_map, target_frame=frame, feet=self.feet,
            source_profile=profile,
        )  # fmt: skip
        self._prepared.append(prepared)
        return prepared

    def play(self, motion: Motion, profile: SkeletonProfile | None = None) -> RetargetResult:
        """`motion` (on any humanoid skeleton, its files' axes and units) played by this rig."""
        return self.retargeter(motion, profile)(motion)

    def record(self) -> dict:
        """What a manifest says of the rig: its name or file, and per source skeleton met, the leg ratio
        and the target joints left in their reference pose."""
        return {
            "target": self.named,
            "feet": self.feet,
            "leg_ratio": [round(r.leg_ratio, 6) for r in self._prepared],
            "rest_joints": sorted({j for r in self._prepared for j in r.rest_joints}),
        }


def to_joints(target: Motion | Skeleton) -> int:
    return (target.skeleton if isinstance(target, Motion) else target).num_joints


def _same_skeleton(a: Skeleton, b: Skeleton) -> bool:
    return a is b or (a.same_hierarchy(b) and np.allclose(a.offsets, b.offsets))
