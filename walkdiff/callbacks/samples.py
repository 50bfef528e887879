"""Every N epochs: one clip per style from fixed seeds, as BVH, a GIF and a filmstrip, into the MLflow run."""

from __future__ import annotations

import tempfile
from pathlib import Path

import lightning as L
import torch
from PIL import Image

from walkdiff.generation import Sampling, generate_long
from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.representation import decode
from walkdiff.render import render_gif, render_png
from walkdiff.tracking import log_file


class SampleClips(L.Callback):
    """Logs `samples/epoch_NNNN/<style>.bvh`, `samples/epoch_NNNN/styles.gif` and a filmstrip image (a row
    of poses per style) as the run's image `samples/styles` at the epoch's step, so MLflow's image view
    steps through the epochs.

    The same seed every time, so the previews of successive epochs show how each style evolves. Clips
    are `seconds` long (default 4 s: several gait cycles), made window by window as `walkdiff sample`
    makes them; `frames` (one window when neither is given) overrides it.
    """

    def __init__(
        self,
        every_n_epochs: int = 5,
        content: str = "walk",
        frames: int | None = None,
        seconds: float | None = 4.0,
        seed: int = 0,
        sampler: str = "ddpm",
        steps: int | None = None,
    ):
        self.every_n_epochs = every_n_epochs
        self.content = content
        self.frames = frames
        self.seconds = seconds
        self.seed = seed
        self.sampler = sampler
        self.steps = steps

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        epoch = trainer.current_epoch + 1
        if trainer.sanity_checking or epoch % self.every_n_epochs or not trainer.is_global_zero:
            return
        self.write(pl_module, trainer.logger, f"samples/epoch_{epoch:04d}", step=trainer.global_step)

    @torch.no_grad()
    def write(
        self, pl_module, logger, artifact_dir: str, folder: Path | None = None, step: int = 0
    ) -> list[Path]:
        styles = list(pl_module.spec["styles"])
        style_ids = pl_module.label_ids(styles, "style")
        content_ids = pl_module.label_ids([self.content] * len(styles), "content")
        generator = torch.Generator(device=pl_module.device).manual_seed(self.seed)
        fps = pl_module.spec["fps"]
        frames = self.frames or (round(self.seconds * fps) if self.seconds else pl_module.spec["window"])
        sampling = Sampling(self.sampler, self.steps)
        x = generate_long(pl_module, style_ids, content_ids, frames, sampling, generator)
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
            render_gif(gif, positions, skeleton.parents, fps, titles=styles, names=skeleton.names)
            strip = render_png(
                out / "styles.png", positions, skeleton.parents, frames=6, names=skeleton.names,
                titles=styles, size=(300, 300),
            )  # fmt: skip
            files += [gif, strip]
            for path in files:
                log_file(logger, path, artifact_dir)
            if getattr(logger, "run_id", None) is not None:
                with Image.open(strip) as image:
                    logger.experiment.log_image(logger.run_id, image.copy(), key="samples/styles", step=step)
            return files if folder else []
