"""The Xia et al. 2015 style database: labels from file names and the published test split.

File names are `STYLE_CC_NNN.bvh` (see ../shared/data/README.md): 8 styles, 28 content ids in 6 groups.

A clip's content label is its group (walk, run, ...), not its content id: no label names a side, so
mirrored training copies keep their labels (`walkdiff.data.laterality`). The ids' names would not do as
turn labels anyway: measured by the heading, the clips of one id (05 walk_lturn_l1: 11 turn left, 14
right) turn both ways.
"""

from __future__ import annotations

import re
from pathlib import Path

from walkdiff.common.errors import WalkdiffError
from walkdiff.data.clips import ClipInfo, ContentSelection, deterministic_order
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.skeleton import Motion

STYLES = ("angry", "childlike", "depressed", "neutral", "old", "proud", "sexy", "strutting")
CONTENT_NAMES = (
    "walk_s1", "walk_s2", "walk_lturn_s1", "walk_rturn_s1", "walk_lturn_l1", "walk_lturn_l2",
    "walk_l1", "walk_l2", "walk_rturn_s2", "walk_lturn_s2", "walk_rturn_l1", "walk_lturn_l3",
    "run", "run_lturn", "run_rturn", "jump_1", "jump_2", "punch_r", "punch_l", "punch_qr",
    "punch_ql", "kick_l", "kick_r", "trans_jump2walk", "trans_walk2jump", "trans_punch2kick",
    "trans_walk2punch", "trans_run2jump",
)  # fmt: skip
GROUPS = ("walk", "run", "jump", "punch", "kick", "trans")
# Last content id (1-based) of each group, in GROUPS order.
_GROUP_ENDS = (12, 15, 17, 21, 23, 28)

# Held out per style, as in the published style-transfer work (README of the data).
TEST_CLIPS_PER_GROUP = {"walk": 3, "run": 1, "jump": 1, "kick": 1, "punch": 1}
# Validation comes from what is left for training: one clip per style and selected group.
VAL_CLIPS_PER_GROUP = 1

# Skeleton profile settings the clips cannot tell: CMU units are 1/0.45 inch. Everything else (root,
# feet, axes, contact thresholds) is found from the clips like any other dataset's. Foot speeds measured
# over 72 clips at 120 fps: toes rest (< 2 units/s) or swing (20-60 units/s), with a trough at 4-6
# units/s; the profile's rule (0.326 leg lengths/s, 0.0326 leg lengths) gives 4.8 units/s and 0.48 units.
PROFILE = {"units": 0.0254 / 0.45}
# The published style-transfer protocol scores walking.
PROTOCOL_CONTENTS = "walk"

_NAME = re.compile(r"^(?P<style>[a-z]+)_(?P<content>\d{2})_(?P<take>\d{3})$")


def group_of(content_id: int) -> int:
    """Group index (into GROUPS) of a 1-based content id."""
    for group, end in enumerate(_GROUP_ENDS):
        if content_id <= end:
            return group
    raise ValueError(f"content id {content_id} outside 1..28")


def parse_name(path: Path) -> ClipInfo:
    """Labels of one clip from its file name, or a WalkdiffError saying what the name should look like."""
    match = _NAME.match(path.stem)
    expected = f"expected STYLE_CC_NNN.bvh with STYLE in {', '.join(STYLES)} and CC in 01..28"
    if match is None:
        raise WalkdiffError(f"file name does not follow the Xia pattern: {expected}", path=path)
    style, content = match["style"], int(match["content"])
    if style not in STYLES or not 1 <= content <= len(CONTENT_NAMES):
        raise WalkdiffError(f"unknown style or content in file name: {expected}", path=path)
    return ClipInfo(path=path, name=path.stem, style=STYLES.index(style), content=group_of(content))


def list_clips(folder: Path) -> list[ClipInfo]:
    files = sorted(folder.glob("*.bvh"))
    if not files:
        raise WalkdiffError("no .bvh files found; expected the 572 Xia clips", path=folder)
    return [parse_name(f) for f in files]


def split_clips(clips: list[ClipInfo], selection: ContentSelection) -> dict[str, list[ClipInfo]]:
    """Deterministic clip-level split: test as published, then validation, the rest for training.

    Within each (style, group) the clips are ranked by a hash of their name, so the split does not
    depend on file order, and adding contents to the selection never moves a clip between splits.
    """
    splits: dict[str, list[ClipInfo]] = {"train": [], "val": [], "test": []}
    for style in range(len(STYLES)):
        for group, group_name in enumerate(GROUPS):
            ranked = deterministic_order([c for c in clips if c.style == style and c.content == group])
            n_test = TEST_CLIPS_PER_GROUP.get(group_name, 0)
            n_val = VAL_CLIPS_PER_GROUP
            test, val, train = ranked[:n_test], ranked[n_test : n_test + n_val], ranked[n_test + n_val :]
            if group_name not in selection.names:
                continue
            splits["test"] += test
            splits["val"] += val
            splits["train"] += train
    return splits


def load(clip: ClipInfo) -> Motion:
    return read_bvh(clip.path)
