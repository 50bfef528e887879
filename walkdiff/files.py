"""Writing output files atomically: readers (and a crash) never see a half-written file."""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO


def write_atomic(path: str | Path, save: Callable[[IO[bytes]], None]) -> Path:
    """Let `save` write into a temporary file in the target folder, then rename it onto `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            save(f)
        os.chmod(temp, 0o644)  # mkstemp creates 0600; outputs are meant to be shared
        os.replace(temp, path)
    except BaseException:
        Path(temp).unlink(missing_ok=True)
        raise
    return path


def output_folder(path: str | Path, option: str = "--out") -> Path:
    """`path` as an output folder, or a WalkdiffError when a file of that name is in the way."""
    from walkdiff.errors import WalkdiffError

    path = Path(path)
    if path.exists() and not path.is_dir():
        raise WalkdiffError(
            f"{option}: a file of that name exists; expected a folder for the outputs", path=path
        )
    return path


def write_text(path: str | Path, text: str) -> Path:
    return write_atomic(path, lambda f: f.write(text.encode("utf-8")))


def strict_json(data):
    """`data` with every non-finite float as null: JSON has no NaN or Infinity, strict readers refuse them."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: strict_json(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [strict_json(v) for v in data]
    return data


def write_json(path: str | Path, data) -> Path:
    """Strict JSON (non-finite numbers become null), written atomically."""
    return write_text(
        path, json.dumps(strict_json(data), indent=2, ensure_ascii=False, allow_nan=False) + "\n"
    )


def read_utf8(path: Path, what: str) -> str:
    """A text file's contents (a UTF-8 byte-order mark dropped), or a WalkdiffError naming `what`."""
    from walkdiff.errors import WalkdiffError

    try:
        return Path(path).read_bytes().decode("utf-8-sig")
    except OSError as e:
        raise WalkdiffError(f"cannot read {what} ({e.strerror})", path=path) from None
    except UnicodeDecodeError:
        raise WalkdiffError(f"{what} is not UTF-8 text", path=path) from None


def read_config(path: str | Path, what: str) -> dict:
    """A YAML or JSON mapping from a file, or a WalkdiffError naming the file and what was expected."""
    from omegaconf import OmegaConf

    from walkdiff.errors import WalkdiffError

    path = Path(path)
    if not path.is_file():
        raise WalkdiffError(f"{what}: file not found", path=path)
    try:
        data = OmegaConf.to_container(OmegaConf.load(path))
    except Exception as error:  # omegaconf raises yaml's errors, with the line in the message
        raise WalkdiffError(f"{what}: not a YAML/JSON mapping ({error})", path=path) from None
    if not isinstance(data, dict):
        raise WalkdiffError(f"{what}: expected a mapping of fields, got {type(data).__name__}", path=path)
    return data
