"""Every N epochs: one clip per style from fixed seeds, as BVH and one GIF, into the MLflow run."""

from __future__ import annotations

import tempfile
from pathlib import Path

import lightning as L
import torch

from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.representation import decode
from walkdiff.render import render_gif
from walkdiff.tracking import log_file


class SampleClips(L.Callback):
    """Logs `samples/epoch_NNNN/<style>.bvh` and `samples/epoch_NNNN/styles.gif`.

    The same seed every time, so the GIFs of successive epochs show how each style evolves.
    """

    def __init__(
        self,
        every_n_epochs: int = 5,
        content: str = "walk",
        frames: int | None = None,
        seed: int = 0,
        sampler: str = "ddpm",
        steps: int | None = None,
    ):
        self.every_n_epochs = every_n_epochs
        self.content = content
        self.frames = frames
        self.seed = seed
        self.sampler = sampler
        self.steps = steps

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        epoch = trainer.current_epoch + 1
        if trainer.sanity_checking or epoch % self.every_n_epochs or not trainer.is_global_zero:
            return
        self.write(pl_module, trainer.logger, f"samples/epoch_{epoch:04d}")

    @torch.no_grad()
    def write(self, pl_module, logger, artifact_dir: str, folder: Path | None = None) -> list[Path]:
        styles = list(pl_module.spec["styles"])
        style_ids = pl_module.label_ids(styles, "style")
        content_ids = pl_module.label_ids([self.content] * len(styles), "content")
        generator = torch.Generator(device=pl_module.device).manual_seed(self.seed)
        x = pl_module.generate(
            style_ids, content_ids, self.frames, sampler=self.sampler, steps=self.steps, generator=generator
        )
        raw = pl_module.to_raw(x)
        skeleton = pl_module.skeleton
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(folder or tmp)
            out.mkdir(parents=True, exist_ok=True)
            files, positions = [], []
            for style, features in zip(styles, raw):
                motion = decode(features, skeleton, 1.0 / pl_module.spec["fps"])
                path = out / f"{style}_{self.content}.bvh"
                write_bvh(path, pl_module.to_file(motion))
                files.append(path)
                positions.append(motion_world_positions(motion))
            gif = out / "styles.gif"
            render_gif(
                gif, positions, skeleton.parents, pl_module.spec["fps"], titles=styles, names=skeleton.names
            )
            files.append(gif)
            for path in files:
                log_file(logger, path, artifact_dir)
            return files if folder else []
