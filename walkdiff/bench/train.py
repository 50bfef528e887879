"""`walkdiff bench train`: training windows/s of a config under Lightning beside the same step in a plain
PyTorch loop, and with `walkdiff fit` overrides, seconds per batch of the overridden config beside the
config as it is (a recipe's cost against today's, both timed in one run)."""

from __future__ import annotations

import os
import statistics
import time

import torch

from walkdiff.bench.measure import machine, report
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.progress import progress


def overridden(cfg: dict, fit_args: list[str] | None) -> dict:
    """The config with `walkdiff fit` overrides (`--model.x V`, `--data.y=V`) on its model and data
    init_args; trainer options do not change a batch and are left out."""
    import yaml

    cfg = {k: dict(v) if isinstance(v, dict) else v for k, v in cfg.items()}
    args = list(fit_args or [])
    while args:
        option = args.pop(0)
        if not option.startswith("--") or option == "--":
            raise WalkdiffError(f"fit option: expected --section.key VALUE, got {option!r}")
        key, has_value, value = option[2:].partition("=")
        if not has_value:
            if not args:
                raise WalkdiffError(f"fit option {option}: expected a value after it")
            value = args.pop(0)
        section, _, name = key.partition(".")
        if section == "trainer":
            continue
        if section not in ("model", "data") or not name or "." in name:
            raise WalkdiffError(f"fit option {option}: bench train times --model.KEY and --data.KEY options")
        cfg[section] = dict(cfg[section])
        cfg[section]["init_args"] = dict(cfg[section]["init_args"]) | {name: yaml.safe_load(value)}
    return cfg


def _config_model_and_data(config: str, fit_args: list[str] | None = None):
    """The model and data module exactly as `walkdiff fit --config CONFIG [FIT_ARGS]` would build them."""
    from omegaconf import OmegaConf

    from walkdiff.data.datamodule import MotionDataModule
    from walkdiff.models.styled_ddpm import StyledMotionDiffusion

    cfg = overridden(OmegaConf.to_container(OmegaConf.load(config), resolve=True), fit_args)
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


def _lightning_seconds(
    config: str, batches: int, warmup: int, fit_args: list[str] | None = None
) -> tuple[float, float]:
    """(wall seconds, process CPU seconds) of `batches` training batches under Lightning."""
    import lightning as L

    model, dm = _config_model_and_data(config, fit_args)
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


def bench_train_recipe(
    out: str, config: str, fit_args: list[str], batches: int = 30, warmup: int = 5, repeats: int = 3
):
    """Seconds per training batch of the config with `fit_args` beside the config as it is, interleaved
    repeats so that both see the same machine load; the ratio of their medians."""
    if not fit_args:
        raise WalkdiffError("bench train: a recipe to time needs fit options after --")
    times: dict[str, list[float]] = {"config": [], "recipe": []}
    cpu: dict[str, list[float]] = {"config": [], "recipe": []}
    for _ in progress(range(repeats), desc="bench train (config, recipe)", unit="repeat"):
        for name, args in (("config", None), ("recipe", fit_args)):
            wall, process = _lightning_seconds(config, batches, warmup, args)
            times[name].append(wall / batches)
            cpu[name].append(process / batches)
    median = {name: statistics.median(values) for name, values in times.items()}
    result = {
        "benchmark": "train_recipe",
        "config": config,
        "fit_args": list(fit_args),
        "batches_timed": batches,
        "repeats": repeats,
        "seconds_per_batch": {name: [round(x, 4) for x in values] for name, values in times.items()},
        "seconds_per_batch_median": {name: round(value, 4) for name, value in median.items()},
        "cpu_seconds_per_batch_median": {name: round(statistics.median(v), 4) for name, v in cpu.items()},
        "recipe_over_config": round(median["recipe"] / median["config"], 3),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "machine": machine(),
    }
    report(out, result)
    return result
