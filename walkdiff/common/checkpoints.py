"""Reading model files safely: a checkpoint (`.ckpt`) or an exported model folder, always weights-only.

A checkpoint is a pickle, and unpickling can run any code the file names. walkdiff writes only tensors and
plain data (numbers, strings, lists, dicts) into its checkpoints and reads every model file with torch's
weights-only loader, which refuses anything else before it runs: a file that needs more is named, with the
one command that opens such a file on the user's word (`walkdiff checkpoint upgrade ... --trust`).

Every command that takes `--ckpt` or `--evaluator` reads the small metadata first (memory-mapped, so the
weights are not loaded twice) and checks which model wrote it, so that an evaluator given to `sample`
says so instead of failing somewhere inside Lightning's loader.
"""

from __future__ import annotations

import io
import json
import pickle
import re
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

# An exported model (`walkdiff export`): the weights as safetensors beside a JSON card of everything else.
EXPORT_WEIGHTS = "model.safetensors"
EXPORT_CARD = "model.json"
EXPORT_FORMAT = "walkdiff-model/1"


def read_checkpoint(path: str | Path, what: str = "model", mmap: bool = True) -> dict:
    """The checkpoint dict of a `.ckpt` file or an exported model folder, read weights-only, or a
    WalkdiffError naming the file and what is wrong with it."""
    path = Path(path)
    if path.is_dir():
        return read_export(path, what)
    if not path.is_file():
        raise WalkdiffError(f"{what} checkpoint not found", path=path)
    if path.stat().st_size == 0:
        raise WalkdiffError(f"empty file: expected a {what} checkpoint written by `walkdiff fit`", path=path)
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True, mmap=mmap)
    except pickle.UnpicklingError as error:
        if "weights only" not in str(error).lower():
            raise _unreadable(path, what, error) from None
        raise WalkdiffError(
            f"holds pickled Python objects{_named_global(str(error))}, which could run code when opened, "
            f"so walkdiff does not open it (expected a {what} checkpoint of tensors and plain data). If you "
            f"trust where it came from: `walkdiff checkpoint upgrade {path} --out NEW.ckpt --trust`",
            path=path,
        ) from None
    except (RuntimeError, EOFError, OSError, ValueError, zipfile.BadZipFile) as error:
        raise _unreadable(path, what, error) from None
    if not isinstance(checkpoint, dict) or "state_dict" not in checkpoint:
        raise WalkdiffError(
            f"not a Lightning checkpoint (no state_dict); expected a {what} checkpoint", path=path
        )
    return checkpoint


def _unreadable(path: Path, what: str, error: BaseException) -> WalkdiffError:
    first = str(error).splitlines()[0] if str(error) else ""
    return WalkdiffError(
        f"not a readable checkpoint (truncated or not a torch file: {type(error).__name__}: {first}); "
        f"expected a {what} checkpoint",
        path=path,
    )


def _named_global(message: str) -> str:
    """' (NAME)' for the first class or function torch's weights-only loader refused, if it says."""
    found = re.search(r"GLOBAL ([\w.]+)", message)
    return f" ({found.group(1)})" if found else ""


def read_export(folder: Path, what: str = "model", weights: bool = True) -> dict:
    """An exported model folder as the checkpoint dict it was made from (less the training state); with
    `weights` False, the card's part alone (what the kind check needs), leaving the weights unread."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    card_path, weights_path = folder / EXPORT_CARD, folder / EXPORT_WEIGHTS
    if not card_path.is_file() or not weights_path.is_file():
        raise WalkdiffError(
            f"a folder given as a {what} must hold {EXPORT_WEIGHTS} and {EXPORT_CARD} (written by "
            "`walkdiff export`)",
            path=folder,
        )
    try:
        card = json.loads(card_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise WalkdiffError(f"not a model card (JSON): {error}", path=card_path) from None
    if not isinstance(card, dict) or card.get("format") != EXPORT_FORMAT:
        raise WalkdiffError(f"expected a model card with format {EXPORT_FORMAT!r}", path=card_path)
    if not weights:
        return dict(card["checkpoint"])
    try:
        state = load_file(weights_path)
    except (SafetensorError, OSError) as error:
        raise WalkdiffError(f"not readable safetensors: {error}", path=weights_path) from None
    return {**card["checkpoint"], "state_dict": state}


def loadable(path: str | Path) -> Path | io.BytesIO:
    """What Lightning's `load_from_checkpoint` can open: a `.ckpt` file as it is, an exported folder as
    the checkpoint it stands for, in memory."""
    path = Path(path)
    if not path.is_dir():
        return path
    buffer = io.BytesIO()
    torch.save(read_export(path), buffer)
    buffer.seek(0)
    return buffer


def checkpoint_class(path: str | Path, what: str = "model") -> str:
    """The class path of the LightningModule a checkpoint was saved from."""
    path = Path(path)
    checkpoint = read_export(path, what, weights=False) if path.is_dir() else read_checkpoint(path, what)
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
