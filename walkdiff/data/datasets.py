"""The dataset modules walkdiff knows, by the name used in configs (`data.dataset`)."""

from __future__ import annotations

import importlib
from types import ModuleType

from walkdiff.errors import WalkdiffError

# A dataset module provides: STYLES, GROUPS, CONTACTS, list_clips(folder), split_clips(clips, selection),
# load(clip) -> Motion. Adding a dataset is one module and one line here.
DATASETS = {"xia": "walkdiff.data.xia", "humanact12": "walkdiff.data.humanact12"}


def dataset_module(name: str) -> ModuleType:
    if name not in DATASETS:
        raise WalkdiffError(f"data.dataset: unknown dataset {name!r}; expected one of {', '.join(DATASETS)}")
    return importlib.import_module(DATASETS[name])
