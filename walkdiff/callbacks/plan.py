"""What a training plan costs on this machine: the seconds per batch of a config's model, timed on
random windows of its data's shape, times the batches the config trains (`walkdiff data scan` prints it).

The data is not preprocessed for this: the feature size, labels and skeleton are known from the data
module before preprocessing (`MotionDataModule.spec`, `.profile`), and a batch of random windows costs
the networks, losses and optimizers what a real one does.
"""

from __future__ import annotations

import importlib
import logging
import time
import warnings
from pathlib import Path

from walkdiff.common.progress import duration

HOUR_S = 3600.0


def _config(path: str | Path) -> dict:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(OmegaConf.load(path), resolve=True)


def _class(class_path: str):
    module, name = class_path.rsplit(".", 1)
    return getattr(importlib.import_module(module), name)


class _RandomWindows:
    """`count` batches of random normalised windows with random labels, shaped like the data's."""

    def __init__(self, spec, count: int, batch_size: int, seed: int = 0):
        import torch

        generator = torch.Generator().manual_seed(seed)
        self.items = [
            {
                "features": torch.randn(spec.window, spec.feature_dim, generator=generator),
                "style": int(torch.randint(len(spec.styles), (1,), generator=generator)),
                "content": int(torch.randint(len(spec.contents), (1,), generator=generator)),
                "clip": "random",
            }
            for _ in range(count * batch_size)
        ]

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> dict:
        return self.items[i]


def seconds_per_batch(config: str | Path, batches: int = 3, warmup: int = 1) -> float:
    """Median wall seconds of one training batch of CONFIG's model under Lightning, as `fit` runs it
    (precision, optimizers and losses from the config) on random windows of its data's shape."""
    import lightning as L
    import torch

    cfg = _config(config)
    datamodule = _class(cfg["data"]["class_path"])(**cfg["data"]["init_args"])
    model = _class(cfg["model"]["class_path"])(datamodule.spec, **cfg["model"].get("init_args", {}))
    model.profile = datamodule.profile  # found from one clip: nothing is preprocessed
    if hasattr(model.hparams, "adv_warmup_batches"):
        model.hparams.adv_warmup_batches = 0  # time the whole step: discriminator and adversarial term
    batch_size = cfg["data"]["init_args"].get("batch_size", 64)
    loader = torch.utils.data.DataLoader(
        _RandomWindows(datamodule.spec, warmup + batches, batch_size), batch_size=batch_size
    )
    times: list[float] = []

    class Clock(L.Callback):
        def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
            self.started = time.perf_counter()

        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
            if batch_idx >= warmup:
                times.append(time.perf_counter() - self.started)

    # A timing probe: Lightning's remarks about its loader and the stop it was told to make are noise here.
    quiet = logging.getLogger("lightning.pytorch")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            trainer = L.Trainer(
                accelerator="cpu", devices=1, precision=cfg.get("trainer", {}).get("precision", "32-true"),
                max_steps=warmup + batches, limit_val_batches=0, logger=False, enable_checkpointing=False,
                enable_progress_bar=False, enable_model_summary=False, callbacks=[Clock()],
            )  # fmt: skip
            trainer.fit(model, train_dataloaders=loader)
    finally:
        quiet.setLevel(level)
    return sorted(times)[len(times) // 2]


def plan(configs: list[str | Path], batches: int = 3) -> dict:
    """Per config: the batches it trains (`trainer.max_steps`), the seconds per batch measured here and
    the expected minutes of training (without validation and metrics); and the total."""
    rows = []
    for config in configs:
        steps = int(_config(config)["trainer"]["max_steps"])
        per_batch = seconds_per_batch(config, batches)
        rows.append({"config": str(config), "steps": steps, "s_per_batch": per_batch, "s": steps * per_batch})
    return {"configs": rows, "total_s": sum(r["s"] for r in rows)}


def plan_lines(result: dict) -> list[str]:
    """What `data scan` prints: each config's batches x seconds, the total, and a warning past an hour."""
    lines = ["expected training time on this machine (batches x seconds per batch, timed now):"]
    for row in result["configs"]:
        lines.append(
            f"  {row['config']}: {row['steps']:,} batches x {row['s_per_batch']:.2f} s = {duration(row['s'])}"
        )
    total = result["total_s"]
    lines.append(f"  total: {duration(total)} (validation and metrics add to it)")
    if total > HOUR_S:
        lines.append(
            f"warning: the plan takes more than an hour here ({duration(total)}): a smaller data.window or "
            "batch_size, or fewer trainer.max_steps, shortens it; a busier machine lengthens it"
        )
    return lines
