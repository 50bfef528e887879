"""Every N batches trained: the evaluation protocol on generated windows, into the MLflow run."""

from __future__ import annotations

import tempfile
import time
import warnings
from pathlib import Path

import lightning as L
import numpy as np
import torch
from matplotlib.figure import Figure
from torchmetrics.classification import MulticlassConfusionMatrix

from walkdiff.callbacks.checkpoints import mlflow_logger
from walkdiff.callbacks.clock import Due, step_folder
from walkdiff.callbacks.tracking import checkpoint_tags
from walkdiff.common.checkpoints import expect_class
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.tracking import log_file
from walkdiff.evaluation.scorer import (
    EVALUATORS,
    MotionScorer,
    WindowSet,
    drawn_labels,
    generate_windows,
    load_evaluator,
    matching_windows,
    window_set,
)


class MotionMetrics(L.Callback):
    """Logs `metrics/fmd`, `metrics/style_acc`, `metrics/diversity`, `metrics/skate_ratio`, ... and the
    images `metrics/step_NNNNNN/style_confusion.png` and `metrics/step_NNNNNN/feature_pca.png`.

    Rank 0 generates and scores; the values are broadcast so that every rank logs the same numbers (and a
    ModelCheckpoint may monitor them). The real windows are embedded once; the generation noise is
    the same at every measurement, so successive values differ by the model only.

    Args:
        evaluator_ckpt: checkpoint of a trained `MotionEvaluator`.
        every_n_steps: measure after the first validation past every N batches trained.
        num_samples: generated windows, each asked for the labels of a reference window drawn at random
            (every label as often as the reference split holds it).
        sampler, steps, guidance: passed to the model's `generate`.
        batch_size: windows generated at once.
        seed: seed of the generation noise and of the metrics' random pairs.
        split: the real windows FMD is measured against. 'train' by default: a checkpoint chosen on
            these numbers must not have seen the test split, and validation has too few windows.

    `history` keeps every measurement (batches trained, its own seconds, the values) for
    `walkdiff bench train --to-bar`, which also asks `held_out_reference` what real windows score.
    """

    def __init__(
        self,
        evaluator_ckpt: str,
        every_n_steps: int = 500,
        num_samples: int = 256,
        sampler: str = "ddpm",
        steps: int | None = None,
        guidance: float = 1.0,
        batch_size: int = 128,
        seed: int = 0,
        split: str = "train",
    ):
        self.split = split
        self.evaluator_ckpt = evaluator_ckpt
        self.due = Due(every_n_steps)
        self.num_samples = num_samples
        self.sampler = sampler
        self.steps = steps
        self.guidance = guidance
        self.batch_size = batch_size
        self.seed = seed
        self.scorer: MotionScorer | None = None
        self.real: WindowSet | None = None
        self.history: list[dict] = []

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # Fail now, not after the first measurement: a missing, unsafe or wrong kind of evaluator file.
        if not Path(self.evaluator_ckpt).exists():
            raise WalkdiffError(
                "evaluator checkpoint not found; train it first with `make evaluator` "
                "(walkdiff fit --config conf/evaluator_xia.yaml)",
                path=self.evaluator_ckpt,
            )
        expect_class(self.evaluator_ckpt, EVALUATORS, "the metrics' evaluator")
        logger = mlflow_logger(trainer)
        if logger is not None and trainer.is_global_zero:  # which evaluator judged this run, and its run
            for key, value in checkpoint_tags(self.evaluator_ckpt, "evaluator").items():
                logger.experiment.set_tag(logger.run_id, key, value)

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        step = self.due(trainer, rank_zero_only=False)  # every rank logs the broadcast values
        if step is None:
            return
        values = None
        if trainer.is_global_zero:
            started = time.perf_counter()
            values = self.measure(trainer, pl_module, step_folder("metrics", step))
            seconds = time.perf_counter() - started
            self.history.append({"batches": step, "seconds": seconds} | values)
        values = trainer.strategy.broadcast(values, src=0)
        for name, value in values.items():
            pl_module.log(f"metrics/{name}", value, on_step=False, on_epoch=True, sync_dist=False)

    def _prepare(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        """Load the evaluator and embed the real test windows, once."""
        if self.scorer is not None:
            return
        self.datamodule = datamodule = trainer.datamodule
        evaluator = load_evaluator(self.evaluator_ckpt, pl_module.device)
        skeleton = pl_module.skeleton if pl_module.skeleton is not None else datamodule.skeleton
        self.scorer = MotionScorer(evaluator, skeleton, pl_module.spec["fps"], batch_size=self.batch_size)
        self.real = self.scorer.embed(
            window_set(datamodule.split_features(self.split), pl_module.spec["window"])
        )
        self.scorer.set_reference(self.real)

    @torch.no_grad()
    def measure(
        self, trainer: L.Trainer, pl_module: L.LightningModule, artifact_dir: str
    ) -> dict[str, float]:
        self._prepare(trainer, pl_module)
        generator = torch.Generator(device=pl_module.device).manual_seed(self.seed)
        labels = drawn_labels(self.real, self.num_samples, self._label_draw())
        windows = generate_windows(
            pl_module,
            labels,
            generator,
            self.batch_size,
            sampler=self.sampler,
            steps=self.steps,
            guidance=self.guidance,
            desc=f"metrics: generating {self.num_samples} windows",
        )
        generated = self.scorer.embed(windows)
        values = self.scorer.score(generated, seed=self.seed)
        styles = list(pl_module.spec["styles"])
        with tempfile.TemporaryDirectory() as tmp:
            confusion = Path(tmp) / "style_confusion.png"
            projection = Path(tmp) / "feature_pca.png"
            counts = MulticlassConfusionMatrix(len(styles))(generated.style_logits, generated.style).float()
            # Shares of each requested style; a style the drawn labels did not ask for is an empty row.
            matrix = counts / counts.sum(dim=1, keepdim=True).clamp(min=1)
            confusion_figure(matrix.numpy(), styles, confusion)
            projection_figure(self.real, generated, styles, projection)
            for path in (confusion, projection):
                log_file(trainer.logger, path, artifact_dir)
        return values

    def held_out_reference(self, split: str = "test", repeats: int = 5) -> list[dict[str, float]]:
        """The scores of real windows of a held-out split, `num_samples` per repeat with the labels a
        measurement asks the generator for, scored exactly as generated ones are (against this
        callback's reference windows): what a generator's numbers here are to be compared with (FMD: the
        train-vs-held-out floor)."""
        if self.scorer is None:
            raise WalkdiffError("held_out_reference needs a measurement first (the evaluator is loaded then)")
        held_out = self.scorer.embed(
            window_set(self.datamodule.split_features(split), self.real.raw.shape[1])
        )
        # The labels a measurement asks the generator for (the first repeat's exactly), each window drawn
        # among the held-out windows of its label.
        label_draw, draw = self._label_draw(), torch.Generator().manual_seed(self.seed + 1)
        scores, unmatched = [], 0
        for repeat in range(repeats):
            labels = drawn_labels(self.real, self.num_samples, label_draw)
            windows, missing = matching_windows(held_out, labels, draw)
            scores.append(self.scorer.score(windows, seed=self.seed + repeat))
            unmatched += missing
        if unmatched:
            warnings.warn(
                f"{unmatched} of the {repeats * self.num_samples} held-out windows have a style and content "
                f"pair the {split} split lacks: drawn among its windows of that content instead",
                stacklevel=2,
            )
        return scores

    def _label_draw(self) -> torch.Generator:
        return torch.Generator().manual_seed(self.seed)


def confusion_figure(matrix: np.ndarray, names: list[str], path: Path) -> None:
    """Rows: requested style; columns: style the evaluator recognises; cells: share of the row."""
    figure = Figure(figsize=(6, 5.2), layout="constrained")
    ax = figure.add_subplot()
    image = ax.imshow(matrix, vmin=0, vmax=1, cmap="Blues")
    ax.set_xticks(range(len(names)), names, rotation=45, ha="right")
    ax.set_yticks(range(len(names)), names)
    ax.set_xlabel("recognised style")
    ax.set_ylabel("requested style")
    for (row, col), value in np.ndenumerate(matrix):
        ax.text(
            col,
            row,
            f"{value:.2f}",
            ha="center",
            va="center",
            color="white" if value > 0.5 else "black",
            fontsize=7,
        )
    figure.colorbar(image, ax=ax, shrink=0.8)
    figure.savefig(path, dpi=100)


def projection_figure(real: WindowSet, generated: WindowSet, names: list[str], path: Path) -> None:
    """Evaluator features of real and generated windows on the first two principal axes of both together."""
    features = torch.cat([real.features, generated.features]).double()
    centred = features - features.mean(dim=0)
    # Principal axes from the SVD of the centred data: exact, and cheap for a few hundred points.
    _, _, vt = torch.linalg.svd(centred, full_matrices=False)
    points = (centred @ vt[:2].T).numpy()
    real_points, generated_points = points[: len(real)], points[len(real) :]
    figure = Figure(figsize=(6.5, 5), layout="constrained")
    ax = figure.add_subplot()
    colours = [f"C{i % 10}" for i in range(len(names))]
    for style, name in enumerate(names):
        ax.scatter(
            *real_points[real.style.numpy() == style].T,
            s=14,
            marker="o",
            facecolors="none",
            edgecolors=colours[style],
            linewidths=0.8,
            label=name,
        )
        ax.scatter(
            *generated_points[generated.style.numpy() == style].T,
            s=14,
            marker="x",
            color=colours[style],
            linewidths=0.8,
        )
    ax.set_xlabel("PC 1")
    ax.set_ylabel("PC 2")
    ax.set_title("evaluator features: o real test, x generated")
    ax.legend(fontsize=7, ncols=2, loc="best")
    figure.savefig(path, dpi=100)
