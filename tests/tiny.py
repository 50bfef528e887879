"""Tiny trained models the tests share: each fitted in seconds on a few clips and saved as a checkpoint.

Good enough to run every command and API call on, never to judge motion quality by.
"""

from __future__ import annotations

from pathlib import Path

import lightning as L
import numpy as np
import synthetic
import torch
from test_speech import write_take

from walkdiff.data.datamodule import MotionDataModule
from walkdiff.data.speech import SpeechDataModule
from walkdiff.models.diffmotion import DiffMotion
from walkdiff.models.path_walker import PathWalker
from walkdiff.models.styled_ddpm import StyledMotionDiffusion

# It predicts x0: a tiny eps-model needs far longer before x0 = (x_t - sqrt(1 - abar) eps) / sqrt(abar)
# stops exploding at large t, and the tests are about the machinery around the network, which is the same
# for every prediction type.
GENERATOR = dict(
    d_model=32, layers=1, heads=2, dropout=0.0, prediction="x0", lambda_adv=0.0, lr=3e-3,
    lr_warmup_batches=10, ema_decay=0.9,
)  # fmt: skip
WALKER = dict(hidden=32, lstm_layers=2, control_hidden=16, channels=8, residual_layers=2, timesteps=8)
GESTURES = dict(hidden=32, lstm_layers=2, audio_hidden=16, channels=8, residual_layers=4, timesteps=10)


def generator(
    root: Path, epochs: int = 60, name: str = "tiny", data_options: dict | None = None, **options
) -> Path:
    """A StyledMotionDiffusion fitted for `epochs` on the Xia-named clips in root/xia (MotionDataModule
    settings beside or instead of these: `data_options`); its checkpoint, root/`name`.ckpt."""
    settings = dict(
        root=str(root), cache_dir=str(root / "cache"), batch_size=16, window=24, preprocess_workers=1
    )
    dm = MotionDataModule(**(settings | (data_options or {})))
    L.seed_everything(0)
    model = StyledMotionDiffusion(dm.spec, **(GENERATOR | options))
    trainer = synthetic.quiet_trainer(max_epochs=epochs, limit_val_batches=0)
    trainer.fit(model, dm)
    path = root / f"{name}.ckpt"
    trainer.save_checkpoint(path)
    return path


def walker(root: Path) -> tuple[PathWalker, Path]:
    """A PathWalker fitted for a few steps on the Xia-named walks in root/xia; the model, its checkpoint."""
    dm = MotionDataModule(
        root=str(root), cache_dir=str(root / "cache"), window=24, stride=8, batch_size=4, preprocess_workers=1
    )
    torch.manual_seed(0)
    model = PathWalker(dm.spec, **WALKER, lr=3e-3)
    trainer = synthetic.quiet_trainer(max_steps=4)
    before = model.eps_net.output.weight.detach().clone()
    trainer.fit(model, dm)
    assert not torch.equal(before, model.eps_net.output.weight), "training did not update the walker"
    path = root / "walker.ckpt"
    trainer.save_checkpoint(path)
    return model, path


def gestures(root: Path) -> tuple[Path, Path]:
    """A DiffMotion fitted for a few steps on two synthetic takes (a: 10 s, b: 8 s) it writes in
    root/takes; (its checkpoint, the takes folder)."""
    folder = root / "takes"
    write_take(folder, "a", 10.0, seed=1)
    write_take(folder, "b", 8.0, seed=2)
    torch.manual_seed(0)
    dm = SpeechDataModule(str(folder), window=40, stride=10, past=5, lookahead=8, batch_size=4)
    model = DiffMotion(dm.spec, **GESTURES, lr=3e-3)
    trainer = synthetic.quiet_trainer(max_steps=6)
    before = model.eps_net.output.weight.detach().clone()
    trainer.fit(model, dm)
    assert not torch.equal(before, model.eps_net.output.weight), "training did not update the eps network"
    assert np.isfinite(float(trainer.callback_metrics["loss/train"]))
    path = root / "tiny.ckpt"
    trainer.save_checkpoint(path)
    return path, folder
