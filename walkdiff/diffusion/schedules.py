"""Noise schedules: the per-step variances beta_1..beta_T of the forward process."""

from __future__ import annotations

import math

import torch

from walkdiff.common.errors import WalkdiffError

SCHEDULES = ("linear", "cosine", "quad")

# Nichol & Dhariwal (2021): the offset keeps beta_1 from being vanishingly small, the cap keeps the
# last steps from destroying the signal in one go (abar_T -> 0 makes beta_T -> 1).
COSINE_OFFSET = 0.008
MAX_BETA = 0.999


def cosine_alphas_cumprod(t: torch.Tensor, T: int, s: float = COSINE_OFFSET) -> torch.Tensor:
    """abar(t) = f(t) / f(0) with f(t) = cos^2(((t / T) + s) / (1 + s) * pi / 2), for real t in [0, T]."""

    def f(u: torch.Tensor) -> torch.Tensor:
        return torch.cos((u / T + s) / (1 + s) * math.pi / 2) ** 2

    t = t.to(torch.float64)
    return f(t) / f(torch.zeros_like(t))


def beta_schedule(name: str, T: int, beta_start: float = 1e-4, beta_end: float = 0.02) -> torch.Tensor:
    """The betas of schedule `name` over T steps, float64, shape (T,).

    linear: evenly spaced from beta_start to beta_end. quad: evenly spaced in sqrt(beta) (DiffMotion
    uses 1e-4 to 0.1 with T=100). cosine: from the cosine abar curve (beta_start / beta_end unused).
    """
    if T < 1:
        raise WalkdiffError(f"the number of diffusion steps must be >= 1, got {T}")
    if name in ("linear", "quad") and not (0 < beta_start <= beta_end < 1):
        raise WalkdiffError(f"expected 0 < beta_start <= beta_end < 1, got {beta_start} and {beta_end}")
    if name == "linear":
        return torch.linspace(beta_start, beta_end, T, dtype=torch.float64)
    if name == "quad":
        return torch.linspace(beta_start**0.5, beta_end**0.5, T, dtype=torch.float64) ** 2
    if name == "cosine":
        abar = cosine_alphas_cumprod(torch.arange(T + 1), T)
        return (1 - abar[1:] / abar[:-1]).clamp(max=MAX_BETA)
    raise WalkdiffError(f"unknown beta schedule {name!r}; expected one of {', '.join(SCHEDULES)}")
