"""Every N batches trained, previews of what the model makes into the MLflow run: a style grid
(`SampleClips`) for the styled generator, a walk along a fixed path (`WalkSamples`) for the path walker,
a gesture take (`GestureSamples`) for the gesture model.

The style grid has one row per style: a real clip of that style and content from the training data
(the same clip every time) beside a generated one (from the same seed every time), so the previews
compare. It is logged as a still (`render_strobe`, the run's image `samples/styles` at the training
step, so MLflow's image view steps through training) and as a GIF (and MP4) beside the BVH files.
"""

from __future__ import annotations

import logging
import tempfile
import time
from pathlib import Path

import lightning as L
import numpy as np
import torch
from PIL import Image

from walkdiff.callbacks.clock import Due, step_folder
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.tracking import log_file
from walkdiff.gestures.commands import write_clips
from walkdiff.gestures.generator import synthesize
from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.representation import decode
from walkdiff.preview.render import Marks, PreviewCap, render_gif, render_strobe
from walkdiff.styled.generation import Sampling, generate_long

log = logging.getLogger(__name__)

GRID_COLUMNS = 2  # real | generated: two 480 px stills (400 px GIF panels) fit the UI's ~1000 px
STILL_PANEL = (480, 220)
GIF_PANEL = (400, 250)
GIF_FPS = 15  # 16 panels of 4 s stay under the preview pixel budget
GRID_CAP = PreviewCap(seconds=10.0)


def log_image(logger, path: Path, key: str, step: int) -> None:
    """An image into the run's image view at `step` (no-op without an MLflow run)."""
    if getattr(logger, "run_id", None) is not None:
        with Image.open(path) as image:
            logger.experiment.log_image(logger.run_id, image.copy(), key=key, step=step)


def looped(positions: np.ndarray, frames: int) -> np.ndarray:
    """A clip (F, J, 3) repeated to `frames` frames, each repeat moved on by the clip's own horizontal
    travel so the root path continues instead of jumping back."""
    repeats = -(-frames // len(positions))
    travel = positions[-1, 0] - positions[0, 0]
    travel[1] = 0.0
    return np.concatenate([positions + k * travel for k in range(repeats)])[:frames]


def real_references(datamodule, styles: list[str], content: str) -> dict[str, tuple[str, np.ndarray]]:
    """Per style, (clip name, raw features) of the longest clip of that style and content in the training
    split (else the validation split): a fixed reference, the same at every preview."""
    if not hasattr(datamodule, "split_features"):
        return {}
    contents = list(datamodule.spec.contents)
    if content not in contents:
        return {}
    found: dict[str, tuple[str, np.ndarray]] = {}
    for split in ("train", "val"):
        for clip, name, features in sorted(datamodule.split_features(split), key=lambda c: c[1]):
            style = styles[clip.style]
            if clip.content != contents.index(content) or (style in found and split != "train"):
                continue
            if style not in found or len(features) > len(found[style][1]):
                found[style] = (name, features)
    return found


class SampleClips(L.Callback):
    """Every N batches trained, logs `samples/step_NNNNNN/<style>_<content>.bvh`, `styles.gif` (and
    `styles.mp4`) and the still `styles.png`, which is also the run's image `samples/styles` at that step.

    Clips are `seconds` long (default 4 s: several gait cycles), made window by window as `walkdiff
    sample` makes them; `frames` (one window when neither is given) overrides it. With `real` (and a
    data module that has clips of the content) each style's row starts with its real reference clip,
    looped to the generated length where it is shorter (Xia's walks last 1-3 s). `video: true` adds the
    same frames as MP4 (off by default: encoding it costs several times the GIF's drawing).
    """

    def __init__(
        self,
        every_n_steps: int = 1000,
        content: str = "walk",
        frames: int | None = None,
        seconds: float | None = 4.0,
        seed: int = 0,
        sampler: str = "ddpm",
        steps: int | None = None,
        real: bool = True,
        video: bool = False,
    ):
        self.due = Due(every_n_steps)
        self.content = content
        self.video = video
        self.frames = frames
        self.seconds = seconds
        self.seed = seed
        self.sampler = sampler
        self.steps = steps
        self.real = real
        self.references: dict[str, tuple[str, np.ndarray]] | None = None

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        step = self.due(trainer)
        if step is None:
            return
        if self.references is None:
            styles = list(pl_module.spec["styles"])
            datamodule = getattr(trainer, "datamodule", None)
            self.references = real_references(datamodule, styles, self.content) if self.real else {}
        self.write(pl_module, trainer.logger, step_folder("samples", step), step=step)

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
        x = generate_long(
            pl_module, style_ids, content_ids, frames, Sampling(self.sampler, self.steps), generator
        )
        raw = pl_module.to_raw(x)
        skeleton = pl_module.skeleton
        started = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(folder or tmp)
            out.mkdir(parents=True, exist_ok=True)
            files, generated = [], []
            for style, features in zip(styles, raw):
                motion = decode(features, skeleton, 1.0 / fps)
                path = out / f"{style}_{self.content}.bvh"
                write_bvh(path, pl_module.to_file(motion))
                files.append(path)
                generated.append(motion_world_positions(motion))
            positions, titles = self._grid(styles, generated, skeleton, fps)
            columns = GRID_COLUMNS if len(positions) > len(styles) else min(GRID_COLUMNS, len(styles))
            marks = Marks.of(pl_module.profile)
            common = {"names": skeleton.names, "titles": titles, "marks": marks, "columns": columns}
            gif = render_gif(
                out / "styles.gif", positions, skeleton.parents, fps, size=GIF_PANEL, max_fps=GIF_FPS,
                cap=GRID_CAP, video=self.video, **common,
            )  # fmt: skip
            still = render_strobe(
                out / "styles.png", positions, skeleton.parents, fps, size=STILL_PANEL, turn=True, **common
            )
            files += [gif, *([gif.with_suffix(".mp4")] if self.video else []), still]
            log.info(f"style grid preview: {time.perf_counter() - started:.2f} s to decode and draw")
            for path in files:
                log_file(logger, path, artifact_dir)
            log_image(logger, still, "samples/styles", step)
            return files if folder else []

    def _grid(self, styles, generated, skeleton, fps) -> tuple[list[np.ndarray], list[str]]:
        """Panels in rows of styles: real | generated where every style has its reference, else the
        generated clips alone (and a warning naming the styles without one)."""
        references = self.references or {}
        missing = [s for s in styles if s not in references]
        if not references or missing:
            if references:
                log.warning(
                    f"no real {self.content} clip of {', '.join(missing)}: the grid shows generated only"
                )
            return generated, [f"{s} · generated" for s in styles]
        positions, titles = [], []
        for style, clip in zip(styles, generated, strict=True):
            name, features = references[style]
            real = motion_world_positions(decode(features, skeleton, 1.0 / fps))
            note = f"{len(real) / fps:.1f} s" + (", looped" if len(real) < len(clip) else "")
            positions += [looped(real, len(clip)), clip]
            titles += [f"{style} · real {name} ({note})", f"{style} · generated"]
        return positions, titles


# An S bend 4 m long in metres (about 3.5 s at a walking pace): turns both ways and a straight start.
TEST_PATH = ((0.0, 0.0), (0.8, 0.0), (1.6, 0.4), (2.4, 0.0), (3.2, -0.4), (4.0, 0.0))


class WalkSamples(L.Callback):
    """Every N batches trained, the path walker walks a fixed path (`points`, [x, z] in metres) as `style`
    (by default the first style with walks in the training data) at its training pace, and logs
    `samples/step_NNNNNN/<style>_walk.bvh`, its GIF and MP4 with the path drawn on the ground, the still
    `walk.png` (the run's image `samples/walk` at that step) and the top-down plot
    `walk_path.png` (image `samples/walk_path`)."""

    def __init__(
        self,
        every_n_steps: int = 1000,
        points: list[list[float]] | None = None,
        style: str | None = None,
        seed: int = 0,
    ):
        from walkdiff.motion.path import Polyline

        self.due = Due(every_n_steps)
        self.metres = Polyline.of(TEST_PATH if points is None else points)
        self.style = style
        self.seed = seed

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        step = self.due(trainer)
        if step is None:
            return
        self.write(pl_module, trainer.logger, step_folder("samples", step), step=step)

    @torch.no_grad()
    def write(
        self, pl_module, logger, artifact_dir: str, folder: Path | None = None, step: int = 0
    ) -> list[Path]:
        from walkdiff.motion.path import Polyline
        from walkdiff.motion.take import Take
        from walkdiff.walker.follow import path_error, to_motion, walk_paths
        from walkdiff.walker.plots import plot_paths, render_walk

        styles = list(pl_module.spec["styles"])
        walked = [s for s, speed in zip(styles, pl_module.style_speed.tolist(), strict=True) if speed > 0]
        style = self.style or (walked or styles)[0]  # the first style the training data has walks of
        if style not in styles:
            raise WalkdiffError(f"WalkSamples: unknown style {style!r}; valid: {', '.join(styles)}")
        unit = pl_module.profile.metres_per_unit
        path = Polyline.of(self.metres.points / unit)
        raw, start, _ = walk_paths(pl_module, path, [styles.index(style)], None, self.seed)
        motion = to_motion(pl_module, raw[0], start)
        started = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(folder or tmp)
            out.mkdir(parents=True, exist_ok=True)
            bvh = out / f"{style}_walk.bvh"
            take = Take.from_canonical(motion, pl_module.profile)
            write_bvh(bvh, take.motion)
            gif = render_walk(out / f"{style}_walk.gif", take, path, GRID_CAP, title=style)
            skeleton = pl_module.skeleton
            error = path_error(self.metres, motion.root_positions[:, [0, 2]] * unit)
            title = f"{style} · off the path by {error['mean_distance']:.2f} m on average"
            still = render_strobe(
                out / "walk.png", [motion_world_positions(motion)], skeleton.parents, motion.fps,
                names=skeleton.names, titles=[title], marks=Marks.of(pl_module.profile), paths=[path.points],
                size=(960, 420), poses=9,
            )  # fmt: skip
            plot = plot_paths(
                out / "walk_path.png",
                [(style, self.metres, [(style, motion.root_positions[:, [0, 2]] * unit)])],
            )
            files = [bvh, gif, gif.with_suffix(".mp4"), still, plot]
            log.info(f"walk preview: {time.perf_counter() - started:.2f} s to draw")
            for file in files:
                log_file(logger, file, artifact_dir)
            log_image(logger, still, "samples/walk", step)
            log_image(logger, plot, "samples/walk_path", step)
            return files if folder else []


class GestureSamples(L.Callback):
    """Every N batches trained: a sample of the first take's held-out audio as BVH + GIF into the MLflow
    run, logged as `samples/step_NNNNNN/<take>.bvh` and `.gif`, always from the same seed, so successive
    previews compare.
    """

    def __init__(self, every_n_steps: int = 1000, seconds: float = 10.0, seed: int = 0):
        self.due = Due(every_n_steps)
        self.seconds, self.seed = seconds, seed

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module) -> None:
        step = self.due(trainer)
        if step is None:
            return
        self.write(pl_module, trainer.datamodule, trainer.logger, step_folder("samples", step))

    def write(
        self, pl_module, datamodule, logger, artifact_dir: str, folder: Path | None = None
    ) -> list[Path]:
        take = datamodule.load_takes()[0]
        begin, end = datamodule.split_frames(take, "test")
        end = min(end, begin + round(self.seconds * pl_module.spec["fps"]))
        was_training = pl_module.training
        pl_module.eval()
        clip = synthesize(pl_module, take.audio[begin:end], 1, self.seed, smooth=True)[0]
        pl_module.train(was_training)
        with tempfile.TemporaryDirectory() as tmp:
            files, _ = write_clips(Path(folder or tmp), take.name, pl_module, [clip], ["smoothed"])
            for path in files:
                log_file(logger, path, artifact_dir)
            return files if folder else []
