"""What every `fit` records about its MLflow run, beyond Lightning's logger.

- The experiment is marked a model-training one (`mlflow.experimentKind`). MLflow 3.17's UI does not
  read that mark to choose an experiment's landing page (its sidebar's switch does, GenAI by default):
  `make ui` prints each experiment's run-list address (`walkdiff.common.tracking.ui_addresses`).
- The git commit of the code and whether it had uncommitted changes.
- The process and host, and the runs of killed processes closed (`walkdiff.common.tracking.close_dead_runs`).
- System metrics (CPU, memory, GPU) every 10 s, by MLflow's own monitor.
- The best and last checkpoint of every RunCheckpoint, logged once at the end of training under
  `checkpoints/` with what they were chosen by (Lightning's logger logs one callback's only).
- In every checkpoint, the run that wrote it, so that a generator's run names its evaluator's.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

from lightning.pytorch.callbacks import Callback
from lightning.pytorch.utilities.rank_zero import rank_zero_only

from walkdiff.callbacks.checkpoints import RunCheckpoint, mlflow_logger
from walkdiff.common.checkpoints import read_checkpoint
from walkdiff.common.tracking import close_dead_runs, tag_process

EXPERIMENT_KIND = ("mlflow.experimentKind", "custom_model_development")
RUN_KEY = "walkdiff_mlflow_run"  # in checkpoints: the run that wrote them
SYSTEM_METRICS_SECONDS = 10
SOURCE = Path(__file__).resolve().parents[2]  # walkdiff's checkout, when installed from one


def git_state(folder: Path = SOURCE) -> dict[str, str]:
    """MLflow's git tags for the code in `folder` (walkdiff's checkout), or {} outside a git checkout."""
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=folder, capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()
        changes = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=folder, capture_output=True, text=True, timeout=10, check=True,
        ).stdout  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return {}
    return {"mlflow.source.git.commit": commit, "walkdiff.git_dirty": str(bool(changes.strip())).lower()}


class RunTracking(Callback):
    """Added by `walkdiff fit` to every trainer that logs to MLflow (see the module docstring)."""

    def __init__(self) -> None:
        self.monitor = None

    @rank_zero_only
    def setup(self, trainer, pl_module, stage: str) -> None:
        logger = mlflow_logger(trainer)
        if logger is None or stage != "fit":
            return
        client, run_id = logger.experiment, logger.run_id
        client.set_experiment_tag(logger.experiment_id, *EXPERIMENT_KIND)
        for key, value in git_state().items():
            client.set_tag(run_id, key, value)
        tag_process(client, run_id)
        close_dead_runs(client, logger.experiment_id)
        self._start_monitor(run_id, client.tracking_uri)

    def _start_monitor(self, run_id: str, uri: str) -> None:
        from mlflow.system_metrics.system_metrics_monitor import SystemMetricsMonitor

        try:
            self.monitor = SystemMetricsMonitor(run_id, SYSTEM_METRICS_SECONDS, tracking_uri=uri)
            self.monitor.start()
        except Exception as error:  # psutil missing or an unsupported platform: say so, train anyway
            print(
                f"walkdiff: no system metrics for this run ({type(error).__name__}: {error})", file=sys.stderr
            )
            self.monitor = None

    def _stop_monitor(self) -> None:
        if self.monitor is not None:
            self.monitor.finish()
            self.monitor = None

    @rank_zero_only
    def on_train_end(self, trainer, pl_module) -> None:
        logger = mlflow_logger(trainer)
        if logger is not None:
            log_checkpoints(logger, trainer.checkpoint_callbacks)
        self._stop_monitor()

    def on_save_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        # So that runs using this checkpoint (a generator's metrics use the evaluator's) can name its run.
        logger = mlflow_logger(trainer)
        if logger is not None:
            checkpoint[RUN_KEY] = {
                "run_id": logger.run_id,
                "experiment_id": logger.experiment_id,
                "tracking_uri": logger.experiment.tracking_uri,
            }

    def on_exception(self, trainer, pl_module, exception: BaseException) -> None:
        self._stop_monitor()

    def teardown(self, trainer, pl_module, stage: str) -> None:
        self._stop_monitor()


def log_checkpoints(logger, callbacks) -> None:
    """Each RunCheckpoint's files as artifacts `checkpoints/<link>.ckpt`, and `checkpoints/index.json`
    saying which file each is and, for a monitored one, by which metric and score it was chosen."""
    index = {}
    for callback in callbacks:
        if not isinstance(callback, RunCheckpoint):
            continue
        for link, target in callback.links().items():
            if not Path(target).is_file():
                continue
            with tempfile.TemporaryDirectory() as tmp:
                named = Path(tmp) / link.name
                named.symlink_to(Path(target).resolve())
                logger.experiment.log_artifact(logger.run_id, str(named), "checkpoints")
            monitored = link.stem == callback.link and callback.monitor is not None
            score = callback.best_model_score if monitored else None
            index[link.name] = {
                "file": str(target),
                "monitor": callback.monitor if monitored else None,
                "mode": callback.mode if monitored else None,
                "score": None if score is None else float(score),
            }
    if index:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "index.json"
            path.write_text(json.dumps(index, indent=2) + "\n")
            logger.experiment.log_artifact(logger.run_id, str(path), "checkpoints")


def checkpoint_tags(path: str | Path, role: str) -> dict[str, str]:
    """Tags naming a checkpoint a run uses (`walkdiff.<role>_checkpoint`) and, when it was written by a
    `walkdiff fit` tracked in MLflow, that run (`walkdiff.<role>_run`: experiment id / run id)."""
    path = Path(path)
    tags = {f"walkdiff.{role}_checkpoint": str(path.resolve())}
    run = read_checkpoint(path, f"{role} model").get(RUN_KEY)
    if run:
        tags[f"walkdiff.{role}_run"] = f"{run['experiment_id']}/{run['run_id']}"
    return tags
