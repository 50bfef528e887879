"""How a trained GAN-DDPM makes motion of any length and restyles clips: windows, samplers, transfer.

The model denoises fixed windows (24 frames at 30 fps for Xia). Longer motion is made window after window:
each window after the first starts `overlap` frames before the end of what exists, and those frames are
inpainted, i.e. held to the frames already made while the rest is denoised around them. Features hold root
*velocities*, so the windows' features joined into one sequence decode to one continuous root path.

Transfer restyles a clip (SDEdit): its features are noised to step strength·T with q_sample and denoised
from there under the target style, window by window as above. The noise level sets how much of the
original survives: content and timing at 0.6, little but the path at 1.0. `keep_trajectory` inpaints the
root velocity and turning channels with the source's, so the restyled clip walks exactly the source's path.

styled/pipeline.py puts this behind one object (`walkdiff.load`); styled/commands.py writes its clips.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.progress import progress, step_hook
from walkdiff.diffusion import SamplerChoice, log_snr_timesteps, respace, run_steps, step_coefficients
from walkdiff.models.style_statistics import StyleStatistics
from walkdiff.motion.representation import FeatureLayout, features_to_positions
from walkdiff.motion.skeleton import Motion

# Inpainted (known) region of a window: (mask, values), both (B, frames, D), as the samplers take them.
Known = tuple[torch.Tensor, torch.Tensor]


@dataclass(frozen=True)
class Sampling(SamplerChoice):
    """The sampler spec of the window generator, and the example clips' statistics each window is moved to
    (--style-clip, models/style_statistics.py), which the request adds."""

    match: StyleStatistics | None = field(default=None, compare=False)

    @property
    def sampler(self) -> str:
        return self.name

    @property
    def order(self) -> int:
        """Order of the solver step (step_coefficients): 2 for DPM-Solver++, 1 for DDPM and DDIM."""
        return 2 if self.name == "dpmpp" else 1


def batch_of(labels: torch.Tensor, count: int) -> torch.Tensor:
    """One style id () or mixing vector (S,), or one content id, repeated for a batch."""
    return labels.expand(count, *labels.shape).clone()


def check_finite(clips: list[Motion], sampling: Sampling) -> None:
    """Refuse clips with NaN or infinite values, naming the setting that made them: no such clip is ever
    returned or written (a BVH of NaN reads as motion in no program)."""
    bad = [
        i
        for i, clip in enumerate(clips)
        if not (np.isfinite(clip.rotations).all() and np.isfinite(clip.positions).all())
    ]
    if not bad:
        return
    which = (
        f"clip {bad[0]}" if len(clips) == 1 else f"{len(bad)} of {len(clips)} clips, the first clip {bad[0]}"
    )
    if sampling.guidance != 1:
        raise WalkdiffError(
            f"--guidance {sampling.guidance:g} made non-finite motion (NaN or infinite values in {which}); "
            "use a lower guidance (1: none; a few at most is useful)"
        )
    raise WalkdiffError(
        f"the model made non-finite motion (NaN or infinite values in {which}, sampler {sampling.sampler}): "
        "its network may have diverged in training; try another checkpoint"
    )


# ---------------------------------------------------------------- windows


def window_plan(frames: int, window: int, overlap: int) -> list[tuple[int, int]]:
    """(start, known) per window: where it starts and how many of its first frames already exist.

    Windows advance by window - overlap; the last one is pulled back to end exactly at `frames` (so it may
    overlap more). A sequence no longer than a window is one window of its own length.
    """
    if frames < 1:
        raise WalkdiffError(f"--frames must be at least 1, got {frames}")
    if not 0 < overlap < window:
        raise WalkdiffError(f"the window overlap must be in [1, {window - 1}], got {overlap}")
    plan, done = [(0, 0)], min(window, frames)
    while done < frames:
        start = min(done - overlap, frames - window)
        plan.append((start, done - start))
        done = start + window
    return plan


def seam_steps(frames: int, window: int, overlap: int, blend: int = 0) -> list[int]:
    """Frame steps (t -> t + 1, by t) from a window's last held frame through its cross-fade."""
    return [
        start + known - blend - 1 + k
        for start, known in window_plan(frames, window, overlap)[1:]
        for k in range(min(blend, known - 1) + 1)
    ]


def split_seams(speeds: torch.Tensor, seams: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, steps) joint speeds -> (speeds of the steps inside windows, speeds of the seam steps)."""
    inside = torch.ones(speeds.shape[1], dtype=torch.bool)
    inside[seams] = False
    return speeds[:, inside], speeds[:, seams]


def seam_tails(speeds: torch.Tensor, seams: list[int]) -> tuple[float, float]:
    """Shares of the seam steps slower than the 5th and faster than the 95th percentile of the joint
    speeds inside windows, over (B, steps) speeds: 5% each where seams look like the rest."""
    inner, at_seams = split_seams(speeds, seams)
    low, high = inner.quantile(torch.tensor([0.05, 0.95], dtype=inner.dtype))
    return float((at_seams < low).double().mean()), float((at_seams > high).double().mean())


def seams_within_spread(speeds: torch.Tensor, seams: list[int]) -> bool:
    """No visible seam: the seam steps' joint speeds lie within the spread of those inside windows, i.e.
    no more than 10% of them (twice the 5% of a seamless clip) beyond either end of its 5-95% band.
    A jump or a halt at the seams puts most of them beyond it."""
    return max(seam_tails(speeds, seams)) <= 0.10


def joint_speeds(model, x: torch.Tensor) -> torch.Tensor:
    """Mean joint speed (units/s) of each step between frames of normalised features (B, F, D): (B, F - 1)."""
    skeleton = model.skeleton
    raw = torch.from_numpy(model.to_raw(x, grounded=False)).double()  # a vertical shift keeps speeds
    positions = features_to_positions(raw, torch.from_numpy(skeleton.offsets), skeleton.parents)
    return (positions[:, 1:] - positions[:, :-1]).norm(dim=-1).mean(-1) * model.spec["fps"]


def resolve_windows(window: int, overlap: int | None, blend: int | None) -> tuple[int, int]:
    """The overlap (default half the window: its first half held as context for the gait, its second
    half softly held and cross-faded) and the cross-fade (default half the overlap), checked.
    `walkdiff bench sample` measures the seams of this and of a third of the window."""
    overlap = overlap or max(1, window // 2)
    if not 0 < overlap < window:
        raise WalkdiffError(
            f"--overlap must be in [1, {window - 1}] for {window}-frame windows, got {overlap}"
        )
    blend = overlap // 2 if blend is None else blend
    if not 0 <= blend < overlap:
        raise WalkdiffError(f"--blend must be in [0, {overlap - 1}] (less than the overlap), got {blend}")
    return overlap, blend


def windowed(
    batch: int,
    frames: int,
    dim: int,
    window: int,
    overlap: int,
    denoise: Callable[[int, int, Known | None], torch.Tensor],
    blend: int = 0,
) -> torch.Tensor:
    """(B, frames, D) made window by window; denoise(start, stop, known) returns the window [start, stop).

    Of the frames a window shares with what exists, the first are held (inpainted) and the last `blend`
    are made anew and cross-faded from the old frames to the new ones, so the step where the window's
    own motion takes over is spread over `blend` frames.
    """
    out = torch.zeros(batch, frames, dim)
    for start, known in window_plan(frames, window, overlap):
        stop = start + min(window, frames)
        if not known:
            out[:, start:stop] = denoise(start, stop, None).float().cpu()
            continue
        fade = min(blend, known - 1)
        held = known - fade
        # Held frames are kept at every denoising step; fade frame j of `fade` is kept for the noisiest
        # (fade + 1 - j) / (fade + 1) of the steps, so its coarse motion is the old one's and the two
        # agree before they are cross-faded (a cross-fade between disagreeing frames adds speed).
        weight = torch.arange(1, fade + 1, dtype=torch.float32).div(fade + 1)[:, None]
        mask = torch.zeros(batch, stop - start, dim)
        mask[:, :held] = 1.0
        mask[:, held:known] = 1 - weight
        new = denoise(start, stop, (mask, out[:, start:stop].clone())).float().cpu()
        old = out[:, start + held : start + known]
        out[:, start + held : start + known] = old + weight * (new[:, held:known] - old)
        out[:, start + known : stop] = new[:, known:]
    return out


def generate_long(
    model,
    style: torch.Tensor,
    content: torch.Tensor,
    frames: int,
    sampling: Sampling = Sampling(),
    generator: torch.Generator | None = None,
    overlap: int | None = None,
    blend: int | None = None,
    style_at: Callable[[int, int], torch.Tensor] | None = None,
) -> torch.Tensor:
    """Normalised features (B, frames, D) of any length from a model whose `generate` makes windows,
    with a progress bar over windows x denoising steps. `style_at(start, stop)`: each window's style
    (a timeline), instead of `style` for all."""
    window = model.spec["window"]
    overlap, blend = resolve_windows(window, overlap, blend)
    windows = len(window_plan(frames, window, overlap))  # a bad length fails before the bar opens
    wanted, frames = frames, max(frames, window)  # fewer: the first frames of a whole window (short_note)
    bar = progress(desc="sampling", unit="step")
    hook = step_hook(bar, windows)

    def denoise(start: int, stop: int, inpaint: Known | None) -> torch.Tensor:
        return model.generate(
            style if style_at is None else style_at(start, stop),
            content,
            stop - start,
            sampler=sampling.sampler,
            steps=sampling.steps,
            eta=sampling.eta,
            guidance=sampling.guidance,
            generator=generator,
            inpaint=inpaint,
            progress=hook,
            match=sampling.match,
        )

    with bar:
        out = windowed(style.shape[0], frames, model.spec["feature_dim"], window, overlap, denoise, blend)
    return out[:, :wanted]


def short_note(frames: int, window: int, fps: float) -> str | None:
    """What sampling fewer frames than the model's window does, for the user; None for a window or more.
    A whole window is made and its first frames kept: the model only ever learned whole windows, and a
    shorter one costs the same steps."""
    if frames >= window:
        return None
    return (
        f"--frames {frames} ({frames / fps:.2f} s) is less than the model's {window}-frame window "
        f"({window / fps:.2f} s): one whole window is made and its first {frames} frames are kept"
    )


def noised_steps(model, strength: float, sampling: Sampling) -> tuple[int, list[int], float]:
    """(t0, timesteps from t0 down to 0, eta) of a transfer at `strength` in (0, 1]."""
    if not 0 < strength <= 1:
        raise WalkdiffError(f"--strength must be in (0, 1], got {strength}")
    total = model.diffusion.num_timesteps
    t0 = max(1, round(strength * total)) - 1
    if sampling.sampler == "ddpm":
        return t0, list(range(t0, -1, -1)), 1.0
    # DDIM and DPM-Solver++ keep their step density: K steps over all of T become ~K·strength below t0.
    steps = min(max(1, round((sampling.steps or 10) * (t0 + 1) / total)), t0 + 1)
    if sampling.sampler == "dpmpp":
        return t0, log_snr_timesteps(model.diffusion, steps, t0), 0.0
    return t0, respace(t0 + 1, steps), sampling.eta


def restyle(
    model,
    source: torch.Tensor,
    style: torch.Tensor,
    content: torch.Tensor,
    strength: float = 0.6,
    sampling: Sampling = Sampling(),
    generator: torch.Generator | None = None,
    keep_trajectory: bool = False,
    overlap: int | None = None,
    blend: int | None = None,
) -> torch.Tensor:
    """Normalised source features (B, F, D) noised to strength·T and denoised under `style` and `content`."""
    diffusion = model.diffusion
    t0, timesteps, eta = noised_steps(model, strength, sampling)
    table = step_coefficients(diffusion, timesteps, eta, sampling.order)
    model_fn = model.model_fn(style, content, sampling.guidance, match=sampling.match)
    layout = FeatureLayout.from_dim(source.shape[-1])
    window = model.spec["window"]
    overlap, blend = resolve_windows(window, overlap, blend)
    batch, frames, dim = source.shape
    windows = len(window_plan(frames, window, overlap))  # a bad length fails before the bar opens
    bar = progress(desc="transfer", unit="step")
    hook = step_hook(bar, windows)
    root = torch.zeros(source.shape[-1], dtype=torch.bool)
    root[layout.root_vel] = root[layout.heading_vel] = True
    device = diffusion.betas.device

    def denoise(start: int, stop: int, inpaint: Known | None) -> torch.Tensor:
        x0 = source[:, start:stop].to(device)
        # Hold strengths as `windowed` gives them (1: held, in (0, 1): softly held); the root path is held.
        mask = torch.zeros(x0.shape) if inpaint is None else inpaint[0].float()
        known = torch.zeros(x0.shape) if inpaint is None else inpaint[1]
        if keep_trajectory:
            known = torch.where(root & (mask < 1), x0.cpu(), known)
            mask = torch.where(root, 1.0, mask)
        draw_on = x0.device if generator is None else generator.device
        noise = torch.randn(x0.shape, generator=generator, device=draw_on).to(device)
        x_t = diffusion.q_sample(x0, torch.full((x0.shape[0],), t0, device=device), noise)
        inpainted = (mask, known) if mask.any() else None
        return run_steps(
            model_fn, diffusion, None, table, generator=generator, x_T=x_t, inpaint=inpainted, progress=hook
        )

    with bar:
        return windowed(batch, frames, dim, window, overlap, denoise, blend)


# ---------------------------------------------------------------- loading


def load_generator(path: str | Path, device: str = "cpu"):
    """A trained StyledMotionDiffusion with the skeleton it writes BVH on."""
    from walkdiff.models.styled_ddpm import StyledMotionDiffusion

    return StyledMotionDiffusion.from_trained(path, "generator", device)
