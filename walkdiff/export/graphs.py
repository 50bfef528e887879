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


class FrameGraph(nn.Module):
    """The frame of `model` under `sampler`; `WalkerFrame` and `GestureFrame` add their control."""

    def __init__(self, model, sampler: SamplerChoice):
        super().__init__()
        self.model = model.eval()
        self.steps = sampler.table(model.diffusion)
        with torch.no_grad():
            embed = model.eps_net.embed_steps
            device = model.device
            self.embeddings = [embed(torch.tensor([t], device=device)) for t in self.steps.timesteps]

    @property
    def noise_slots(self) -> int:
        """Noise vectors a frame takes: the start of the sampler, then one after each step."""
        return len(self.steps.timesteps) + 1

    def frame(self, encoded, previous, h, c, noise):
        """(pose in feature units, pose normalised, h, c) of one frame from the encoded control."""
        model, steps = self.model, self.steps
        h_top, (h, c) = model.encoder.step(torch.cat([previous, encoded], dim=1), (h, c))
        cond = model.eps_net.condition(model.denoiser_input(h_top, encoded))
        x, x0_prev = noise[0], None
        for k in range(len(steps.timesteps)):
            out = model.eps_net(x, self.embeddings[k], cond)
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
