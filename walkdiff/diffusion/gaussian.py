"""The Gaussian forward process q(x_t | x_0) and the algebra that links a network's output to x_0 and eps.

Tensors have any shape (B, ...); per-sample timesteps t (shape (B,), integers in [0, T)) broadcast over
the trailing dimensions. Index t = 0 is the first noising step, so x_0 (the data) has no index here.
"""

from __future__ import annotations

import torch
from torch import nn

from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion.schedules import beta_schedule

PREDICTIONS = ("eps", "x0", "v")


def extract(values: torch.Tensor, t: torch.Tensor | int, like: torch.Tensor) -> torch.Tensor:
    """values[t] shaped (B, 1, ..., 1) to broadcast against `like` of shape (B, ...)."""
    t = torch.as_tensor(t, device=values.device)
    out = values[t]
    if out.ndim == 0:
        return out
    return out.reshape(out.shape[0], *([1] * (like.ndim - 1)))


class GaussianDiffusion(nn.Module):
    """A DDPM forward process with T steps and the prediction type of the network ('eps', 'x0' or 'v').

    The schedule is computed in float64 and stored as float32 buffers, so it follows the model to
    its device and is saved in checkpoints.
    """

    def __init__(
        self,
        timesteps: int = 100,
        schedule: str = "linear",
        beta_start: float = 1e-4,
        beta_end: float = 0.02,
        prediction: str = "eps",
    ):
        super().__init__()
        if timesteps < 2:
            raise WalkdiffError(f"a diffusion process needs at least 2 timesteps, got {timesteps}")
        if prediction not in PREDICTIONS:
            raise WalkdiffError(
                f"unknown prediction type {prediction!r}; expected one of {', '.join(PREDICTIONS)}"
            )
        self.num_timesteps = timesteps
        self.prediction = prediction

        betas = beta_schedule(schedule, timesteps, beta_start, beta_end)
        alphas = 1 - betas
        abar = torch.cumprod(alphas, 0)
        abar_prev = torch.cat([abar.new_ones(1), abar[:-1]])
        post_var = betas * (1 - abar_prev) / (1 - abar)

        buffers = {
            "betas": betas,
            "alphas_cumprod": abar,
            "alphas_cumprod_prev": abar_prev,
            "sqrt_alphas_cumprod": abar.sqrt(),
            "sqrt_one_minus_alphas_cumprod": (1 - abar).sqrt(),
            "sqrt_recip_alphas_cumprod": abar.rsqrt(),
            "sqrt_recipm1_alphas_cumprod": (1 / abar - 1).sqrt(),
            "posterior_variance": post_var,
            # The posterior variance is 0 at t = 0; repeat t = 1 so the log stays finite.
            "posterior_log_variance_clipped": torch.cat([post_var[1:2], post_var[1:]]).log(),
            "posterior_mean_coef1": betas * abar_prev.sqrt() / (1 - abar),
            "posterior_mean_coef2": (1 - abar_prev) * alphas.sqrt() / (1 - abar),
        }
        for name, value in buffers.items():
            self.register_buffer(name, value.to(torch.float32))

    def alphas_cumprod64(self) -> torch.Tensor:
        """abar_t in float64 on the CPU, recomputed from the betas (for precomputing sampler steps)."""
        return torch.cumprod(1 - self.betas.detach().to("cpu", torch.float64), 0)

    def q_sample(self, x0: torch.Tensor, t: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """x_t = sqrt(abar_t) x0 + sqrt(1 - abar_t) noise."""
        return (
            extract(self.sqrt_alphas_cumprod, t, x0) * x0
            + extract(self.sqrt_one_minus_alphas_cumprod, t, x0) * noise
        )

    def q_posterior(
        self, x0: torch.Tensor, x_t: torch.Tensor, t: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Mean, variance and (clipped) log-variance of q(x_{t-1} | x_t, x0)."""
        mean = (
            extract(self.posterior_mean_coef1, t, x_t) * x0 + extract(self.posterior_mean_coef2, t, x_t) * x_t
        )
        var = extract(self.posterior_variance, t, x_t)
        logvar = extract(self.posterior_log_variance_clipped, t, x_t)
        return mean, var, logvar

    def predict_x0(self, model_out: torch.Tensor, x_t: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """The clean sample implied by the network output (unclipped: data is normalised, not in [-1, 1])."""
        if self.prediction == "x0":
            return model_out
        if self.prediction == "eps":
            return (
                extract(self.sqrt_recip_alphas_cumprod, t, x_t) * x_t
                - extract(self.sqrt_recipm1_alphas_cumprod, t, x_t) * model_out
            )
        # v = sqrt(abar) eps - sqrt(1 - abar) x0  =>  x0 = sqrt(abar) x_t - sqrt(1 - abar) v
        return (
            extract(self.sqrt_alphas_cumprod, t, x_t) * x_t
            - extract(self.sqrt_one_minus_alphas_cumprod, t, x_t) * model_out
        )

    def predict_eps(self, model_out: torch.Tensor, x_t: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """The noise implied by the network output."""
        if self.prediction == "eps":
            return model_out
        if self.prediction == "x0":
            return (x_t - extract(self.sqrt_alphas_cumprod, t, x_t) * model_out) / extract(
                self.sqrt_one_minus_alphas_cumprod, t, x_t
            )
        return (
            extract(self.sqrt_one_minus_alphas_cumprod, t, x_t) * x_t
            + extract(self.sqrt_alphas_cumprod, t, x_t) * model_out
        )

    def training_target(self, x0: torch.Tensor, noise: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """What the network should output for x_t = q_sample(x0, t, noise)."""
        if self.prediction == "eps":
            return noise
        if self.prediction == "x0":
            return x0
        return (
            extract(self.sqrt_alphas_cumprod, t, x0) * noise
            - extract(self.sqrt_one_minus_alphas_cumprod, t, x0) * x0
        )

    def min_snr_weights(self, t: torch.Tensor, gamma: float) -> torch.Tensor:
        """Min-SNR-γ loss weights (Hang et al. 2023) of the network's output error at steps t, (B,).

        Every prediction type's squared error is that of x0 times a factor of the SNR ᾱ/(1−ᾱ); min-SNR
        makes the x0 error's weight min(SNR, γ): the steps near the data stop dominating, the steps near
        the noise (SNR < 1) count for less. Divided by the mean over all steps, so the term keeps the
        scale of a uniform weighting beside the other loss terms."""
        abar = self.alphas_cumprod.double()
        snr = abar / (1 - abar)
        per_step = {"x0": 1.0, "eps": snr, "v": snr + 1}[self.prediction]  # output error = x0 error / this
        weights = snr.clamp(max=gamma) / per_step
        return (weights / weights.mean()).to(self.alphas_cumprod.dtype)[t]

    def sample_timesteps(self, batch: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """Uniform training timesteps, shape (batch,), long, on the schedule's device."""
        device = self.betas.device if generator is None else generator.device
        t = torch.randint(0, self.num_timesteps, (batch,), generator=generator, device=device)
        return t.to(self.betas.device)

    def extra_repr(self) -> str:
        return f"timesteps={self.num_timesteps}, prediction={self.prediction!r}"
