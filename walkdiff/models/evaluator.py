"""`MotionEvaluator`: a style + content classifier whose penultimate features define the FMD space.

The protocol of Action2Motion / ACTOR / MDM scores generated motion with a recognition network trained on
real data: its accuracy on generated clips says whether the requested labels show, and the statistics of
its penultimate features give the Fréchet motion distance, diversity and multimodality.

The network is a stack of temporal convolutions over the frames of a window, averaged over time: it takes
windows of any length, so generators with other window sizes can be scored. `features` and `classify`
take RAW features (data units): every generator normalises its data its own way, the evaluator applies
its own normaliser, which it keeps in its state dict.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn
from torchmetrics.classification import MulticlassAccuracy

from walkdiff.errors import WalkdiffError
from walkdiff.models.base import MotionModule
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


class MotionEvaluator(MotionModule):
    """Recognises style and content of motion windows (B, F, D).

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
        self.save_hyperparameters(ignore=["data_spec"])
        self.hparams["data_spec"] = spec = self.spec
        num_styles, num_contents = len(spec["styles"]), len(spec["contents"])

        self.input = nn.Conv1d(spec["feature_dim"], hidden, kernel, padding=kernel // 2)
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

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Normalised windows (B, F, D) -> (features (B, embed_dim), style logits, content logits)."""
        h = self.blocks(F.gelu(self.input(x.transpose(1, 2))))
        features = self.embed(h.mean(dim=2))
        hidden = self.head_dropout(F.gelu(features))
        return features, self.style_head(hidden), self.content_head(hidden)

    def _normalised(self, raw: torch.Tensor) -> torch.Tensor:
        d = self.spec["feature_dim"]
        if raw.ndim != 3 or raw.shape[-1] != d or raw.shape[1] < 1:
            raise WalkdiffError(
                f"the evaluator expects raw feature windows (B, F, {d}), got {tuple(raw.shape)}"
            )
        return self.normalizer.normalize(raw.to(device=self.device, dtype=self.dtype))

    @torch.no_grad()
    def features(self, raw: torch.Tensor) -> torch.Tensor:
        """Penultimate features (B, embed_dim) of raw (data-unit) feature windows (B, F, D)."""
        return self.eval()(self._normalised(raw))[0]

    @torch.no_grad()
    def classify(self, raw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(style logits, content logits) of raw (data-unit) feature windows (B, F, D)."""
        _, style, content = self.eval()(self._normalised(raw))
        return style, content

    @torch.no_grad()
    def embed_and_classify(self, raw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Features and both logits in one pass: what the evaluation protocol needs."""
        return self.eval()(self._normalised(raw))

    # ---------------------------------------------------------------- training

    def _step(self, batch: dict, split: str) -> torch.Tensor:
        x = batch["features"]
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
        self.log_dict(
            {f"{split}/loss": loss, f"{split}/loss_style": style_loss, f"{split}/loss_content": content_loss},
            on_step=split == "train",
            on_epoch=True,
            sync_dist=split != "train",
            batch_size=batch_size,
        )
        # Metric objects are reduced across ranks by torchmetrics itself.
        self.log_dict(
            {f"{split}/style_acc": style_acc, f"{split}/content_acc": content_acc},
            on_step=False,
            on_epoch=True,
            prog_bar=split != "test",
            batch_size=batch_size,
        )
        return loss

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        return self._step(batch, "train")

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self._step(batch, "val")

    def test_step(self, batch: dict, batch_idx: int) -> None:
        self._step(batch, "test")

    def configure_optimizers(self):
        h = self.hparams
        optimizer = torch.optim.AdamW(self.parameters(), lr=h.lr, weight_decay=h.weight_decay)
        total = self.trainer.estimated_stepping_batches
        if not math.isfinite(total):  # training bounded by time only: keep the learning rate
            return optimizer
        scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=max(1, int(total)))
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}
