"""What the objects `walkdiff.load` returns share: a trained model loaded once, its frame rate, the
skeleton of the files it was trained on, and its clips handed back as `Take`s on that skeleton."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.memory import SAMPLE_BYTES_PER_FRAME, check_frames
from walkdiff.diffusion import SamplerChoice
from walkdiff.models.base import MotionModule
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.resample import resample
from walkdiff.motion.skeleton import Motion, Skeleton
from walkdiff.retarget.take import Take
from walkdiff.retarget.target_rig import TargetRig


def specs_first(options: dict) -> dict:
    """A command's request options with the sampler and the rig read into their specs (SamplerChoice,
    TargetRig) first: a bad sampler or rig is said before the model loads."""
    sampler = {k: options.pop(k) for k in ("steps", "eta", "guidance") if k in options}
    sampler = SamplerChoice.of(options.pop("sampler", "ddpm"), **sampler)
    to = TargetRig.of(options.pop("to", None), options.pop("to_map", None))
    return options | {"sampler": sampler, "to": to}


@dataclass
class Generated:
    """What one call of the API made: the takes, the settings used (as the manifest records them) and
    the timings in seconds. It reads as the list of its takes (`for take in model.sample(...)`), and a
    result of one take as that take (`model.transfer(...).to_bvh(...)`)."""

    takes: list[Take]
    settings: dict
    timing: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    seed: int = 0
    rig: TargetRig | None = None  # the rig the takes are played on
    label: str = ""  # what file names are made of
    extra: dict = field(default_factory=dict)  # what a command writes beside the takes (a timeline ...)

    def __iter__(self):
        return iter(self.takes)

    def __len__(self) -> int:
        return len(self.takes)

    def __getitem__(self, index):
        return self.takes[index]

    @property
    def take(self) -> Take:
        """The one take of a result of one."""
        if len(self.takes) != 1:
            raise WalkdiffError(f"this result holds {len(self.takes)} takes; index them or iterate")
        return self.takes[0]

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.take, name)


class Pipeline:
    """A trained model behind one object (StyledGenerator, PathFollower, GestureGenerator) whose methods
    return motion instead of writing it."""

    def __init__(self, model: MotionModule):
        self.model = model

    def to(self, device: str | torch.device) -> Pipeline:
        """Moves the model to `device` ('cpu', 'cuda'); itself, as a torch module does."""
        self.model.to(device)
        return self

    @property
    def fps(self) -> float:
        """Frames per second of the motion it makes."""
        return self.model.spec["fps"]

    @property
    def skeleton(self) -> Skeleton:
        """The training files' skeleton, which every `Take` is on."""
        return self.model.profile.skeleton

    def take(self, motion: Motion, rig: TargetRig | None = None) -> Take:
        """A canonical clip the model made, on the training files' skeleton, axes and units, or played
        by `rig` on its own."""
        take = Take.from_canonical(motion, self.model.profile)
        return take if rig is None else take.retarget(rig)

    def source(
        self, motion: Motion | Take | str | os.PathLike, what: str = "transfer", min_frames: int = 2
    ) -> Motion:
        """A clip to restyle or take a style from, as the model takes it: checked to be on its skeleton,
        canonical, at its fps. `what` names the option in errors; `min_frames`: 1 where a single pose
        will do (the clips around a gap)."""
        path = None
        if isinstance(motion, Generated):  # a result of one take: that take
            motion = motion.take
        if isinstance(motion, Take):
            motion = motion.motion
        elif isinstance(motion, str | os.PathLike):
            path = Path(motion)
            motion = read_bvh(path)
        elif not isinstance(motion, Motion):
            raise WalkdiffError(
                f"{what}: expected a Motion, a Take or the path of a BVH file, got {type(motion).__name__}"
            )
        self.model.profile.check(motion.skeleton, path)
        motion = self.model.profile.to_canonical(motion)
        if abs(motion.fps - self.fps) > 1e-3 * self.fps:
            motion = resample(motion, self.fps)
        check_frames("--input", motion.num_frames, SAMPLE_BYTES_PER_FRAME)
        if motion.num_frames < min_frames:  # one pose: no motion, and its root velocities are 0
            raise WalkdiffError(
                f"{motion.num_frames} frame at the model's {self.fps:g} fps: expected at least 2 frames of "
                "motion",
                path=path,
            )
        return motion
