"""How long `data scan`'s configs train, in batches, from what a folder holds: its kinds of motion.

The budget is in batches, whatever the folder's size: the recipe of conf/xia_cpu.yaml reaches the quality
bar in about half its 1,800 batches on Xia walking, and a larger folder needs no more batches to reach it
(docs/training.md, "Time to the quality bar"). A varied folder, whose contents include one-off actions
(contents whose root stays in place), gets twice the batches: on the disguised actions folder 3,600 took
skating from 3.9x real to 1.9x and style from 0.60 to 0.77 of real (docs/training.md, "The quality
suite").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.skeleton import Motion

GENERATOR_STEPS, VARIED_GENERATOR_STEPS, EVALUATOR_STEPS = 1800, 3600, 1800
# Windows per batch. The generator's 96 (the evaluator's 64), of which the discriminator judges 64: its
# step and the adversarial term then cost the same at any batch. With it every folder of the quality
# suite is at the bar (docs/training.md, "The quality suite"): 48 judged held the all-contents Xia FMD
# lower (1.87x the floor against 1.92x) but left the actions folder's style at 0.89x real (0.91x at 64),
# and 96 all judged cost 1.45x to 1.60x the seconds per batch of the config `data scan` wrote when issue
# 42 was filed, over its 1.5x bound.
BATCH_SIZE, GENERATOR_BATCH_SIZE, DISCRIMINATOR_WINDOWS = 64, 96, 64
# A content travels when its clips' root moves at least this many body heights a second (median over its
# clips, along the ground, sampled every TRAVEL_STEP_SECONDS so standing sway does not add up). On Xia:
# walks 0.71, runs 0.96, jumps 0.50, transitions 0.29; punches 0.04 and kicks 0.10 stay in place.
TRAVEL_SPEED, TRAVEL_STEP_SECONDS = 0.25, 0.25


@dataclass(frozen=True)
class Budget:
    """The generator's batches and why."""

    steps: int
    why: str


def root_travel(profile: SkeletonProfile, motion: Motion) -> float:
    """Body heights per second the clip's root moves along the ground (canonical axes: y up)."""
    step = max(1, round(TRAVEL_STEP_SECONDS / motion.frame_time))
    ground = profile.to_canonical(motion).positions[::step, 0][:, [0, 2]]
    path = float(np.linalg.norm(np.diff(ground, axis=0), axis=1).sum())
    return path / (motion.num_frames * motion.frame_time) / profile.body_height


def generator_budget(groups: tuple[str, ...], contents: list[int], travel: np.ndarray) -> Budget:
    """The generator's budget for clips of content indices `contents` (into `groups`) whose roots travel
    `travel` body heights a second: twice the batches where several contents include some that stay in
    place."""
    speeds: dict[int, list[float]] = {g: [] for g in range(len(groups))}
    for content, speed in zip(contents, travel, strict=True):
        speeds[content].append(float(speed))
    still = [groups[g] for g, v in speeds.items() if v and float(np.median(v)) < TRAVEL_SPEED]
    if len(groups) > 1 and still:
        shown = ", ".join(still[:8]) + (f" and {len(still) - 8} more" if len(still) > 8 else "")
        return Budget(
            VARIED_GENERATOR_STEPS,
            f"a varied folder: {len(still)} of its {len(groups)} contents stay in place (one-off actions: "
            f"{shown}), so twice the batches of a walking folder",
        )
    if len(groups) > 1:
        return Budget(GENERATOR_STEPS, f"all {len(groups)} contents travel (locomotion)")
    return Budget(GENERATOR_STEPS, "one content")
