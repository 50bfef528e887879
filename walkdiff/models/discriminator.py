"""The LSGAN discriminator over whole motion windows."""

from __future__ import annotations

import torch
from torch import nn


class MotionDiscriminator(nn.Module):
    """Temporal conv net scoring whole windows (LSGAN: real -> 1, generated -> 0).

    With labels it uses projection conditioning (score += <embed(label), h>), so it can also judge
    whether a window looks like its requested style and content.
    """

    def __init__(
        self,
        feature_dim: int,
        num_styles: int = 0,
        num_contents: int = 0,
        hidden: int = 256,
        layers: int = 3,
        conditional: bool = True,
    ):
        super().__init__()
        blocks: list[nn.Module] = []
        width = feature_dim
        for i in range(layers):
            blocks += [
                nn.utils.parametrizations.spectral_norm(
                    nn.Conv1d(width, hidden, 3, stride=1 if i == 0 else 2, padding=1)
                ),
                nn.LeakyReLU(0.2),
            ]
            width = hidden
        self.body = nn.Sequential(*blocks)
        self.score = nn.Linear(hidden, 1)
        self.style = nn.Embedding(num_styles, hidden) if conditional and num_styles else None
        self.content = nn.Embedding(num_contents, hidden) if conditional and num_contents else None

    def forward(
        self, x: torch.Tensor, style: torch.Tensor | None = None, content: torch.Tensor | None = None
    ) -> torch.Tensor:
        h = self.body(x.transpose(1, 2)).mean(dim=-1)
        out = self.score(h).squeeze(-1)
        if self.style is not None and style is not None:
            out = out + (self.style(style) * h).sum(-1)
        if self.content is not None and content is not None:
            out = out + (self.content(content) * h).sum(-1)
        return out
