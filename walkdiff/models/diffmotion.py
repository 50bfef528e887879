"""DiffMotion (Zhang, Ji, Gao, Li 2023): an autoregressive LSTM encoder and a per-frame DDPM over poses.

Per frame t:

    h_{t-1} = LSTM([x_{t-1}, A(c_t)], state)        c_t = audio frames t - past .. t + lookahead
    x_t     ~ DDPM(eps_net(x^n, n, h_{t-1}))         n = N-1 .. 0, one sample per frame

A is a linear map of the flattened control window. eps_net is TimeGrad's: the pose vector is a
1-channel signal of length D, run through gated residual layers of dilated 1D convolutions, each told
the diffusion step (a sinusoidal embedding through an MLP) and the conditioner (h mapped to length D).

Training teacher-forces the LSTM over whole sequences (the true previous poses, optionally with a little
noise against exposure bias) and takes the DDPM loss of every frame in one batch. Generation carries the
LSTM state and draws one sample per frame (the public code's median of 200 samples is slow and kills
diversity); several streams (takes, or seeds of one take) run batched. The state at a sequence start
is zero and the previous pose there is the mean pose (0 after normalisation), in training and generation.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from walkdiff.diffusion import GaussianDiffusion, run_steps, step_coefficients
from walkdiff.models.base import MotionModule
from walkdiff.motion.representation import Normalizer
from walkdiff.spec import NeutralPose, SpeechSpec


def sinusoidal_embedding(steps: torch.Tensor, dim: int) -> torch.Tensor:
    """(B,) integer steps -> (B, dim) sin/cos features over geometric frequencies."""
    half = dim // 2
    freqs = torch.exp(-math.log(10_000) * torch.arange(half, device=steps.device) / half)
    angles = steps.float()[:, None] * freqs[None]
    return torch.cat([angles.sin(), angles.cos()], dim=-1)


class EpsNetwork(nn.Module):
    """TimeGrad's eps_theta(x^n, n, h) over one pose vector of D numbers (a 1-channel length-D signal).

    Written channels-last with plain matrix products, because per-frame sampling on a CPU is bound by
    the number of operations, not by arithmetic (a Conv1d call costs ~100 us, a small addmm ~10 us):
    a dilated kernel-3 convolution is one product over the three taps [y(i - d), y(i), y(i + d)], the
    step and conditioner terms come in as that product's bias, and the residual update is one addmm.
    The conditioner is projected once per frame (`condition`) and reused for all N denoising steps.
    """

    def __init__(
        self, dim: int, cond_dim: int, channels: int = 32, layers: int = 8, cycle: int = 2, step_dim: int = 64
    ):
        super().__init__()
        self.channels, self.layers, self.step_dim = channels, layers, step_dim
        self.dilations = [2 ** (i % cycle) for i in range(layers)]
        self.step_mlp = nn.Sequential(nn.Linear(step_dim, step_dim), nn.SiLU(), nn.Linear(step_dim, step_dim))
        self.step_proj = nn.Linear(step_dim, layers * 2 * channels)
        self.cond_upsample = nn.Sequential(
            nn.Linear(cond_dim, dim), nn.LeakyReLU(0.4), nn.Linear(dim, dim), nn.LeakyReLU(0.4)
        )
        self.cond_proj = nn.Linear(1, layers * 2 * channels)  # per pose number: its conditioner value
        self.input = nn.Linear(1, channels)  # these Linears run as addmm in forward (half the overhead)
        self.dilated = nn.ParameterList(
            nn.Parameter(torch.randn(3 * channels, 2 * channels) / math.sqrt(3 * channels))
            for _ in range(layers)
        )
        self.residual = nn.ParameterList(
            nn.Parameter(torch.randn(channels, channels) / math.sqrt(channels)) for _ in range(layers - 1)
        )
        self.skip = nn.Linear(layers * channels, channels)
        self.output = nn.Linear(channels, 1)
        nn.init.zeros_(self.output.weight)  # start by predicting eps = 0 (TimeGrad does the same)
        nn.init.zeros_(self.output.bias)

    def embed_steps(self, steps: torch.Tensor) -> torch.Tensor:
        """(B,) diffusion steps -> (layers, B, 1, 2 channels)."""
        emb = self.step_proj(self.step_mlp(sinusoidal_embedding(steps, self.step_dim)))
        return emb.view(-1, self.layers, 1, 2 * self.channels).transpose(0, 1).contiguous()

    def condition(self, h: torch.Tensor) -> torch.Tensor:
        """(B, cond_dim) encoder states -> (layers, B, D, 2 channels)."""
        cond = self.cond_proj(self.cond_upsample(h).unsqueeze(-1))  # (B, D, layers * 2C)
        b, d = cond.shape[:2]
        return cond.view(b, d, self.layers, 2 * self.channels).permute(2, 0, 1, 3).contiguous()

    def forward(self, x: torch.Tensor, step_emb: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """x (B, D) noisy poses, step_emb from `embed_steps`, cond from `condition` -> eps (B, D)."""
        b, d = x.shape
        # unbind, not bias[i]: indexing makes autograd zero-fill the whole stack once per layer.
        bias = (cond + step_emb).view(self.layers, b * d, 2 * self.channels).unbind(0)
        y = F.leaky_relu(torch.addmm(self.input.bias, x.reshape(b * d, 1), self.input.weight.t()), 0.4)
        gated = []
        for i, dilation in enumerate(self.dilations):
            padded = F.pad(y.view(b, d, -1), (0, 0, dilation, dilation))
            taps = torch.cat([padded[:, :d], y.view(b, d, -1), padded[:, 2 * dilation :]], dim=-1)
            gate, value = torch.addmm(bias[i], taps.view(b * d, -1), self.dilated[i]).chunk(2, dim=-1)
            g = torch.sigmoid(gate) * torch.tanh(value)
            gated.append(g)
            if i < self.layers - 1:  # y <- y / sqrt(2) + g W: the sum keeps the scale of one path
                y = torch.addmm(y, g, self.residual[i], beta=0.7071067811865476)
        skip = F.leaky_relu(torch.addmm(self.skip.bias, torch.cat(gated, dim=-1), self.skip.weight.t()), 0.4)
        return torch.addmm(self.output.bias, skip, self.output.weight.t()).view(b, d)


class ATEncoder(nn.Module):
    """DiffMotion's AT-Encoder: an LSTM over the previous pose and the frame's encoded control window."""

    def __init__(
        self, pose_dim: int, window_dim: int, hidden: int, layers: int, audio_dim: int, dropout: float
    ):
        super().__init__()
        self.audio = nn.Sequential(nn.Linear(window_dim, audio_dim), nn.SiLU(), nn.Dropout(dropout))
        self.lstm = nn.LSTM(pose_dim + audio_dim, hidden, layers, batch_first=True, dropout=dropout)

    def forward(
        self,
        previous: torch.Tensor,
        audio: torch.Tensor,
        state: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """previous (B, L, D) poses, audio (B, L, A) from `self.audio` -> h (B, L, hidden), state."""
        return self.lstm(torch.cat([previous, audio], dim=-1), state)


@dataclass
class FrameStreams:
    """What carries from one frame to the next for B streams of an `AutoregressiveDiffusion`.

    All streams advance together in offline generation; a streaming batch advances the ones with a frame
    ready (`select` and `update` gather and scatter their rows).
    """

    previous: torch.Tensor  # (B, 1, D) each stream's last pose, normalised (zeros, the mean pose, at a start)
    state: tuple[torch.Tensor, torch.Tensor] | None  # the LSTM's (h, c), (layers, B, hidden); None: all zero
    tables: tuple  # the sampler's tables, computed once

    @property
    def rows(self) -> int:
        return self.previous.shape[0]

    def add(self, rows: int) -> None:
        """`rows` more streams at their start (streams may join a running batch)."""
        self.previous = torch.cat([self.previous, self.previous.new_zeros(rows, *self.previous.shape[1:])])
        if self.state is not None:
            self.state = tuple(
                torch.cat([s, s.new_zeros(s.shape[0], rows, s.shape[2])], 1) for s in self.state
            )

    def select(
        self, rows: torch.Tensor | None, lstm: nn.LSTM
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor] | None]:
        """The previous poses and LSTM state of `rows` (None: all, as they are)."""
        if rows is None:
            return self.previous, self.state
        if self.state is None:
            zeros = self.previous.new_zeros(lstm.num_layers, self.rows, lstm.hidden_size)
            self.state = (zeros, zeros.clone())
        return self.previous[rows], (self.state[0][:, rows], self.state[1][:, rows])

    def update(
        self, rows: torch.Tensor | None, previous: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor]
    ) -> None:
        """The streams `rows` (None: all) a frame on."""
        if rows is None:
            self.previous, self.state = previous, state
            return
        self.previous[rows] = previous
        self.state[0][:, rows] = state[0]
        self.state[1][:, rows] = state[1]


class AutoregressiveDiffusion(MotionModule):
    """DiffMotion's machinery, whatever steers it: the AT-Encoder and the per-frame eps network.

    A subclass turns its control signal into one encoded vector per frame (B, L, control_hidden), and
    calls `sequence_loss` in its `loss`; generation and streaming start streams (`start_streams`) and
    `advance` them a frame at a time from each frame's encoded control.
    """

    sequence_key = "features"  # the batch entry holding the pose sequences

    def build(
        self,
        control_dim: int,
        hidden: int,
        lstm_layers: int,
        control_hidden: int,
        channels: int,
        residual_layers: int,
        dilation_cycle: int,
        dropout: float,
        timesteps: int,
        schedule: str,
        beta_start: float,
        beta_end: float,
    ) -> None:
        dim = self.spec["feature_dim"]
        self.diffusion = GaussianDiffusion(timesteps, schedule, beta_start, beta_end, "eps")
        self.encoder = ATEncoder(dim, control_dim, hidden, lstm_layers, control_hidden, dropout)
        self.eps_net = EpsNetwork(dim, hidden, channels, residual_layers, dilation_cycle)

    def sequence_loss(self, poses: torch.Tensor, control: torch.Tensor) -> torch.Tensor:
        """Teacher forcing: the DDPM loss of every frame of (B, L, D) normalised poses in one batch."""
        b, length, dim = poses.shape
        previous = torch.cat([poses.new_zeros(b, 1, dim), poses[:, :-1]], dim=1)
        if self.training and self.hparams.pose_noise > 0:
            previous = previous + self.hparams.pose_noise * torch.randn_like(previous)
        h, _ = self.encoder(previous, control)
        x0 = poses.reshape(b * length, dim)
        t = self.diffusion.sample_timesteps(b * length)
        noise = torch.randn_like(x0)
        x_t = self.diffusion.q_sample(x0, t, noise)
        eps = self.eps_net(
            x_t, self.eps_net.embed_steps(t), self.eps_net.condition(h.reshape(b * length, -1))
        )
        return F.mse_loss(eps, noise)

    def sampling_tables(self):
        """The ancestral DDPM steps and the step embeddings, computed once per generation."""
        steps = step_coefficients(self.diffusion, range(self.diffusion.num_timesteps - 1, -1, -1), eta=1.0)
        table = self.eps_net.embed_steps(torch.arange(self.diffusion.num_timesteps, device=self.device))
        return steps, table

    def sample_frame(self, h: torch.Tensor, tables, generator: torch.Generator | None) -> torch.Tensor:
        """One normalised pose per row (B, D) for encoder states h (B, hidden): all N denoising steps."""
        steps, step_table = tables
        cond = self.eps_net.condition(h)

        def model_fn(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
            return self.eps_net(x, step_table[:, t], cond)

        return run_steps(
            model_fn, self.diffusion, (h.shape[0], self.spec["feature_dim"]), steps, generator=generator
        )

    # ------------------------------------------------------------ frame by frame (generation, streaming)

    @torch.inference_mode()
    def start_streams(self, rows: int) -> FrameStreams:
        """`rows` streams at their start: zero LSTM state, the mean pose before them, the sampler's tables."""
        previous = torch.zeros(rows, 1, self.spec["feature_dim"], device=self.device)
        return FrameStreams(previous, None, self.sampling_tables())

    @torch.inference_mode()
    def advance(
        self,
        streams: FrameStreams,
        control: torch.Tensor,
        generator: torch.Generator | None,
        rows: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """One frame for the streams `rows` (default: all) from their encoded controls (R, control_hidden):
        their poses (R, D), normalised; those streams' state moves on by the frame."""
        previous, state = streams.select(rows, self.encoder.lstm)
        h, state = self.encoder(previous, control[:, None], state)
        x = self.sample_frame(h[:, 0], streams.tables, generator)
        streams.update(rows, x[:, None], state)
        return x

    def loss(self, batch: dict) -> torch.Tensor:
        raise NotImplementedError

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        loss = self.loss(batch)
        self.log("loss/train", loss, prog_bar=True, batch_size=len(batch[self.sequence_key]))
        return loss

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self.log("loss/val", self.loss(batch), prog_bar=True, batch_size=len(batch[self.sequence_key]))

    def configure_optimizers(self):
        h = self.hparams
        return torch.optim.AdamW(self.parameters(), lr=h.lr, weight_decay=h.weight_decay)

    def configure_gradient_clipping(self, optimizer, gradient_clip_val=None, gradient_clip_algorithm=None):
        self.clip_gradients(optimizer, self.hparams.grad_clip, "norm")


class DiffMotion(AutoregressiveDiffusion):
    sequence_key = "poses"

    def __init__(
        self,
        data_spec: SpeechSpec | dict | None = None,
        hidden: int = 512,
        lstm_layers: int = 2,
        audio_hidden: int = 256,
        channels: int = 16,
        residual_layers: int = 6,
        dilation_cycle: int = 2,
        dropout: float = 0.1,
        timesteps: int = 100,
        schedule: str = "quad",
        beta_start: float = 1e-4,
        beta_end: float = 0.1,
        pose_noise: float = 0.0,
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        grad_clip: float = 1.0,
    ):
        super().__init__(data_spec)
        self.save_hyperparameters(ignore=["data_spec"], logger=False)  # the run logs its config (run_params)
        self.hparams["data_spec"] = spec = self.spec
        self.window = spec["past"] + 1 + spec["lookahead"]
        self.audio_normalizer = Normalizer(spec["audio_dim"])
        self.neutral: NeutralPose | None = None
        self.build(
            self.window * spec["audio_dim"],
            hidden,
            lstm_layers,
            audio_hidden,
            channels,
            residual_layers,
            dilation_cycle,
            dropout,
            timesteps,
            schedule,
            beta_start,
            beta_end,
        )

    # ------------------------------------------------------------ state that travels with the checkpoint

    def setup(self, stage: str) -> None:
        super().setup(stage)
        datamodule = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if datamodule is None:
            return
        if stage == "fit":
            self.audio_normalizer.load_state_dict(datamodule.audio_normalizer.state_dict())
        if self.neutral is None:
            self.neutral = datamodule.neutral

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        super().on_save_checkpoint(checkpoint)
        if self.neutral is not None:
            checkpoint["neutral_pose"] = self.neutral.to_dict()

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        super().on_load_checkpoint(checkpoint)
        if "neutral_pose" in checkpoint:
            self.neutral = NeutralPose.from_dict(checkpoint["neutral_pose"])

    # ------------------------------------------------------------ training

    def control_windows(self, audio: torch.Tensor) -> torch.Tensor:
        """(B, past + L + lookahead, M) normalised audio -> (B, L, window * M) flattened windows."""
        return audio.unfold(1, self.window, 1).transpose(-1, -2).flatten(2)

    def loss(self, batch: dict) -> torch.Tensor:
        return self.sequence_loss(batch["poses"], self.encoder.audio(self.control_windows(batch["audio"])))

    # ------------------------------------------------------------ generation

    @torch.inference_mode()  # ~15% faster than no_grad for these ~5,000 small ops a frame
    def generate(
        self,
        audio: torch.Tensor,
        generator: torch.Generator | None = None,
        streams: int = 1,
        on_frame: Callable[[int, int], None] | None = None,
    ) -> torch.Tensor:
        """Poses (B * streams, F, D) in feature units from raw log-mel audio (B, F, M) or (F, M).

        Each take is repeated `streams` times (stream k of take b is row b * streams + k), and all rows
        are generated together, frame by frame, carrying the LSTM state. `on_frame(done, total)` is
        called after every frame (a progress bar).
        """
        if audio.ndim == 2:
            audio = audio.unsqueeze(0)
        audio = self.audio_normalizer.normalize(audio.to(self.device)).repeat_interleave(streams, dim=0)
        past, ahead = self.spec["past"], self.spec["lookahead"]
        padded = torch.cat([audio[:, :1].expand(-1, past, -1), audio, audio[:, -1:].expand(-1, ahead, -1)], 1)
        audio_emb = self.encoder.audio(self.control_windows(padded))
        rows, frames, dim = audio.shape[0], audio.shape[1], self.spec["feature_dim"]
        streams = self.start_streams(rows)
        poses = audio.new_zeros(rows, frames, dim)
        for f in range(frames):
            poses[:, f] = self.advance(streams, audio_emb[:, f], generator)
            if on_frame is not None:
                on_frame(f + 1, frames)
        return self.normalizer.denormalize(poses)
