"""Reading checkpoint files: a clear error for a missing, empty, truncated or wrong kind of checkpoint.

Every command that takes `--ckpt` or `--evaluator` reads the small metadata first (memory-mapped, so the
weights are not loaded twice) and checks which model wrote it, so that an evaluator given to `sample`
says so instead of failing somewhere inside Lightning's loader.
"""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path

import torch

from walkdiff.common.errors import WalkdiffError

# Model classes by what commands call them.
KINDS = {
    "walkdiff.models.styled_ddpm.StyledMotionDiffusion": "a StyledMotionDiffusion (walking generator)",
    "walkdiff.models.evaluator.MotionEvaluator": "a MotionEvaluator (style + content classifier)",
    "walkdiff.models.action_evaluator.ActionEvaluator": "an ActionEvaluator (HumanAct12 classifier)",
    "walkdiff.models.diffmotion.DiffMotion": "a DiffMotion (speech-driven gestures)",
    "walkdiff.models.path_walker.PathWalker": "a PathWalker (walking along a path)",
}


def read_checkpoint(path: str | Path, what: str = "model", mmap: bool = True) -> dict:
    """The checkpoint dict, or a WalkdiffError naming the file and what is wrong with it."""
    path = Path(path)
    if not path.is_file():
        raise WalkdiffError(f"{what} checkpoint not found", path=path)
    if path.stat().st_size == 0:
        raise WalkdiffError(f"empty file: expected a {what} checkpoint written by `walkdiff fit`", path=path)
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False, mmap=mmap)
    except (RuntimeError, EOFError, OSError, ValueError, pickle.UnpicklingError, zipfile.BadZipFile) as error:
        raise WalkdiffError(
            f"not a readable checkpoint (truncated or not a torch file: {type(error).__name__}: "
            f"{str(error).splitlines()[0] if str(error) else ''}); expected a {what} checkpoint",
            path=path,
        ) from None
    if not isinstance(checkpoint, dict) or "state_dict" not in checkpoint:
        raise WalkdiffError(
            f"not a Lightning checkpoint (no state_dict); expected a {what} checkpoint", path=path
        )
    return checkpoint


def checkpoint_class(path: str | Path, what: str = "model") -> str:
    """The class path of the LightningModule a checkpoint was saved from."""
    checkpoint = read_checkpoint(path, what)
    hparams = checkpoint.get("hyper_parameters") or {}
    return (
        checkpoint.get("evaluator_class")
        or checkpoint.get("model_class")
        or hparams.get("_class_path", "walkdiff.models.styled_ddpm.StyledMotionDiffusion")
    )


def expect_class(path: str | Path, expected: str | tuple[str, ...], what: str) -> str:
    """The checkpoint's class path, or a WalkdiffError saying what it is and what was needed."""
    expected = (expected,) if isinstance(expected, str) else expected
    found = checkpoint_class(path, what)
    if found not in expected:
        kind = KINDS.get(found, found)
        needed = " or ".join(KINDS.get(e, e).split(" (")[0] for e in expected)
        raise WalkdiffError(f"this is {kind} checkpoint; {what} needs {needed} checkpoint", path=path)
    return found
