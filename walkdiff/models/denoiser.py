"""The sequence denoiser: a transformer over a window's frames, conditioned on step, content and style."""

from __future__ import annotations

import math

import torch
from torch import nn

from walkdiff.models.style_encoder import CodeStyle, StyleEncoder


def sinusoidal(positions: torch.Tensor, dim: int) -> torch.Tensor:
    """Transformer-style sinusoidal embedding of (fractional) positions or diffusion steps."""
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, device=positions.device) / half)
    angles = positions.float()[..., None] * freqs
    return torch.cat([angles.sin(), angles.cos()], dim=-1)


class LabelEmbedding(nn.Module):
    """A learned table with one extra row, the null label used for classifier-free guidance.

    Accepts class ids (B,) or mixing weights (B, classes) so that styles can be blended.
    """

    def __init__(self, num_classes: int, dim: int):
        super().__init__()
        self.num_classes = num_classes
        self.table = nn.Embedding(num_classes + 1, dim)

    @property
    def null_id(self) -> int:
        return self.num_classes

    def forward(self, labels: torch.Tensor) -> torch.Tensor:
        if labels.is_floating_point():
            return labels @ self.table.weight[: self.num_classes]
        return self.table(labels)

    def drop(self, labels: torch.Tensor, p: float, generator: torch.Generator | None = None) -> torch.Tensor:
        """Replace each id by the null id with probability p (training for guidance)."""
        if p <= 0:
            return labels
        drop = torch.rand(labels.shape, device=labels.device, generator=generator) < p
        return torch.where(drop, torch.full_like(labels, self.null_id), labels)


# model.conditioning: how step, content and style enter the transformer (MotionDenoiser).
CONDITIONING = ("prefix", "adaln")


def zero_modulation(d_model: int, parts: int) -> nn.Sequential:
    """The conditioning to `parts` vectors of d_model (shifts, scales, gates), starting at zero."""
    modulation = nn.Sequential(nn.SiLU(), nn.Linear(d_model, parts * d_model))
    nn.init.zeros_(modulation[1].weight)
    nn.init.zeros_(modulation[1].bias)
    return modulation


class ModulatedLayer(nn.Module):
    """A pre-norm transformer layer whose two norms are shifted and scaled, and whose two branches gated,
    by the conditioning (adaLN-Zero, Peebles & Xie 2023, DiT). The modulation starts at zero, so each layer
    starts as the identity, and the condition then sets every layer's statistics instead of entering once,
    at the input, where the layers above can wash it out."""

    def __init__(self, d_model: int, heads: int, ff: int, dropout: float):
        super().__init__()
        self.attention_norm = nn.LayerNorm(d_model, elementwise_affine=False)
        self.attention = nn.MultiheadAttention(d_model, heads, dropout=dropout, batch_first=True)
        self.feedforward_norm = nn.LayerNorm(d_model, elementwise_affine=False)
        self.feedforward = nn.Sequential(
            nn.Linear(d_model, ff), nn.GELU(), nn.Dropout(dropout), nn.Linear(ff, d_model)
        )
        self.dropout = nn.Dropout(dropout)
        self.modulation = zero_modulation(d_model, 6)

    def forward(self, h: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """h (B, F, d_model), cond (B, 1, d_model)."""
        shift_a, scale_a, gate_a, shift_f, scale_f, gate_f = self.modulation(cond).chunk(6, dim=-1)
        a = self.attention_norm(h) * (1 + scale_a) + shift_a
        h = h + gate_a * self.dropout(self.attention(a, a, a, need_weights=False)[0])
        f = self.feedforward_norm(h) * (1 + scale_f) + shift_f
        return h + gate_f * self.dropout(self.feedforward(f))


class MotionDenoiser(nn.Module):
    """Predicts the diffusion target (eps, x0 or v) for a noisy window x_t of shape (B, F, D).

    The conditioning (step + content + style) enters in one of two ways (`conditioning`): `prefix`, a
    token that every frame attends to and a bias added to every frame at the input; or `adaln`, every
    layer's norms shifted and scaled and its branches gated by it (`ModulatedLayer`).

    A distilled student (walkdiff/distill.py) also takes `jump`, how many trained steps the sampler's
    step spans (B,): a jump above 1 adds its embedding to the conditioning, so one network gives both
    the one-step estimate DDPM uses and the estimate a long DDIM step needs. 0 or 1 (or None) is the
    plain denoiser.
    """

    def __init__(
        self,
        feature_dim: int,
        num_styles: int,
        num_contents: int,
        d_model: int = 256,
        layers: int = 4,
        heads: int = 4,
        ff_mult: int = 4,
        dropout: float = 0.1,
        jump_conditioning: bool = False,
        code_dim: int = 0,
        conditioning: str = "prefix",
    ):
        super().__init__()
        self.d_model, self.conditioning = d_model, conditioning
        self.input = nn.Linear(feature_dim, d_model)
        self.step_mlp = nn.Sequential(nn.Linear(d_model, d_model), nn.SiLU(), nn.Linear(d_model, d_model))
        # With code_dim > 0 style comes as codes of example motion (models/style_encoder.py), labels too.
        self.style = (
            CodeStyle(num_styles, code_dim, d_model) if code_dim else LabelEmbedding(num_styles, d_model)
        )
        self.style_encoder = StyleEncoder(feature_dim, code_dim) if code_dim else None
        self.content = LabelEmbedding(num_contents, d_model)
        if conditioning == "adaln":
            self.layers = nn.ModuleList(
                ModulatedLayer(d_model, heads, ff_mult * d_model, dropout) for _ in range(layers)
            )
            self.norm = nn.LayerNorm(d_model, elementwise_affine=False)
            self.final_modulation = zero_modulation(d_model, 2)
        else:
            layer = nn.TransformerEncoderLayer(
                d_model,
                heads,
                ff_mult * d_model,
                dropout,
                activation="gelu",
                batch_first=True,
                norm_first=True,
            )
            self.encoder = nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)
            self.norm = nn.LayerNorm(d_model)
        self.output = nn.Linear(d_model, feature_dim)
        self.jump_mlp = None
        if jump_conditioning:
            self.add_jump_conditioning()

    def add_jump_conditioning(self) -> None:
        """The jump embedding, starting at zero so the network still computes what it did."""
        d = self.d_model
        self.jump_mlp = nn.Sequential(nn.Linear(d, d), nn.SiLU(), nn.Linear(d, d))
        nn.init.zeros_(self.jump_mlp[2].weight)
        nn.init.zeros_(self.jump_mlp[2].bias)

    def condition(
        self, t: torch.Tensor, style: torch.Tensor, content: torch.Tensor, jump: torch.Tensor | None = None
    ) -> torch.Tensor:
        cond = self.step_mlp(sinusoidal(t, self.d_model)) + self.style(style) + self.content(content)
        if jump is not None:
            if self.jump_mlp is None:
                raise ValueError("this denoiser was not distilled: it takes no jump")
            cond = cond + self.jump_mlp(sinusoidal(jump, self.d_model)) * (jump > 1)[:, None]
        return cond

    def forward(
        self,
        x_t: torch.Tensor,
        t: torch.Tensor,
        style: torch.Tensor,
        content: torch.Tensor,
        jump: torch.Tensor | None = None,
    ) -> torch.Tensor:
        frames = x_t.shape[1]
        cond = self.condition(t, style, content, jump)[:, None]
        pos = sinusoidal(torch.arange(frames, device=x_t.device), self.d_model)
        if self.conditioning == "adaln":
            h = self.input(x_t) + pos
            for layer in self.layers:
                h = layer(h, cond)
            shift, scale = self.final_modulation(cond).chunk(2, dim=-1)
            return self.output(self.norm(h) * (1 + scale) + shift)
        h = self.input(x_t) + pos + cond
        h = self.encoder(torch.cat([cond, h], dim=1))[:, 1:]
        return self.output(self.norm(h))
