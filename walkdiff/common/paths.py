"""Where walkdiff finds its data: `WALKDIFF_DATA`, default `./data`."""

from __future__ import annotations

import os
from pathlib import Path

from walkdiff.common.errors import WalkdiffError

GET_DATA_HINT = (
    "Set WALKDIFF_DATA to the folder that holds xia/ (and zeggs/, humanact12/), "
    "or put them under ./data; see README.md, section 'Get the data'."
)


def data_root(root: str | os.PathLike | None = None) -> Path:
    """The data root: an explicit argument, else $WALKDIFF_DATA, else ./data."""
    return Path(root if root is not None else os.environ.get("WALKDIFF_DATA", "data")).expanduser()


def dataset_dir(name: str, root: str | os.PathLike | None = None) -> Path:
    """`<root>/<name>`, or a WalkdiffError naming the path tried and how to get the data."""
    path = data_root(root) / name
    if not path.is_dir():
        raise WalkdiffError(f"dataset folder not found (tried {path.resolve()}). {GET_DATA_HINT}", path=path)
    return path
