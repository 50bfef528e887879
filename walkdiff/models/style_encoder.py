"""Style from an example clip: an encoder from motion windows to a unit style code, and the denoiser's
style input that takes codes, labels (their stored codes) or mixes of both.

Why codes are trained the way they are (`reference_windows`): each training window is conditioned on the
code of a *different* clip of the same style, cropped at random, so a code can only help the denoiser by
what that other clip shares with it, its style, and not by its content, path or timing. A small
classification term (`CodeStyle.logits`) keeps the codes of one style together. The features the encoder
reads are already blind to where the body stands and which way it faces on the ground (root velocities in
the heading frame, the turning rate, local poses), so the code is too.

Labels become codes: `CodeStyle.codes` holds one code per training style, the running mean of the
EMA encoder's codes of that style's training windows (`update_codes`), saved in the checkpoint, so sampling
by label costs no more than it did.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from walkdiff.common.errors import WalkdiffError

CODE_MOMENTUM = 0.99  # the stored codes' running mean: about the last hundred batches


class StyleEncoder(nn.Module):
    """Normalised feature windows (B, F, D), any F >= 8, to unit style codes (B, code_dim): three temporal
    convolutions (the middle one halves the frames), then the mean and the maximum over time."""

    def __init__(self, feature_dim: int, code_dim: int, hidden: int = 128):
        super().__init__()
        self.convs = nn.Sequential(
            nn.Conv1d(feature_dim, hidden, 5, padding=2), nn.SiLU(),
            nn.Conv1d(hidden, hidden, 5, stride=2, padding=2), nn.SiLU(),
            nn.Conv1d(hidden, hidden, 5, padding=2), nn.SiLU(),
        )  # fmt: skip
        self.out = nn.Linear(2 * hidden, code_dim)

    def forward(self, windows: torch.Tensor) -> torch.Tensor:
        h = self.convs(windows.transpose(1, 2))
        pooled = torch.cat([h.mean(dim=-1), h.amax(dim=-1)], dim=-1)
        return F.normalize(self.out(pooled), dim=-1)


class CodeStyle(nn.Module):
    """The denoiser's style input for a model with a style encoder. It takes what `LabelEmbedding` takes,
    ids (B,) with `null_id` for none, or mixing weights (B, styles), as the stored codes of those styles,
    and codes (B, code_dim) from the encoder; the unconditional input is the zero code."""

    def __init__(self, num_styles: int, code_dim: int, dim: int):
        super().__init__()
        if code_dim == num_styles:  # a (B, n) input must say by its width whether it is codes or weights
            raise WalkdiffError(
                f"model.style_code_dim: {code_dim} equals the number of styles; choose another size"
            )
        self.num_styles, self.code_dim = num_styles, code_dim
        self.project = nn.Linear(code_dim, dim)
        self.classify = nn.Linear(code_dim, num_styles)
        self.register_buffer("codes", torch.zeros(num_styles, code_dim))

    @property
    def null_id(self) -> int:
        return self.num_styles

    def as_codes(self, style: torch.Tensor) -> torch.Tensor:
        """Codes (B, code_dim) for ids, mixing weights or codes; zero for the null id."""
        if not style.is_floating_point():
            table = torch.cat([self.codes, self.codes.new_zeros(1, self.code_dim)])
            return table[style]
        if style.shape[-1] == self.num_styles:
            return F.normalize(style @ self.codes, dim=-1)
        return style

    def forward(self, style: torch.Tensor) -> torch.Tensor:
        return self.project(self.as_codes(style))

    def logits(self, codes: torch.Tensor) -> torch.Tensor:
        return self.classify(codes)

    def drop(self, style: torch.Tensor, p: float, generator: torch.Generator | None = None) -> torch.Tensor:
        """Ids replaced by the null id, or codes by zero, with probability p (training for guidance)."""
        if p <= 0:
            return style
        drop = torch.rand(style.shape[0], device=style.device, generator=generator) < p
        if style.is_floating_point():
            return style * (~drop).to(style.dtype)[:, None]
        return torch.where(drop, torch.full_like(style, self.null_id), style)

    @torch.no_grad()
    def update_codes(self, codes: torch.Tensor, styles: torch.Tensor) -> None:
        """Move each style's stored code towards the mean of its `codes` in this batch."""
        for s in styles.unique().tolist():
            mean = codes[styles == s].mean(dim=0)
            old = self.codes[s]
            new = mean if not old.any() else CODE_MOMENTUM * old + (1 - CODE_MOMENTUM) * mean
            self.codes[s] = F.normalize(new, dim=0)


def reference_windows(
    features: torch.Tensor, styles: torch.Tensor, clips: list[str], min_share: float = 0.5
) -> tuple[torch.Tensor, torch.Tensor]:
    """For each window of a batch, a random crop of another window of the same style from another clip (a
    clip and its mirrored copy count as one); its own when the batch has none. Returns the crops
    (B, F', D), one random length F' in [min_share * F, F] for the batch, and which window each came
    from (B,). Draws from torch's global generator (seeded per batch by the training step)."""
    batch, frames = features.shape[:2]
    base = [c.split("#", 1)[0] for c in clips]
    ids = torch.tensor([base.index(b) for b in base], device=features.device)  # one id per clip
    same_style = styles[:, None] == styles[None, :]
    other_clip = ids[:, None] != ids[None, :]
    allowed = same_style & other_clip
    score = torch.rand(batch, batch, device=features.device).masked_fill(~allowed, -1.0)
    source = torch.where(allowed.any(dim=1), score.argmax(dim=1), torch.arange(batch, device=features.device))
    shortest = min(frames, max(8, int(min_share * frames)))
    length = int(torch.randint(shortest, frames + 1, ()).item())
    starts = torch.randint(0, frames - length + 1, (batch,)).to(features.device)
    steps = starts[:, None] + torch.arange(length, device=features.device)[None]
    return features[source[:, None], steps], source
