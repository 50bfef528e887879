"""`ActionEvaluator`: the action recognition network of the HumanAct12 protocol (Action2Motion / ACTOR).

As in Action2Motion, a GRU reads the 24 x 3 joint positions of every frame; its last output, through a
small tanh layer, is the feature vector of FID, diversity and multimodality, and a linear head gives
the action. Joint positions come from the features by forward kinematics on the training skeleton,
with the clip starting at the origin and facing +Z, so where a clip stands does not matter.

The interface is the one `walkdiff.evaluation.MotionScorer` uses with `MotionEvaluator`: `features`,
`classify` and `embed_and_classify` take RAW feature windows (data units, any length). HumanAct12 has
no styles: the style logits are a constant column per style, and the scorer leaves style accuracy out.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn
from torchmetrics.classification import MulticlassAccuracy

from walkdiff.errors import WalkdiffError
from walkdiff.models.base import MotionModule
from walkdiff.models.evaluator import MotionEvaluator
from walkdiff.motion.representation import features_to_positions
from walkdiff.spec import DataSpec


class ActionEvaluator(MotionModule):
    """Recognises the action (content) of motion windows (B, F, D) from their joint positions.

    Args:
        data_spec: linked from the data module by `walkdiff fit` (a DataSpec, or its dict form).
        hidden: GRU width (Action2Motion: 128).
        layers: GRU layers (Action2Motion: 2).
        embed_dim: size of the feature vector (Action2Motion: 30).
        input_noise: std (metres) of Gaussian noise on the training joint positions, so that the
            evaluator does not rely on details generated motion never reproduces exactly.
        lr, weight_decay: AdamW settings; the learning rate follows a cosine decay over training.
    """

    def __init__(
        self,
        data_spec: DataSpec | dict | None = None,
        hidden: int = 128,
        layers: int = 2,
        embed_dim: int = 30,
        input_noise: float = 0.01,
        lr: float = 1e-3,
        weight_decay: float = 0.0,
    ):
        super().__init__(data_spec)
        self.save_hyperparameters(ignore=["data_spec"])
        self.hparams["data_spec"] = spec = self.spec
        num_actions = len(spec["contents"])
        self.gru = nn.GRU(3 * spec["num_joints"], hidden, layers, batch_first=True)
        self.embed = nn.Linear(hidden, embed_dim)
        self.action_head = nn.Linear(embed_dim, num_actions)
        for split in ("train", "val", "test"):
            setattr(self, f"{split}_action_acc", MulticlassAccuracy(num_actions, average="micro"))

    # ---------------------------------------------------------------- network

    def positions(self, raw: torch.Tensor) -> torch.Tensor:
        """Raw feature windows (B, F, D) -> flattened joint positions (B, F, 3J) on the model's skeleton."""
        if self.skeleton is None:
            raise WalkdiffError("the action evaluator has no skeleton: train it with `walkdiff fit`")
        offsets = torch.as_tensor(self.skeleton.offsets, dtype=raw.dtype, device=raw.device)
        return features_to_positions(raw, offsets, self.skeleton.parents).flatten(-2)

    def forward(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Joint positions (B, F, 3J) -> (features (B, embed_dim), style logits, action logits)."""
        output, _ = self.gru(positions)
        features = torch.tanh(self.embed(output[:, -1]))
        style_logits = features.new_zeros(features.shape[0], len(self.spec["styles"]))
        return features, style_logits, self.action_head(features)

    @torch.no_grad()
    def embed_and_classify(self, raw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(features, style logits, action logits) of raw (data-unit) feature windows (B, F, D)."""
        d = self.spec["feature_dim"]
        if raw.ndim != 3 or raw.shape[-1] != d or raw.shape[1] < 1:
            raise WalkdiffError(
                f"the evaluator expects raw feature windows (B, F, {d}), got {tuple(raw.shape)}"
            )
        return self.eval()(self.positions(raw.to(device=self.device, dtype=self.dtype)))

    def features(self, raw: torch.Tensor) -> torch.Tensor:
        """Feature vectors (B, embed_dim) of raw feature windows (B, F, D)."""
        return self.embed_and_classify(raw)[0]

    def classify(self, raw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(style logits, action logits) of raw feature windows (B, F, D)."""
        return self.embed_and_classify(raw)[1:]

    # ---------------------------------------------------------------- training

    def _step(self, batch: dict, split: str) -> torch.Tensor:
        positions = self.positions(self.normalizer.denormalize(batch["features"]))
        if split == "train" and self.hparams.input_noise > 0:
            positions = positions + self.hparams.input_noise * torch.randn_like(positions)
        _, _, logits = self(positions)
        loss = F.cross_entropy(logits, batch["content"])
        accuracy = getattr(self, f"{split}_action_acc")
        accuracy(logits, batch["content"])
        batch_size = positions.shape[0]
        self.log(
            f"{split}/loss", loss, on_step=split == "train", on_epoch=True, sync_dist=split != "train",
            batch_size=batch_size,
        )  # fmt: skip
        # Metric objects are reduced across ranks by torchmetrics itself.
        self.log(
            f"{split}/action_acc", accuracy, on_step=False, on_epoch=True, prog_bar=split != "test",
            batch_size=batch_size,
        )  # fmt: skip
        return loss

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        return self._step(batch, "train")

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self._step(batch, "val")

    def test_step(self, batch: dict, batch_idx: int) -> None:
        self._step(batch, "test")

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        super().on_save_checkpoint(checkpoint)
        checkpoint["evaluator_class"] = f"{type(self).__module__}.{type(self).__qualname__}"

    # The same AdamW with a cosine decay as the motion evaluator.
    configure_optimizers = MotionEvaluator.configure_optimizers
