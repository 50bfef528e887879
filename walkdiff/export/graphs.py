"""One frame of an `AutoregressiveDiffusion` (the path walker, DiffMotion's gestures) as a torch module
whose every input and output is a tensor, so that it traces into a graph ONNX Runtime runs on its own.

A frame: the control encoded, one LSTM step over [previous pose, encoded control], and every step of
a fixed sampler unrolled, the noise it needs coming in as an input, never drawn inside: the same
numbers as `AutoregressiveDiffusion.advance` (the plain network and `run_steps`) for the same noise. The
normalisers are inside: raw control in, pose features in the model's units out, so an engine needs no
statistics of its own. The fused eps network (`FusedEps`) is not traced: it writes into buffers in
place, and ONNX Runtime fuses the plain network's small operations itself.
"""

from __future__ import annotations

import torch
from torch import nn

from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion import SamplerChoice


def frame_kind(model) -> str:
    """'walker' for a PathWalker, 'gesture' for a DiffMotion (what the graph's control is)."""
    from walkdiff.models.diffmotion import DiffMotion
    from walkdiff.models.path_walker import PathWalker

    if isinstance(model, PathWalker):
        return "walker"
    if isinstance(model, DiffMotion):
        return "gesture"
    raise WalkdiffError(
        f"ONNX export takes a path walker or a gesture model (DiffMotion), got {type(model).__name__}"
    )


class PlainEps(nn.Module):
    """The eps network as it is, its step embeddings computed once per sampler step."""

    def __init__(self, net: nn.Module, timesteps: list[int]):
        super().__init__()
        self.net = net
        with torch.no_grad():
            self.embeddings = [net.embed_steps(torch.tensor([t])) for t in timesteps]

    def condition(self, h: torch.Tensor) -> torch.Tensor:
        return self.net.condition(h)

    def forward(self, x: torch.Tensor, k: int, cond: torch.Tensor) -> torch.Tensor:
        return self.net(x, self.embeddings[k], cond)


class LeanTimeGrad(nn.Module):
    """TimeGrad's eps network (`EpsNetwork`) in the fewest graph nodes, the same arithmetic.

    ONNX Runtime spends about a microsecond a node whatever its size, and a traced `EpsNetwork` is over
    a hundred nodes a step (a pad, two slices and a concatenation per dilated tap, reshapes that follow
    the batch). Here the pose is laid out channels-first (B, C, D), so a dilated kernel-3 layer is one
    Conv node with the trained (3 C, 2 C) weights rearranged; 1x1 convolutions read the gated outputs;
    and the residual scale 1/sqrt(2) is folded into the weights (layer i sees y / a^i, a = 1/sqrt(2)), so
    each residual update is one Add. The conditioner and each step's embedding are the same numbers.
    """

    def __init__(self, net, timesteps: list[int]):
        super().__init__()
        a = 0.7071067811865476
        c, layers = net.channels, net.layers
        self.dilations = net.dilations
        with torch.no_grad():
            steps = [net.embed_steps(torch.tensor([t])) for t in timesteps]  # (layers, 1, 1, 2C)
            self.step_bias = [e.reshape(1, layers * 2 * c, 1).clone() for e in steps]
            self.up = net.cond_upsample
            self.cond_weight = net.cond_proj.weight[:, 0].reshape(1, -1, 1).clone()
            self.cond_bias = net.cond_proj.bias.reshape(1, -1, 1).clone()
            self.input_weight = net.input.weight[:, 0].reshape(1, c, 1).clone()
            self.input_bias = net.input.bias.reshape(1, c, 1).clone()
            # taps [y(i - d), y(i), y(i + d)] @ W (3C, 2C) as a Conv weight (2C, C, 3), y_i = a^i y^_i.
            self.dilated = [
                (w.view(3, c, 2 * c).permute(2, 1, 0) * a**i).contiguous() for i, w in enumerate(net.dilated)
            ]
            self.residual = [
                (r.t() / a ** (i + 1))[..., None].contiguous() for i, r in enumerate(net.residual)
            ]
            self.skip_weight = net.skip.weight[..., None].clone()
            self.skip_bias = net.skip.bias.clone()
            self.output_weight = net.output.weight[..., None].clone()
            self.output_bias = net.output.bias.clone()
        self.split, self.channels = [2 * c] * layers, c

    def condition(self, h: torch.Tensor) -> list[torch.Tensor]:
        """(B, cond_dim) -> (B, layers 2C, D): each pose number's conditioner, once a frame."""
        return self.up(h).unsqueeze(1) * self.cond_weight + self.cond_bias

    def forward(self, x: torch.Tensor, k: int, cond: torch.Tensor) -> torch.Tensor:
        import torch.nn.functional as F

        y = F.leaky_relu(x.unsqueeze(1) * self.input_weight + self.input_bias, 0.4)
        biases = torch.split(cond + self.step_bias[k], self.split, dim=1)
        gated = []
        for i, dilation in enumerate(self.dilations):
            z = F.conv1d(y, self.dilated[i], padding=dilation, dilation=dilation) + biases[i]
            gate, value = torch.split(z, self.channels, dim=1)
            g = torch.sigmoid(gate) * torch.tanh(value)
            gated.append(g)
            if i < len(self.residual):
                y = y + F.conv1d(g, self.residual[i])
        skip = F.leaky_relu(F.conv1d(torch.cat(gated, dim=1), self.skip_weight, self.skip_bias), 0.4)
        return F.conv1d(skip, self.output_weight, self.output_bias).squeeze(1)


class FrameGraph(nn.Module):
    """The frame of `model` under `sampler`; `WalkerFrame` and `GestureFrame` add their control."""

    def __init__(self, model, sampler: SamplerChoice):
        from walkdiff.models.diffmotion import EpsNetwork

        super().__init__()
        self.model = model.eval()
        self.steps = sampler.table(model.diffusion)
        lean = isinstance(model.eps_net, EpsNetwork)
        self.eps = (LeanTimeGrad if lean else PlainEps)(model.eps_net, self.steps.timesteps)

    @property
    def noise_slots(self) -> int:
        """Noise vectors a frame takes: the start of the sampler, then one after each step."""
        return len(self.steps.timesteps) + 1

    def frame(self, encoded, previous, h, c, noise):
        """(pose in feature units, pose normalised, h, c) of one frame from the encoded control."""
        model, steps = self.model, self.steps
        h_top, (h, c) = model.encoder.step(torch.cat([previous, encoded], dim=1), (h, c))
        cond = self.eps.condition(model.denoiser_input(h_top, encoded))
        x, x0_prev = noise[0], None
        for k in range(len(steps.timesteps)):
            out = self.eps(x, k, cond)
            x0 = x * steps.x0_x_coef[k] + out * steps.x0_out_coef[k] if any(steps.prev_coef) else None
            x = x * steps.x_coef[k] + out * steps.out_coef[k]
            if steps.prev_coef[k]:
                x = x + x0_prev * steps.prev_coef[k]
            x0_prev = x0
            if steps.sigma[k] > 0:
                x = x + noise[k + 1] * steps.sigma[k]
        return model.normalizer.denormalize(x), x, h, c


class WalkerFrame(FrameGraph):
    """control (B, 2K) raw path points ahead, style (B, S) mixing weights, previous (B, D), h and c
    (layers, B, hidden), noise (steps + 1, B, D)."""

    inputs = ("control", "style", "previous", "h", "c", "noise")

    def forward(self, control, style, previous, h, c, noise):
        encoded = self.model.encode_control(control[:, None], style)[:, 0]
        return self.frame(encoded, previous, h, c, noise)

    def examples(self, batch: int = 1) -> tuple[torch.Tensor, ...]:
        model = self.model
        control = torch.zeros(batch, 2 * len(model.ahead))
        style = torch.full((batch, len(model.spec["styles"])), 1.0 / len(model.spec["styles"]))
        return (control, style, *state_examples(model, batch), self.noise(batch))

    def noise(self, batch: int) -> torch.Tensor:
        return torch.zeros(self.noise_slots, batch, self.model.spec["feature_dim"])


class GestureFrame(FrameGraph):
    """audio (B, past + 1 + lookahead, bands) raw log-mel frames around the frame, previous (B, D), h and
    c (layers, B, hidden), noise (steps + 1, B, D)."""

    inputs = ("audio", "previous", "h", "c", "noise")

    def forward(self, audio, previous, h, c, noise):
        model = self.model
        encoded = model.encoder.audio(model.audio_normalizer.normalize(audio).flatten(1))
        return self.frame(encoded, previous, h, c, noise)

    def examples(self, batch: int = 1) -> tuple[torch.Tensor, ...]:
        model = self.model
        audio = torch.zeros(batch, model.window, model.spec["audio_dim"])
        return (audio, *state_examples(model, batch), self.noise(batch))

    def noise(self, batch: int) -> torch.Tensor:
        return torch.zeros(self.noise_slots, batch, self.model.spec["feature_dim"])


OUTPUTS = ("pose", "previous_out", "h_out", "c_out")


def state_examples(model, batch: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A start state of `batch` streams: the mean pose before them (zeros, normalised), a zero LSTM."""
    lstm = model.encoder.lstm
    zeros = torch.zeros(lstm.num_layers, batch, lstm.hidden_size)
    return torch.zeros(batch, model.spec["feature_dim"]), zeros, zeros.clone()


def frame_graph(model, sampler: SamplerChoice) -> FrameGraph:
    """The traceable frame of a path walker or a gesture model."""
    return (WalkerFrame if frame_kind(model) == "walker" else GestureFrame)(model, sampler.unguided())
