"""`walkdiff bench train --to-bar`: a whole training run, timed until its metrics reach the quality bar."""

from __future__ import annotations

import os
import statistics
import sys
import time
from unittest import mock

from walkdiff.bench.measure import machine, report
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_json

# The quality bar of the training issue, as ratios to real data scored the same way: style recognised
# at least 90% as often as in real held-out windows, FMD at most twice the train-vs-held-out floor, foot
# skating at most 1.2 times real held-out windows'.
BAR = {"style_acc": ("min", 0.9), "fmd": ("max", 2.0), "skate_ratio": ("max", 1.2)}


class _TimeToBar:
    """A Lightning callback timing a run (wall time since training started, and the batch loops alone:
    the wall time less validations, metrics and previews) that rewrites the time-to-bar report after
    every MotionMetrics measurement, so an interrupted run still says how far it got."""

    def __init__(self, out: str, config: str, evaluator: str | None, repeats: int, fit_args: list[str]):
        import lightning as L

        self.out, self.config, self.evaluator, self.repeats = out, config, evaluator, repeats
        self.fit_args = fit_args
        self.started = self.validation_started = None
        self.validation_s = 0.0
        self.at_validation: dict[int, dict] = {}  # batches trained -> times when that validation ended
        self.real: dict[str, float] | None = None
        self.load_before = os.getloadavg()
        bench = self

        class Callback(L.Callback):
            def setup(cb, trainer, pl_module, stage):
                if bench.evaluator is not None:
                    _metrics_callback(trainer).evaluator_ckpt = bench.evaluator

            def on_train_start(cb, trainer, pl_module):
                bench.started = time.perf_counter()

            def on_validation_start(cb, trainer, pl_module):
                bench.validation_started = time.perf_counter()

            def on_validation_end(cb, trainer, pl_module):
                if trainer.sanity_checking:
                    return
                bench.validation_s += time.perf_counter() - bench.validation_started
                bench.at_validation[trainer.global_step] = bench.times()
                metrics = _metrics_callback(trainer)
                if metrics.history and metrics.history[-1]["batches"] == trainer.global_step:
                    bench.report(trainer, finished=False)

        self.callback = Callback()

    def times(self) -> dict:
        wall = time.perf_counter() - self.started
        return {"wall_s": wall, "train_loop_s": wall - self.validation_s}

    def report(self, trainer, finished: bool) -> dict:
        from walkdiff.callbacks.checkpoints import mlflow_logger

        metrics = _metrics_callback(trainer)
        if self.real is None:  # once, with the evaluator the first measurement loaded
            references = metrics.held_out_reference("test", self.repeats)
            self.real = {name: statistics.fmean(r[name] for r in references) for name in BAR}
        bar = {name: factor * self.real[name] for name, (_, factor) in BAR.items()}
        rows = _bar_rows(metrics.history, self.at_validation, bar)
        measuring_s = sum(m["seconds"] for m in metrics.history)
        now = self.times()
        logger = mlflow_logger(trainer)
        result = {
            "benchmark": "time_to_bar",
            "finished": finished,  # false: written after a measurement of a run still training
            "config": self.config,
            "fit_args": self.fit_args,
            "evaluator": metrics.evaluator_ckpt,
            "mlflow_run_id": None if logger is None else logger.run_id,
            "batches": trainer.global_step,
            "max_steps": trainer.max_steps,
            "batches_per_epoch": trainer.num_training_batches,
            "metrics": {
                "every_n_steps": metrics.due.every_n_steps,
                "num_samples": metrics.num_samples,
                "sampler": metrics.sampler,
                "steps": metrics.steps,
            },
            "real_held_out": {name: round(value, 4) for name, value in self.real.items()}
            | {"repeats": self.repeats},
            "bar": {
                name: {
                    "rule": f"{'>=' if kind == 'min' else '<='} {factor} x real",
                    "value": round(bar[name], 4),
                }
                for name, (kind, factor) in BAR.items()
            },
            "measurements": rows,
            "checkpoints": _checkpoints(trainer),
            "time_to_bar": _first(rows, "at_bar"),
            "per_criterion": {name: _first(rows, f"{name}_ok") for name in BAR},
            "training_s": round(now["wall_s"] - measuring_s, 1),
            "train_loop_s": round(now["train_loop_s"], 1),
            "metrics_s": round(measuring_s, 1),
            "load_average_before": [round(x, 2) for x in self.load_before],
            "load_average_now": [round(x, 2) for x in os.getloadavg()],
            "machine": machine(),
        }
        if finished:
            report(self.out, result)
        else:
            write_json(self.out, result)
        return result


def _checkpoints(trainer) -> dict[str, str]:
    """{stable link name: this run's file} of every RunCheckpoint (e.g. last, best): the files of this
    run, where the links may since point at a newer run's."""
    from walkdiff.callbacks.checkpoints import RunCheckpoint

    return {
        c.link: c.best_model_path
        for c in trainer.callbacks
        if isinstance(c, RunCheckpoint) and c.best_model_path
    }


def _metrics_callback(trainer):
    from walkdiff.callbacks.metrics import MotionMetrics

    found = [c for c in trainer.callbacks if isinstance(c, MotionMetrics)]
    if not found:
        raise WalkdiffError(
            "the config has no walkdiff.callbacks.metrics.MotionMetrics callback: time to the quality bar "
            "is read from its measurements"
        )
    return found[0]


def _bar_rows(history: list[dict], times: dict[int, dict], bar: dict[str, float]) -> list[dict]:
    """Per measurement: batches, times, each metric against its bar, and whether all three hold."""
    rows, metrics_s = [], 0.0
    for measured in history:
        metrics_s += measured["seconds"]
        clock = times[measured["batches"]]
        row = {
            "batches": measured["batches"],
            # Everything since training started except the metric measurements themselves: the
            # batches, validation, checkpoints and any other callbacks the config has.
            "training_s": round(clock["wall_s"] - metrics_s, 1),
            "train_loop_s": round(clock["train_loop_s"], 1),
            "metrics_s": round(measured["seconds"], 1),
            "wall_s": round(clock["wall_s"], 1),
        }
        for name, (kind, _) in BAR.items():
            value = measured[name]
            row[name] = round(value, 4)
            row[f"{name}_ok"] = value >= bar[name] if kind == "min" else value <= bar[name]
        row["at_bar"] = all(row[f"{name}_ok"] for name in BAR)
        rows.append(row)
    return rows


def _first(rows: list[dict], key: str) -> dict | None:
    """The first row where `key` holds, and the first from which it holds at every later measurement."""
    first = next((r for r in rows if r[key]), None)
    stays = None
    for row in reversed(rows):
        if not row[key]:
            break
        stays = row
    pick = ("batches", "training_s", "train_loop_s", "wall_s")
    return {
        "first": None if first is None else {k: first[k] for k in pick},
        "from_then_on": None if stays is None else {k: stays[k] for k in pick},
    }


def bench_time_to_bar(
    out: str,
    config: str = "conf/xia_cpu.yaml",
    evaluator: str | None = None,
    repeats: int = 5,
    fit_args: list[str] | tuple[str, ...] = (),
) -> dict:
    """Trains CONFIG exactly as `walkdiff fit --config CONFIG` does (bounded by its steps, with its
    MLflow run and checkpoints) and reads its MotionMetrics measurements against the quality bar.

    The real references are the callback's own numbers for real windows of the test split (as many as
    it generates, `repeats` draws, averaged): held-out windows scored against the same training
    windows, by the same evaluator. Writes OUT (JSON) after every measurement and at the end: per
    measurement the batches trained, the training time without the measurements (and the
    batch loops alone), the measurement's own time, each metric against its bar, and the first
    measurement where all three hold.
    """
    from walkdiff.callbacks.fit import lightning_cli

    bench = _TimeToBar(out, config, evaluator, repeats, list(fit_args))
    # LightningCLI warns when it is given args and sys.argv holds more (this bench's own options).
    with mock.patch.object(sys, "argv", sys.argv[:1]):
        cli = lightning_cli(["fit", "--config", config, *fit_args], callbacks=[bench.callback])
    trainer = cli.trainer
    metrics = _metrics_callback(trainer)
    if not metrics.history:
        raise WalkdiffError(
            f"the run made no metrics measurement: MotionMetrics measures every "
            f"{metrics.due.every_n_steps} batches, after a validation (trainer.val_check_interval), and "
            f"it trained {trainer.global_step} batches",
            path=config,
        )
    return bench.report(trainer, finished=True)
