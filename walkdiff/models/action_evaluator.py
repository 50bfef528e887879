"""`ActionEvaluator`: the action recognition network of the HumanAct12 protocol (Action2Motion / ACTOR).

As in Action2Motion, a GRU reads the 24 x 3 joint positions of every frame; its last output, through a
small tanh layer, is the feature vector of FID, diversity and multimodality, and a linear head gives
the action. Every window is moved to start at the origin facing +Z, the facing found from the body's
left/right joints (`BodyFrame.heading`), so where a clip stands and how its rotations are written do
not matter.

The interface is `PositionEvaluator`'s, as `MotionEvaluator`'s: world joint positions (B, F, J, 3) in.
HumanAct12 has no styles: the style logits are a constant column per style, and the scorer leaves style
accuracy out.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn
from torchmetrics.classification import MulticlassAccuracy

from walkdiff.models.evaluator import PositionEvaluator
from walkdiff.spec import DataSpec


class ActionEvaluator(PositionEvaluator):
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
        self.save_hyperparameters(ignore=["data_spec"], logger=False)  # the run logs its config (run_params)
        self.hparams["data_spec"] = spec = self.spec
        num_actions = len(spec["contents"])
        self.gru = nn.GRU(3 * spec["num_joints"], hidden, layers, batch_first=True)
        self.embed = nn.Linear(hidden, embed_dim)
        self.action_head = nn.Linear(embed_dim, num_actions)
        for split in ("train", "val", "test"):
            setattr(self, f"{split}_action_acc", MulticlassAccuracy(num_actions, average="micro"))

    # ---------------------------------------------------------------- network

    def inputs(self, positions: torch.Tensor) -> torch.Tensor:
        """Positions (B, F, J, 3) -> flattened (B, F, 3J), each window from the origin, facing +Z."""
        body = self.body
        start = positions[:, :1, body.root : body.root + 1, :] * positions.new_tensor([1.0, 0.0, 1.0])
        heading = body.heading(positions[:, 0])[:, None, None]
        cos, sin = torch.cos(heading), torch.sin(heading)
        x, y, z = (positions - start).unbind(-1)
        return torch.stack([cos * x - sin * z, y, sin * x + cos * z], dim=-1).flatten(-2)

    def forward(self, inputs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Aligned positions (B, F, 3J) -> (features (B, embed_dim), style logits, action logits)."""
        output, _ = self.gru(inputs)
        features = torch.tanh(self.embed(output[:, -1]))
        style_logits = features.new_zeros(features.shape[0], len(self.spec["styles"]))
        return features, style_logits, self.action_head(features)

    # ---------------------------------------------------------------- training

    def _step(self, batch: dict, split: str) -> torch.Tensor:
        inputs = self.inputs(self.raw_positions(self.normalizer.denormalize(batch["features"])))
        if split == "train" and self.hparams.input_noise > 0:
            inputs = inputs + self.hparams.input_noise * torch.randn_like(inputs)
        _, _, logits = self(inputs)
        loss = F.cross_entropy(logits, batch["content"])
        accuracy = getattr(self, f"{split}_action_acc")
        accuracy(logits, batch["content"])
        batch_size = inputs.shape[0]
        self.log(
            f"loss/{split}", loss, on_step=False, on_epoch=True, sync_dist=split != "train",
            batch_size=batch_size,
        )  # fmt: skip
        # Metric objects are reduced across ranks by torchmetrics itself.
        self.log(
            f"action_acc/{split}", accuracy, on_step=False, on_epoch=True, prog_bar=split != "test",
            batch_size=batch_size,
        )  # fmt: skip
        return loss
