"""What the objects `walkdiff.load` returns share: a trained model loaded once, its frame rate, the
skeleton of the files it was trained on, and its clips handed back as `Take`s on that skeleton."""

from __future__ import annotations

from walkdiff.models.base import MotionModule
from walkdiff.motion.skeleton import Motion, Skeleton
from walkdiff.motion.take import Take
from walkdiff.motion.target_rig import TargetRig


class Pipeline:
    """A trained model behind one object (StyledGenerator, PathFollower, GestureGenerator) whose methods
    return motion instead of writing it."""

    def __init__(self, model: MotionModule):
        self.model = model

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
