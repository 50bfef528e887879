"""The styled walking GAN-DDPM (Findlay et al., MIG 2023) as a LightningModule with manual optimization.

Loss of the generator (the denoiser), per batch:
    L = ||target - net(x_t, t, c, s)||^2                          (target: eps, x0 or v; the paper: eps)
        + lambda_contact * w_t * ||contacts(x0_hat) - contacts(x0)||^2
        + lambda_root    * w_t * ||root(x0_hat) - root(x0)||^2   (root integrated from velocities;
                                                                     in contact heights, like P below)
        + lambda_adv     * w_t * 1/2 (D(x0_hat) - 1)^2                (LSGAN)
    beyond the paper, on world joint positions P = FK(x0_hat) (the root integrated, then the skeleton):
        + lambda_velocity * w_t * ||dP(x0_hat) - dP(x0)||^2           (joint velocities)
        + lambda_foot     * w_t * ||dP_feet(x0_hat)||^2 where x0's foot is in contact  (no sliding)
        + lambda_foot_height * w_t * ||P_feet,y(x0_hat) - P_feet,y(x0)||^2   (how high the feet swing)
        + lambda_low_foot * w_t * max(|dP_feet,xz(x0_hat)| - 1, 0) where x0_hat's own foot is near the ground
        + lambda_foot_velocity * w_t * ||dP_feet(x0_hat) - dP_feet(x0)||^2  (feet as fast as real ones)
        + lambda_position * w_t * ||(P - P_root)(x0_hat) - (P - P_root)(x0)||^2  (the pose's geometry)
The position terms measure velocities in multiples of the skeleton profile's contact speed threshold
(0.326 leg lengths/s: 4.8 units/s for Xia) and positions in contact heights (0.0326 leg lengths), so they
are unitless whatever the skeleton's size and units; a foot that slides at the
threshold speed costs 1.
The paper's losses constrain root and contact labels but not the legs, so its stance feet slide: the
foot term is the foot-contact loss of MDM (Tevet et al. 2023), which is what the skating metric checks.
The foot-height term weighs the feet's world heights on their own: in the position term they are 4 of
the skeleton's joints and relative to the root, and a swinging foot that skims the ground (a toe that
drags) is foot skating by the geometric rule that judges real and generated motion alike. The low-foot
term applies that rule to the prediction itself: the foot term stops a foot where the real clip plants
one, but a sample is no one real clip, and its feet skim the floor where real ones are in the air.
The discriminator sees real x0 against detached x0_hat: 1/2 (D(x0) - 1)^2 + 1/2 w_t D(x0_hat)^2.

Why w_t = alpha_bar_t: with eps-prediction, x0_hat = (x_t - sqrt(1 - abar) eps_hat) / sqrt(abar), so an
error e in eps becomes an error sqrt((1 - abar) / abar) e in x0_hat: at t near T (abar ~ 2e-5 for the
default schedule) that is ~200 e. Multiplying the squared x0-space terms by abar_t caps them at
(1 - abar_t) e^2, no larger than the eps loss itself, while keeping them at full weight for small t,
where x0_hat is a meaningful motion. It is smooth (no threshold to tune) and needs no extra head.

Step counting: each batch steps the discriminator and then the generator, but only the generator's step
is counted (`_step_uncounted`), so `trainer.global_step`, `max_steps`, `val_check_interval`, the warm-ups
and the LR schedule all count batches: the configs bound training by batches, whatever the data's size.
"""

from __future__ import annotations

import logging
import math
import os

import numpy as np
import torch
import torch.nn.functional as F
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion import (
    DEFAULT_STEPS,
    GaussianDiffusion,
    Progress,
    ddim_sample,
    ddpm_sample,
    dpm_solver_sample,
    guided,
    guided_batched,
    randn_like,
    respace,
    run_steps,
    step_coefficients,
    step_jumps,
)
from walkdiff.models.base import MotionModule
from walkdiff.models.body_terms import at_least_float32
from walkdiff.models.denoiser import CONDITIONING, MotionDenoiser
from walkdiff.models.discriminator import MotionDiscriminator
from walkdiff.models.style_encoder import reference_windows
from walkdiff.models.style_statistics import StyleStatistics
from walkdiff.motion.footfix import ground, ground_tolerance, planted_heights
from walkdiff.motion.representation import decode_root
from walkdiff.spec import DataSpec

log = logging.getLogger(__name__)


# Discriminator terms as charted: its LSGAN loss and its mean outputs on real and generated windows.
DISCRIMINATOR_TERMS = {"d": "discriminator", "d_real": "discriminator_real", "d_fake": "discriminator_fake"}


class TrainingDiverged(RuntimeError):
    """A loss term became NaN or infinite; the message names the batch and the term."""


class StyledMotionDiffusion(MotionModule):
    def __init__(
        self,
        data_spec: DataSpec | dict | None = None,
        d_model: int = 256,
        layers: int = 4,
        heads: int = 4,
        dropout: float = 0.1,
        conditioning: str = "prefix",  # how step, content and style enter the denoiser (models/denoiser.py)
        timesteps: int = 100,
        schedule: str = "linear",
        beta_start: float = 1e-3,
        beta_end: float = 0.2,
        prediction: str = "eps",
        min_snr_gamma: float | None = None,  # Min-SNR-γ weighting of the diffusion term; None: uniform
        lambda_contact: float = 1.0,
        lambda_root: float = 1.0,
        lambda_adv: float = 0.05,
        lambda_velocity: float = 0.0,
        lambda_foot: float = 0.0,
        lambda_foot_height: float = 0.0,
        lambda_low_foot: float = 0.0,
        lambda_foot_velocity: float = 0.0,
        lambda_position: float = 0.0,
        adv_warmup_batches: int = 500,
        discriminator_windows: int | None = None,  # N of a batch's windows judged by D; None: all
        cond_drop: float = 0.1,
        conditional_discriminator: bool = True,
        lr: float = 2e-4,
        lr_discriminator: float = 2e-4,
        weight_decay: float = 0.0,
        lr_warmup_batches: int = 100,
        grad_clip: float = 1.0,
        ema_decay: float = 0.999,
        distilled_steps: list[int] | int = 0,  # set by `walkdiff distill`: DDIM over these step counts jumps
        style_code_dim: int = 0,  # > 0: style also from example clips, codes of this size (style_encoder.py)
        lambda_style_code: float = 0.1,
        style_crop_min: float = 0.5,
    ):
        super().__init__(data_spec)
        self.save_hyperparameters(ignore=["data_spec"], logger=False)  # the run logs its config (run_params)
        self.hparams["data_spec"] = spec = self.spec
        self.automatic_optimization = False
        if min_snr_gamma is not None and not min_snr_gamma > 0:
            raise WalkdiffError(
                f"model.min_snr_gamma: expected a number > 0 (5 is usual) or null, got {min_snr_gamma}"
            )
        if discriminator_windows is not None and discriminator_windows < 1:
            raise WalkdiffError(
                f"model.discriminator_windows: expected >= 1 or null, got {discriminator_windows}"
            )
        if conditioning not in CONDITIONING:
            raise WalkdiffError(
                f"model.conditioning: expected one of {', '.join(CONDITIONING)}, got {conditioning!r}"
            )

        self.diffusion = GaussianDiffusion(timesteps, schedule, beta_start, beta_end, prediction)
        num_styles, num_contents = len(spec["styles"]), len(spec["contents"])

        def denoiser(dropout: float, jump_conditioning: bool) -> MotionDenoiser:
            return MotionDenoiser(spec["feature_dim"], num_styles, num_contents, d_model, layers, heads, 4,
                                  dropout, jump_conditioning, style_code_dim, conditioning)  # fmt: skip

        self.denoiser = denoiser(dropout, jump_conditioning=bool(self.distilled_steps))
        # The windows the discriminator judges, its step and the adversarial term alike: the first N of
        # a batch (a random subset, batches being drawn in random order), or all.
        self.judged = slice(None, discriminator_windows)
        self.discriminator = (
            MotionDiscriminator(
                spec["feature_dim"], num_styles, num_contents, conditional=conditional_discriminator
            )
            if lambda_adv > 0
            else None
        )
        self.ema = AveragedModel(
            self.denoiser, multi_avg_fn=get_ema_multi_avg_fn(ema_decay), use_buffers=True
        )
        self.ema.requires_grad_(False)
        # A distilled student carries its teacher's network, frozen: every sampler the student was not
        # distilled for (DDPM, DPM-Solver++, other DDIM counts, transfer, --fix-feet) samples the teacher.
        self.teacher = None
        if self.distilled_steps:
            self.teacher = denoiser(0.0, jump_conditioning=False).requires_grad_(False)
        # Where real planted feet stand (contact joints, data units): generated clips are grounded to it.
        # Measured on the unmirrored training clips: a mirrored copy keeps Xia's asymmetric offsets, so
        # its feet stand up to ~0.2 units off where a real foot on that side does.
        self.register_buffer("planted_height", torch.zeros(4))
        # How far real windows' planted feet stand from it by the same measure: moved only beyond that.
        self.register_buffer("ground_tolerance", torch.zeros(()))
        self.grounded_heights = True

    def setup(self, stage: str) -> None:
        super().setup(stage)
        datamodule = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if stage == "fit" and datamodule is not None:
            train = [f for _, _, f in datamodule.split_features("train")]
            heights = planted_heights(train, self.skeleton, self.contact_spec)
            never = [n for n, h in zip(self.contact_spec.joints, heights, strict=True) if np.isnan(h)]
            if never:
                log.warning(f"contact joints never planted in the training data: {', '.join(never)}; "
                            "grounding of generated clips leaves them out")  # fmt: skip
            self.planted_height.copy_(torch.from_numpy(heights))
            window = datamodule.hparams.window
            tolerance = ground_tolerance(train, self.skeleton, self.contact_spec, heights, window)
            self.ground_tolerance.fill_(tolerance)

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        super().on_load_checkpoint(checkpoint)
        if self.distilled_steps and not any(k.startswith("teacher.") for k in checkpoint["state_dict"]):
            raise WalkdiffError(
                "a student distilled before walkdiff kept the teacher's network in it; distil it again "
                "with `walkdiff distill`"
            )
        # Checkpoints saved before walkdiff measured planted feet load, but cannot be grounded.
        self.grounded_heights = "planted_height" in checkpoint["state_dict"]
        checkpoint["state_dict"].setdefault("planted_height", torch.full((4,), float("nan")))
        # Saved before the tolerance was measured: grounded by the whole shift, as they were then.
        checkpoint["state_dict"].setdefault("ground_tolerance", torch.zeros(()))

    @property
    def batches_done(self) -> int:
        return self.global_step  # one counted optimizer step per batch (see `_step_uncounted`)

    def _step_uncounted(self, optimizer) -> None:
        """Steps `optimizer` (a LightningOptimizer) the way its own `step` does, through the strategy and
        its precision plugin, but without Lightning's optimizer-step counter."""
        self.trainer.strategy.optimizer_step(optimizer.optimizer, lambda: None, model=self)

    # ---------------------------------------------------------------- losses

    def _noisy(self, x0: torch.Tensor, generator: torch.Generator | None = None):
        t = torch.randint(
            0, self.diffusion.num_timesteps, (x0.shape[0],), device=x0.device, generator=generator
        )
        noise = torch.randn(x0.shape, device=x0.device, generator=generator)
        return t, noise, self.diffusion.q_sample(x0, t, noise)

    @property
    def uses_positions(self) -> bool:
        h = self.hparams
        return max(h.lambda_velocity, h.lambda_foot, h.lambda_foot_height, h.lambda_low_foot,
                   h.lambda_foot_velocity, h.lambda_position) > 0  # fmt: skip

    @property
    def contact_spec(self):
        return self.profile.contacts

    def denoise(
        self,
        batch: dict,
        net=None,
        cond_drop: float = 0.0,
        generator: torch.Generator | None = None,
        style: torch.Tensor | None = None,
    ):
        """Noise x0 to a random level and run the network: (output, its target, x0_hat, t). `style`: codes
        to condition on instead of the batch's labels."""
        net = net or self.denoiser
        x0 = batch["features"]
        t, noise, x_t = self._noisy(x0, generator)
        style = net.style.drop(batch["style"] if style is None else style, cond_drop)
        content = net.content.drop(batch["content"], cond_drop)
        out = net(x_t, t, style, content)
        return out, self.diffusion.training_target(x0, noise, t), self.diffusion.predict_x0(out, x_t, t), t

    def generator_losses(
        self, batch: dict, out, target, x0_hat, t, adversarial: bool
    ) -> dict[str, torch.Tensor]:
        h = self.hparams
        weight = self.diffusion.alphas_cumprod[t]  # (B,), see the module docstring
        out, x0_hat = at_least_float32(out), at_least_float32(x0_hat)  # under bf16 autocast too
        raw_hat = self.normalizer.denormalize(x0_hat)
        raw = self.normalizer.denormalize(batch["features"])
        contacts = self.layout.contacts
        losses = {
            "diffusion": self._diffusion_loss(out, target, t),
            "contact": (
                weight * (raw_hat[..., contacts] - raw[..., contacts]).pow(2).mean(dim=(1, 2))
            ).mean(),
            "root": (
                weight
                * self.body_terms.in_heights(decode_root(raw_hat) - decode_root(raw)).pow(2).mean(dim=(1, 2))
            ).mean(),
        }
        if self.uses_positions:
            body = self.body_terms
            positions_hat = body.positions(raw_hat)
            with torch.no_grad():
                positions = body.positions(raw)
            velocity_hat, velocity = body.velocities(positions_hat), body.velocities(positions)
            losses["velocity"] = (weight * (velocity_hat - velocity).pow(2).mean(dim=(1, 2, 3))).mean()
            pose_error = (body.pose(positions_hat) - body.pose(positions)).pow(2).mean(dim=(1, 2, 3))
            losses["position"] = (weight * pose_error).mean()
            # A foot is planted over a step when the real motion labels it in contact at both ends.
            planted = raw[..., contacts] > 0.5
            planted = (planted[:, 1:] & planted[:, :-1]).to(raw.dtype)
            losses["foot"] = (weight * body.foot_slide(velocity_hat, planted).mean(dim=(1, 2))).mean()
            if h.lambda_foot_height > 0:
                height_error = body.foot_height_error(positions_hat, positions)
                losses["foot_height"] = (weight * height_error.pow(2).mean(dim=(1, 2))).mean()
            if h.lambda_low_foot > 0:
                low_slide = body.low_foot_slide(positions_hat, velocity_hat, self.planted_height)
                losses["low_foot"] = (weight * low_slide.mean(dim=(1, 2))).mean()
            if h.lambda_foot_velocity > 0:
                feet_error = body.foot_velocity_error(velocity_hat, velocity).pow(2).sum(-1)
                losses["foot_velocity"] = (weight * feet_error.mean(dim=(1, 2))).mean()
        if adversarial:
            j = self.judged
            fake = self.discriminator(x0_hat[j], batch["style"][j], batch["content"][j])
            losses["adv"] = (weight[j] * 0.5 * (fake - 1).pow(2)).mean()
        return losses

    def _diffusion_loss(self, out: torch.Tensor, target: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """The network's squared error, uniform over noise levels or Min-SNR-γ weighted."""
        gamma = self.hparams.min_snr_gamma
        if gamma is None:
            return F.mse_loss(out, target)
        error = (out - target).pow(2).mean(dim=tuple(range(1, out.ndim)))
        return (self.diffusion.min_snr_weights(t, gamma) * error).mean()

    def total_loss(self, losses: dict[str, torch.Tensor]) -> torch.Tensor:
        h = self.hparams
        lambdas = {
            "diffusion": 1.0,
            "contact": h.lambda_contact,
            "root": h.lambda_root,
            "velocity": h.lambda_velocity,
            "foot": h.lambda_foot,
            "foot_height": h.lambda_foot_height,
            "low_foot": h.lambda_low_foot,
            "foot_velocity": h.lambda_foot_velocity,
            "position": h.lambda_position,
            "adv": h.lambda_adv,
            "style_code": h.lambda_style_code,
        }
        return sum(lambdas[k] * v for k, v in losses.items())

    def discriminator_loss(
        self, batch: dict, x0_hat: torch.Tensor, t: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        j = self.judged
        weight = self.diffusion.alphas_cumprod[t[j]]
        style, content = batch["style"][j], batch["content"][j]
        real = self.discriminator(batch["features"][j], style, content)
        fake = self.discriminator(x0_hat[j].detach(), style, content)
        loss = 0.5 * (real - 1).pow(2).mean() + (weight * 0.5 * fake.pow(2)).mean()
        return {"d": loss, "d_real": real.mean().detach(), "d_fake": fake.mean().detach()}

    def _check_finite(self, losses: dict[str, torch.Tensor]) -> None:
        for name, value in losses.items():
            if not torch.isfinite(value):
                raise TrainingDiverged(
                    f"loss term {name!r} is {value.item()} at batch {self.batches_done} "
                    f"(epoch {self.current_epoch}, global step {self.global_step}); lower the learning rate "
                    "or lambda_" + name
                )

    # ---------------------------------------------------------------- training

    def training_step(self, batch: dict, batch_idx: int) -> None:
        h = self.hparams
        # The noise, noise levels, label dropout and dropout of batch b depend only on (seed, b, rank),
        # so an interrupted and resumed run draws exactly what an uninterrupted one does.
        seed = int(os.environ.get("PL_GLOBAL_SEED", 0))
        torch.manual_seed(hash((seed, self.batches_done, self.global_rank)) % 2**63)
        optimizers = self.optimizers()
        schedulers = self.lr_schedulers()
        opt_g, opt_d = (optimizers, None) if self.discriminator is None else optimizers
        sched_g, sched_d = (schedulers, None) if self.discriminator is None else schedulers

        x0 = batch["features"]
        crops = codes = None
        if self.denoiser.style_encoder is not None:  # conditioned on another clip of the same style
            crops, _ = reference_windows(x0, batch["style"], batch["clip"], h.style_crop_min)
            codes = self.denoiser.style_encoder(crops)
        out, target, x0_hat, t = self.denoise(batch, cond_drop=h.cond_drop, style=codes)

        logs: dict[str, torch.Tensor] = {}
        if self.discriminator is not None:
            d_losses = self.discriminator_loss(batch, x0_hat, t)
            self._check_finite({"d": d_losses["d"]})
            opt_d.zero_grad(set_to_none=True)
            self.manual_backward(d_losses["d"])
            self.clip_gradients(opt_d, gradient_clip_val=h.grad_clip, gradient_clip_algorithm="norm")
            self._step_uncounted(opt_d)
            sched_d.step()
            logs |= {f"{DISCRIMINATOR_TERMS[k]}/train": v for k, v in d_losses.items()}

        adversarial = self.discriminator is not None and self.batches_done >= h.adv_warmup_batches
        losses = self.generator_losses(batch, out, target, x0_hat, t, adversarial)
        if codes is not None:
            losses["style_code"] = F.cross_entropy(self.denoiser.style.logits(codes), batch["style"])
        self._check_finite(losses)
        total = self.total_loss(losses)
        opt_g.zero_grad(set_to_none=True)
        self.manual_backward(total)
        self.clip_gradients(opt_g, gradient_clip_val=h.grad_clip, gradient_clip_algorithm="norm")
        opt_g.step()
        sched_g.step()
        self.ema.update_parameters(self.denoiser)
        if crops is not None:
            self._update_style_codes(crops, batch["style"])

        # One metric per term, named `<term>/<split>` as in validation, so MLflow shows a term's train and
        # val charts side by side; per step only (an epoch mean of the same numbers would chart them twice).
        logs |= {f"{k}/train": v.detach() for k, v in losses.items()}
        logs["total/train"] = total.detach()
        logs["lr"] = torch.tensor(sched_g.get_last_lr()[0])
        self.log_dict(
            logs, prog_bar=False, on_step=True, on_epoch=False, sync_dist=True, batch_size=x0.shape[0]
        )
        self.log("loss", total.detach(), prog_bar=True, on_step=True, on_epoch=False, logger=False)

    @torch.no_grad()
    def _update_style_codes(self, crops: torch.Tensor, styles: torch.Tensor) -> None:
        """The labels' stored codes, from the EMA encoder (what sampling uses), kept equal in the live
        denoiser so that the EMA's averaging of buffers leaves them as they are."""
        ema = self.ema.module
        ema.style.update_codes(ema.style_encoder(crops), styles)
        self.denoiser.style.codes.copy_(ema.style.codes)

    @torch.no_grad()
    def style_code(self, windows: torch.Tensor | None) -> torch.Tensor | None:
        """One unit code (code_dim,) of normalised feature windows (N, F, D) of example motion: the
        direction of the mean of their codes (None for None: only whether the model takes examples)."""
        ema = self.ema.module.eval()
        if ema.style_encoder is None:
            raise WalkdiffError(
                "this model takes style labels only: it was trained without a style encoder "
                "(model.style_code_dim 0); train one with model.style_code_dim > 0 to use example clips"
            )
        if windows is None:
            return None
        return F.normalize(ema.style_encoder(windows).mean(dim=0), dim=0)

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        # Fixed noise per batch, so validation losses are comparable across epochs.
        generator = torch.Generator(device=self.device).manual_seed(1000 + batch_idx)
        out, target, x0_hat, t = self.denoise(batch, net=self.ema.module, generator=generator)
        losses = self.generator_losses(batch, out, target, x0_hat, t, adversarial=False)
        self.log_dict(
            {f"{k}/val": v for k, v in losses.items()} | {"total/val": self.total_loss(losses)},
            on_epoch=True,
            sync_dist=True,
            batch_size=batch["features"].shape[0],
        )

    def configure_optimizers(self):
        h = self.hparams
        total = self.trainer.estimated_stepping_batches if self._trainer is not None else math.inf

        def warmup_cosine(batch: int) -> float:
            if batch < h.lr_warmup_batches:
                return (batch + 1) / h.lr_warmup_batches
            if not math.isfinite(total) or total <= h.lr_warmup_batches:
                return 1.0
            progress = min(1.0, (batch - h.lr_warmup_batches) / (total - h.lr_warmup_batches))
            return 0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * progress))

        opt_g = torch.optim.AdamW(self.denoiser.parameters(), lr=h.lr, weight_decay=h.weight_decay)
        sched_g = torch.optim.lr_scheduler.LambdaLR(opt_g, warmup_cosine)
        if self.discriminator is None:
            return [opt_g], [sched_g]
        opt_d = torch.optim.AdamW(self.discriminator.parameters(), lr=h.lr_discriminator, betas=(0.5, 0.999))
        sched_d = torch.optim.lr_scheduler.LambdaLR(opt_d, warmup_cosine)
        return [opt_g, opt_d], [sched_g, sched_d]

    # ---------------------------------------------------------------- generation

    def label_ids(self, names: list[str], kind: str) -> torch.Tensor:
        vocabulary = list(self.spec["styles" if kind == "style" else "contents"])
        unknown = [n for n in names if n not in vocabulary]
        if unknown:
            raise WalkdiffError(f"unknown {kind} {', '.join(unknown)}; valid: {', '.join(vocabulary)}")
        return torch.tensor([vocabulary.index(n) for n in names], device=self.device)

    @torch.no_grad()
    def generate(
        self,
        style: torch.Tensor,
        content: torch.Tensor,
        frames: int | None = None,
        *,
        sampler: str = "ddpm",
        steps: int | None = None,
        eta: float = 0.0,
        guidance: float = 1.0,
        generator: torch.Generator | None = None,
        inpaint: tuple[torch.Tensor, torch.Tensor] | None = None,
        progress: Progress = False,
        match: StyleStatistics | None = None,
    ) -> torch.Tensor:
        """Normalised feature windows (B, frames, D) from the EMA denoiser.

        `style` holds ids (B,) or mixing weights (B, styles) or codes; `guidance` W = 1 is plain
        conditional sampling, W > 1 pushes towards the requested labels (classifier-free guidance);
        `match`: example clips' statistics the windows are moved to (models/style_statistics.py).
        """
        frames = frames or self.spec["window"]
        shape = (style.shape[0], frames, self.spec["feature_dim"])
        jumps = self.jumps(sampler, steps, eta)
        model_fn = self.model_fn(style, content, guidance, jumps, match)
        common = dict(generator=generator, progress=progress, inpaint=inpaint)
        if sampler == "ddpm":
            return ddpm_sample(model_fn, self.diffusion, shape, **common)
        if sampler == "ddim":
            x = ddim_sample(model_fn, self.diffusion, shape, steps or DEFAULT_STEPS, eta, **common)
            if jumps is not None and inpaint is not None:
                x = self.harmonised(x, style, content, guidance, inpaint, generator, match)
            return x
        if sampler == "dpmpp":
            return dpm_solver_sample(model_fn, self.diffusion, shape, steps or DEFAULT_STEPS, **common)
        raise WalkdiffError(f"unknown sampler {sampler!r}; expected ddpm, ddim or dpmpp")

    def harmonised(
        self,
        x: torch.Tensor,
        style: torch.Tensor,
        content: torch.Tensor,
        guidance: float,
        inpaint: tuple[torch.Tensor, torch.Tensor],
        generator: torch.Generator | None = None,
        match: StyleStatistics | None = None,
    ) -> torch.Tensor:
        """A student's window made around held frames, noised again to the middle of the schedule and
        denoised in one step with the frames held. In 1 or 2 steps the network sees the held frames only
        as noise (t = T - 1) or half drowned (t = T/2 - 1), and the new frames do not join them smoothly:
        this pass shows it the held frames and its own at once, at the level of the 2-step schedule's last
        step, which the student was distilled for (the teacher's network when it was not)."""
        level = respace(self.diffusion.num_timesteps, 2)[-1]
        model_fn = self.model_fn(style, content, guidance, self.jumps("ddim", 2, 0.0), match)
        t = torch.full((x.shape[0],), level, device=x.device)
        x_t = self.diffusion.q_sample(x, t, randn_like(x, generator))
        table = step_coefficients(self.diffusion, [level], 0.0)
        return run_steps(model_fn, self.diffusion, None, table, generator=generator, x_T=x_t, inpaint=inpaint)

    def jumps(self, sampler: str, steps: int | None, eta: float) -> torch.Tensor | None:
        """The jumps (T,) a distilled student samples with where it was distilled, deterministic DDIM
        over its step count (walkdiff/distill.py); None everywhere else: the plain denoiser."""
        steps = steps or DEFAULT_STEPS
        if not (sampler == "ddim" and eta == 0 and steps in self.distilled_steps):
            return None
        total = self.diffusion.num_timesteps
        return step_jumps(total, respace(total, steps), self.device)

    @property
    def distilled_steps(self) -> list[int]:
        """The DDIM step counts a distilled student was made for (walkdiff/distill.py); [] for a trained
        model. Students of one count saved the number itself."""
        steps = self.hparams.get("distilled_steps", 0)
        return ([steps] if steps else []) if isinstance(steps, int) else list(steps)

    def model_fn(
        self,
        style: torch.Tensor,
        content: torch.Tensor,
        guidance: float = 1.0,
        jumps: torch.Tensor | None = None,
        match: StyleStatistics | None = None,
    ):
        """The EMA denoiser as the samplers call it, (x_t, t) -> output, with classifier-free guidance,
        its clean estimate moved to `match`'s statistics when given. `jumps` (T,): the jump each trained
        step takes (`jumps`), for a distilled student's DDIM; without them a student's teacher samples."""
        model_fn = self._guided_fn(style, content, guidance, jumps)
        return model_fn if match is None else match.guide(model_fn, self.diffusion)

    def _guided_fn(self, style, content, guidance: float, jumps: torch.Tensor | None):
        ema = (self.ema.module if jumps is not None or self.teacher is None else self.teacher).eval()

        def net(x, t, s, c):
            return ema(x, t, s, c, None if jumps is None else jumps[t])

        if guidance == 1.0:
            return lambda x, t: net(x, t, style, content)
        null_style = torch.full((style.shape[0],), ema.style.null_id, device=self.device)
        null_content = torch.full_like(content, ema.content.null_id)
        if style.is_floating_point():
            # Mixing weights and the null id (the unconditional pass) cannot share one batch tensor.
            return guided(
                lambda x, t: net(x, t, style, content),
                lambda x, t: net(x, t, null_style, null_content),
                guidance,
            )
        pair_style = torch.cat([style, null_style])
        pair_content = torch.cat([content, null_content])
        return guided_batched(lambda x, t: net(x, t, pair_style, pair_content), guidance)

    def to_raw(self, x: torch.Tensor, grounded: bool = True) -> np.ndarray:
        """Normalised features -> features in data units (numpy), ready for representation.decode.

        `grounded`: shifted so the planted feet stand where real ones do (footfix.ground).
        """
        raw = self.normalizer.denormalize(x).float().cpu().numpy()
        return self.ground(raw) if grounded else raw

    @property
    def floor_heights(self) -> np.ndarray | None:
        """(4,) where real planted feet stand, in data units; None for a checkpoint saved before walkdiff
        measured it."""
        return self.planted_height.cpu().numpy() if self.grounded_heights else None

    def ground(self, raw: np.ndarray) -> np.ndarray:
        """Raw features (..., F, D) shifted so their planted feet stand where real ones do."""
        if self.floor_heights is None:
            raise WalkdiffError(
                "this checkpoint was saved before walkdiff stored where planted feet stand, so its clips "
                "cannot be grounded: retrain it, or pass --no-ground"
            )
        return ground(raw, self.skeleton, self.contact_spec, self.floor_heights, float(self.ground_tolerance))
