"""Ancestral DDPM, DDIM and DPM-Solver++(2M) samplers, inpainting and classifier-free guidance.

Both samplers share one loop. With x0_hat and eps_hat the network's estimates at step t, DDIM moves to
the previous (respaced) step s by

    x_s = sqrt(abar_s) x0_hat + sqrt(1 - abar_s - sigma^2) eps_hat + sigma z,
    sigma = eta sqrt((1 - abar_s) / (1 - abar_t)) sqrt(1 - abar_t / abar_s).

With every step kept and eta = 1 this is exactly the DDPM posterior q(x_{t-1} | x_t, x0_hat), so DDPM is
that special case. x0_hat and eps_hat are linear in (x_t, model output) for every prediction type, so a
step is x <- a x + b out + sigma z with a, b, sigma precomputed in float64: the per-step work besides the
network is a few elementwise ops.

DPM-Solver++(2M) (Lu et al. 2022) solves the same ODE as DDIM at eta = 0 to second order: with
lambda = log(sqrt(abar) / sqrt(1 - abar)) and h = lambda_s - lambda_t, DDIM's step is
x_s = (sigma_s / sigma_t) x_t + sqrt(abar_s) (1 - e^-h) x0_hat, and 2M replaces x0_hat by the extrapolation
(1 + 1/2r) x0_hat - (1/2r) x0_hat_prev, r = h_prev / h, from the estimate of the step before. It costs
one network pass per step like DDIM and is much closer to the ODE's solution at 10 steps. Still linear:
x <- a x + b out + c x0_hat_prev.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion.gaussian import GaussianDiffusion

# model_fn(x_t, t) -> network output; t is a long tensor (B,) of trained timesteps.
ModelFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
# False, True (a progress bar) or a hook called as hook(steps_done, steps_total) after every
# step (walkdiff.common.progress.step_hook feeds one bar over many runs).
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
    prev_coef: list[float]  # c: weight of the previous step's x0 estimate (second order; 0 for DDIM)
    x0_x_coef: list[float]  # x0_hat = x0_x_coef x_t + x0_out_coef out, kept for the next step
    x0_out_coef: list[float]
    sqrt_abar: list[float]  # q_sample constants at t, for inpainting
    sqrt_one_minus_abar: list[float]


SAMPLERS = ("ddpm", "ddim", "dpmpp")
DEFAULT_STEPS = 10  # DDIM / DPM-Solver++ steps when none are given
# Guidance weights that still make motion are a few (1: none); far above, every sample is garbage and
# weights like 1e30 overflow to NaN. cli/options.py repeats it so that the parser imports no torch.
MAX_GUIDANCE = 100.0


@dataclass(frozen=True)
class SamplerChoice:
    """How a model samples, as a user names it (the one sampler spec of the API and every command):
    ancestral DDPM over all T trained steps, DDIM over `steps` of them (`eta` its noise: 0 deterministic,
    1 with every step kept is DDPM), or DPM-Solver++(2M) over `steps` spaced in log-SNR; `guidance` the
    classifier-free guidance weight (1: none; models without it take 1 only). Options a sampler does not
    use are refused."""

    name: str = "ddpm"
    steps: int | None = None  # DDIM / DPM-Solver++ steps (default DEFAULT_STEPS); unused by DDPM
    eta: float = 0.0  # DDIM noise
    guidance: float = 1.0

    def __post_init__(self) -> None:
        if self.name not in SAMPLERS:
            raise WalkdiffError(f"--sampler: expected one of {', '.join(SAMPLERS)}, got {self.name!r}")
        if self.name != "ddim" and self.eta != 0:
            raise WalkdiffError(
                f"--eta applies to ddim only ({self.name} sets its own noise), got {self.eta}"
            )
        if self.steps is not None and self.steps < 1:
            raise WalkdiffError(f"--steps must be at least 1, got {self.steps}")
        if self.name == "ddpm" and self.steps is not None:
            raise WalkdiffError("--steps applies to ddim and dpmpp: ddpm always takes every trained step")
        if not (math.isfinite(self.eta) and 0 <= self.eta <= 1):
            raise WalkdiffError(f"--eta must be in [0, 1], got {self.eta}")
        if not (math.isfinite(self.guidance) and 0 <= self.guidance <= MAX_GUIDANCE):
            raise WalkdiffError(
                f"--guidance must be a number in [0, {MAX_GUIDANCE:g}] (1: none; a few at most is useful), "
                f"got {self.guidance:g}"
            )

    @classmethod
    def of(cls, sampler=None, steps: int | None = None, eta: float = 0.0, guidance: float = 1.0):
        """The spec from what a caller gave: a name with the other settings beside it, a dict of them, or
        a SamplerChoice (then alone: its own steps, eta and guidance are the ones used)."""
        if isinstance(sampler, SamplerChoice):
            if (steps, eta, guidance) != (None, 0.0, 1.0):
                raise WalkdiffError("sampler: give steps, eta and guidance inside the SamplerChoice")
            return (
                sampler
                if type(sampler) is cls
                else cls(sampler.name, sampler.steps, sampler.eta, sampler.guidance)
            )
        if isinstance(sampler, dict):
            return cls.of(cls(**sampler), steps, eta, guidance)
        return cls("ddpm" if sampler is None else sampler, steps, eta, guidance)

    def record(self) -> dict:
        """What a manifest says of the sampler."""
        return {"sampler": self.name, "steps": self.steps, "eta": self.eta, "guidance": self.guidance}

    def unguided(self) -> SamplerChoice:
        """Itself, for a model without classifier-free guidance (the frame models): other weights refused."""
        if self.guidance != 1:
            raise WalkdiffError(
                f"--guidance: this model has no classifier-free guidance (1 only), got {self.guidance:g}"
            )
        return self

    def table(self, diffusion: GaussianDiffusion) -> SamplerSteps:
        """The per-step constants of this sampler over `diffusion`'s trained steps."""
        total = diffusion.num_timesteps
        if self.name == "ddpm":
            return step_coefficients(diffusion, range(total - 1, -1, -1), eta=1.0)
        steps = self.steps or DEFAULT_STEPS
        if self.name == "ddim":
            return step_coefficients(diffusion, respace(total, steps), self.eta)
        return step_coefficients(diffusion, log_snr_timesteps(diffusion, steps), 0.0, order=2)

    def label(self, diffusion: GaussianDiffusion) -> str:
        """'ddpm-100', 'ddim-10', 'ddim-10-eta0.5', 'dpmpp-10': the sampler and its network passes."""
        steps = diffusion.num_timesteps if self.name == "ddpm" else self.steps or DEFAULT_STEPS
        return f"{self.name}-{steps}" + (f"-eta{self.eta:g}" if self.eta else "")


def respace(num_timesteps: int, steps: int) -> list[int]:
    """`steps` trained timesteps, descending from T - 1 by T / steps ("trailing" spacing, Lin et al. 2024):
    100 steps in 2 are [99, 49], in 10 [99, 89, ..., 9]. The last step goes from T / steps - 1 to clean
    data; spacing that ends at t = 0 instead spends a whole step on the nearly clean t = 0 and leaves the
    others one step short (2 steps would be [99, 0]: a single real step)."""
    if not 1 <= steps <= num_timesteps:
        raise WalkdiffError(f"the number of sampling steps must be in [1, {num_timesteps}], got {steps}")
    return [round(num_timesteps - 1 - i * num_timesteps / steps) for i in range(steps)]


def step_jumps(num_timesteps: int, timesteps: Sequence[int], device=None) -> torch.Tensor:
    """(T,) long: at each of `timesteps` (descending, ending at 0), how many trained steps the sampler's
    step from there spans (the last, to clean data, spans one); 0 at the steps it skips."""
    jumps = torch.zeros(num_timesteps, dtype=torch.long, device=device)
    for t, s in zip(timesteps, [*timesteps[1:], -1], strict=True):
        jumps[t] = t - s
    return jumps


def log_snr_timesteps(diffusion: GaussianDiffusion, steps: int, first: int | None = None) -> list[int]:
    """`steps` trained timesteps from `first` (default T - 1) down to 0, evenly spaced in log-SNR lambda:
    the spacing DPM-Solver is derived for. Rounded to the trained grid and kept distinct, so where the
    grid is coarser than the spacing (the last, nearly clean steps) neighbours are pushed apart."""
    first = diffusion.num_timesteps - 1 if first is None else first
    if not 1 <= steps <= first + 1:
        raise WalkdiffError(f"the number of sampling steps must be in [1, {first + 1}], got {steps}")
    if first == 0:
        return [0]
    lam = [_log_snr(a) for a in diffusion.alphas_cumprod64()[: first + 1].tolist()]  # falling with t
    ts = []
    for target in torch.linspace(lam[first], lam[0], steps, dtype=torch.float64).tolist():
        # lambda -> t, interpolated between the trained steps t and t + 1 that bracket it.
        t = next((t for t in range(first) if lam[t + 1] <= target), first - 1)
        ts.append(round(t + min(max((lam[t] - target) / (lam[t] - lam[t + 1]), 0.0), 1.0)))
    for i in range(len(ts) - 2, -1, -1):  # distinct: push each above the next ...
        ts[i] = max(ts[i], ts[i + 1] + 1)
    return [min(t, first - i) for i, t in enumerate(ts)]  # ... and keep them within [0, first]


def _estimate_coefs(prediction: str, abar: float) -> tuple[float, float, float, float]:
    """(px, po, ex, eo) with x0_hat = px x_t + po out and eps_hat = ex x_t + eo out."""
    sa, sb = math.sqrt(abar), math.sqrt(1 - abar)
    if prediction == "eps":
        return 1 / sa, -sb / sa, 0.0, 1.0
    if prediction == "x0":
        return 0.0, 1.0, 1 / sb, -sa / sb
    return sa, -sb, sb, sa  # v


def step_coefficients(
    diffusion: GaussianDiffusion, timesteps: Sequence[int], eta: float, order: int = 1
) -> SamplerSteps:
    """Precompute the update x <- a x + b out + c x0_prev + sigma z for each step of `timesteps`
    (descending). order 1: DDIM (DDPM at eta 1 over every step); order 2: DPM-Solver++(2M), eta 0 only."""
    if eta < 0:
        raise WalkdiffError(f"eta must be >= 0, got {eta}")
    if order not in (1, 2) or (order == 2 and eta != 0):
        raise WalkdiffError(f"order must be 1, or 2 with eta 0 (a deterministic solver); got {order}, {eta}")
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
    steps = SamplerSteps(ts, [], [], [], [], [], [], [], [])
    h_prev = None
    for i, t in enumerate(ts):
        a_t = abar[t]
        a_s = abar[ts[i + 1]] if i + 1 < len(ts) else 1.0
        sigma = eta * math.sqrt((1 - a_s) / (1 - a_t) * (1 - a_t / a_s))
        c_x0, c_eps = math.sqrt(a_s), math.sqrt(max(1 - a_s - sigma**2, 0.0))
        px, po, ex, eo = _estimate_coefs(diffusion.prediction, a_t)
        a, b, c = c_x0 * px + c_eps * ex, c_x0 * po + c_eps * eo, 0.0
        h = _log_snr(a_s) - _log_snr(a_t) if a_s < 1 else math.inf
        if order == 2 and h_prev is not None and h < math.inf:
            # DDIM's x0 weight m = sqrt(abar_s) (1 - e^-h) goes to (1 + w) x0_hat - w x0_prev. The last
            # step (to abar = 1, h infinite) stays first order, as in the solver's reference setting.
            w, m = h / (2 * h_prev), c_x0 - math.sqrt((1 - a_s) / (1 - a_t) * a_t)
            a, b, c = a + m * w * px, b + m * w * po, -m * w
        h_prev = h
        steps.x_coef.append(a)
        steps.out_coef.append(b)
        steps.prev_coef.append(c)
        steps.x0_x_coef.append(px)
        steps.x0_out_coef.append(po)
        steps.sigma.append(sigma)
        steps.sqrt_abar.append(math.sqrt(a_t))
        steps.sqrt_one_minus_abar.append(math.sqrt(1 - a_t))
    return steps


def _log_snr(abar: float) -> float:
    """lambda = log(sqrt(abar) / sqrt(1 - abar)), the solver's time variable."""
    return 0.5 * math.log(abar / (1 - abar))


def randn_like(x: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
    """Standard normal noise of x's shape, dtype and device, from `generator` (the samplers' draws)."""
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
        x = randn_like(torch.empty(tuple(shape), device=device), generator)
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

    second_order, x0_prev = any(steps.prev_coef), None
    order = range(total)
    if progress is True:
        from walkdiff.common.progress import progress as bar

        order = bar(order, desc="sampling", unit="step")
    for k in order:
        if inpaint is not None:
            # Keep the known region on the current noise level so the model sees a consistent x_t.
            noisy_known = known * steps.sqrt_abar[k] + randn_like(x, generator) * steps.sqrt_one_minus_abar[k]
            held = strength >= 1 - steps.timesteps[k] / diffusion.num_timesteps
            x = torch.where(held, noisy_known, x)
        out = model_fn(x, t_table[k])
        x0_hat = _x0_estimate(x, out, steps.x0_x_coef[k], steps.x0_out_coef[k]) if second_order else None
        x = x.mul(steps.x_coef[k]).add_(out, alpha=steps.out_coef[k])
        if steps.prev_coef[k]:
            x.add_(x0_prev, alpha=steps.prev_coef[k])
        x0_prev = x0_hat
        if steps.sigma[k] > 0:
            x.add_(randn_like(x, generator), alpha=steps.sigma[k])
        if callable(progress):
            progress(k + 1, total)
    if inpaint is not None:
        x = torch.where(final, known, x)
    return x


def _x0_estimate(x: torch.Tensor, out: torch.Tensor, x_coef: float, out_coef: float) -> torch.Tensor:
    # An x0-predicting network's output is the estimate itself: no copy.
    return out if (x_coef, out_coef) == (0.0, 1.0) else x * x_coef + out * out_coef


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


def dpm_solver_sample(
    model_fn: ModelFn,
    diffusion: GaussianDiffusion,
    shape: Sequence[int] | None,
    steps: int = 10,
    *,
    generator: torch.Generator | None = None,
    x_T: torch.Tensor | None = None,
    progress: Progress = False,
    inpaint: Inpaint | None = None,
) -> torch.Tensor:
    """DPM-Solver++(2M) over `steps` trained timesteps evenly spaced in log-SNR (deterministic)."""
    table = step_coefficients(diffusion, log_snr_timesteps(diffusion, steps), 0.0, order=2)
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
