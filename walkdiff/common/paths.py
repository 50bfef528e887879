"""Where walkdiff finds its data (`WALKDIFF_DATA`, default `./data`), and which paths in a data folder it
will open."""

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


def refuse_link_out(folder: Path, path: Path, what: str) -> None:
    """WalkdiffError when `path`, inside `folder` by name, is a symbolic link (or lies below one) that
    leads out of it. A folder from elsewhere must not make walkdiff open, and quote in its errors, any
    file this user can read; links that stay inside, and paths named outside on purpose, are fine."""
    base = Path(os.path.abspath(folder))
    if not Path(os.path.abspath(path)).is_relative_to(base):
        return  # data.labels given as an absolute or ../ path: the user named that file
    target = path.resolve()
    if not target.is_relative_to(base.resolve()):
        raise WalkdiffError(
            f"{what} is a symbolic link to {target}, outside the dataset folder {base}: refused "
            "(copy the file into the folder, or link to a file inside it)",
            path=path,
        )
