"""DiffMotion steered by a walking path instead of speech (beyond the paper), trained on Xia walking.

The architecture is DiffMotion's (`AutoregressiveDiffusion`): an LSTM over the previous pose and the
frame's encoded control, and a per-frame DDPM. The control of frame t says where to walk next:

    c_t = the path's positions k = 0, e, 2e, .. lookahead frames ahead, (x, z) in the walker's own frame
          (its root position and heading at frame t), plus a learned embedding of the style id

Their spacing is the desired root velocity, their direction the desired heading. In training the
"path" is where the real walker goes (the window's own root, held at its last velocity and turn rate
past the window's end). In generation it is the user's path, read from where the walker actually is:
the reference is the closest path point to the walker, and the points ahead follow the path at the
requested speed, so drifting off the path shows up as a path that bends back, which the model follows.

Beyond DiffMotion, training can weigh where each predicted frame puts the body in the world (terms of
`BodyTerms`, weighted by abar_t as in the styled GAN-DDPM). Teacher forcing predicts frame t from the
real frames before it, so its clean estimate is set between the real frames t-1 and t+1 and the three
are run through forward kinematics: the predicted pose and root step must carry the body from the real
frame before to the real frame after, joint velocities as real ones (`lambda_velocity`), feet that the
real motion has planted standing still (`lambda_foot`), and feet at their real heights
(`lambda_foot_height`). Without them the per-frame samples swing the legs out of step with the root:
feet on the ground slide nearly as fast as the body moves.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion import SamplerChoice
from walkdiff.models.diffmotion import AutoregressiveDiffusion
from walkdiff.models.pose_mlp import PoseMLP
from walkdiff.models.style_statistics import RunningMatch, StyleStatistics
from walkdiff.motion.path import Polyline
from walkdiff.motion.representation import FeatureLayout, Normalizer, root_trajectory
from walkdiff.spec import DataSpec


def local_offsets(targets: torch.Tensor, origin: torch.Tensor, heading: torch.Tensor) -> torch.Tensor:
    """World points (..., K, 2) as (x, z) in the frame at `origin` (..., 2) facing `heading` (...).

    The inverse of `yaw_matrix`: the walker's forward (+Z) axis is (sin h, cos h) in the world.
    """
    d = targets - origin.unsqueeze(-2)
    sin, cos = heading.sin().unsqueeze(-1), heading.cos().unsqueeze(-1)
    x = d[..., 0] * cos - d[..., 1] * sin
    z = d[..., 0] * sin + d[..., 1] * cos
    return torch.stack([x, z], dim=-1).flatten(-2)


def advance_root(
    position: np.ndarray, heading: np.ndarray, raw: np.ndarray, layout: FeatureLayout
) -> tuple[np.ndarray, np.ndarray]:
    """The root (x, z) (B, 2) and heading (B,) one frame on, by a frame of raw features (B, D).

    The same integration as `root_trajectory`: the planar velocity in the heading frame, then the turn.
    """
    vx, vz = raw[:, layout.root_vel.start], raw[:, layout.root_vel.start + 1]
    sin, cos = np.sin(heading), np.cos(heading)
    position = position + np.stack([vx * cos + vz * sin, -vx * sin + vz * cos], axis=-1)
    return position, heading + raw[:, layout.heading_vel.start]


def path_start(path: Polyline) -> tuple[np.ndarray, float]:
    """Where a walk along `path` starts: its first point, facing along its first segment."""
    forward = path.direction(0.0)
    return path.points[0].copy(), float(np.arctan2(forward[0], forward[1]))


def path_control(
    path: Polyline,
    position: np.ndarray,
    heading: np.ndarray,
    progress: np.ndarray,
    pace: np.ndarray,
    reach: float,
) -> tuple[torch.Tensor, np.ndarray]:
    """The raw controls (B, 2K) of walkers at `position` (B, 2) facing `heading` (B,), and how far along
    the path they are (B,): their closest path point within `reach` of `progress`, a frame ago's.

    The path is read no farther than progress + reach + pace[:, -1] (arc length): a path still growing
    gives the same controls as the whole path once it is longer than that (streaming).
    """
    progress, _ = path.project(position, near=progress, reach=reach)
    targets = torch.from_numpy(path.at(progress[:, None] + pace)).float()
    control = local_offsets(targets, torch.from_numpy(position).float(), torch.from_numpy(heading).float())
    return control, progress


class PathWalker(AutoregressiveDiffusion):
    def __init__(
        self,
        data_spec: DataSpec | dict | None = None,
        hidden: int = 512,
        lstm_layers: int = 2,
        control_hidden: int = 128,
        channels: int = 16,
        residual_layers: int = 6,
        dilation_cycle: int = 2,
        dropout: float = 0.1,
        timesteps: int = 100,
        schedule: str = "quad",
        beta_start: float = 1e-4,
        beta_end: float = 0.1,
        pose_noise: float = 0.05,
        lookahead: int = 15,
        control_every: int = 3,
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        grad_clip: float = 1.0,
        lambda_velocity: float = 0.0,
        lambda_foot: float = 0.0,
        lambda_foot_height: float = 0.0,
        denoiser: str = "timegrad",
        denoiser_hidden: int = 512,
        denoiser_layers: int = 3,
        prediction: str = "eps",
        control_to_denoiser: bool = False,
    ):
        super().__init__(data_spec)
        self.save_hyperparameters(ignore=["data_spec"], logger=False)  # the run logs its config (run_params)
        self.hparams["data_spec"] = spec = self.spec
        if lookahead < 0 or control_every < 1:
            raise WalkdiffError(
                f"model.lookahead must be >= 0 and model.control_every >= 1, got {lookahead}, {control_every}"
            )
        self.ahead = list(range(0, lookahead + 1, control_every))
        control_dim = 2 * len(self.ahead)
        if denoiser not in ("timegrad", "mlp"):
            raise WalkdiffError(f"model.denoiser must be timegrad or mlp, got {denoiser!r}")
        if control_to_denoiser and denoiser != "mlp":
            raise WalkdiffError("model.control_to_denoiser needs model.denoiser mlp")
        eps_net = None
        if denoiser == "mlp":  # see pose_mlp.py: TimeGrad's network samples the legs from the noise
            cond_dim = hidden + (control_hidden if control_to_denoiser else 0)
            eps_net = PoseMLP(spec["feature_dim"], cond_dim, denoiser_hidden, denoiser_layers)
        self.build(
            control_dim, hidden, lstm_layers, control_hidden, channels, residual_layers,
            dilation_cycle, dropout, timesteps, schedule, beta_start, beta_end, eps_net, prediction,
        )  # fmt: skip
        self.style = nn.Embedding(len(spec["styles"]), control_hidden)
        self.control_normalizer = Normalizer(control_dim)
        # Mean walking speed of each style in the training data (units/s): the default pace of a path.
        self.register_buffer("style_speed", torch.zeros(len(spec["styles"])))

    # ------------------------------------------------------------ control

    def controls_of(self, raw: torch.Tensor) -> torch.Tensor:
        """(B, F, 2K) controls of real walking (raw features (B, F, D)): where the walker itself goes."""
        frames = raw.shape[1]
        extended = torch.cat([raw, raw[:, -1:].expand(-1, self.ahead[-1], -1)], dim=1)
        heading, root = root_trajectory(extended)
        index = torch.arange(frames, device=raw.device)[:, None] + torch.tensor(self.ahead, device=raw.device)
        targets = root[:, index][..., [0, 2]]  # (B, F, K, 2)
        return local_offsets(targets, root[:, :frames, [0, 2]], heading[:, :frames])

    def encode_control(self, control: torch.Tensor, style: torch.Tensor) -> torch.Tensor:
        """Raw controls (B, F, 2K) and style ids (B,) or mixing weights (B, styles) -> encoder inputs
        (B, F, control_hidden)."""
        embedded = style @ self.style.weight if style.is_floating_point() else self.style(style)
        return self.encoder.audio(self.control_normalizer.normalize(control)) + embedded[:, None]

    def denoiser_input(self, h: torch.Tensor, control: torch.Tensor) -> torch.Tensor:
        """The encoder state, and with `control_to_denoiser` the frame's encoded control and style beside it:
        the style reaches each frame's denoiser directly, not only through the LSTM's memory of past poses
        (a walker fed its own frames otherwise drifts towards the styles it makes best)."""
        return torch.cat([h, control], dim=-1) if self.hparams.control_to_denoiser else h

    def pace(self, speed: torch.Tensor) -> np.ndarray:
        """(B, K) arc lengths of the control's points ahead of a walker at `speed` (B,) units/s."""
        return speed.double().cpu().numpy()[:, None] * np.asarray(self.ahead) / self.spec["fps"]

    def setup(self, stage: str) -> None:
        super().setup(stage)
        datamodule = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if datamodule is None or stage != "fit":
            return
        # Statistics of the controls and speeds of the real training walks (mirrored copies included).
        controls, speeds = [], {i: [] for i in range(len(self.spec["styles"]))}
        for clip, _, features in datamodule.split_features("train", mirrored=datamodule.hparams.mirror):
            raw = torch.from_numpy(features).unsqueeze(0)
            controls.append(self.controls_of(raw)[0].numpy())
            step = raw[0, :, self.layout.root_vel].norm(dim=-1) * self.spec["fps"]
            speeds[clip.style].append(step.numpy())
        fitted = Normalizer.fit(np.concatenate(controls))
        self.control_normalizer.load_state_dict(fitted.state_dict())
        for style, values in speeds.items():
            if values:
                self.style_speed[style] = float(np.concatenate(values).mean())

    # ------------------------------------------------------------ training

    def loss(self, batch: dict) -> torch.Tensor:
        losses = self.losses(batch)
        stage = "train" if self.training else "val"
        for name, value in losses.items():
            if name != "diffusion" and self._trainer is not None:
                self.log(f"loss/{name}_{stage}", value, batch_size=len(batch["features"]))
        h = self.hparams
        weights = {"diffusion": 1.0, "velocity": h.lambda_velocity, "foot": h.lambda_foot,
                   "foot_height": h.lambda_foot_height}  # fmt: skip
        return sum(weights[name] * value for name, value in losses.items())

    def losses(self, batch: dict) -> dict[str, torch.Tensor]:
        """The noise loss and, when weighted, the body terms (see the module docstring)."""
        raw = self.normalizer.denormalize(batch["features"])
        control = self.encode_control(self.controls_of(raw), batch["style"])
        out, target, x_t, t = self.denoise_sequence(batch["features"], control)
        losses = {"diffusion": F.mse_loss(out, target)}
        h = self.hparams
        if max(h.lambda_velocity, h.lambda_foot, h.lambda_foot_height) > 0 and raw.shape[1] >= 3:
            x0_hat = self.diffusion.predict_x0(out, x_t, t).view_as(raw)
            weight = self.diffusion.alphas_cumprod[t].view(raw.shape[:2])[:, 1:-1]  # (B, L-2)
            losses |= self.body_losses(raw, self.normalizer.denormalize(x0_hat), weight)
        return losses

    def body_losses(self, raw: torch.Tensor, raw_hat: torch.Tensor, weight: torch.Tensor) -> dict:
        """Terms on (real t-1, predicted t, real t+1) for every inner frame t of raw features (B, L, D)."""
        body = self.body_terms
        around = torch.stack([raw[:, :-2], raw_hat[:, 1:-1], raw[:, 2:]], dim=2)  # (B, L-2, 3, D)
        positions_hat = body.positions(around)
        with torch.no_grad():
            positions = body.positions(torch.stack([raw[:, :-2], raw[:, 1:-1], raw[:, 2:]], dim=2))
        velocity_hat, velocity = body.velocities(positions_hat), body.velocities(positions)
        planted = raw[..., self.layout.contacts] > 0.5
        planted = planted[:, 1:] & planted[:, :-1]  # (B, L-1, feet): planted over a step
        planted = torch.stack([planted[:, :-1], planted[:, 1:]], dim=2).to(raw.dtype)  # (B, L-2, 2, feet)
        return {
            "velocity": (weight * (velocity_hat - velocity).pow(2).mean(dim=(2, 3, 4))).mean(),
            "foot": (weight * body.foot_slide(velocity_hat, planted).mean(dim=(2, 3))).mean(),
            "foot_height": (
                weight * body.foot_height_error(positions_hat[:, :, 1], positions[:, :, 1]).pow(2).mean(-1)
            ).mean(),
        }

    # ------------------------------------------------------------ generation

    def match_streams(
        self, streams, target: StyleStatistics, sampler: SamplerChoice | None = None
    ) -> RunningMatch:
        """Every frame the streams make from now on moved to example clips' statistics (`RunningMatch`,
        over a second of frames); the guide, whose target may be replaced between frames."""
        if streams.tables.fused is not None:  # the fused network takes no guide
            streams.tables = self.sampling_tables(sampler, fused=False)
        last = streams.tables.steps.timesteps[-1]
        streams.tables.guide = RunningMatch(target, round(self.spec["fps"]), self.diffusion, last)
        return streams.tables.guide

    @torch.inference_mode()  # per-frame sampling is thousands of small ops: see DiffMotion.generate
    def generate(
        self,
        path: Polyline,
        style: torch.Tensor,
        speed: torch.Tensor,
        frames: int,
        generator: torch.Generator | None = None,
        on_frame: Callable[[int, int], None] | None = None,
        sampler: SamplerChoice | None = None,
        fused: bool = True,
        style_at: Callable[[int], tuple[torch.Tensor, torch.Tensor]] | None = None,
        match: StyleStatistics | None = None,
    ) -> tuple[np.ndarray, tuple[np.ndarray, float]]:
        """Walk `path` once per row of `style` (B,) at `speed` (B,) units/s for `frames` frames;
        `on_frame(done, total)` is called after every frame (a progress bar). `sampler` and `fused` as
        in `DiffMotion.generate`. `style_at(frame)`: (style, speed) of each frame instead (a timeline).
        `match`: example clips' statistics each frame is moved to (`RunningMatch`, over a second).

        Returns raw features (B, F, D) and the start pose (x, z), heading to decode them with.
        """
        rows, dim = style.shape[0], self.spec["feature_dim"]
        start, start_heading = path_start(path)
        position = np.tile(start, (rows, 1))
        heading = np.full(rows, start_heading)
        progress = np.zeros(rows)
        pace = self.pace(speed)
        reach = 2 * float(pace[:, -1].max()) + 1.0  # how far along the path a walker may get in a frame
        streams = self.start_streams(rows, sampler, fused and match is None)
        if match is not None:
            self.match_streams(streams, match, sampler)
        poses = torch.zeros(rows, frames, dim, device=self.device)
        style = style.to(self.device)
        for f in range(frames):
            if style_at is not None:
                style, speed = style_at(f)
                style, pace = style.to(self.device), self.pace(speed)
            control, progress = path_control(path, position, heading, progress, pace, reach)
            x = self.advance(
                streams, self.encode_control(control.to(self.device)[:, None], style)[:, 0], generator
            )
            poses[:, f] = x
            raw = self.normalizer.denormalize(x).double().cpu().numpy()
            position, heading = advance_root(position, heading, raw, self.layout)
            if on_frame is not None:
                on_frame(f + 1, frames)
        return self.normalizer.denormalize(poses).cpu().numpy(), (start.copy(), start_heading)
