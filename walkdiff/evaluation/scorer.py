"""Scoring sets of motion windows with a trained evaluator: the machinery of every quality number.

A `WindowSet` holds windows (a generator's raw features, or positions read from files) with their labels;
a `MotionScorer` embeds them with a `MotionEvaluator` (or HumanAct12's `ActionEvaluator`) and scores one
set against a fixed real reference set: FMD, style and content recognition accuracy, diversity,
multimodality, foot skating and jitter. `walkdiff evaluate`, `walkdiff score`, the training metrics
callback and the benchmarks all score through it.
"""

from __future__ import annotations

import importlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torchmetrics.classification import MulticlassAccuracy

from walkdiff.common.checkpoints import expect_class
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.progress import progress, step_hook
from walkdiff.metrics import Diversity, FootSkating, FrechetMotionDistance, Jitter, Multimodality
from walkdiff.motion.representation import FeatureLayout, features_to_positions
from walkdiff.motion.skeleton import Skeleton


@dataclass
class WindowSet:
    """Motion windows with labels and, once embedded, their joint positions and the evaluator's outputs.

    A generator's windows come as raw features (`raw`), turned into positions by `MotionScorer.embed`;
    windows read from files (`walkdiff score`) come as positions directly.
    """

    raw: torch.Tensor | None  # (N, W, D) features in data units, or None
    style: torch.Tensor  # (N,) style ids (true or requested)
    content: torch.Tensor  # (N,) content group ids
    clip: torch.Tensor  # (N,) index of the source clip; -1 for generated windows
    positions: torch.Tensor | None = None  # (N, W, J, 3) world joint positions, canonical axes
    features: torch.Tensor | None = None  # (N, E) evaluator features
    style_logits: torch.Tensor | None = None
    content_logits: torch.Tensor | None = None

    def __len__(self) -> int:
        return self.style.shape[0]

    def take(self, index: torch.Tensor) -> WindowSet:
        def pick(x):
            return None if x is None else x[index]

        return WindowSet(*(pick(getattr(self, name)) for name in self.__dataclass_fields__))


def window_set(clips: list, window: int, stride: int = 1) -> WindowSet:
    """Every `window`-frame window of `(clip, name, features)` triples, as from `split_features`."""
    raws, styles, contents, sources = [], [], [], []
    for i, (info, _, features) in enumerate(clips):
        starts = range(0, features.shape[0] - window + 1, stride)
        raws += [features[s : s + window] for s in starts]
        styles += [info.style] * len(starts)
        contents += [info.content] * len(starts)
        sources += [i] * len(starts)
    if not raws:
        raise WalkdiffError(f"no clip of this split is at least {window} frames long; no window to evaluate")
    return WindowSet(
        torch.from_numpy(np.stack(raws)),
        torch.tensor(styles),
        torch.tensor(contents),
        torch.tensor(sources),
    )


class MotionScorer:
    """Scores sets of windows with an evaluator, against a fixed real reference set.

    `skeleton` is the skeleton of the raw feature windows it is given (a generator's); it must have the
    evaluator's joints.
    """

    def __init__(self, evaluator, skeleton: Skeleton, fps: float, batch_size: int = 512):
        self.evaluator = evaluator.eval()
        self.spec = evaluator.spec
        self.fps = fps
        self.batch_size = batch_size
        names = list(evaluator.body.names)
        if list(skeleton.names) != names:
            differ = sorted(set(skeleton.names) ^ set(names)) or ["the same joints in another order"]
            raise WalkdiffError(f"the motion's skeleton is not the evaluator's ({', '.join(differ[:8])})")
        contacts = evaluator.profile.contacts
        self.foot_joints = [names.index(name) for name in contacts.joints]
        self.speed_threshold = contacts.speed_threshold
        self.height_threshold = contacts.height_threshold
        self.floor: torch.Tensor | None = None  # per foot joint, from the real reference set
        self.offsets = torch.from_numpy(skeleton.offsets)
        self.parents = skeleton.parents
        self.fmd_real: FrechetMotionDistance | None = None

    def embed(self, windows: WindowSet) -> WindowSet:
        """The windows with positions (from `raw` when given) and the evaluator's outputs."""
        positions = windows.positions if windows.raw is None else self.positions(windows.raw)
        outputs = [
            self.evaluator.embed_and_classify(positions[i : i + self.batch_size])
            for i in range(0, len(windows), self.batch_size)
        ]
        features, style, content = (torch.cat([o[k] for o in outputs]).float().cpu() for k in range(3))
        return replace(
            windows, positions=positions, features=features, style_logits=style, content_logits=content
        )

    def set_reference(self, reference: WindowSet) -> None:
        """The real statistics every FMD of `score` is measured against, and the real floor height."""
        self.fmd_real = fmd_metric(reference.features)
        feet = reference.positions[..., self.foot_joints, 1]
        self.floor = torch.quantile(feet.flatten(0, 1).double(), 0.05, dim=0)

    def positions(self, raw: torch.Tensor) -> torch.Tensor:
        """(N, W, J, 3) float32 positions of raw windows, each starting at the origin (float64 FK in
        chunks: jitter multiplies position errors by fps^3)."""
        chunks = [
            features_to_positions(raw[i : i + self.batch_size].double(), self.offsets, self.parents).float()
            for i in range(0, raw.shape[0], self.batch_size)
        ]
        return torch.cat(chunks) if chunks else torch.zeros(0, raw.shape[1], len(self.parents), 3)

    def ground_contacts(self, positions: torch.Tensor) -> torch.Tensor:
        """A foot joint touches the ground when it is within the contact height of the real floor.

        Decided from the geometry, not from the predicted contact labels, so real and generated motion
        are judged alike (with labels, real data would have no skating by construction).
        """
        height = positions[..., self.foot_joints, 1].double() - self.floor
        return height < self.height_threshold

    def score(self, windows: WindowSet, seed: int = 0) -> dict[str, float]:
        """Every metric of one set of embedded windows (one repeat of the protocol)."""
        if self.fmd_real is None:
            raise RuntimeError("MotionScorer.set_reference must be called before score")
        self.fmd_real.reset()  # keeps the real statistics (reset_real_features=False)
        self.fmd_real.update(windows.features, real=False)
        values = {"fmd": self.fmd_real.compute()}

        for kind, labels, logits in (
            ("style", windows.style, windows.style_logits),
            ("content", windows.content, windows.content_logits),
        ):
            if len(self.spec[f"{kind}s"]) > 1:  # HumanAct12 has one style: nothing to recognise
                accuracy = MulticlassAccuracy(len(self.spec[f"{kind}s"]), average="micro")
                values[f"{kind}_acc"] = accuracy(logits, labels)

        diversity = Diversity(num_pairs=200, seed=seed)
        diversity.update(windows.features)
        values["diversity"] = diversity.compute()
        multimodality = Multimodality(num_pairs=20, seed=seed)
        # Per style; per action (content) for a dataset without styles, as in Action2Motion / ACTOR.
        styled = len(self.spec["styles"]) > 1
        multimodality.update(windows.features, windows.style if styled else windows.content)
        values["multimodality"] = multimodality.compute()

        positions = windows.positions.double()
        skating = FootSkating(self.foot_joints, self.fps, self.speed_threshold)
        skating.update(positions, self.ground_contacts(positions))
        values |= skating.compute()
        jitter = Jitter(self.fps)
        jitter.update(positions)
        values["jitter"] = jitter.compute()
        return {name: float(value) for name, value in values.items()}

    def per_content(self, windows: WindowSet, seed: int = 0) -> dict[int, dict[str, float]]:
        """Per content label of embedded windows with raw features: the signed heading change in degrees
        per second (positive to the body's left), multimodality (pairs of one style inside the label) and
        foot skating. Pooled figures hide a label that turns half as far or varies less than real."""
        if windows.raw is None:
            raise WalkdiffError("per-label figures need raw feature windows (a generator's or a split's)")
        heading = windows.raw[:, :, FeatureLayout.heading_vel.start].double().mean(dim=1)
        rows = {}
        for content in windows.content.unique(sorted=True).tolist():
            mask = windows.content == content
            multimodality = Multimodality(num_pairs=20, seed=seed)
            multimodality.update(windows.features[mask], windows.style[mask])
            # No style with two windows of this label in this draw (a rare label): no pair to measure.
            paired = bool((torch.bincount(windows.style[mask]) >= 2).any())
            positions = windows.positions[mask].double()
            skating = FootSkating(self.foot_joints, self.fps, self.speed_threshold)
            skating.update(positions, self.ground_contacts(positions))
            rows[content] = {
                "turn_deg_s": math.degrees(float(heading[mask].mean())) * self.fps,
                "multimodality": float(multimodality.compute()) if paired else math.nan,
                "skate_ratio": float(skating.compute()["skate_ratio"]),
                "windows": int(mask.sum()),
            }
        return rows


def fmd_metric(real_features: torch.Tensor) -> FrechetMotionDistance:
    metric = FrechetMotionDistance(real_features.shape[1], reset_real_features=False)
    metric.update(real_features, real=True)
    return metric


def drawn_labels(
    reference: WindowSet, num: int, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """(style ids, content ids) of `num` windows of `reference` drawn at random with replacement.

    Generated windows are asked for the labels real ones have, as often as the real ones have them (as
    ACTOR and MDM condition generation on the real set's labels): FMD, multimodality and recognition then
    compare like with like. Labels cycled evenly against a real set that is mostly one label measure the
    mixture of labels, not the motion (docs/evaluation.md, "Which labels are generated")."""
    index = torch.randint(len(reference), (num,), generator=generator)
    return reference.style[index], reference.content[index]


def matching_windows(
    pool: WindowSet, labels: tuple[torch.Tensor, torch.Tensor], generator: torch.Generator
) -> tuple[WindowSet, int]:
    """Windows of `pool` with the given (style ids, content ids), each drawn at random among the pool's
    windows of its pair: real windows in another set's mixture of labels, so that a floor row (training
    windows against test ones) holds the labels the generated row holds. A pair the pool lacks is drawn
    among its windows of that content, or of any content if it has none; how many were is returned
    beside (the caller says so)."""
    style, content = labels
    width = int(max(pool.content.max(), content.max())) + 1
    pool_cells, cells = pool.style * width + pool.content, style * width + content
    index = torch.empty(len(cells), dtype=torch.long)
    unmatched = 0
    for cell in cells.unique():
        wanted = cells == cell
        members = (pool_cells == cell).nonzero().flatten()
        if len(members) == 0:
            unmatched += int(wanted.sum())
            members = (pool.content == cell % width).nonzero().flatten()
            members = members if len(members) else torch.arange(len(pool))
        index[wanted] = members[torch.randint(len(members), (int(wanted.sum()),), generator=generator)]
    return pool.take(index), unmatched


def generate_windows(
    model,
    labels: tuple[torch.Tensor, torch.Tensor],
    generator: torch.Generator,
    batch_size: int,
    grounded: bool = True,
    desc: str = "generating windows",
    timed: Callable[[int, float], None] | None = None,
    **sampling,
) -> WindowSet:
    """One raw window from a generator (`generate`, `to_raw`) per (style id, content id) of `labels`,
    grounded unless told otherwise, with a progress bar `desc` over batches x denoising steps;
    `timed(windows, seconds)` after each batch."""
    style, content = labels
    num = len(style)
    raws = []
    with progress(desc=desc, unit="step") as bar:
        hook = step_hook(bar, math.ceil(num / batch_size))
        for i in range(0, num, batch_size):
            started = time.perf_counter()
            x = model.generate(
                style[i : i + batch_size].to(model.device),
                content[i : i + batch_size].to(model.device),
                generator=generator,
                progress=hook,
                **sampling,
            )
            raws.append(torch.from_numpy(model.to_raw(x, grounded)))
            if timed is not None:
                timed(len(x), time.perf_counter() - started)
    return WindowSet(torch.cat(raws), style, content, torch.full((num,), -1))


def halves_fmd(reference: WindowSet, generator: torch.Generator) -> float:
    """FMD between two halves of a real set, split by clip and balanced over styles."""
    first = []
    for style in reference.style.unique():
        clips = reference.clip[reference.style == style].unique()
        clips = clips[torch.randperm(len(clips), generator=generator)]
        first.append(clips[: len(clips) // 2])
    in_first = torch.isin(reference.clip, torch.cat(first))
    if in_first.sum() < 2 or (~in_first).sum() < 2:
        raise WalkdiffError("the reference split has too few clips to split into halves")
    metric = fmd_metric(reference.features[in_first])
    metric.update(reference.features[~in_first], real=False)
    return float(metric.compute())


EVALUATORS = ("walkdiff.models.evaluator.MotionEvaluator", "walkdiff.models.action_evaluator.ActionEvaluator")


def load_evaluator(path: str | Path, device: str | torch.device = "cpu"):
    """The trained evaluator of a checkpoint: a MotionEvaluator, or the HumanAct12 ActionEvaluator."""
    class_path = expect_class(path, EVALUATORS, "--evaluator")
    module, name = class_path.rsplit(".", 1)
    evaluator_class = getattr(importlib.import_module(module), name)
    return evaluator_class.from_trained(path, "evaluator", device)
