"""The training clock: batches trained, not epochs.

An epoch's length grows with the data (a folder ten times Xia's has epochs ten times longer), so every
walkdiff config bounds training by `trainer.max_steps` and validates every `val_check_interval` batches,
and the callbacks that measure and preview do so every N batches (`Due`). `trainer.global_step` counts
one step per batch for every walkdiff model (the styled GAN's discriminator step is not counted: see
`walkdiff.models.styled_ddpm`).

`ProgressLog` writes one line per interval (step, loss, speed, ETA) to stderr when it is not a terminal,
so a run whose output goes to a file shows how far it is while it runs.
"""

from __future__ import annotations

import sys
import time

import lightning as L

from walkdiff.common.progress import duration


class Due:
    """Whether a measurement is due after a validation: the first validation at or after every multiple
    of `every_n_steps` batches (validations need not fall on the multiples), on rank 0, never in the
    sanity check."""

    def __init__(self, every_n_steps: int):
        if every_n_steps < 1:
            raise ValueError(f"every_n_steps must be at least 1, got {every_n_steps}")
        self.every_n_steps = every_n_steps
        self.done = 0  # multiples of every_n_steps already measured

    def __call__(self, trainer: L.Trainer, rank_zero_only: bool = True) -> int | None:
        """The step of the measurement when one is due now, else None."""
        if trainer.sanity_checking or (rank_zero_only and not trainer.is_global_zero):
            return None
        reached = trainer.global_step // self.every_n_steps
        if reached <= self.done:
            return None
        self.done = reached
        return trainer.global_step


def step_folder(kind: str, step: int) -> str:
    """The MLflow artifact folder of a measurement or preview, e.g. `samples/step_001200`."""
    return f"{kind}/step_{step:06d}"


class ProgressLog(L.Callback):
    """One line per `every_s` seconds of training on stderr (when it is not a terminal, where Lightning's
    progress bar already shows the same): step of max_steps, the loss, seconds per batch, and the ETA."""

    def __init__(self, every_s: float = 30.0, stream=None):
        self.every_s = every_s
        self.stream = stream
        self.started = self.last = 0.0
        self.first_step = 0

    def _out(self):
        return self.stream if self.stream is not None else sys.stderr

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.started = self.last = time.perf_counter()
        self.first_step = trainer.global_step

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        now = time.perf_counter()
        if now - self.last < self.every_s or not trainer.is_global_zero:
            return
        self.last = now
        self._out().write(self.line(trainer, now) + "\n")
        self._out().flush()

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.is_global_zero and self.first_step < trainer.global_step:
            self._out().write(self.line(trainer, time.perf_counter()) + " (done)\n")
            self._out().flush()

    def line(self, trainer: L.Trainer, now: float) -> str:
        step, planned = trainer.global_step, trainer.max_steps
        done = step - self.first_step
        per_batch = (now - self.started) / max(done, 1)
        metrics = trainer.callback_metrics
        loss = metrics.get("loss", metrics.get("loss/train"))  # per batch, else the last epoch's mean
        of = f"/{planned} ({100 * step / planned:.0f}%)" if planned > 0 else ""
        parts = [f"walkdiff: step {step}{of}"]
        if loss is not None:
            parts.append(f"loss {float(loss):.4f}")
        parts.append(f"{per_batch:.2f} s/batch")
        if planned > 0:
            parts.append(f"ETA {duration(per_batch * max(planned - step, 0))}")
        return ", ".join(parts)
