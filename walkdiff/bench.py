"""`walkdiff bench ...`: measured numbers written to JSON (never asserted by timed unit tests)."""

from __future__ import annotations

import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import torch


def machine() -> dict:
    return {
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "platform": platform.platform(),
    }


def write_json(path: str | Path, result: dict) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(result, indent=2) + "\n")
    os.replace(tmp, path)
    print(json.dumps(result, indent=2))


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
    write_json(out, result)
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


class _BatchClock:
    """Wall time of training batches [skip, skip + count) as Lightning runs them."""

    def __init__(self, skip: int):
        import lightning as L

        class Clock(L.Callback):
            def on_train_batch_start(cb, trainer, pl_module, batch, batch_idx):
                if batch_idx == skip:
                    self.start = time.perf_counter()

            def on_train_batch_end(cb, trainer, pl_module, outputs, batch, batch_idx):
                self.end = time.perf_counter()

        self.callback = Clock()
        self.start = self.end = 0.0


def _lightning_seconds(config: str, batches: int, warmup: int) -> float:
    import lightning as L

    model, dm = _config_model_and_data(config)
    model.hparams.adv_warmup_batches = 0  # time the full step: D + G with the adversarial term
    clock = _BatchClock(warmup)
    trainer = L.Trainer(
        accelerator="cpu", devices=1, precision="32-true", max_epochs=1, limit_train_batches=warmup + batches,
        limit_val_batches=0, logger=False, enable_checkpointing=False, enable_progress_bar=False,
        enable_model_summary=False, callbacks=[clock.callback],
    )  # fmt: skip
    trainer.fit(model, dm)
    return clock.end - clock.start


def _plain_seconds(config: str, batches: int, warmup: int) -> float:
    """The same networks, losses, optimizers, clipping and EMA in a hand-written loop."""
    model, dm = _config_model_and_data(config)
    dm.setup("fit")
    model.normalizer.load_state_dict(dm.normalizer.state_dict())
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
        out, target, x0_hat, t = model.denoise(batch, cond_drop=h.cond_drop)
        d_loss = model.discriminator_loss(batch, x0_hat, t)["d"]
        opt_d.zero_grad(set_to_none=True)
        d_loss.backward()
        torch.nn.utils.clip_grad_norm_(model.discriminator.parameters(), h.grad_clip)
        opt_d.step()
        sched_d.step()
        total = model.total_loss(model.generator_losses(batch, out, target, x0_hat, t, adversarial=True))
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
    lightning_s, plain_s = [], []
    for _ in range(repeats):  # interleaved, so both see the same machine load
        lightning_s.append(_lightning_seconds(config, batches, warmup))
        plain_s.append(_plain_seconds(config, batches, warmup))
    lightning_rate = batches * batch_size / statistics.median(lightning_s)
    plain_rate = batches * batch_size / statistics.median(plain_s)
    result = {
        "benchmark": "train",
        "config": config,
        "batch_size": batch_size,
        "window": dm.hparams.window,
        "batches_timed": batches,
        "repeats": repeats,
        "lightning_s": [round(x, 3) for x in lightning_s],
        "plain_s": [round(x, 3) for x in plain_s],
        "lightning_windows_per_s_median": round(lightning_rate, 1),
        "plain_windows_per_s_median": round(plain_rate, 1),
        "lightning_over_plain_ratio": round(lightning_rate / plain_rate, 3),
        "seconds_per_batch_median": round(statistics.median(lightning_s) / batches, 3),
        "machine": machine(),
    }
    write_json(out, result)
    return result


def run(args) -> None:
    if args.what == "data":
        bench_data(args.out, args.dataset, args.root)
    elif args.what == "train":
        bench_train(args.out, args.config, args.batches)
