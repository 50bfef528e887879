"""Writing model files to share: `walkdiff export` (safetensors and a JSON card) and `walkdiff checkpoint
upgrade` (a pickled checkpoint the user trusts rewritten as tensors and plain data).

`upgrade_checkpoint` is the one place in walkdiff that unpickles a file in full, and only on `--trust`:
everything else reads model files weights-only (`common/checkpoints.py`).
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path, PurePath

import numpy as np
import torch

from walkdiff.common.checkpoints import (
    EXPORT_CARD,
    EXPORT_FORMAT,
    EXPORT_WEIGHTS,
    checkpoint_class,
    read_checkpoint,
)
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import check_free, output_folder, write_atomic, write_text

# What only resuming a training run needs: not part of a model shared for use.
TRAINING_STATE = ("optimizer_states", "lr_schedulers", "loops", "callbacks")


def export_model(ckpt: str | Path, out: str | Path, overwrite: bool = False) -> dict:
    """OUT/model.safetensors (every weight and buffer, the normaliser's statistics among them) and
    OUT/model.json (the card: the model class, its configuration, skeleton profile, labels, the data it
    was trained on and its best metrics); returns the card."""
    from safetensors.torch import save

    checkpoint = read_checkpoint(ckpt, "model", mmap=False)
    out = output_folder(out)
    check_free([out / EXPORT_WEIGHTS, out / EXPORT_CARD], overwrite)
    kept = {k: v for k, v in checkpoint.items() if k not in (*TRAINING_STATE, "state_dict")}
    card = {
        "format": EXPORT_FORMAT,
        "model_class": checkpoint_class(ckpt),
        "exported_from": str(ckpt),
        "summary": _summary(checkpoint),
        "checkpoint": _json_data(kept, "checkpoint"),
    }
    # Clones: safetensors refuses tensors that share memory (the EMA copy, a student's two copies).
    state = {name: value.detach().contiguous().clone() for name, value in checkpoint["state_dict"].items()}
    write_atomic(out / EXPORT_WEIGHTS, lambda f: f.write(save(state)))
    write_text(out / EXPORT_CARD, json.dumps(card, indent=2, ensure_ascii=False) + "\n")
    read_checkpoint(out, "exported model")  # what every command will read: prove it reads back
    return card


def _summary(checkpoint: dict) -> dict:
    """What a person reading the card wants first: labels, data, training length and best metrics."""
    hparams = checkpoint.get("hyper_parameters") or {}
    spec = hparams.get("data_spec") or {}
    data = checkpoint.get("datamodule_hyper_parameters") or {}
    metrics = {}
    for state in (checkpoint.get("callbacks") or {}).values():
        if not isinstance(state, dict):
            continue
        score = state.get("best_model_score")
        if state.get("monitor") and score is not None:
            metrics[state["monitor"]] = float(score)
    return _json_data(
        {
            "styles": spec.get("styles"),
            "contents": spec.get("contents"),
            "fps": spec.get("fps"),
            "window": spec.get("window"),
            "joints": spec.get("num_joints"),
            "data": {k: v for k, v in data.items() if not k.startswith("_")},
            "epochs": checkpoint.get("epoch"),
            "batches": checkpoint.get("global_step"),
            "best_metrics": metrics,
            "distilled": checkpoint.get("distilled"),
            # Per-channel statistics features are normalised with (also in the weights file).
            "normalisers": {
                name: value.tolist()
                for name, value in checkpoint["state_dict"].items()
                if _is_normaliser(name.rpartition(".")[0])
            },
        },
        "summary",
    )


def _is_normaliser(module: str) -> bool:
    """A model's own Normalizer (`normalizer`, `audio_normalizer`, `control_normalizer`, ...)."""
    return "." not in module and module.endswith("normalizer")


def _json_data(value, where: str):
    """`value` if JSON holds it as it is (tuples as lists), else a WalkdiffError naming the key."""
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, list | tuple):
        return [_json_data(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, dict) and all(isinstance(k, str) for k in value):
        return {k: _json_data(v, f"{where}.{k}") for k, v in value.items()}
    raise WalkdiffError(
        f"cannot export {where}: a {type(value).__name__} has no place in the JSON card (tensors belong "
        "in the state dict, dictionary keys must be strings)"
    )


def upgrade_checkpoint(
    old: str | Path, out: str | Path, trust: bool = False, overwrite: bool = False
) -> Path:
    """A checkpoint that needs the full unpickler rewritten as tensors and plain data, which every command
    then reads weights-only. Unpickling runs whatever code the file holds: only on `trust`."""
    old, out = Path(old), Path(out)
    if not trust:
        raise WalkdiffError(
            "upgrading opens the file with Python's full unpickler, which runs any code it holds; pass "
            "--trust only for a checkpoint whose origin you trust",
            path=old,
        )
    if not old.is_file():
        raise WalkdiffError("checkpoint not found", path=old)
    if old.resolve() == out.resolve():
        raise WalkdiffError("--out must be another file: the original is kept", path=out)
    check_free([out], overwrite)
    print(f"walkdiff: warning: unpickling {old} in full, as trusted", file=sys.stderr)
    try:
        checkpoint = torch.load(old, map_location="cpu", weights_only=False)  # the one full unpickling
    except Exception as error:  # any failure of a foreign pickle: said in one line
        raise WalkdiffError(
            f"not a readable checkpoint ({type(error).__name__}: {error})", path=old
        ) from None
    if not isinstance(checkpoint, dict) or "state_dict" not in checkpoint:
        raise WalkdiffError("not a Lightning checkpoint (no state_dict)", path=old)
    plain = _plain_data(checkpoint, "checkpoint")
    write_atomic(out, lambda f: torch.save(plain, f))
    read_checkpoint(out)  # proves it now reads weights-only
    return out


def _plain_data(value, where: str):
    """`value` as tensors and plain data: dataclasses and objects with `to_dict` as dicts, numpy arrays
    and scalars as lists and numbers, paths as strings; anything else refused by name."""
    if value is None or isinstance(value, bool | int | float | str | torch.Tensor | torch.Size):
        return value
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    if isinstance(value, PurePath):
        return str(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _plain_data(dataclasses.asdict(value), where)
    if callable(getattr(value, "to_dict", None)):
        return _plain_data(value.to_dict(), where)
    if isinstance(value, dict):
        return type(value)((k, _plain_data(v, f"{where}.{k}")) for k, v in value.items())
    if isinstance(value, list | tuple | set | frozenset):
        items = [_plain_data(v, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if isinstance(value, tuple) else items
    raise WalkdiffError(
        f"{where} is a {type(value).__module__}.{type(value).__qualname__}, which has no plain-data form; "
        "the checkpoint cannot be upgraded"
    )
