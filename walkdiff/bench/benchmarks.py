"""`walkdiff bench ...`: measured numbers written to JSON (never asserted by timed unit tests)."""

from __future__ import annotations

import contextlib
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from unittest import mock

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import strict_json, write_atomic, write_json
from walkdiff.common.progress import progress


def machine() -> dict:
    return {
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "platform": platform.platform(),
    }


def report(out: str | Path, result: dict) -> None:
    """Write a benchmark's JSON (atomically) and show it."""
    write_json(out, result)
    print(json.dumps(strict_json(result), indent=2))


def bench_data(out: str, dataset: str = "xia", root: str | None = None, repeats: int = 3) -> dict:
    """Cold preprocessing of every clip, warm (cached) load, and windows/s through the DataLoader."""
    from walkdiff.data.datamodule import MotionDataModule

    with tempfile.TemporaryDirectory() as cache:
        kwargs = dict(dataset=dataset, root=root, contents="all", cache_dir=cache, batch_size=64)
        start = time.perf_counter()
        dm = MotionDataModule(**kwargs)
        dm.prepare_data()
        cold = time.perf_counter() - start

        warm_times = []
        for _ in range(repeats):
            start = time.perf_counter()
            warm = MotionDataModule(**kwargs)
            warm._ensure_processed(progress=False)
            warm.setup("fit")
            warm_times.append(time.perf_counter() - start)

        loader = warm.train_dataloader()
        epoch_times, windows = [], len(loader) * loader.batch_size
        for _ in range(repeats):
            start = time.perf_counter()
            for _batch in loader:
                pass
            epoch_times.append(time.perf_counter() - start)

    result = {
        "benchmark": "data",
        "dataset": dataset,
        "clips": len(dm.clips),
        "frames_at_fps": int(sum(f.shape[0] for f in dm.processed.features)),
        "fps": dm.hparams.fps,
        "preprocess_workers": dm.hparams.preprocess_workers,
        "cold_preprocess_s": round(cold, 2),
        "warm_load_s_median": round(statistics.median(warm_times), 3),
        "warm_load_s_all": [round(t, 3) for t in warm_times],
        "train_windows": len(warm.datasets["train"]),
        "window": dm.hparams.window,
        "dataloader_windows_per_s_median": round(windows / statistics.median(epoch_times)),
        "machine": machine(),
    }
    report(out, result)
    return result


def _config_model_and_data(config: str):
    """The model and data module exactly as `walkdiff fit --config CONFIG` would build them."""
    from omegaconf import OmegaConf

    from walkdiff.data.datamodule import MotionDataModule
    from walkdiff.models.styled_ddpm import StyledMotionDiffusion

    cfg = OmegaConf.to_container(OmegaConf.load(config), resolve=True)
    dm = MotionDataModule(**cfg["data"]["init_args"])
    model = StyledMotionDiffusion(dm.spec, **cfg["model"]["init_args"])
    return model, dm


def _config_precision(config: str) -> str:
    """The config's trainer.precision (Lightning's default 32-true when it names none)."""
    from omegaconf import OmegaConf

    precision = str(OmegaConf.load(config).get("trainer", {}).get("precision", "32-true"))
    if precision not in ("32-true", "32", "bf16-mixed"):
        raise WalkdiffError(
            f"trainer.precision: bench train times 32-true or bf16-mixed, not {precision!r}", path=config
        )
    return precision


class _BatchClock:
    """Wall and process CPU time of training batches [skip, skip + count) as Lightning runs them."""

    def __init__(self, skip: int):
        import lightning as L

        class Clock(L.Callback):
            def on_train_batch_start(cb, trainer, pl_module, batch, batch_idx):
                if batch_idx == skip:
                    self.start, self.cpu_start = time.perf_counter(), time.process_time()

            def on_train_batch_end(cb, trainer, pl_module, outputs, batch, batch_idx):
                self.end, self.cpu_end = time.perf_counter(), time.process_time()

        self.callback = Clock()
        self.start = self.end = self.cpu_start = self.cpu_end = 0.0


def _lightning_seconds(config: str, batches: int, warmup: int) -> tuple[float, float]:
    """(wall seconds, process CPU seconds) of `batches` training batches under Lightning."""
    import lightning as L

    model, dm = _config_model_and_data(config)
    model.hparams.adv_warmup_batches = 0  # time the full step: D + G with the adversarial term
    clock = _BatchClock(warmup)
    trainer = L.Trainer(
        accelerator="cpu", devices=1, precision=_config_precision(config), max_epochs=1,
        limit_train_batches=warmup + batches,
        limit_val_batches=0, logger=False, enable_checkpointing=False, enable_progress_bar=False,
        enable_model_summary=False, callbacks=[clock.callback],
    )  # fmt: skip
    trainer.fit(model, dm)
    return clock.end - clock.start, clock.cpu_end - clock.cpu_start


def _plain_seconds(config: str, batches: int, warmup: int) -> float:
    """The same networks, losses, optimizers, clipping and EMA in a hand-written loop."""
    model, dm = _config_model_and_data(config)
    # bf16-mixed as Lightning runs it: the forward passes and losses under autocast, float32 weights.
    autocast = torch.autocast("cpu", torch.bfloat16, enabled=_config_precision(config) == "bf16-mixed")
    dm.setup("fit")
    model.normalizer.load_state_dict(dm.normalizer.state_dict())
    model.profile = dm.profile  # the FK losses need the skeleton (Lightning's setup sets it too)
    model.train()
    h = model.hparams
    (opt_g, opt_d), (sched_g, sched_d) = model.configure_optimizers()
    loader = dm.train_dataloader()
    start = 0.0
    for i, batch in enumerate(loader):
        if i == warmup:
            start = time.perf_counter()
        if i == warmup + batches:
            break
        with autocast:
            out, target, x0_hat, t = model.denoise(batch, cond_drop=h.cond_drop)
            d_loss = model.discriminator_loss(batch, x0_hat, t)["d"]
        opt_d.zero_grad(set_to_none=True)
        d_loss.backward()
        torch.nn.utils.clip_grad_norm_(model.discriminator.parameters(), h.grad_clip)
        opt_d.step()
        sched_d.step()
        with autocast:
            losses = model.generator_losses(batch, out, target, x0_hat, t, adversarial=True)
            total = model.total_loss(losses)
        opt_g.zero_grad(set_to_none=True)
        total.backward()
        torch.nn.utils.clip_grad_norm_(model.denoiser.parameters(), h.grad_clip)
        opt_g.step()
        sched_g.step()
        model.ema.update_parameters(model.denoiser)
    return time.perf_counter() - start


def bench_train(
    out: str, config: str = "conf/xia_cpu.yaml", batches: int = 30, warmup: int = 5, repeats: int = 3
):
    """Training windows/s of a config under Lightning, and the same step in a plain PyTorch loop."""
    _, dm = _config_model_and_data(config)
    batch_size = dm.hparams.batch_size
    lightning_s, lightning_cpu_s, plain_s = [], [], []
    # interleaved, so both see the same machine load
    for _ in progress(range(repeats), desc="bench train", unit="repeat"):
        wall, cpu = _lightning_seconds(config, batches, warmup)
        lightning_s.append(wall)
        lightning_cpu_s.append(cpu)
        plain_s.append(_plain_seconds(config, batches, warmup))
    lightning_rate = batches * batch_size / statistics.median(lightning_s)
    plain_rate = batches * batch_size / statistics.median(plain_s)
    result = {
        "benchmark": "train",
        "config": config,
        "batch_size": batch_size,
        "window": dm.hparams.window,
        "precision": _config_precision(config),
        "batches_timed": batches,
        "repeats": repeats,
        "lightning_s": [round(x, 3) for x in lightning_s],
        "plain_s": [round(x, 3) for x in plain_s],
        "lightning_windows_per_s_median": round(lightning_rate, 1),
        "plain_windows_per_s_median": round(plain_rate, 1),
        "lightning_over_plain_ratio": round(lightning_rate / plain_rate, 3),
        "seconds_per_batch_median": round(statistics.median(lightning_s) / batches, 3),
        # CPU seconds of all torch threads: on a busy machine near what the batches would take on a
        # quiet one with one thread, where wall time grows with the load.
        "cpu_seconds_per_batch_median": round(statistics.median(lightning_cpu_s) / batches, 3),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "machine": machine(),
    }
    report(out, result)
    return result


# The quality bar of the training issue, as ratios to real data scored the same way: style recognised
# at least 90% as often as in real held-out windows, FMD at most twice the train-vs-held-out floor, foot
# skating at most 1.2 times real held-out windows'.
BAR = {"style_acc": ("min", 0.9), "fmd": ("max", 2.0), "skate_ratio": ("max", 1.2)}


class _TimeToBar:
    """A Lightning callback timing a run (wall time since training started, and the training epochs'
    batch loops alone) that rewrites the time-to-bar report after every MotionMetrics measurement, so an
    interrupted run still says how far it got."""

    def __init__(self, out: str, config: str, evaluator: str | None, repeats: int, fit_args: list[str]):
        import lightning as L

        self.out, self.config, self.evaluator, self.repeats = out, config, evaluator, repeats
        self.fit_args = fit_args
        self.started = self.epoch_started = None
        self.loop_s = 0.0
        self.at_validation: dict[int, dict] = {}  # epoch -> times when its validation (and metrics) ended
        self.real: dict[str, float] | None = None
        self.load_before = os.getloadavg()
        bench = self

        class Callback(L.Callback):
            def setup(cb, trainer, pl_module, stage):
                if bench.evaluator is not None:
                    _metrics_callback(trainer).evaluator_ckpt = bench.evaluator

            def on_train_start(cb, trainer, pl_module):
                bench.started = time.perf_counter()

            def on_train_epoch_start(cb, trainer, pl_module):
                bench.epoch_started = time.perf_counter()

            def on_validation_start(cb, trainer, pl_module):
                bench.end_of_batches()

            def on_validation_end(cb, trainer, pl_module):
                if trainer.sanity_checking:
                    return
                bench.at_validation[trainer.current_epoch + 1] = bench.times()
                metrics = _metrics_callback(trainer)
                if metrics.history and metrics.history[-1]["epoch"] == trainer.current_epoch + 1:
                    bench.report(trainer, finished=False)

            def on_train_epoch_end(cb, trainer, pl_module):
                bench.end_of_batches()

        self.callback = Callback()

    def end_of_batches(self) -> None:
        if self.epoch_started is not None:
            self.loop_s += time.perf_counter() - self.epoch_started
            self.epoch_started = None

    def times(self) -> dict:
        return {"wall_s": time.perf_counter() - self.started, "train_loop_s": self.loop_s}

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
            "epochs": trainer.current_epoch + (0 if finished else 1),
            "max_epochs": trainer.max_epochs,
            "batches": trainer.lightning_module.batches_done,
            "batches_per_epoch": trainer.num_training_batches,
            "metrics": {
                "every_n_epochs": metrics.every_n_epochs,
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
    """Per measurement: epoch, batches, times, each metric against its bar, and whether all three hold."""
    rows, metrics_s = [], 0.0
    for measured in history:
        metrics_s += measured["seconds"]
        clock = times[measured["epoch"]]
        row = {
            "epoch": measured["epoch"],
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
    pick = ("epoch", "batches", "training_s", "train_loop_s", "wall_s")
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
    """Trains CONFIG exactly as `walkdiff fit --config CONFIG` does (bounded by its epochs, with its
    MLflow run and checkpoints) and reads its MotionMetrics measurements against the quality bar.

    The real references are the callback's own numbers for real windows of the test split (as many as
    it generates, `repeats` draws, averaged): held-out windows scored against the same training
    windows, by the same evaluator. Writes OUT (JSON) after every measurement and at the end: per
    measurement the epoch, the batches trained, the training time without the measurements (and the
    batch loops alone), the measurement's own time, each metric against its bar, and the first epoch
    where all three hold.
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
            f"the run made no metrics measurement: MotionMetrics measures every {metrics.every_n_epochs} "
            f"epochs, after a validation (trainer.check_val_every_n_epoch), and it trained "
            f"{trainer.current_epoch} epochs",
            path=config,
        )
    return bench.report(trainer, finished=True)


# ---------------------------------------------------------------- sampling


def bench_distill(
    out: str,
    teacher: str,
    student: str,
    evaluator: str,
    num: int = 256,
    seed: int = 0,
    seeds: int = 3,
    ground: bool = True,
) -> dict:
    """A distilled student's DDIM samples against its teacher's DDPM-100, DDIM and DPM-Solver++.

    Writes OUT (JSON): the teacher's DDPM over all T steps (the reference of `fmd_over_ddpm`), DDIM and
    DPM-Solver++(2M) at each of the student's step counts; the student's DDIM at each of its counts (its
    other samplers are the teacher's, which it carries). Each the mean over `seeds` seeds (the same for
    all), scored on the teacher's real test windows. `bench sample` on the student adds its speed, seams
    and transfer.
    """
    from walkdiff.styled.generation import load_generator

    teacher_model, student_model = load_generator(teacher), load_generator(student)
    record = torch.load(student, map_location="cpu", weights_only=False, mmap=True).get("distilled")
    if record is None:
        raise WalkdiffError("not a distilled checkpoint (made by `walkdiff distill`)", path=student)
    carried, given = student_model.teacher.state_dict(), teacher_model.ema.module.state_dict()
    if carried.keys() != given.keys() or any(not torch.equal(carried[k], v) for k, v in given.items()):
        raise WalkdiffError(
            f"--teacher {teacher}: the student was distilled from another teacher ({record['teacher']}), "
            "whose network it carries; pass that checkpoint",
            path=student,
        )
    counts = student_model.distilled_steps
    bench = _QualityBench(teacher_model, teacher, evaluator, num, seed, seeds, ground)
    ddpm_steps = teacher_model.diffusion.num_timesteps
    settings = [("teacher", teacher_model, "ddpm", ddpm_steps)]
    settings += [("teacher", teacher_model, sampler, k) for k in counts for sampler in ("ddim", "dpmpp")]
    settings += [("student", student_model, "ddim", k) for k in counts]
    rows = []
    for who, model, sampler, k in settings:
        row, first_seed = bench.row(model, sampler, k, 1.0 if sampler == "ddpm" else 0.0)
        rows.append(_with_ratios({"model": who} | row, rows[0] if rows else row))
        if (who, sampler, k) == ("student", "ddim", counts[0]):
            student_windows, student_scores = first_seed
    # --fix-feet on the samples the student is for (first seed), as `bench sample` does on DDPM's.
    fix_feet = {"before": student_scores, "after": bench.scored(_fix_feet(student_model, student_windows))}
    result = {
        "benchmark": "distill",
        "teacher": teacher,
        "student": student,
        "distilled": record,
        "evaluator": evaluator,
        "num": num,
        "seed": seed,
        "seeds": seeds,
        "grounded": ground,
        "quality": rows,
        "student_ddim_fix_feet": fix_feet,
        "machine": machine(),
    }
    report(out, result)
    return result


def _median_seconds(fn, repeats: int) -> float:
    return _interleaved_medians([fn], repeats)[0]


def _interleaved_medians(fns: list, repeats: int) -> list[float]:
    """Median seconds of each of `fns`, run in turn `repeats` times: timings that are to be compared
    share the machine's slow and fast moments."""
    times = [[] for _ in fns]
    for _ in range(repeats):
        for fn, spent in zip(fns, times, strict=True):
            start = time.perf_counter()
            fn()
            spent.append(time.perf_counter() - start)
    return [statistics.median(spent) for spent in times]


def _seam_speeds(model, x: torch.Tensor, overlap: int, blend: int) -> dict:
    """Joint speeds (units/s) at the window seams of long samples against the steps inside windows.

    A seam is every step from a window's last held frame through its cross-fade; `within_spread` is
    `generation.seams_within_spread` (at most 10% of seam steps beyond either end of the inside 5-95%
    band), the criterion the tests hold generation to.
    """
    from walkdiff.styled.generation import (
        joint_speeds,
        seam_steps,
        seam_tails,
        seams_within_spread,
        split_seams,
    )

    speed = joint_speeds(model, x)
    seams = seam_steps(x.shape[1], model.spec["window"], overlap, blend)
    inner, at_seams = split_seams(speed, seams)
    quantiles = inner.quantile(torch.tensor([0.05, 0.5, 0.95], dtype=torch.float64))
    below, above = seam_tails(speed, seams)
    return {
        "seam_mean": round(float(at_seams.mean()), 3),
        "seam_p95": round(float(at_seams.quantile(0.95)), 3),
        "seam_max": round(float(at_seams.max()), 3),
        "inside_mean": round(float(inner.mean()), 3),
        "inside_p05_p50_p95": [round(float(q), 3) for q in quantiles],
        "inside_max": round(float(inner.max()), 3),
        "seams_below_inside_p05": round(below, 4),
        "seams_above_inside_p95": round(above, 4),
        "within_spread": seams_within_spread(speed, seams),
    }


def _transfer_windows(model, dm, strength: float, keep_trajectory: bool, seed: int, ground: bool = True):
    """Every test clip restyled to every other style, cut into windows; plus the root path errors."""
    from walkdiff.evaluation.evaluate import WindowSet
    from walkdiff.motion.representation import decode_root
    from walkdiff.styled.generation import Sampling, restyle

    window, styles = model.spec["window"], len(model.spec["styles"])
    walk = list(model.spec["contents"]).index("walk")
    generator = torch.Generator().manual_seed(seed)
    raws, targets, sources, errors = [], [], [], []
    for info, _, features in dm.split_features("test"):
        if features.shape[0] < window:
            continue
        target = torch.tensor([s for s in range(styles) if s != info.style])
        source = model.normalizer.normalize(torch.from_numpy(features))[None].expand(len(target), -1, -1)
        content = torch.full_like(target, walk)
        x = restyle(model, source, target, content, strength, Sampling(), generator, keep_trajectory)
        raw = torch.from_numpy(model.to_raw(x, ground))
        root_in, root_out = decode_root(torch.from_numpy(features)), decode_root(raw)
        walked = (root_in[1:, [0, 2]] - root_in[:-1, [0, 2]]).norm(dim=-1).sum()
        errors += ((root_out - root_in)[..., [0, 2]].norm(dim=-1).mean(-1) / walked).tolist()
        for start in range(0, raw.shape[1] - window + 1, 4):
            raws.append(raw[:, start : start + window])
            targets.append(target)
            sources.append(torch.full_like(target, info.style))
    raw = torch.cat(raws)
    windows = WindowSet(raw, torch.cat(targets), torch.full((len(raw),), walk), torch.full((len(raw),), -1))
    return windows, torch.cat(sources), errors


def _plot_quality(path: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.5))
    for ax, key, label in (
        (axes[0], "fmd", "FMD (lower is better)"),
        (axes[1], "style_acc", "style accuracy"),
    ):
        for sampler, label_ in (("ddim", "DDIM (eta 0)"), ("dpmpp", "DPM-Solver++(2M)")):
            line = [r for r in rows if r["sampler"] == sampler and r["eta"] == 0]
            ax.plot([r["steps"] for r in line], [r[key] for r in line], "o-", label=label_)
        noisy = [r for r in rows if r["sampler"] == "ddim" and r["eta"] > 0]
        for r, color in zip(noisy, ("C2", "C4", "C5", "C6"), strict=False):
            ax.plot([r["steps"]], [r[key]], "^", color=color, label=f"DDIM (eta {r['eta']})")
        for r in rows:
            if r["sampler"] == "ddpm":
                ax.plot([r["steps"]], [r[key]], "s", color="C3", label="DDPM")
                if key == "fmd":
                    ax.axhline(1.1 * r[key], color="C3", ls=":", lw=1, label="DDPM + 10%")
        ax.set_xscale("log")
        if key == "style_acc":
            ax.set_ylim(0, 1.05)
        ax.set_xlabel("denoising steps")
        ax.set_title(label)
        ax.legend(fontsize=7)
    fig.tight_layout()
    write_atomic(path, lambda f: fig.savefig(f, format="png", dpi=120))
    plt.close(fig)


class _QualityBench:
    """FMD and recognition of generated windows against the real test windows of a generator's data
    (evaluation.py's scorer), each setting from `seeds` seeds (the same seeds for every setting): one
    seed's FMD moves by a few units, as much as some of the differences measured."""

    keys = ("fmd", "style_acc", "content_acc", "diversity", "skate_ratio", "slide_speed", "jitter")

    def __init__(self, model, ckpt: str, evaluator: str, num: int, seed: int, seeds: int, ground: bool):
        from walkdiff.data.datamodule import MotionDataModule, data_settings
        from walkdiff.evaluation.evaluate import MotionScorer, load_evaluator, window_set

        checkpoint = torch.load(ckpt, map_location="cpu", weights_only=False, mmap=True)
        self.datamodule = MotionDataModule(**data_settings(checkpoint))
        spec = model.spec
        self.scorer = MotionScorer(load_evaluator(evaluator), model.skeleton, spec["fps"])
        self.reference = self.scorer.embed(window_set(self.datamodule.split_features("test"), spec["window"]))
        self.scorer.set_reference(self.reference)
        self.content_ids = [list(spec["contents"]).index(name) for name in self.datamodule.selection.names]
        self.num, self.seed, self.seeds, self.ground = num, seed, seeds, ground

    def scored(self, windows) -> dict:
        values = self.scorer.score(self.scorer.embed(windows), seed=self.seed)
        return {k: round(values[k], 4) for k in self.keys}

    def row(self, model, sampler: str, steps: int, eta: float):
        """(the setting's mean scores over the seeds, the first seed's windows and their scores)."""
        from walkdiff.evaluation.evaluate import generate_windows

        runs, elapsed, first = [], 0.0, None
        for s in range(self.seed, self.seed + self.seeds):
            start = time.perf_counter()
            windows = generate_windows(
                model, self.num, self.content_ids, torch.Generator().manual_seed(s), self.num, self.ground,
                sampler=sampler, steps=steps, eta=eta,
            )  # fmt: skip
            elapsed += time.perf_counter() - start
            first = windows if first is None else first
            runs.append(self.scored(windows))
        row = {"sampler": sampler, "steps": steps, "eta": eta}
        row |= {k: round(statistics.mean(r[k] for r in runs), 4) for k in self.keys}
        row |= {"fmd_per_seed": [r["fmd"] for r in runs], "seconds_per_seed": round(elapsed / self.seeds, 2)}
        print(f"{sampler}-{steps} eta {eta}: {row}", flush=True)
        return row, (first, runs[0])


def _fix_feet(model, windows):
    """The windows with `--fix-feet` applied to their raw features."""
    from walkdiff.motion.footfix import fix_feet_features

    raw = fix_feet_features(windows.raw.numpy(), model.profile, model.spec["fps"])
    return replace(windows, raw=torch.from_numpy(raw))


def _with_ratios(row: dict, reference: dict) -> dict:
    return row | {
        "fmd_over_ddpm": round(row["fmd"] / reference["fmd"], 3),
        "style_acc_over_ddpm": round(row["style_acc"] / reference["style_acc"], 3),
    }


def bench_sample(
    out: str,
    ckpt: str,
    evaluator: str,
    num: int = 400,
    seed: int = 0,
    ddim_steps: tuple[int, ...] = (50, 20, 10, 5),
    dpm_steps: tuple[int, ...] = (20, 10, 5),
    seeds: int = 3,
    batch_size: int = 32,
    repeats: int = 3,
    strength: float = 0.6,
    ground: bool = True,
) -> dict:
    """Quality against steps, speed, foot clean-up and transfer of a StyledMotionDiffusion checkpoint.

    Writes OUT/sample.json and OUT/sample.png. Quality: FMD and recognition against the real test
    windows (evaluation.py's scorer) of `num` windows balanced over styles, DDPM over all T steps, DDIM
    over each of `ddim_steps` and DPM-Solver++(2M) over each of `dpm_steps`, averaged over `seeds` seeds
    (the same seeds for every sampler), with each one's ratio to DDPM. A distilled student's DDIM step
    counts (`walkdiff distill`) join the DDIM rows, the speed (frames/s at each) and the seams.
    """
    from walkdiff.diffusion import respace
    from walkdiff.styled.generation import Sampling, generate_long, load_generator, resolve_windows

    model = load_generator(ckpt)
    bench = _QualityBench(model, ckpt, evaluator, num, seed, seeds, ground)
    dm, spec, reference, scored = bench.datamodule, model.spec, bench.reference, bench.scored
    content_ids = bench.content_ids
    # DDPM over all T steps; DDIM at eta 0 over the step counts and at 10 steps with some of DDPM's noise
    # put back (eta > 0); DPM-Solver++(2M) over its steps.
    configs = [("ddpm", model.diffusion.num_timesteps, 1.0)]
    distilled = model.distilled_steps
    ddim_counts = sorted({*ddim_steps, *distilled}, reverse=True)
    configs += [("ddim", k, 0.0) for k in ddim_counts] + [("ddim", 10, eta) for eta in (0.5, 1.0)]
    configs += [("dpmpp", k, 0.0) for k in dpm_steps]
    quality, generated = [], {}
    for config in configs:
        row, generated[config] = bench.row(model, *config)
        quality.append(_with_ratios(row, quality[0] if quality else row))
    real = scored(
        reference.take(torch.randperm(len(reference), generator=torch.Generator().manual_seed(seed))[:num])
    )

    # Foot clean-up on the DDPM windows, scored the same way.
    ddpm, ddpm_scores = generated[configs[0]]
    fix_feet = {"before": ddpm_scores, "after": scored(_fix_feet(model, ddpm))}

    # Speed: batch of windows with DDIM-10, per-step cost against one network pass, batch-1 latency.
    torch.manual_seed(seed)
    style = torch.arange(batch_size) % len(spec["styles"])
    content = torch.full((batch_size,), content_ids[0])
    window, dim = spec["window"], spec["feature_dim"]

    def sample10(sampler: str):
        return lambda: model.generate(style, content, sampler=sampler, steps=10)

    sample10("ddim")()  # warm-up
    # The network as DDIM-10 calls it (a distilled student's with its jumps), at one of its steps.
    net = model.model_fn(style, content, jumps=model.jumps("ddim", 10, 0.0))
    x = torch.randn(batch_size, window, dim)
    t = torch.full((batch_size,), respace(model.diffusion.num_timesteps, 10)[5])

    def ten_forwards():
        with torch.no_grad():  # as generate runs the network
            for _ in range(10):
                net(x, t)

    def student(k: int):
        return lambda: model.generate(style, content, sampler="ddim", steps=k)

    for k in distilled:
        student(k)()  # warm-up
    medians = _interleaved_medians(
        [sample10("ddim"), sample10("dpmpp"), ten_forwards, *(student(k) for k in distilled)], repeats
    )
    batch_s, dpm_s, ten_s = medians[:3]
    forward_s = ten_s / 10
    long_frames = 300
    generate_long(model, style, content, long_frames, Sampling("ddim", 10))  # warm-up
    long_s = _median_seconds(
        lambda: generate_long(model, style, content, long_frames, Sampling("ddim", 10)), 1
    )
    two_seconds = round(2 * spec["fps"])
    latency = {
        name: round(
            _median_seconds(
                lambda s=s: generate_long(model, style[:1], content[:1], two_seconds, s), repeats
            ),
            3,
        )
        for name, s in (
            ("ddim10_s", Sampling("ddim", 10)),
            ("dpmpp10_s", Sampling("dpmpp", 10)),
            ("ddpm_s", Sampling()),
        )
    }
    speed = {
        "batch": batch_size,
        "ddim10_window_frames_per_s": round(batch_size * window / batch_s, 1),
        "dpmpp10_window_frames_per_s": round(batch_size * window / dpm_s, 1),
        "ddim10_long_frames_per_s": round(batch_size * long_frames / long_s, 1),
        **{
            f"student_ddim{k}_window_frames_per_s": round(batch_size * window / k_s, 1)
            for k, k_s in zip(distilled, medians[3:], strict=True)
        },
        "step_s": round(batch_s / 10, 5),
        "dpmpp_step_s": round(dpm_s / 10, 5),
        "forward_s": round(forward_s, 5),
        "step_over_forward": round(batch_s / 10 / forward_s, 3),
        "dpmpp_step_over_forward": round(dpm_s / 10 / forward_s, 3),
        f"batch1_latency_{two_seconds}_frames": latency,
    }
    # Seams of 300-frame samples: the default overlap held only (blend 0), a third of the window with its
    # cross-fade, and the default; DDPM and DDIM-10.
    seams = {}
    for overlap, blend in ((None, 0), (max(1, window // 3), None), (None, None)):
        overlap, blend = resolve_windows(window, overlap, blend)
        samplings = (
            ("ddpm", Sampling()),
            ("ddim10", Sampling("ddim", 10)),
            ("dpmpp10", Sampling("dpmpp", 10)),
            *((f"student_ddim{k}", Sampling("ddim", k)) for k in distilled),
        )
        for name, sampling in samplings:
            x = generate_long(
                model,
                style,
                content,
                long_frames,
                sampling,
                torch.Generator().manual_seed(seed),
                overlap,
                blend,
            )
            seams[f"{name}_overlap{overlap}_blend{blend}"] = _seam_speeds(model, x, overlap, blend)

    # Transfer: every walking test clip to every other style, noised to `strength`, DDPM from there.
    transfer = {"strength": strength, "real_test_style_acc": real["style_acc"]}
    for keep in (False, True):
        windows, source_style, errors = _transfer_windows(model, dm, strength, keep, seed, ground)
        values = scored(windows)
        embedded = bench.scorer.embed(windows)
        transfer["keep_trajectory" if keep else "free"] = {
            "windows": len(windows),
            "target_style_acc": values["style_acc"],
            "target_over_real": round(values["style_acc"] / real["style_acc"], 3),
            "still_source_style": round(
                float((embedded.style_logits.argmax(-1) == source_style).float().mean()), 4
            ),
            "content_acc_walk": values["content_acc"],
            "root_path_error_relative_mean": statistics.mean(errors),
            "root_path_error_relative_max": max(errors),
            "fmd": values["fmd"],
        }

    result = {
        "benchmark": "sample",
        "ckpt": ckpt,
        "evaluator": evaluator,
        "num": num,
        "seed": seed,
        "grounded": ground,
        "seeds": seeds,
        "quality": quality,
        "real_test": real,
        "fix_feet": fix_feet,
        "speed": speed,
        "seams_300_frames": seams,
        "transfer": transfer,
        "machine": machine(),
    }
    out_dir = Path(out)
    report(out_dir / "sample.json", result)
    _plot_quality(out_dir / "sample.png", quality)
    return result


def _gesture_model(ckpt: str | None):
    """The DiffMotion checkpoint, or an untrained one of the ZEGGS config's size (N = 100).

    Speed depends on the architecture and the sampler only, so untrained weights time as trained ones.
    """
    from walkdiff.models.diffmotion import DiffMotion

    if ckpt is not None:
        from walkdiff.autoregressive.gesture import load_model

        return load_model(ckpt).eval()
    spec = dict(
        dataset="zeggs", feature_dim=45, num_joints=15, window=120, fps=20.0,
        joints=tuple(map(str, range(15))), rotation="expmap", audio_dim=27, past=10, lookahead=20,
    )  # fmt: skip
    return DiffMotion(spec).eval()


def bench_gesture(
    out: str,
    ckpt: str | None = None,
    frames: int = 40,
    repeats: int = 5,
    sampler: str = "ddim",
    steps: int | None = 10,
    eta: float = 1.0,
    streams: tuple[int, ...] = (16, 64, 128),
) -> dict:
    """DiffMotion generation speed: seconds per frame of one stream with DDPM over all N steps and with
    the few-step `sampler`, each plain (the eps module and `run_steps`) and fused (`FusedEps`); frames per
    second of `streams` streams batched (few-step, fused) and which of them keep up with the model's fps.

    Timings that are compared are interleaved rounds, `repeats` of them, reported as medians.
    """
    from walkdiff.diffusion import SamplerChoice

    few = SamplerChoice(sampler, steps, eta)
    model = _gesture_model(ckpt)
    fps, n = model.spec["fps"], model.diffusion.num_timesteps
    audio = torch.randn(frames, model.spec["audio_dim"])
    settings = {
        f"{label}_{kind}": (choice, kind == "fused")
        for choice, label in (
            (SamplerChoice(), f"ddpm{n}"),
            (few, few.label(model.diffusion).replace("-", "")),
        )
        for kind in ("plain", "fused")
    }
    result = {
        "benchmark": "gesture",
        "checkpoint": ckpt,
        "frames_timed": frames,
        "repeats": repeats,
        "fps": fps,
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
    }
    batch_rounds = max(1, repeats // 2)
    bar = progress(
        total=len(settings) * repeats + len(streams) * batch_rounds, desc="bench gesture", unit="run"
    )

    def counted(fn):  # a timed run that then advances the bar (microseconds, inside the timing)
        return lambda: (fn(), bar.update(1))

    with bar:
        for choice, fused in settings.values():  # warm-up
            model.generate(audio[:3], sampler=choice, fused=fused)
        runs = [
            counted(lambda choice=choice, fused=fused: model.generate(audio, sampler=choice, fused=fused))
            for choice, fused in settings.values()
        ]
        one = _interleaved_medians(runs, repeats)
        result["seconds_per_frame_1_stream"] = {name: round(t / frames, 5) for name, t in zip(settings, one)}
        result["lstm_step_ms"] = _lstm_step_ms(model, repeats)
        batched = _interleaved_medians(
            [counted(lambda s=s: model.generate(audio, streams=s, sampler=few)) for s in streams],
            batch_rounds,
        )
    result["sampler_batched"] = few.label(model.diffusion)
    result["frames_per_second_batched"] = {str(s): round(s * frames / t, 1) for s, t in zip(streams, batched)}
    realtime = [s for s, t in zip(streams, batched) if t / frames <= 1 / fps]
    result["realtime_streams"] = max(realtime, default=0)  # the most measured streams that keep up
    result["realtime_streams_estimate"] = int(max(s * frames / t for s, t in zip(streams, batched)) // fps)
    result["target"] = {"seconds_per_frame_1_stream": 0.005, "realtime_streams": 64}
    result["machine"] = machine()
    report(out, result)
    return result


# ---------------------------------------------------------------- streaming


def _percentiles(values: list[float]) -> dict:
    values = np.asarray(values) * 1000
    return {
        "median_ms": round(float(np.median(values)), 1),
        "p95_ms": round(float(np.percentile(values, 95)), 1),
    }


def _stream_walker(ckpt: str | None, speed: float):
    """A PathWalker: the checkpoint, or untrained of conf/walk_xia.yaml's size on a Xia-sized body.

    Untrained weights sample poses at random, and a root that jumps anywhere outruns a path drawn at
    walking pace; its normaliser is set to walk straight on at `speed` (units/s) whatever it samples,
    so it waits for the path as a trained walker does (speed does not depend on the weights).
    """
    from walkdiff.models.path_walker import PathWalker

    if ckpt is not None:
        from walkdiff.autoregressive.walk import load_walker

        return load_walker(ckpt)
    spec = dict(
        dataset="xia", feature_dim=8 + 6 * 31, num_joints=31, window=24, fps=30.0,
        styles=tuple(f"style{i}" for i in range(8)), contents=("walk",),
    )  # fmt: skip
    walker = PathWalker(spec).eval()
    layout, normalizer = walker.layout, walker.normalizer
    for part in (layout.root_vel, layout.heading_vel):
        normalizer.std[part] = 1e-4
    normalizer.mean[layout.root_vel] = torch.tensor([0.0, speed / spec["fps"]])  # forward is +z
    walker.style_speed.fill_(speed)
    return walker


def _realtime_latency(push, arrivals: list[float], frame_times) -> tuple[list[float], list[float], float]:
    """Push inputs at their arrival times (s after now, real-time pace): per frame made, the wall time
    from the arrival of the input that completed it, and from its own moment (`frame_times(t)` s in);
    and the CPU seconds of this process per frame (on a busy machine, what a free core would take)."""
    latency, since_moment, made = [], [], 0
    start, cpu = time.perf_counter(), time.process_time()
    for i, arrival in enumerate(arrivals):
        wait = start + arrival - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        count = push(i)
        done = time.perf_counter()
        for t in range(made, made + count):
            latency.append(done - (start + arrival))
            since_moment.append(done - (start + frame_times(t)))
        made += count
    return latency, since_moment, (time.process_time() - cpu) / max(made, 1)


def _most_streams(make_batch, fps: float, frames: int, most: int, desc: str) -> tuple[int, dict]:
    """Streams batched in lockstep, doubled (then bisected) until a frame of all of them takes longer than
    1 / fps: the most that keep real time, and the seconds per frame measured at each count."""
    timed: dict[int, float] = {}
    cpu: dict[int, float] = {}

    def seconds_per_frame(n: int) -> float:
        step = make_batch(n)
        step()  # warm-up
        started = time.process_time()
        timed[n] = _median_seconds(step, frames)
        cpu[n] = (time.process_time() - started) / frames
        return timed[n]

    good, bad, n = 0, None, 1
    with progress(desc=desc, unit="count") as bar:
        while n <= most:
            bar.update(1)
            if seconds_per_frame(n) > 1 / fps:
                bad = n
                break
            good, n = n, 2 * n
        while bad is not None and bad - good > max(1, good // 8):  # to within an eighth
            bar.update(1)
            middle = (good + bad) // 2
            good, bad = (middle, bad) if seconds_per_frame(middle) <= 1 / fps else (good, middle)
    return good, {
        "seconds_per_frame_by_streams": {str(k): round(v, 4) for k, v in sorted(timed.items())},
        "cpu_seconds_per_frame_by_streams": {str(k): round(v, 4) for k, v in sorted(cpu.items())},
    }


def _sustained(make_batch, fps: float, frames: int, most: int, threads: tuple[int, ...]) -> dict:
    """`_most_streams` at each torch thread count, and the best of them."""
    rows = {}
    for count in threads:
        torch.set_num_threads(count)
        good, timed = _most_streams(
            make_batch, fps, frames, most, f"bench stream: streams, {count} thread(s)"
        )
        rows[str(count)] = {"realtime_streams": good, **timed}
    best = max(rows, key=lambda k: rows[k]["realtime_streams"])
    return {"realtime_streams": rows[best]["realtime_streams"], "best_threads": int(best), "by_threads": rows}


def bench_stream(
    out: str,
    ckpt: str | None = None,
    walker: str | None = None,
    seconds: float = 6.0,
    chunk_ms: float = 20.0,
    rate: int = 16000,
    frames: int = 6,
    most: int = 256,
    seed: int = 0,
    threads: tuple[int, ...] = (1, 2),
    sampler: str = "ddpm",
    steps: int | None = None,
    eta: float = 0.0,
) -> dict:
    """Streaming: latency from audio in to pose out with audio arriving in real time, the streams kept
    in real time batched; the same for the path walker (a path drawn while walking). Latency is timed
    with one torch thread (as fast as two for one stream on a quiet machine, far faster on a busy one);
    the streams kept in real time at each of `threads`."""
    before = torch.get_num_threads()
    try:
        from walkdiff.diffusion import SamplerChoice

        choice = SamplerChoice(sampler, steps, eta)
        return _bench_stream(out, ckpt, walker, seconds, chunk_ms, rate, frames, most, seed, threads, choice)
    finally:
        torch.set_num_threads(before)


def _bench_stream(out, ckpt, walker, seconds, chunk_ms, rate, frames, most, seed, threads, sampler) -> dict:
    torch.set_num_threads(1)
    from walkdiff.autoregressive.streaming import GestureBatch, GestureStream, WalkBatch, WalkStream

    model = _gesture_model(ckpt).eval()  # the checkpoint, or ZEGGS-sized untrained
    rate = model.spec.get("sample_rate") or rate
    fps, rng = model.spec["fps"], np.random.default_rng(seed)
    audio = rng.normal(0, 0.1, round(seconds * rate)).astype(np.float32)
    chunk = max(1, round(chunk_ms / 1000 * rate))
    GestureStream(model, rate, seed, sampler=sampler).push(audio[:rate])  # warm-up
    stream = GestureStream(model, rate, seed, sampler=sampler)
    pieces = [audio[i : i + chunk] for i in range(0, len(audio), chunk)]
    arrivals = [min((i + 1) * chunk, len(audio)) / rate for i in range(len(pieces))]
    latency, since_moment, cpu_per_frame = _realtime_latency(
        lambda i: len(stream.push(pieces[i])), arrivals, lambda t: t / fps
    )
    lookahead_ms = 1000 * stream.features.needed(model.spec["lookahead"]) / rate
    if not latency:
        raise WalkdiffError(
            f"--seconds {seconds:g}: no pose before the audio ended; give more than the "
            f"model's look-ahead of {lookahead_ms / 1000:g} s"
        )

    hop, first = stream.features.hop, (model.spec["lookahead"] + 1) * stream.features.hop
    steady = rng.normal(0, 0.1, first + (frames + 2) * hop).astype(np.float32)

    def gesture_batch(n: int):
        batch = GestureBatch(model, seed, sampler)
        streams = [GestureStream(model, rate, batch=batch) for _ in range(n)]
        for s in streams:  # audio up to the first frame's look-ahead: then each hop makes a frame
            s.feed(steady[:first])
        at = [first]

        def step():
            for s in streams:
                s.feed(steady[at[0] : at[0] + hop])
            at[0] += hop
            if batch.step() != n:
                raise RuntimeError("a stream fell out of lockstep")

        return step

    sustained = _sustained(gesture_batch, fps, frames, most, threads)
    torch.set_num_threads(1)
    result = {
        "benchmark": "stream", "checkpoint": ckpt, "seed": seed,
        "gesture": {
            "sampler": sampler.label(model.diffusion), "fps": fps, "rate": rate, "chunk_ms": chunk_ms,
            "audio_seconds": seconds,
            "lookahead_ms": round(lookahead_ms, 1),
            "latency_chunk_to_pose": _percentiles(latency),
            "latency_audio_to_pose": _percentiles(since_moment),
            "target_audio_to_pose_ms": round(lookahead_ms + 50, 1),
            "latency_threads": 1, "latency_cpu_ms_per_frame": round(1000 * cpu_per_frame, 1), **sustained,
        },
    }  # fmt: skip

    walk = _stream_walker(walker, 12.0)  # Xia units/s: ~0.7 m/s
    wfps, speed = walk.spec["fps"], float(walk.style_speed.max())
    step = speed / wfps  # one path point per frame time, as far as the walker goes in it
    u = np.arange(round(seconds * wfps) + 200) * step
    points = np.stack([3 * speed * np.sin(u / (4 * speed)), u], axis=-1)  # a gentle S, drawn as walked
    walking = WalkStream(walk, 0, speed, seed, sampler=sampler)
    lead = int(np.ceil((walking.reach + walking.pace[0, -1]) / step)) + 2  # the path ahead it needs first
    WalkStream(walk, 0, speed, seed, sampler=sampler).push(points[: lead + 10])  # warm-up
    walking.push(points[:lead])  # the frames the lead allows at once, untimed: then a frame per point
    arrivals = [i / wfps for i in range(round(seconds * wfps))]
    w_latency, _, w_cpu_per_frame = _realtime_latency(
        lambda i: len(walking.push(points[lead + i : lead + i + 1])), arrivals, lambda t: t / wfps
    )

    def walk_batch(n: int):
        batch = WalkBatch(walk, seed, sampler)
        walkers = [WalkStream(walk, k % len(walk.spec["styles"]), speed, batch=batch) for k in range(n)]
        for w in walkers:
            w.feed(points)  # far ahead of them: every frame is ready

        def step():
            if batch.step() != n:
                raise RuntimeError("a walker fell out of lockstep")

        return step

    w_sustained = _sustained(walk_batch, wfps, frames, most, threads)
    result["walk"] = {
        "checkpoint": walker, "fps": wfps, "speed_units_s": speed, "path_lead_points": lead,
        "latency_point_to_pose": _percentiles(w_latency), "frames_measured": len(w_latency),
        "latency_threads": 1, "latency_cpu_ms_per_frame": round(1000 * w_cpu_per_frame, 1), **w_sustained,
    }  # fmt: skip
    result["machine"] = machine()
    report(out, result)
    return result


def _lstm_step_ms(model, repeats: int) -> dict:
    """Milliseconds of one encoder step of one stream: nn.LSTM against the addmm form generation uses."""
    encoder = model.encoder
    x = torch.randn(1, 1, encoder.lstm.input_size)
    rounds = 50
    with torch.inference_mode():
        state = encoder.step(x[:, 0], None)[1]

        def lstm() -> None:
            for _ in range(rounds):
                encoder.lstm(x, state)

        def addmm() -> None:
            for _ in range(rounds):
                encoder.step(x[:, 0], state)

        lstm(), addmm()
        times = _interleaved_medians([lstm, addmm], repeats)
    return {"nn_lstm": round(1e3 * times[0] / rounds, 4), "addmm": round(1e3 * times[1] / rounds, 4)}


def _strengths(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if not values or not all(0 < v <= 1 for v in values):
        raise WalkdiffError(f"--strengths: expected comma-separated numbers in (0, 1], got {text!r}")
    return values


def _thread_counts(text: str) -> tuple[int, ...]:
    return _frame_counts(text, "--threads")


def _frame_counts(text: str, option: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        values = ()
    if not values or min(values) < 1:
        raise WalkdiffError(f"{option}: expected comma-separated whole numbers >= 1, got {text!r}")
    return values


def run(args) -> None:
    if args.what == "protocol":
        from walkdiff.evaluation.protocol import bench_protocol

        bench_protocol(
            args.out, args.ckpt, args.evaluator, args.student, _strengths(args.strengths), args.samples,
            args.bootstrap, args.seed,
        )  # fmt: skip
        print(f"wrote {args.out}/protocol.json and protocol.md")
    elif args.what == "data":
        bench_data(args.out, args.dataset, args.root)
    elif args.what == "train":
        if args.to_bar:
            bench_time_to_bar(args.out, args.config, args.evaluator, args.repeats, args.fit_args)
        elif args.fit_args:
            raise WalkdiffError(
                f"bench train takes fit options only with --to-bar: {' '.join(args.fit_args)}"
            )
        else:
            bench_train(args.out, args.config, args.batches)
    elif args.what == "sample":
        bench_sample(
            args.out, args.ckpt, args.evaluator, num=args.num, seed=args.seed, seeds=args.seeds,
            strength=args.strength, ground=args.ground,
        )  # fmt: skip
    elif args.what == "distill":
        bench_distill(
            args.out, args.teacher, args.student, args.evaluator, num=args.num, seed=args.seed,
            seeds=args.seeds, ground=args.ground,
        )  # fmt: skip
    elif args.what == "gesture":
        bench_gesture(
            args.out, args.ckpt, args.frames, args.repeats, args.sampler, args.steps, args.eta,
            _frame_counts(args.streams, "--streams"),
        )  # fmt: skip
    elif args.what == "stream":
        bench_stream(
            args.out,
            args.ckpt,
            args.walker,
            args.seconds,
            args.chunk_ms,
            args.rate,
            args.frames,
            args.most,
            threads=_thread_counts(args.threads),
            sampler=args.sampler,
            steps=args.steps,
            eta=args.eta,
        )
    elif args.what == "memory":
        bench_memory(
            args.out, args.ckpt, _frame_counts(args.frames, "--frames"), args.walker, args.gesture,
            args.audio, _frame_counts(args.seconds, "--seconds"),
        )  # fmt: skip
    elif args.what == "view":
        bench_view(args.out, args.files, args.repeats)
    elif args.what == "walk":
        from walkdiff.autoregressive.walk import bench_walk

        print(json.dumps(strict_json(bench_walk(args.out, args.ckpt, args.evaluator, args.seed)), indent=2))


# ---------------------------------------------------------------- memory


# Runs a walkdiff command and, as it exits, writes the peak resident memory of its own address space
# (VmHWM). The rusage of a child is no measure: Linux carries the high-water mark of the process that
# forked it across exec, so a child of a big process (a test session) reports at least that one's size.
_PEAK_WRAPPER = """\
import atexit, sys
from pathlib import Path
report = Path(sys.argv.pop(1))
def write_peak():
    status = Path("/proc/self/status").read_text().splitlines()
    report.write_text(next(line.split()[1] for line in status if line.startswith("VmHWM:")))
atexit.register(write_peak)
from walkdiff.cli.main import main
sys.argv[0] = "walkdiff"
sys.exit(main(sys.argv[1:]))
"""


def peak_rss(args: list[str], env: dict | None = None) -> tuple[int, float, float]:
    """Run `walkdiff ARGS` in a subprocess: (its exit code, its peak resident memory in bytes, seconds)."""
    import subprocess

    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "peak"
        child = subprocess.run(
            [sys.executable, "-c", _PEAK_WRAPPER, str(report), *args],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        )  # fmt: skip
        if child.returncode != 0 or not report.exists():
            raise WalkdiffError(
                f"benchmark run failed ({child.returncode}): walkdiff {' '.join(args)}\n"
                + child.stderr.decode()[-2000:]
            )
        peak = int(report.read_text()) * 1024  # kB
    return child.returncode, peak, time.perf_counter() - started


def bench_memory(
    out: str,
    ckpt: str,
    frames: tuple[int, ...] = (300, 10_000, 100_000),
    walker: str | None = None,
    gesture: str | None = None,
    audio: str | None = None,
    seconds: tuple[int, ...] = (10, 120),
) -> dict:
    """Peak memory of `walkdiff sample --frames N --num 1` (GIF included) for each N, each in its own
    process, beside the estimate `walkdiff.common.memory` refuses frame counts by; with `walker`, of `walkdiff
    walk` along straight paths of each of `seconds`; with `gesture` and `audio`, of `walkdiff gesture`
    on the WAV repeated to each of `seconds`.

    The windows are denoised with DDIM over one step: memory does not depend on the sampler or its steps
    (one window is denoised at a time), and 100,000 frames of DDPM would take hours.
    """

    from walkdiff.common.memory import SAMPLE_BYTES_PER_FRAME, check_frames, memory_limit
    from walkdiff.styled.generation import load_generator

    style = load_generator(ckpt).spec["styles"][0]
    env = os.environ | {"WALKDIFF_PROGRESS": "0"}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        extra = {}
        if walker is not None:
            extra["walk"] = [_walk_memory(walker, s, Path(tmp), env) for s in seconds]
        if gesture is not None:
            if audio is None:
                raise WalkdiffError("bench memory: --gesture needs --audio (a speech WAV to repeat)")
            extra["gesture"] = [_gesture_memory(gesture, audio, s, Path(tmp), env) for s in seconds]
        for n in progress(frames, desc="bench memory", unit="run"):
            estimate = check_frames("--frames", n, SAMPLE_BYTES_PER_FRAME)
            command = [
                "sample", "--ckpt", str(ckpt), "--out", f"{tmp}/{n}",
                "--style", style, "--num", "1", "--frames", str(n), "--sampler", "ddim", "--steps", "1",
            ]  # fmt: skip
            _, peak, seconds = peak_rss(command, env)
            manifest = json.loads((Path(tmp) / str(n) / "manifest.json").read_text())
            gif = next((Path(tmp) / str(n)).glob("*.gif"))
            rows.append(
                {
                    "command": f"walkdiff sample --frames {n} --num 1 --sampler ddim --steps 1",
                    "frames": n,
                    "peak_rss_mb": round(peak / 1e6, 1),
                    "estimate_mb": round(estimate / 1e6, 1),
                    "seconds": round(seconds, 1),
                    "gif_mb": round(gif.stat().st_size / 1e6, 2),
                    "preview": manifest["preview"]["note"],
                }
            )
    result = {
        "benchmark": "memory",
        "ckpt": ckpt,
        "limit_mb": round(memory_limit() / 1e6),
        "sample": rows,
        **extra,
        "machine": machine(),
    }
    report(out, result)
    return result


def _walk_memory(ckpt: str, seconds: int, tmp: Path, env: dict) -> dict:
    """Peak memory of `walkdiff walk` along a straight path walked in `seconds` at 1.2 m/s."""
    from walkdiff.autoregressive.walk import load_walker
    from walkdiff.common.memory import WALK_BYTES_PER_FRAME, check_frames

    model = load_walker(ckpt)
    path = tmp / f"straight_{seconds}s.json"
    write_json(path, {"points": [[0, 0], [0, 1.2 * seconds]], "speed": 1.2})
    frames = round(seconds * model.spec["fps"]) + 1
    style = model.spec["styles"][0]
    command = [
        "walk",
        "--ckpt",
        ckpt,
        "--style",
        style,
        "--path",
        str(path),
        "--out",
        str(tmp / path.stem),
    ]
    _, peak, spent = peak_rss(command, env)
    return {
        "command": f"walkdiff walk --path <straight, {seconds} s at 1.2 m/s>",
        "frames": frames,
        "peak_rss_mb": round(peak / 1e6, 1),
        "estimate_mb": round(check_frames("--path", frames, WALK_BYTES_PER_FRAME) / 1e6, 1),
        "seconds": round(spent, 1),
    }


def _gesture_memory(ckpt: str, audio: str, seconds: int, tmp: Path, env: dict) -> dict:
    """Peak memory of `walkdiff gesture` on `audio` repeated (or cut) to `seconds`."""
    import soundfile

    from walkdiff.autoregressive.gesture import load_model
    from walkdiff.common.memory import GESTURE_BYTES_PER_FRAME, check_frames
    from walkdiff.data.speech import read_wav

    samples, rate = read_wav(audio)
    long = np.resize(samples, seconds * rate)  # repeated end to end
    wav = tmp / f"speech_{seconds}s.wav"
    soundfile.write(str(wav), long, rate)
    fps = load_model(ckpt).spec["fps"]
    command = ["gesture", "--ckpt", ckpt, "--audio", str(wav), "--out", str(tmp / wav.stem)]
    _, peak, spent = peak_rss(command, env)
    return {
        "command": f"walkdiff gesture --audio <{seconds} s of speech>",
        "frames": round(seconds * fps),
        "peak_rss_mb": round(peak / 1e6, 1),
        "estimate_mb": round(check_frames("--audio", round(seconds * fps), GESTURE_BYTES_PER_FRAME) / 1e6, 1),
        "seconds": round(spent, 1),
    }


# ---------------------------------------------------------------- view


def _default_view_files() -> list[str]:
    from walkdiff.common.paths import dataset_dir

    files = sorted(dataset_dir("xia").glob("*.bvh"))[:2]
    if len(files) < 2:
        raise WalkdiffError(f"bench view: expected two BVH files in {dataset_dir('xia')}, found {len(files)}")
    return [str(f) for f in files]


@contextlib.contextmanager
def _serving_view(files: list[str]):
    """`walkdiff view FILES --port 0` running: (its address, seconds it took to serve)."""
    import re
    import subprocess
    import threading

    started = time.perf_counter()
    server = subprocess.Popen(
        [sys.executable, "-m", "walkdiff.cli", "view", *files, "--port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env=os.environ | {"WALKDIFF_PROGRESS": "0"},
    )  # fmt: skip
    drain = threading.Thread(target=server.stdout.read, daemon=True)  # never block its prints
    try:
        said = []
        for line in server.stdout:
            said.append(line)
            address = re.search(r"walkdiff view: (http://\S+)", line)
            if address:
                drain.start()
                yield address[1], time.perf_counter() - started
                break
        else:
            server.wait()
            raise WalkdiffError(
                f"bench view: `walkdiff view` ended without serving: {''.join(said)[-500:].strip()}"
            )
    finally:
        server.terminate()
        server.wait(timeout=30)
        if drain.is_alive():
            drain.join(timeout=10)
        server.stdout.close()


def _drawn(page) -> tuple[int, int] | None:
    """The left and right limb pixels of a screenshot of the page, once the skeletons are drawn."""
    from walkdiff.preview.view import limb_pixels, skeletons_shown

    pixels = limb_pixels(page.screenshot())
    return pixels if skeletons_shown(*pixels) else None


def bench_view(out: str, files: list[str] | None = None, repeats: int = 5, timeout: float = 60.0) -> dict:
    """Seconds from launching headless Chromium at a `walkdiff view` page until the skeletons are drawn
    (both sides' limb colours in a screenshot, as tests/test_view.py counts them), each repeat in a fresh
    browser with an empty cache, with the steps on the way; and how long `walkdiff view` took to serve."""
    from walkdiff.preview.browser import Browser, chromium_version
    from walkdiff.preview.view import WINDOW

    files = list(files) if files else _default_view_files()
    for file in files:
        if not Path(file).is_file():
            raise WalkdiffError(f"bench view: {file}: no such BVH file", path=file)
    # Where the time goes: the page's script has mounted the 3-D canvas; the page has connected to the
    # server and shows the controls it sent (the help text); the skeletons are drawn.
    steps = {
        "canvas": "document.querySelectorAll('canvas').length > 0",
        "connected": "document.body.innerText.includes('walkdiff view:')",
    }
    times: dict[str, list[float]] = {name: [] for name in [*steps, "shown"]}
    shots = []
    with _serving_view(files) as (address, served):
        for _ in progress(range(repeats), desc="bench view", unit="load"):
            with Browser(address, *WINDOW, timeout=timeout) as page:
                for name, expression in steps.items():
                    page.wait_for(expression, every=0.05)
                    times[name].append(time.monotonic() - page.launched)
                pixels = page.wait_until(
                    lambda page=page: _drawn(page), "the skeletons (limb-coloured pixels)", every=0.05
                )
                times["shown"].append(time.monotonic() - page.launched)
                shots.append(pixels)
    result = {
        "benchmark": "view",
        "files": files,
        "repeats": repeats,
        "served_s": round(served, 2),
        "shown_s_median": round(statistics.median(times["shown"]), 2),
        "shown_s_all": [round(s, 2) for s in times["shown"]],
        "canvas_s_median": round(statistics.median(times["canvas"]), 2),
        "connected_s_median": round(statistics.median(times["connected"]), 2),
        "limb_pixels_left_right": shots,
        "target_s": 5.0,
        "window": list(WINDOW),
        "chromium": chromium_version(),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "machine": machine(),
    }
    report(out, result)
    return result
