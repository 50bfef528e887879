"""walkdiff from Python: `load` a checkpoint once, then call it; motion comes back in memory as `Take`s.

As with a diffusers pipeline, one object per kind of model holds the trained network, and its methods are
what the commands generate, without the files: a StyledGenerator (`sample`, `transfer`) for a
StyledMotionDiffusion, a PathFollower (`follow`, `stream`, `controller`) for a PathWalker, a
GestureGenerator (`gesture`, `stream`) for a DiffMotion. Every generating command, streams and live
control included, is written on these. The manual is docs/api.md.
"""

from __future__ import annotations

from pathlib import Path

from walkdiff.common.checkpoints import KINDS, checkpoint_class
from walkdiff.common.errors import WalkdiffError
from walkdiff.gestures.generator import GestureGenerator
from walkdiff.styled.pipeline import StyledGenerator
from walkdiff.walker.follow import PathFollower

# The object for each model class a checkpoint can be saved from (common/checkpoints.py KINDS).
PIPELINES = {
    "walkdiff.models.styled_ddpm.StyledMotionDiffusion": StyledGenerator,
    "walkdiff.models.path_walker.PathWalker": PathFollower,
    "walkdiff.models.diffmotion.DiffMotion": GestureGenerator,
}


def load(ckpt: str | Path, device: str = "cpu") -> StyledGenerator | PathFollower | GestureGenerator:
    """The object for a trained checkpoint, chosen by the model class the checkpoint records; a
    WalkdiffError naming the file for a missing or broken file and for any other kind of checkpoint."""
    found = checkpoint_class(ckpt)
    if found not in PIPELINES:
        *others, last = (KINDS[name] for name in PIPELINES)
        takes = f"{', '.join(others)} or {last}"
        raise WalkdiffError(
            f"this is {KINDS.get(found, found)} checkpoint; walkdiff.load takes {takes} checkpoint", path=ckpt
        )
    return PIPELINES[found].load(ckpt, device)
