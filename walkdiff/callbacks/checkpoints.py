"""Checkpoints in a folder of their own per run, and stable links to the newest run's files.

With Lightning's ModelCheckpoint a rerun of a config wrote `last-v1.ckpt` beside the older run's
`last.ckpt`, so the path the README, the Makefile and the configs use kept pointing at the older run.
"""

from __future__ import annotations

import os
import re
import sys
import time
import weakref
from pathlib import Path

from lightning.pytorch.callbacks import ModelCheckpoint

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import link_atomic

RUN_FOLDER_TAG = "walkdiff.checkpoints"  # the MLflow tag naming a run's checkpoint folder

# One run folder name per trainer, shared by all its RunCheckpoints (best and last go together).
_RUN_NAMES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_TAKEN: set[str] = set()


def mlflow_logger(trainer):
    """The trainer's MLFlowLogger, or None."""
    from lightning.pytorch.loggers import MLFlowLogger

    return next((logger for logger in trainer.loggers if isinstance(logger, MLFlowLogger)), None)


def run_name(trainer) -> str:
    """The MLflow run id when the trainer logs to MLflow, else the start time and PID (unique here)."""
    if trainer not in _RUN_NAMES:
        logger = mlflow_logger(trainer)
        if logger is not None:
            name = logger.run_id
        else:
            base = name = f"{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}"
            count = 1
            while name in _TAKEN:  # a second trainer in this process within the same second
                count += 1
                name = f"{base}-{count}"
        _TAKEN.add(name)
        _RUN_NAMES[trainer] = name
    return _RUN_NAMES[trainer]


class RunCheckpoint(ModelCheckpoint):
    """A ModelCheckpoint that saves into `dirpath/<run>/` and never writes over another run's files.

    After every save `dirpath/<link>.ckpt` becomes a relative symlink to this run's file, replaced in one
    step: `checkpoints/xia_cpu/last.ckpt` is always the newest run's, and `--ckpt_path` of it resumes
    that run (into a new run folder; the best score so far is carried on, and files of earlier runs are
    never deleted). The MLflow run is tagged `walkdiff.checkpoints` with its folder.

    Args:
        dirpath: folder of the run folders and of the links (default: the trainer's default_root_dir, so
            `--trainer.default_root_dir` moves a config's checkpoints and links with it; a path written
            in the config, or interpolated from it, stays where the file put it).
        link: name of the stable link, without `.ckpt` (default: `filename` up to its first `{`, so
            "best-{epoch:04d}" links best.ckpt). With `save_last`, last.ckpt links the run's last too.
        **kwargs: as ModelCheckpoint.
    """

    def __init__(self, dirpath: str | None = None, link: str | None = None, **kwargs):
        if kwargs.get("save_last") == "link":
            raise WalkdiffError("RunCheckpoint: save_last 'link' is not supported; use save_last: true")
        super().__init__(dirpath=dirpath, **kwargs)
        self.root = None if self.dirpath is None else Path(self.dirpath)
        self.link = link or re.split(r"[-_=]*\{", self.filename or "")[0]
        if not self.link:
            raise WalkdiffError(
                f"RunCheckpoint: filename {self.filename!r} gives no name for the stable link; set link"
            )
        self.run_dir: str | None = None
        self._judged = None  # the monitored metric's value the last save looked at

    def setup(self, trainer, pl_module, stage: str) -> None:
        if stage == "fit" and self.run_dir is None:
            if self.root is None:
                self.root = Path(trainer.default_root_dir)
            folder = None
            if trainer.is_global_zero:
                folder = str(self.root / run_name(trainer))
                Path(folder).mkdir(parents=True, exist_ok=True)
                logger = mlflow_logger(trainer)
                if logger is not None:
                    logger.experiment.set_tag(logger.run_id, RUN_FOLDER_TAG, folder)
            self.run_dir = self.dirpath = trainer.strategy.broadcast(folder)
        super().setup(trainer, pl_module, stage)

    def load_state_dict(self, state_dict: dict) -> None:
        # Resumed from an earlier run of this folder: go on from its best score. Lightning deletes only
        # files inside this run's folder, so the earlier run's files stay.
        previous = state_dict.get("dirpath")
        if previous and self.run_dir is not None and Path(previous).parent == self.root:
            state_dict = {**state_dict, "dirpath": self.dirpath}
        super().load_state_dict(state_dict)

    def _save_topk_checkpoint(self, trainer, monitor_candidates: dict) -> None:
        # A metric that only some validations log (MotionMetrics' metrics/fmd, every 5th epoch) is absent
        # from the others, or holds the value an earlier save judged (Lightning keeps a metric's last
        # value, the same object, until it is logged again): skip those, where Lightning's ModelCheckpoint
        # failed the run after its first epoch, or saved epochs on a score they did not get.
        if self.monitor is not None:
            value = trainer.callback_metrics.get(self.monitor)
            if self.monitor not in monitor_candidates or value is self._judged:
                return
            self._judged = value
        super()._save_topk_checkpoint(trainer, monitor_candidates)

    def on_train_end(self, trainer, pl_module) -> None:
        super().on_train_end(trainer, pl_module)
        # A checkpoint without a monitor (last.ckpt) also keeps the batches after its last save: a run
        # that ends between validations (a short or overridden run, one stopped by max_time).
        if self.monitor is None and trainer.global_step > self._last_global_step_saved:
            self._save_none_monitor_checkpoint(trainer, self._monitor_candidates(trainer))
        if self.monitor is not None and self._judged is None and trainer.is_global_zero:
            logged = ", ".join(sorted(set(trainer.callback_metrics) - {"epoch", "step"})) or "none"
            print(
                f"walkdiff: warning: no {self.link} checkpoint saved: its monitor {self.monitor!r} was "
                f"never logged in this run (logged: {logged}); the run ended before what logs it ran, or "
                "the monitor's name is wrong",
                file=sys.stderr,
            )

    def _save_checkpoint(self, trainer, filepath: str) -> None:
        super()._save_checkpoint(trainer, filepath)
        if trainer.is_global_zero:
            for link, target in self.links().items():
                if Path(target).is_file():
                    _point(link, target)

    def links(self) -> dict[Path, str]:
        """{stable link: the checkpoint it is to point at}."""
        links = {}
        if self.best_model_path:
            links[self.root / f"{self.link}{self.FILE_EXTENSION}"] = self.best_model_path
        if self.save_last and self.last_model_path:
            links[self.root / f"{self.CHECKPOINT_NAME_LAST}{self.FILE_EXTENSION}"] = self.last_model_path
        return links


def _point(link: Path, target: str) -> None:
    """link -> target; a checkpoint file already there (saved before run folders) is moved aside, kept."""
    if link.is_file() and not link.is_symlink():
        stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(link.stat().st_mtime))
        kept = link.parent / f"earlier-{stamp}" / link.name
        kept.parent.mkdir(exist_ok=True)
        if kept.exists():
            raise WalkdiffError(f"cannot move the earlier checkpoint aside: {kept} exists", path=link)
        os.replace(link, kept)
        print(f"walkdiff: moved the earlier {link} (saved before run folders) to {kept}", file=sys.stderr)
    link_atomic(link, target)
