"""Where clips come from and how they are labelled: a `MotionSource` per dataset, by config name.

A source is only conventions: which files, which labels, which split. What the skeleton is (root joint,
feet, axes, units) is found from the clips (`walkdiff.motion.profile`), with the source's overrides.

- `folder`: any folder of BVH files, labels from a manifest or a file-name pattern (walkdiff.data.folder);
- `xia`, `humanact12`: the published datasets, with their own file-name labels and published splits.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.paths import data_root, dataset_dir
from walkdiff.data.clips import ClipInfo, ContentSelection
from walkdiff.motion.skeleton import Motion

# Datasets with conventions of their own: one module each (STYLES, GROUPS, PROFILE, list_clips(folder),
# split_clips(clips, selection), load(clip) -> Motion).
MODULES = {"xia": "walkdiff.data.xia", "humanact12": "walkdiff.data.humanact12"}
DATASETS = (*MODULES, "folder")


class MotionSource(Protocol):
    name: str
    folder: Path
    styles: tuple[str, ...]
    groups: tuple[str, ...]
    profile: dict  # profile overrides (walkdiff.motion.profile_detection.OVERRIDE_FIELDS)

    def list_clips(self) -> list[ClipInfo]: ...

    def split_clips(
        self, clips: list[ClipInfo], selection: ContentSelection
    ) -> dict[str, list[ClipInfo]]: ...

    def load(self, clip: ClipInfo) -> Motion: ...

    def empty_split_advice(self, splits: list[str]) -> str: ...


@dataclass
class ModuleSource:
    """A dataset with a module of its own (Xia, HumanAct12). Picklable: workers get it whole."""

    name: str
    folder: Path
    profile: dict = field(default_factory=dict)

    @property
    def module(self):
        return importlib.import_module(MODULES[self.name])

    @property
    def styles(self) -> tuple[str, ...]:
        return tuple(self.module.STYLES)

    @property
    def groups(self) -> tuple[str, ...]:
        return tuple(self.module.GROUPS)

    def list_clips(self) -> list[ClipInfo]:
        return self.module.list_clips(self.folder)

    def split_clips(self, clips: list[ClipInfo], selection: ContentSelection) -> dict[str, list[ClipInfo]]:
        return self.module.split_clips(clips, selection)

    def load(self, clip: ClipInfo) -> Motion:
        return self.module.load(clip)

    def empty_split_advice(self, splits: list[str]) -> str:
        """How to give clips to `splits` that have none (`fit`'s error)."""
        return (
            f"the published {self.name} split gives none: check data.contents and that data.root holds it all"
        )


def protocol_contents(dataset: str) -> str:
    """The content groups a dataset's evaluation protocol scores: its module's PROTOCOL_CONTENTS, or all."""
    if dataset not in MODULES:
        return "all"
    return getattr(importlib.import_module(MODULES[dataset]), "PROTOCOL_CONTENTS", "all")


def open_source(
    dataset: str, root: str | None = None, profile: dict | None = None, **folder_options
) -> MotionSource:
    """The source named `dataset`; `root` is the data root (xia, humanact12) or the folder itself (folder)."""
    if dataset == "folder":
        from walkdiff.data.folder import FolderSource

        if root is None:
            raise WalkdiffError("data.root: the folder dataset needs the folder of BVH files (data.root DIR)")
        folder = data_root(root)
        if not folder.is_dir():
            raise WalkdiffError("data.root: folder not found", path=folder)
        options = {k: v for k, v in folder_options.items() if v is not None}
        return FolderSource(folder, profile=dict(profile or {}), **options)
    if dataset not in MODULES:
        raise WalkdiffError(
            f"data.dataset: unknown dataset {dataset!r}; expected one of {', '.join(DATASETS)}"
        )
    given = {k: v for k, v in folder_options.items() if v is not None}
    if given:
        raise WalkdiffError(
            f"data.{next(iter(given))}: only the folder dataset takes labels, patterns and split fractions"
        )
    source = ModuleSource(dataset, dataset_dir(dataset, root))
    source.profile = {**getattr(source.module, "PROFILE", {}), **(profile or {})}
    return source
