"""Motion-agnostic diffusion: noise schedules, the Gaussian forward process, samplers (DDPM, DDIM,
DPM-Solver++), guidance."""

from walkdiff.diffusion.gaussian import PREDICTIONS, GaussianDiffusion, extract
from walkdiff.diffusion.samplers import (
    DEFAULT_STEPS,
    SAMPLERS,
    Progress,
    SamplerChoice,
    SamplerSteps,
    ddim_sample,
    ddpm_sample,
    dpm_solver_sample,
    guided,
    guided_batched,
    log_snr_timesteps,
    randn_like,
    respace,
    run_steps,
    step_coefficients,
    step_jumps,
)
from walkdiff.diffusion.schedules import SCHEDULES, beta_schedule, cosine_alphas_cumprod

__all__ = [
    "DEFAULT_STEPS",
    "SAMPLERS",
    "SamplerChoice",
    "PREDICTIONS",
    "SCHEDULES",
    "GaussianDiffusion",
    "Progress",
    "SamplerSteps",
    "beta_schedule",
    "cosine_alphas_cumprod",
    "ddim_sample",
    "ddpm_sample",
    "dpm_solver_sample",
    "extract",
    "guided",
    "guided_batched",
    "log_snr_timesteps",
    "randn_like",
    "respace",
    "run_steps",
    "step_coefficients",
    "step_jumps",
]
