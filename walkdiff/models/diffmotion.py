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

from walkdiff.diffusion import GaussianDiffusion, SamplerChoice, SamplerSteps, randn_like, run_steps
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


def _read_gated(weight: torch.Tensor) -> torch.Tensor:
    """Weights (C, out) that read a gated output g = s_g (2 s_v - 1), as weights (2 C, out) that read
    [s_g, s_g s_v]: g W = [s_g, s_g s_v] [-W; 2 W]."""
    return torch.cat([-weight, 2 * weight])


class FusedEps:
    """An `EpsNetwork`'s calls and the sampler's update with fewer, larger operations: the same arithmetic,
    built from the trained weights at generation time (nothing of it is trained or saved).

    Per-frame sampling on a CPU is bound by the number of torch operations (~2-5 us each), not by its
    arithmetic, so the work is laid out to need fewer of them:

    - the B pose vectors are one column of rows, each followed by `gap` zero rows (gap = the largest
      dilation), inside a buffer with `gap` zero rows above and below: a dilated tap is a slice of that
      buffer (views made once per frame), not a pad and two slices per call;
    - the residual update writes in place into the buffer; the gated outputs go straight into their
      columns of the skip layer's input, with no concatenation;
    - tanh(v) = 2 sigmoid(2 v) - 1 (torch's CPU tanh is ~10-20x slower than its sigmoid): one sigmoid
      gives s_g and s_v, the layer keeps [s_g, s_g s_v], and the gated output s_g (2 s_v - 1) is folded
      into the weights that read it ([-W; 2 W]);
    - the gap rows stay exactly zero: their gate bias is -inf (sigmoid 0, so the gated output is 0) and
      their other biases 0;
    - the output layer and the sampler step are one addmm: x <- a x + b (s W + c) is
      addmm(x, [s, 1], b [W; c], beta=a), with the skip layer's output s given a column of ones.

    Kept over TorchScript (deprecated in torch 2.13) and ONNX Runtime (faster in a side measurement, but
    an export of tens of seconds at each generation and a runtime and GPU build of its own): plain
    torch, one code path for CPU and GPU, nothing to compile (README, fast per-frame sampling).
    """

    def __init__(self, net: EpsNetwork, dim: int):
        self.net, self.dim = net, dim
        c, self.layers, self.dilations = net.channels, net.layers, net.dilations
        self.channels, self.gap = c, max(net.dilations)
        with torch.no_grad():
            # The value half of every gate pre-activation doubled: sigmoid(2 v) gives tanh(v).
            double = torch.cat([torch.ones(c), torch.full((c,), 2.0)]).to(net.input.weight)
            self.value_scale = double.repeat(self.layers)  # (layers 2C,) over the conditioner's columns
            self.cond_weight = net.cond_proj.weight.t() * self.value_scale  # (1, layers 2C)
            self.cond_bias = net.cond_proj.bias * self.value_scale
            self.input_weight = net.input.weight.t().clone()  # (1, C)
            self.dilated = [w * double for w in net.dilated]
            self.residual = [_read_gated(w) for w in net.residual]
            skip = net.skip.weight.t().split(c)  # (C, C) per layer
            # The skip layer with one more output, constant 1 on the pose rows (weight 0, bias 1).
            self.skip_weight = F.pad(torch.cat([_read_gated(w) for w in skip]), (0, 1))  # (layers 2C, C + 1)
            self.skip_bias = torch.cat([net.skip.bias, net.skip.bias.new_ones(1)])
            self.output = torch.cat([net.output.weight.t(), net.output.bias[:, None]])  # (C + 1, 1)
        self.workspaces: dict[int, dict] = {}

    def workspace(self, batch: int, like: torch.Tensor) -> dict:
        """Buffers and views for `batch` pose vectors, made once per batch size."""
        if batch in self.workspaces:
            return self.workspaces[batch]
        d, gap, c = self.dim, self.gap, self.channels
        rows = batch * (d + gap)
        pose = like.new_zeros(batch, d + gap, 1)
        pose[:, :d] = 1
        pose = pose.view(rows, 1)
        buffer = like.new_zeros(rows + 2 * gap, c)
        y = buffer[gap : gap + rows]
        gated = like.new_empty(rows, self.layers * 2 * c)
        gate_mask = like.new_zeros(d + gap, self.layers, 2 * c)
        gate_mask[d:, :, :c] = -math.inf
        slots = gated.split(2 * c, dim=1)
        space = {
            "rows": rows,
            "y": y,
            "taps": [
                (buffer[gap - k : gap - k + rows], y, buffer[gap + k : gap + k + rows])
                for k in self.dilations
            ],
            "gated": gated,
            "slots": [(slot, slot[:, :c], slot[:, c:]) for slot in slots],
            "input_bias": pose * self.net.input.bias.detach(),
            "skip_bias": pose * self.skip_bias,
            "gate_mask": gate_mask.view(d + gap, -1),
        }
        self.workspaces[batch] = space
        return space

    def condition(self, h: torch.Tensor, space: dict) -> torch.Tensor:
        """(B, cond_dim) encoder states -> (layers, rows, 2 C): the conditioner per row (gap rows: -inf)."""
        up = self.net.cond_upsample(h)  # (B, D)
        cond = torch.addmm(self.cond_bias, up.reshape(-1, 1), self.cond_weight).view(*up.shape, -1)
        cond = F.pad(cond, (0, 0, 0, self.gap)) + space["gate_mask"]
        return cond.view(space["rows"], self.layers, -1).transpose(0, 1).contiguous()

    def step_bias(self, step_emb: torch.Tensor) -> torch.Tensor:
        """A step embedding (layers, 1, 2 C) with its value halves doubled, to add to `condition`'s."""
        return step_emb * self.value_scale.view(self.layers, 1, -1)

    def features(self, x: torch.Tensor, bias: tuple[torch.Tensor, ...], space: dict) -> torch.Tensor:
        """The skip layer's output with its column of ones (rows, C + 1) for noisy poses x (rows, 1)."""
        y = space["y"]
        F.leaky_relu_(torch.addmm(space["input_bias"], x, self.input_weight, out=y), 0.4)
        for i, (taps, (slot, gate, value)) in enumerate(zip(space["taps"], space["slots"], strict=True)):
            torch.sigmoid(torch.addmm(bias[i], torch.cat(taps, dim=1), self.dilated[i]), out=slot)
            value.mul_(gate)  # [s_g, s_g s_v]
            if i < self.layers - 1:
                y.addmm_(slot, self.residual[i], beta=0.7071067811865476)
        return F.leaky_relu_(torch.addmm(space["skip_bias"], space["gated"], self.skip_weight), 0.4)


class ATEncoder(nn.Module):
    """DiffMotion's AT-Encoder: an LSTM over the previous pose and the frame's encoded control window.

    Training runs `nn.LSTM` over whole sequences. Generation advances one frame at a time, where
    `nn.LSTM` costs 2-5 ms a step on a CPU for ~0.3 ms of arithmetic; there a step is the same maths
    written as one addmm per layer (`step`), on the same weights, laid out once (`step_weights`).
    """

    def __init__(
        self, pose_dim: int, window_dim: int, hidden: int, layers: int, audio_dim: int, dropout: float
    ):
        super().__init__()
        self.audio = nn.Sequential(nn.Linear(window_dim, audio_dim), nn.SiLU(), nn.Dropout(dropout))
        self.lstm = nn.LSTM(pose_dim + audio_dim, hidden, layers, batch_first=True, dropout=dropout)
        self._step_cache: tuple[tuple, list[tuple[torch.Tensor, torch.Tensor]]] | None = None

    def forward(
        self,
        previous: torch.Tensor,
        audio: torch.Tensor,
        state: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """previous (B, L, D) poses, audio (B, L, A) from `self.audio` -> h (B, L, hidden), state."""
        x = torch.cat([previous, audio], dim=-1)
        if x.shape[1] == 1 and not self.training and not torch.is_grad_enabled():
            h, state = self.step(x[:, 0], state)
            return h.unsqueeze(1), state
        return self.lstm(x, state)

    def step_weights(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per layer: [W_ih | W_hh] transposed (in + hidden, 4 hidden) with the gates reordered (i, f, o, g)
        and g's doubled, and b_ih + b_hh likewise. Rebuilt whenever a weight changes (an optimizer step, a
        load, a move)."""
        params = list(self.lstm.parameters())
        # _version counts in-place writes: a cached copy of weights trained since is never used.
        key = tuple((p.data_ptr(), p._version, p.device) for p in params)
        if self._step_cache is None or self._step_cache[0] != key:
            hidden = self.lstm.hidden_size
            order = torch.cat([torch.arange(0, 2 * hidden), torch.arange(3 * hidden, 4 * hidden),
                               torch.arange(2 * hidden, 3 * hidden)]).to(params[0].device)  # fmt: skip
            layers = []
            with torch.no_grad():
                for k in range(self.lstm.num_layers):
                    w_ih, w_hh, b_ih, b_hh = (getattr(self.lstm, f"{n}_l{k}") for n in
                                              ("weight_ih", "weight_hh", "bias_ih", "bias_hh"))  # fmt: skip
                    scale = torch.ones(4 * hidden, 1, device=w_ih.device)
                    scale[3 * hidden :] = 2.0  # the g gate's tanh as a sigmoid (see step)
                    weight = (torch.cat([w_ih, w_hh], dim=1)[order] * scale).t().contiguous()
                    layers.append((weight, (b_ih + b_hh)[order] * scale[:, 0]))
            self._step_cache = (key, layers)
        return self._step_cache[1]

    def step(
        self, x: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor] | None
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """One LSTM step of x (B, in): the top layer's h (B, hidden) and the new state, as nn.LSTM's."""
        hidden = self.lstm.hidden_size
        if state is None:
            state = (x.new_zeros(self.lstm.num_layers, x.shape[0], hidden),) * 2
        hs, cs = [], []
        for (weight, bias), h, c in zip(self.step_weights(), state[0], state[1], strict=True):
            # One sigmoid for all four gates: the g rows are doubled in step_weights, tanh(z) = 2 sig(2z) - 1
            # (torch's CPU tanh is ~10-20x slower than its sigmoid).
            i, f, o, g = torch.sigmoid(torch.addmm(bias, torch.cat([x, h], dim=1), weight)).chunk(4, dim=1)
            c = torch.addcmul(f * c - i, i, g, value=2.0)  # f c + i tanh(.)
            x = torch.addcmul(-o, o, torch.sigmoid(2.0 * c), value=2.0)  # o tanh(c)
            hs.append(x)
            cs.append(c)
        return x, (torch.stack(hs), torch.stack(cs))


@dataclass
class FrameStreams:
    """What carries from one frame to the next for B streams of an `AutoregressiveDiffusion`.

    All streams advance together in offline generation; a streaming batch advances the ones with a frame
    ready (`select` and `update` gather and scatter their rows).
    """

    previous: torch.Tensor  # (B, 1, D) each stream's last pose, normalised (zeros, the mean pose, at a start)
    state: tuple[torch.Tensor, torch.Tensor] | None  # the LSTM's (h, c), (layers, B, hidden); None: all zero
    tables: FrameTables  # the sampler's tables, computed once

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
        eps_net: nn.Module | None = None,
        prediction: str = "eps",
    ) -> None:
        """The networks: `eps_net` in place of TimeGrad's, predicting `prediction` (eps, x0 or v)."""
        dim = self.spec["feature_dim"]
        self.diffusion = GaussianDiffusion(timesteps, schedule, beta_start, beta_end, prediction)
        self.encoder = ATEncoder(dim, control_dim, hidden, lstm_layers, control_hidden, dropout)
        self.eps_net = eps_net or EpsNetwork(dim, hidden, channels, residual_layers, dilation_cycle)

    def sequence_loss(self, poses: torch.Tensor, control: torch.Tensor) -> torch.Tensor:
        """Teacher forcing: the DDPM loss of every frame of (B, L, D) normalised poses in one batch."""
        return F.mse_loss(*self.denoise_sequence(poses, control)[:2])

    def denoise_sequence(self, poses: torch.Tensor, control: torch.Tensor):
        """Teacher forcing over (B, L, D) normalised poses: every frame noised to a random step and the
        network run. Returns (output, its target, noised frames, steps), each flattened to B * L."""
        b, length, dim = poses.shape
        previous = torch.cat([poses.new_zeros(b, 1, dim), poses[:, :-1]], dim=1)
        if self.training and self.hparams.pose_noise > 0:
            previous = previous + self.hparams.pose_noise * torch.randn_like(previous)
        h, _ = self.encoder(previous, control)
        x0, t = poses.reshape(b * length, dim), self.diffusion.sample_timesteps(b * length)
        x_t = self.diffusion.q_sample(x0, t, noise := torch.randn_like(x0))
        cond = self.eps_net.condition(self.denoiser_input(h, control).reshape(b * length, -1))
        target = self.diffusion.training_target(x0, noise, t)
        return self.eps_net(x_t, self.eps_net.embed_steps(t), cond), target, x_t, t

    def denoiser_input(self, h: torch.Tensor, control: torch.Tensor) -> torch.Tensor:
        """What the eps network is conditioned on: the encoder state (a subclass may add the control)."""
        return h

    def sampling_tables(self, sampler: SamplerChoice | None = None, fused: bool = True) -> FrameTables:
        """What sampling a frame needs, computed once per generation from the current weights: the
        sampler's steps (default ancestral DDPM over all N), their step embeddings, and with `fused`
        the eps network laid out for fewer operations (`FusedEps`; the same numbers as the module)."""
        steps = (sampler or SamplerChoice()).table(self.diffusion)
        embeddings = self.eps_net.embed_steps(torch.arange(self.diffusion.num_timesteps, device=self.device))
        fused = fused and isinstance(self.eps_net, EpsNetwork)  # only TimeGrad's network has a fused twin
        twin = FusedEps(self.eps_net, self.spec["feature_dim"]) if fused else None
        return FrameTables(steps, embeddings, twin)

    def sample_frame(
        self, h: torch.Tensor, tables: FrameTables, generator: torch.Generator | None
    ) -> torch.Tensor:
        """One normalised pose per row (B, D) for encoder states h (B, hidden): every step of the sampler."""
        if tables.fused is not None:
            return tables.sample_fused(h, generator)
        cond = self.eps_net.condition(h)

        def model_fn(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
            return self.eps_net(x, tables.embeddings[:, t], cond)

        model_fn = model_fn if tables.guide is None else tables.guide.guide(model_fn)
        shape = (h.shape[0], self.spec["feature_dim"])
        return run_steps(model_fn, self.diffusion, shape, tables.steps, generator=generator)

    # ------------------------------------------------------------ frame by frame (generation, streaming)

    @torch.inference_mode()
    def start_streams(
        self, rows: int, sampler: SamplerChoice | None = None, fused: bool = True
    ) -> FrameStreams:
        """`rows` streams at their start: zero LSTM state, the mean pose before them, the sampler's tables."""
        previous = torch.zeros(rows, 1, self.spec["feature_dim"], device=self.device)
        return FrameStreams(previous, None, self.sampling_tables(sampler, fused))

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
        x = self.sample_frame(self.denoiser_input(h[:, 0], control), streams.tables, generator)
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
        sampler: SamplerChoice | None = None,
        fused: bool = True,
    ) -> torch.Tensor:
        """Poses (B * streams, F, D) in feature units from raw log-mel audio (B, F, M) or (F, M).

        Each take is repeated `streams` times (stream k of take b is row b * streams + k), and all rows
        are generated together, frame by frame, carrying the LSTM state. `on_frame(done, total)` is
        called after every frame (a progress bar). `sampler` draws each frame (default: DDPM over all N
        trained steps); `fused=False` runs the plain eps module instead of its fused twin (same numbers).
        """
        if audio.ndim == 2:
            audio = audio.unsqueeze(0)
        audio = self.audio_normalizer.normalize(audio.to(self.device)).repeat_interleave(streams, dim=0)
        past, ahead = self.spec["past"], self.spec["lookahead"]
        padded = torch.cat([audio[:, :1].expand(-1, past, -1), audio, audio[:, -1:].expand(-1, ahead, -1)], 1)
        audio_emb = self.encoder.audio(self.control_windows(padded))
        rows, frames, dim = audio.shape[0], audio.shape[1], self.spec["feature_dim"]
        streams = self.start_streams(rows, sampler, fused)
        poses = audio.new_zeros(rows, frames, dim)
        for f in range(frames):
            poses[:, f] = self.advance(streams, audio_emb[:, f], generator)
            if on_frame is not None:
                on_frame(f + 1, frames)
        return self.normalizer.denormalize(poses)


class FrameTables:
    """A generation's per-frame sampling constants: the sampler's steps, the embeddings of all trained
    steps (layers, N, 1, 2 C), and the fused network (None: the plain module and `run_steps`)."""

    def __init__(self, steps: SamplerSteps, embeddings: torch.Tensor, fused: FusedEps | None):
        self.steps, self.embeddings, self.fused = steps, embeddings, fused
        self.guide = None  # a RunningMatch moving each clean estimate (the unfused path only)
        if fused is not None:
            # Per step, the output layer times the update's weights: x <- a x + b out, x0 = px x + po out.
            self.step_bias = [fused.step_bias(embeddings[:, t]) for t in steps.timesteps]
            self.update = [fused.output * b for b in steps.out_coef]
            self.estimate = [fused.output * po for po in steps.x0_out_coef] if any(steps.prev_coef) else None

    def sample_fused(self, h: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
        """The fused twin of `run_steps` over the eps network: the same draws from `generator`."""
        fused, steps = self.fused, self.steps
        batch, dim, gap = h.shape[0], fused.dim, fused.gap
        space = fused.workspace(batch, h)
        cond = fused.condition(h, space)

        def noise() -> torch.Tensor:  # drawn (B, D) as run_steps draws it, then given its gap rows
            return F.pad(randn_like(h.new_empty(batch, dim), generator), (0, gap)).view(-1, 1)

        x, x0_prev = noise(), None
        for k in range(len(steps.timesteps)):
            features = fused.features(x, (cond + self.step_bias[k]).unbind(0), space)
            estimate = self.estimate
            x0 = None if estimate is None else torch.addmm(x, features, estimate[k], beta=steps.x0_x_coef[k])
            x = torch.addmm(x, features, self.update[k], beta=steps.x_coef[k])
            if steps.prev_coef[k]:
                x.add_(x0_prev, alpha=steps.prev_coef[k])
            x0_prev = x0
            if steps.sigma[k] > 0:
                x.add_(noise(), alpha=steps.sigma[k])
        return x.view(batch, dim + gap)[:, :dim]
