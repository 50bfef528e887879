"""The evaluators of the metrics: recognition networks over convention-free body features.

The protocol of Action2Motion / ACTOR / MDM scores generated motion with a recognition network trained on
real data: its accuracy on generated clips says whether the requested labels show, and the statistics of
its penultimate features give the Fréchet motion distance, KID, diversity and multimodality.

Evaluators read WORLD JOINT POSITIONS (B, F, J, 3) of the body in canonical axes (Y up, file units), never
rotations: motion made by any pipeline, with any rotation convention or root layout, is judged by where
its joints go (`walkdiff.motion.body_features`). Training batches (a generator's feature windows) are
turned into positions by forward kinematics on the training skeleton.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn
from torchmetrics.classification import MulticlassAccuracy

from walkdiff.common.errors import WalkdiffError
from walkdiff.models.base import MotionModule
from walkdiff.motion.body_features import BodyFrame
from walkdiff.motion.representation import Normalizer, features_to_positions
from walkdiff.spec import DataSpec


class ConvBlock(nn.Module):
    """Residual temporal convolution: keeps the frame count, so any window length goes through."""

    def __init__(self, channels: int, kernel: int, dropout: float):
        super().__init__()
        self.conv = nn.Conv1d(channels, channels, kernel, padding=kernel // 2)
        self.norm = nn.GroupNorm(8, channels)
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.dropout(F.gelu(self.norm(self.conv(x))))


class PositionEvaluator(MotionModule):
    """What every evaluator shares: positions in, (features, style logits, content logits) out."""

    _body: BodyFrame | None = None

    @property
    def body(self) -> BodyFrame:
        """Joint names, heading pairs and body height of the evaluator's skeleton."""
        if self._body is None:
            if self.profile is None:
                raise WalkdiffError("the evaluator has no skeleton profile: train it with `walkdiff fit`")
            self._body = BodyFrame.of(self.profile)
        return self._body

    def raw_positions(self, raw: torch.Tensor) -> torch.Tensor:
        """Feature windows in data units (B, F, D) on the training skeleton -> positions (B, F, J, 3)."""
        skeleton = self.skeleton
        offsets = torch.as_tensor(skeleton.offsets, dtype=raw.dtype, device=raw.device)
        return features_to_positions(raw, offsets, skeleton.parents)

    def _checked(self, positions: torch.Tensor) -> torch.Tensor:
        j = self.spec["num_joints"]
        if positions.ndim != 4 or positions.shape[2:] != (j, 3) or positions.shape[1] < 1:
            raise WalkdiffError(
                f"the evaluator expects joint positions (B, frames, {j}, 3), got {tuple(positions.shape)}"
            )
        return positions.to(device=self.device, dtype=self.dtype)

    @torch.no_grad()
    def embed_and_classify(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(features (B, E), style logits, content logits) of world joint positions (B, F, J, 3)."""
        return self.eval()(self.inputs(self._checked(positions)))

    def features(self, positions: torch.Tensor) -> torch.Tensor:
        return self.embed_and_classify(positions)[0]

    def classify(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.embed_and_classify(positions)[1:]

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        return self._step(batch, "train")

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self._step(batch, "val")

    def test_step(self, batch: dict, batch_idx: int) -> None:
        self._step(batch, "test")

    def configure_optimizers(self):
        """AdamW with a cosine decay over the planned steps."""
        h = self.hparams
        optimizer = torch.optim.AdamW(self.parameters(), lr=h.lr, weight_decay=h.weight_decay)
        total = self.trainer.estimated_stepping_batches
        if not math.isfinite(total):  # training bounded by time only: keep the learning rate
            return optimizer
        scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=max(1, int(total)))
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}


class MotionEvaluator(PositionEvaluator):
    """Recognises style and content of motion from its body features (`BodyFrame.features`).

    Args:
        data_spec: linked from the data module by `walkdiff fit` (a DataSpec, or its dict form).
        hidden: channels of the temporal convolutions.
        embed_dim: size of the penultimate feature vector, the space of FMD / diversity / multimodality.
            Small on purpose: Xia's walking test set has a few hundred windows from 24 clips, too few to
            estimate a large covariance matrix.
        blocks: residual convolution blocks after the input convolution.
        kernel: temporal kernel size (frames).
        dropout: dropout inside the blocks and before the heads.
        input_noise: std of Gaussian noise added to the normalised training inputs, so that the
            evaluator does not rely on details that generated motion never reproduces exactly.
        content_weight: weight of the content loss against the style loss.
        lr, weight_decay: AdamW settings; the learning rate follows a cosine decay over training.
    """

    def __init__(
        self,
        data_spec: DataSpec | dict | None = None,
        hidden: int = 128,
        embed_dim: int = 128,
        blocks: int = 3,
        kernel: int = 5,
        dropout: float = 0.2,
        input_noise: float = 0.1,
        content_weight: float = 1.0,
        lr: float = 1e-3,
        weight_decay: float = 1e-2,
    ):
        super().__init__(data_spec)
        self.save_hyperparameters(ignore=["data_spec"], logger=False)  # the run logs its config (run_params)
        self.hparams["data_spec"] = spec = self.spec
        num_styles, num_contents = len(spec["styles"]), len(spec["contents"])

        body_dim = 6 * spec["num_joints"] + 1  # BodyFrame.dim
        self.feature_normalizer = Normalizer(body_dim)
        self.input = nn.Conv1d(body_dim, hidden, kernel, padding=kernel // 2)
        self.blocks = nn.Sequential(*[ConvBlock(hidden, kernel, dropout) for _ in range(blocks)])
        self.embed = nn.Linear(hidden, embed_dim)
        self.head_dropout = nn.Dropout(dropout)
        self.style_head = nn.Linear(embed_dim, num_styles)
        self.content_head = nn.Linear(embed_dim, num_contents)

        for split in ("train", "val", "test"):
            # A dataset with one style or one content group has a one-class head (always right);
            # torchmetrics wants two classes at least.
            setattr(self, f"{split}_style_acc", MulticlassAccuracy(max(num_styles, 2), average="micro"))
            setattr(self, f"{split}_content_acc", MulticlassAccuracy(max(num_contents, 2), average="micro"))

    # ---------------------------------------------------------------- network

    def inputs(self, positions: torch.Tensor) -> torch.Tensor:
        """Positions (B, F, J, 3) -> normalised body features (B, F, 6J + 1)."""
        features = self.body.features(positions, self.spec["fps"])
        return self.feature_normalizer.normalize(features.to(self.dtype))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Normalised body features (B, F, 6J + 1) -> (features (B, embed_dim), style, content logits)."""
        h = self.blocks(F.gelu(self.input(x.transpose(1, 2))))
        features = self.embed(h.mean(dim=2))
        hidden = self.head_dropout(F.gelu(features))
        return features, self.style_head(hidden), self.content_head(hidden)

    # ---------------------------------------------------------------- training

    def setup(self, stage: str) -> None:
        super().setup(stage)
        datamodule = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if stage == "fit" and datamodule is not None:  # a resumed run loads them back from its checkpoint
            clips = datamodule.split_features("train", mirrored=datamodule.hparams.mirror)
            features = [
                self.body.features(self.raw_positions(torch.tensor(f, dtype=torch.float64)), self.spec["fps"])
                for _, _, f in clips
            ]
            statistics = Normalizer.fit([f.numpy() for f in features])
            self.feature_normalizer.load_state_dict(statistics.state_dict())

    def _step(self, batch: dict, split: str) -> torch.Tensor:
        x = self.inputs(self.raw_positions(self.normalizer.denormalize(batch["features"])))
        if split == "train" and self.hparams.input_noise > 0:
            x = x + self.hparams.input_noise * torch.randn_like(x)
        _, style_logits, content_logits = self(x)
        style_loss = F.cross_entropy(style_logits, batch["style"])
        content_loss = F.cross_entropy(content_logits, batch["content"])
        loss = style_loss + self.hparams.content_weight * content_loss
        style_acc = getattr(self, f"{split}_style_acc")
        content_acc = getattr(self, f"{split}_content_acc")
        style_acc(style_logits.argmax(-1), batch["style"])  # class ids: heads may have one class
        content_acc(content_logits.argmax(-1), batch["content"])
        batch_size = x.shape[0]
        # `<term>/<split>`: a term's train and val charts side by side in MLflow; epoch means only.
        self.log_dict(
            {f"loss/{split}": loss, f"style_loss/{split}": style_loss, f"content_loss/{split}": content_loss},
            on_step=False,
            on_epoch=True,
            sync_dist=split != "train",
            batch_size=batch_size,
        )
        # Metric objects are reduced across ranks by torchmetrics itself.
        self.log_dict(
            {f"style_acc/{split}": style_acc, f"content_acc/{split}": content_acc},
            on_step=False,
            on_epoch=True,
            prog_bar=split != "test",
            batch_size=batch_size,
        )
        return loss
