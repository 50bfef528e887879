"""Ancestral DDPM and DDIM samplers, inpainting and classifier-free guidance.

Both samplers share one loop. With x0_hat and eps_hat the network's estimates at step t, DDIM moves to
the previous (respaced) step s by

    x_s = sqrt(abar_s) x0_hat + sqrt(1 - abar_s - sigma^2) eps_hat + sigma z,
    sigma = eta sqrt((1 - abar_s) / (1 - abar_t)) sqrt(1 - abar_t / abar_s).

With every step kept and eta = 1 this is exactly the DDPM posterior q(x_{t-1} | x_t, x0_hat), so DDPM is
that special case. x0_hat and eps_hat are linear in (x_t, model output) for every prediction type, so a
step is x <- a x + b out + sigma z with a, b, sigma precomputed in float64: the per-step work besides the
network is a few elementwise ops.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from walkdiff.diffusion.gaussian import GaussianDiffusion
from walkdiff.errors import WalkdiffError

# model_fn(x_t, t) -> network output; t is a long tensor (B,) of trained timesteps.
ModelFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
# False, True (a tqdm bar) or a hook called as hook(steps_done, steps_total) after every step.
Progress = bool | Callable[[int, int], None]
# (mask, known_x0): where known_x0 is kept; the mask broadcasts to the sample's shape. A boolean mask
# holds its region at every step. A float mask m in [0, 1] holds an element while the step's t >= (1 - m) T:
# m = 1 always, m = 0.5 for the noisier half of the steps (the coarse motion is the known one, the
# detail is made anew), m = 0 never.
Inpaint = tuple[torch.Tensor, torch.Tensor]


@dataclass(frozen=True)
class SamplerSteps:
    """Per-step constants of a sampling run, in step order (descending t)."""

    timesteps: list[int]  # trained t fed to the network
    x_coef: list[float]  # a: weight of x_t
    out_coef: list[float]  # b: weight of the network output
    sigma: list[float]  # std of the fresh noise added
    sqrt_abar: list[float]  # q_sample constants at t, for inpainting
    sqrt_one_minus_abar: list[float]


def respace(num_timesteps: int, steps: int) -> list[int]:
    """`steps` trained timesteps, evenly spaced and descending, from T - 1 down to 0."""
    if not 1 <= steps <= num_timesteps:
        raise WalkdiffError(f"the number of sampling steps must be in [1, {num_timesteps}], got {steps}")
    return torch.linspace(num_timesteps - 1, 0, steps, dtype=torch.float64).round().long().tolist()


def _estimate_coefs(prediction: str, abar: float) -> tuple[float, float, float, float]:
    """(px, po, ex, eo) with x0_hat = px x_t + po out and eps_hat = ex x_t + eo out."""
    sa, sb = math.sqrt(abar), math.sqrt(1 - abar)
    if prediction == "eps":
        return 1 / sa, -sb / sa, 0.0, 1.0
    if prediction == "x0":
        return 0.0, 1.0, 1 / sb, -sa / sb
    return sa, -sb, sb, sa  # v


def step_coefficients(diffusion: GaussianDiffusion, timesteps: Sequence[int], eta: float) -> SamplerSteps:
    """Precompute the update x <- a x + b out + sigma z for each step of `timesteps` (descending)."""
    if eta < 0:
        raise WalkdiffError(f"eta must be >= 0, got {eta}")
    ts = list(timesteps)
    if (
        not ts
        or any(a <= b for a, b in zip(ts, ts[1:], strict=False))
        or ts[0] >= diffusion.num_timesteps
        or ts[-1] < 0
    ):
        raise WalkdiffError(
            f"timesteps must be strictly descending in [0, {diffusion.num_timesteps}), got {ts}"
        )
    abar = diffusion.alphas_cumprod64().tolist()
    steps = SamplerSteps(ts, [], [], [], [], [])
    for i, t in enumerate(ts):
        a_t = abar[t]
        a_s = abar[ts[i + 1]] if i + 1 < len(ts) else 1.0
        sigma = eta * math.sqrt((1 - a_s) / (1 - a_t) * (1 - a_t / a_s))
        c_x0, c_eps = math.sqrt(a_s), math.sqrt(max(1 - a_s - sigma**2, 0.0))
        px, po, ex, eo = _estimate_coefs(diffusion.prediction, a_t)
        steps.x_coef.append(c_x0 * px + c_eps * ex)
        steps.out_coef.append(c_x0 * po + c_eps * eo)
        steps.sigma.append(sigma)
        steps.sqrt_abar.append(math.sqrt(a_t))
        steps.sqrt_one_minus_abar.append(math.sqrt(1 - a_t))
    return steps


def _randn_like(x: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
    # A generator on another device (say a CPU generator for a CUDA model) draws there and is copied.
    if generator is None or generator.device == x.device:
        return torch.randn(x.shape, generator=generator, device=x.device, dtype=x.dtype)
    return torch.randn(x.shape, generator=generator, device=generator.device, dtype=x.dtype).to(x.device)


@torch.no_grad()
def run_steps(
    model_fn: ModelFn,
    diffusion: GaussianDiffusion,
    shape: Sequence[int] | None,
    steps: SamplerSteps,
    *,
    generator: torch.Generator | None = None,
    x_T: torch.Tensor | None = None,
    progress: Progress = False,
    inpaint: Inpaint | None = None,
) -> torch.Tensor:
    """Run the precomputed `steps` from x_T (default: N(0, I) of `shape`) and return the sample."""
    device = diffusion.betas.device
    if x_T is None:
        if shape is None:
            raise WalkdiffError("give the sample shape or x_T")
        x = _randn_like(torch.empty(tuple(shape), device=device), generator)
    else:
        if shape is not None and tuple(shape) != tuple(x_T.shape):
            raise WalkdiffError(f"x_T has shape {tuple(x_T.shape)} but the sample shape is {tuple(shape)}")
        x = x_T.to(device)
    total = len(steps.timesteps)
    t_table = torch.tensor(steps.timesteps, device=device).unsqueeze(1).repeat(1, x.shape[0])
    if inpaint is not None:
        mask, known = inpaint[0].to(device), inpaint[1].to(device=device, dtype=x.dtype)
        strength = mask.to(x.dtype) if mask.is_floating_point() else (mask != 0).to(x.dtype)
        final = strength >= 1

    order = range(total)
    if progress is True:
        from tqdm.auto import tqdm

        order = tqdm(order, desc="sampling", leave=False)
    for k in order:
        if inpaint is not None:
            # Keep the known region on the current noise level so the model sees a consistent x_t.
            noisy_known = (
                known * steps.sqrt_abar[k] + _randn_like(x, generator) * steps.sqrt_one_minus_abar[k]
            )
            held = strength >= 1 - steps.timesteps[k] / diffusion.num_timesteps
            x = torch.where(held, noisy_known, x)
        out = model_fn(x, t_table[k])
        x = x.mul(steps.x_coef[k]).add_(out, alpha=steps.out_coef[k])
        if steps.sigma[k] > 0:
            x.add_(_randn_like(x, generator), alpha=steps.sigma[k])
        if callable(progress):
            progress(k + 1, total)
    if inpaint is not None:
        x = torch.where(final, known, x)
    return x


def ddpm_sample(
    model_fn: ModelFn,
    diffusion: GaussianDiffusion,
    shape: Sequence[int] | None,
    *,
    generator: torch.Generator | None = None,
    x_T: torch.Tensor | None = None,
    progress: Progress = False,
    inpaint: Inpaint | None = None,
) -> torch.Tensor:
    """Ancestral sampling over all T steps (posterior variance beta_t (1 - abar_{t-1}) / (1 - abar_t))."""
    steps = step_coefficients(diffusion, range(diffusion.num_timesteps - 1, -1, -1), eta=1.0)
    return run_steps(
        model_fn, diffusion, shape, steps, generator=generator, x_T=x_T, progress=progress, inpaint=inpaint
    )


def ddim_sample(
    model_fn: ModelFn,
    diffusion: GaussianDiffusion,
    shape: Sequence[int] | None,
    steps: int = 50,
    eta: float = 0.0,
    *,
    generator: torch.Generator | None = None,
    x_T: torch.Tensor | None = None,
    progress: Progress = False,
    inpaint: Inpaint | None = None,
) -> torch.Tensor:
    """DDIM over `steps` evenly spaced trained timesteps (eta 0: deterministic; steps = T, eta 1: DDPM)."""
    table = step_coefficients(diffusion, respace(diffusion.num_timesteps, steps), eta)
    return run_steps(
        model_fn, diffusion, shape, table, generator=generator, x_T=x_T, progress=progress, inpaint=inpaint
    )


def guided(model_fn_cond: ModelFn, model_fn_uncond: ModelFn, w: float) -> ModelFn:
    """Classifier-free guidance with two calls: out = uncond + w (cond - uncond); w = 1 is cond alone."""
    if w == 1:
        return model_fn_cond

    def model_fn(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return torch.lerp(model_fn_uncond(x, t), model_fn_cond(x, t), w)

    return model_fn


def guided_batched(model_fn_pair: ModelFn, w: float) -> ModelFn:
    """Classifier-free guidance in one forward pass over 2B.

    model_fn_pair(x2, t2) receives the batch twice, [x; x] and [t; t], and must return
    [conditional output; unconditional output], e.g.
    ``lambda x, t: net(x, t, cond=torch.cat([c, null_c]))``.
    """

    def model_fn(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        cond, uncond = model_fn_pair(torch.cat([x, x]), torch.cat([t, t])).chunk(2)
        return torch.lerp(uncond, cond, w)

    return model_fn
