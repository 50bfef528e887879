"""Callbacks and configs the training tests put into real `walkdiff fit` runs (importable by class path)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import lightning as L


class SleepEachBatch(L.Callback):
    """Stands for a slower or busier machine: every training batch takes `seconds` longer."""

    def __init__(self, seconds: float):
        self.seconds = seconds

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        time.sleep(self.seconds)


class RecordSteps(L.Callback):
    """Writes to `path` the global step at the start and end of training, the validation losses and the
    generator's last learning rate."""

    def __init__(self, path: str):
        self.path = Path(path)
        self.record: dict = {"val_loss": []}

    def on_train_start(self, trainer, pl_module):
        self.record["first_step"] = trainer.global_step
        self.record["first_epoch"] = trainer.current_epoch

    def on_validation_epoch_end(self, trainer, pl_module):
        if not trainer.sanity_checking:
            self.record["val_loss"].append(float(trainer.callback_metrics["diffusion/val"]))

    def on_train_end(self, trainer, pl_module):
        lr = trainer.optimizers[0].param_groups[0]["lr"]
        self.record |= {"last_step": trainer.global_step, "epochs": trainer.current_epoch, "lr": lr}
        self.path.write_text(json.dumps(self.record))


def tiny_fit_config(root: Path, name: str, *, epochs: int, batches: int, callbacks: list[dict]) -> str:
    """A `walkdiff fit` config of a tiny StyledMotionDiffusion on the synthetic data in `root`: an MLflow
    sqlite store and checkpoints (`RunCheckpoint`, last every epoch) under the working directory.

    Bounded by steps as walkdiff's own configs are: `epochs` passes of `batches` batches, validated
    after each."""
    extra = "".join(f"    - {json.dumps(c)}\n" for c in callbacks)
    return f"""\
seed_everything: 3
trainer:
  accelerator: cpu
  devices: 1
  max_steps: {epochs * batches}
  max_time: "00:00:10:00"
  limit_train_batches: {batches}
  val_check_interval: {batches}
  check_val_every_n_epoch: null
  limit_val_batches: 1
  num_sanity_val_steps: 0
  log_every_n_steps: 1
  enable_progress_bar: false
  enable_model_summary: false
  logger:
    class_path: lightning.pytorch.loggers.MLFlowLogger
    init_args:
      experiment_name: walkdiff-test
      run_name: {name}
      tracking_uri: sqlite:///mlruns/mlflow.db
      artifact_location: mlruns/artifacts
  callbacks:
    - class_path: walkdiff.callbacks.checkpoints.RunCheckpoint
      init_args:
        dirpath: checkpoints/{name}
        filename: last
        save_top_k: 1
{extra}model:
  class_path: walkdiff.models.styled_ddpm.StyledMotionDiffusion
  init_args:
    d_model: 32
    layers: 1
    heads: 2
    lambda_adv: 0.05
    adv_warmup_batches: 2
    lr_warmup_batches: 2
data:
  class_path: walkdiff.data.datamodule.MotionDataModule
  init_args:
    root: {root}
    cache_dir: {root / "cache"}
    window: 24
    batch_size: 8
    num_workers: 0
    preprocess_workers: 1
"""


class CopyAtEpochStart(L.Callback):
    """Copies `source` (when it exists) to `target` as epoch `epoch` (0-based) starts: what a file said
    while the run was still training."""

    def __init__(self, source: str, target: str, epoch: int):
        self.source, self.target, self.epoch = Path(source), Path(target), epoch

    def on_train_epoch_start(self, trainer, pl_module):
        if trainer.current_epoch == self.epoch and self.source.exists():
            self.target.write_bytes(self.source.read_bytes())


class LogEveryOtherEpoch(L.Callback):
    """Logs `key` (10 - epoch: better each time) after the validation of every `every`-th epoch only, as
    MotionMetrics logs metrics/fmd; the other validations do not log it."""

    def __init__(self, key: str, every: int = 2):
        self.key, self.every = key, every

    def on_validation_epoch_end(self, trainer, pl_module):
        epoch = trainer.current_epoch
        if not trainer.sanity_checking and (epoch + 1) % self.every == 0:
            pl_module.log(self.key, 10.0 - epoch, on_step=False, on_epoch=True)
