"""ONNX Runtime behind a frame model's interface: `OnnxFrames` stands where the torch PathWalker or
DiffMotion stands for `WalkController`, `StreamBatch` and `DiffMotion.generate`, and makes each frame by
running the exported graph (`graphs.py`) instead of torch.

It keeps the torch model for everything around the frame (its spec, skeleton profile, normalisers,
style speeds) and takes over what makes a frame: `start_streams` (the carried state as numpy arrays),
`encode_control` / `encoder.audio` (which only hand the raw control on: the graph encodes it) and
`advance`. Noise is drawn from the caller's torch generator in the order `advance` draws it (the start
of the sampler, then after each step with noise), so the same seed gives the torch model's frames.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion import SamplerChoice, randn_like
from walkdiff.export.contract import FORMAT
from walkdiff.export.graphs import OUTPUTS, frame_kind
from walkdiff.export.onnx_files import DEFAULT_SAMPLER, graph_bytes

RUNTIMES = ("torch", "onnx")
TORCH_FRAMES = ("sample_frame", "sampling_tables", "forward", "sequence_loss", "denoise_sequence")


def session(data: bytes | str, threads: int = 1):
    """An ONNX Runtime CPU session of a graph (bytes or a file) on `threads` threads."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    # Threads that spin between nodes wait for a core other work holds: on the busy 2-core machine, 256
    # gesture streams took 132 ms a frame on 2 spinning threads, 74 ms without spinning (1 thread: 65 ms).
    options.add_session_config_entry("session.intra_op.allow_spinning", "0" if threads > 1 else "1")
    return ort.InferenceSession(data, options, providers=["CPUExecutionProvider"])


class OnnxStreams:
    """What carries from one frame to the next, as `FrameStreams` (numpy, float32)."""

    def __init__(self, rows: int, dim: int, layers: int, hidden: int):
        self.previous = np.zeros((rows, dim), np.float32)
        self.h = np.zeros((layers, rows, hidden), np.float32)
        self.c = np.zeros((layers, rows, hidden), np.float32)
        self.tables = _NoGuide()

    @property
    def rows(self) -> int:
        return len(self.previous)

    def add(self, rows: int) -> None:
        """`rows` more streams at their start."""
        self.previous = np.concatenate([self.previous, np.zeros((rows, self.previous.shape[1]), np.float32)])
        grow = np.zeros((self.h.shape[0], rows, self.h.shape[2]), np.float32)
        self.h, self.c = np.concatenate([self.h, grow], 1), np.concatenate([self.c, grow], 1)


class _NoGuide:
    """The tables a stream batch looks at: no example-clip guide runs on ONNX Runtime."""

    guide = None


class _AudioPassThrough:
    """`encoder.audio` for a stream batch: the graph takes the audio window raw and encodes it itself, so
    the normalised flattened window a `GestureStream` hands over is turned back into raw frames."""

    def __init__(self, model):
        normalizer = model.audio_normalizer
        self.mean, self.std = (v.detach().cpu().numpy() for v in (normalizer.mean, normalizer.std))
        self.shape = (model.window, model.spec["audio_dim"])

    def audio(self, windows: torch.Tensor) -> torch.Tensor:
        # In numpy: torch would run these on its thread pool, whose wake-up on a busy machine took 13 ms
        # a frame at 256 streams on 2 threads (numpy's float32 multiply and add round as torch's).
        flat = windows.detach().cpu().numpy()
        raw = flat.reshape(*flat.shape[:-1], *self.shape) * self.std + self.mean
        return torch.from_numpy(raw.reshape(flat.shape))


class OnnxFrames:
    """A PathWalker or DiffMotion whose frames ONNX Runtime makes (see the module docstring)."""

    runtime = "onnx"  # what manifests record (a torch model has no such attribute: "torch")

    def __init__(
        self,
        model,
        sampler: SamplerChoice = DEFAULT_SAMPLER,
        threads: int | None = None,
        data: bytes | None = None,
    ):
        self.model = model.eval()
        self.kind = frame_kind(model)
        self.sampler = sampler.unguided()
        self.table = sampler.table(model.diffusion)
        self.data = data if data is not None else graph_bytes(model, sampler)
        self.threads, self.sessions = threads, {}
        self.noise_slots = len(self.table.timesteps) + 1
        # The noise the frame draws: the start of the sampler, then after each step with noise.
        self.noisy_slots = [0] + [k + 1 for k, s in enumerate(self.table.sigma) if s > 0]
        self.drawn = np.zeros((self.noise_slots, 0, model.spec["feature_dim"]), np.float32)  # advance's
        if self.kind == "gesture":
            self.encoder = _AudioPassThrough(model)

    def __getattr__(self, name: str):  # spec, profile, normalizer, layout, style_speed, ahead, ...
        if name == "model":
            raise AttributeError(name)
        if name in TORCH_FRAMES:  # they would make torch's frames, not the graph's
            raise WalkdiffError(f"--runtime onnx: {name} makes frames with torch; use advance")
        return getattr(self.model, name)

    def generate(self, *args, **kwargs):
        """The model's own `generate` (gestures for audio, a walk along a path), its frames made here."""
        return type(self.model).generate(self, *args, **kwargs)

    def eval(self) -> OnnxFrames:
        return self

    @property
    def session(self):
        """The session on `threads` threads (None: as many as torch uses now, so `--threads` and the
        benches' thread counts apply to ONNX Runtime too), made once per count."""
        count = self.threads or torch.get_num_threads()
        if count not in self.sessions:
            self.sessions[count] = session(self.data, count)
        return self.sessions[count]

    # ------------------------------------------------------------ the frame interface

    def start_streams(
        self, rows: int, sampler: SamplerChoice | None = None, fused: bool = True
    ) -> OnnxStreams:
        if sampler is not None and sampler.table(self.model.diffusion) != self.table:
            raise WalkdiffError(
                f"--runtime onnx: the graph was made for {self.sampler.label(self.model.diffusion)}, not "
                f"{sampler.label(self.model.diffusion)}"
            )
        lstm = self.model.encoder.lstm
        return OnnxStreams(rows, self.model.spec["feature_dim"], lstm.num_layers, lstm.hidden_size)

    def encode_control(self, control: torch.Tensor, style: torch.Tensor) -> torch.Tensor:
        """The raw control (B, F, 2K) and style weights (B, S) side by side: the graph encodes them."""
        if not style.is_floating_point():
            style = torch.nn.functional.one_hot(style, len(self.model.spec["styles"]))
        weights = style.to(control.dtype)[:, None].expand(-1, control.shape[1], -1)
        return torch.cat([control, weights], dim=-1)

    def match_streams(self, *args, **kwargs):
        raise WalkdiffError(
            "--runtime onnx runs the plain frame: example clips (--style-clip, style_clips) need "
            "--runtime torch"
        )

    def noise(
        self, rows: int, generator: torch.Generator | None, out: np.ndarray | None = None
    ) -> np.ndarray:
        """(slots, rows, D) noise drawn as `advance` of the torch model draws it; unused slots 0. `out`:
        an array of that shape to draw into (its unused slots left as they are: zeros)."""
        dim = self.model.spec["feature_dim"]
        noise = np.zeros((self.noise_slots, rows, dim), np.float32) if out is None else out
        for slot in self.noisy_slots:
            if generator is None or generator.device.type == "cpu":  # drawn in place, no copy
                torch.randn((rows, dim), generator=generator, out=torch.from_numpy(noise[slot]))
            else:
                noise[slot] = randn_like(torch.empty(rows, dim), generator).numpy()
        return noise

    def run(self, control: np.ndarray, previous, h, c, noise) -> list[np.ndarray]:
        """One frame of the graph: (pose, previous_out, h_out, c_out) for raw controls (B, ...)."""
        if self.kind == "walker":
            k = 2 * len(self.model.ahead)
            feeds = {"control": control[:, :k], "style": control[:, k:]}
        else:
            feeds = {"audio": control.reshape(len(control), self.model.window, -1)}  # raw log-mel frames
        feeds |= {"previous": previous, "h": h, "c": c, "noise": noise}
        return self.session.run(list(OUTPUTS), feeds)

    def advance(
        self,
        streams: OnnxStreams,
        control: torch.Tensor,
        generator: torch.Generator | None,
        rows: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """One frame for the streams `rows` (default: all) from their raw controls: their poses (R, D),
        normalised, as `AutoregressiveDiffusion.advance`."""
        control = control.float().cpu().numpy()
        if self.drawn.shape[1] != len(control):  # one buffer per row count: a run only reads it
            self.drawn = np.zeros((self.noise_slots, len(control), self.drawn.shape[2]), np.float32)
        noise = self.noise(len(control), generator, self.drawn)
        if rows is None:
            _, x, streams.h, streams.c = self.run(control, streams.previous, streams.h, streams.c, noise)
            streams.previous = x
        else:
            at = rows.cpu().numpy()
            _, x, h, c = self.run(control, streams.previous[at], streams.h[:, at], streams.c[:, at], noise)
            streams.previous, streams.h, streams.c = (
                streams.previous.copy(),
                streams.h.copy(),
                streams.c.copy(),
            )
            streams.previous[at], streams.h[:, at], streams.c[:, at] = x, h, c
        return torch.from_numpy(x)


def frame_runtime(
    model,
    runtime: str = "torch",
    sampler: SamplerChoice | None = None,
    threads: int | None = None,
    onnx: str | Path | None = None,
):
    """The model itself (torch), or `OnnxFrames` of it under `sampler` (default: ddim 10 steps, eta 1) on
    `threads` threads (None: torch's count at each frame): the frame exported now, in memory, or the graph
    `walkdiff export --format onnx` wrote into the folder `onnx` (checked to be this model's, for this
    sampler)."""
    if runtime not in RUNTIMES:
        raise WalkdiffError(f"--runtime: expected one of {', '.join(RUNTIMES)}, got {runtime!r}")
    if runtime == "torch":
        if onnx is not None:
            raise WalkdiffError("--onnx DIR is the graph --runtime onnx runs: add --runtime onnx")
        return model
    sampler = sampler or DEFAULT_SAMPLER
    data = None if onnx is None else exported_graph(model, sampler, onnx)
    return OnnxFrames(model, sampler, threads, data)


def exported_graph(model, sampler: SamplerChoice, folder: str | Path) -> bytes:
    """The graph `walkdiff export --format onnx` wrote into `folder` for `model` (KIND.onnx beside its
    contract KIND.json), refused with one line where it is another kind of model's, another model's
    (its pose normaliser differs) or another sampler's."""
    kind, folder = frame_kind(model), Path(folder)
    graph, terms_path = folder / f"{kind}.onnx", folder / f"{kind}.json"
    for path in (graph, terms_path):
        if not path.is_file():
            raise WalkdiffError(
                f"--onnx: no {path.name} here; write one with `walkdiff export --format onnx --ckpt CKPT "
                f"--out {folder}`",
                path=path,
            )
    try:
        terms = json.loads(terms_path.read_text())
        made_for, steps = terms["sampler"]["label"], terms["sampler"]["timesteps"]
        pose = terms["normalizers"]["pose"]
    except (ValueError, KeyError, TypeError) as error:
        raise WalkdiffError(
            f"not a contract of `walkdiff export --format onnx` ({error})", path=terms_path
        ) from None
    if terms.get("format") != FORMAT or terms.get("kind") != kind:
        raise WalkdiffError(f"expected a {FORMAT} contract of a {kind}", path=terms_path)
    asked = sampler.unguided().label(model.diffusion)
    if made_for != asked or steps != list(sampler.table(model.diffusion).timesteps):
        raise WalkdiffError(
            f"--onnx: {graph.name} was exported for the sampler {made_for}, this run asks for {asked}: give "
            f"its --sampler, --steps and --eta, or export the checkpoint again with yours",
            path=folder,
        )
    normalizer = model.normalizer
    ours = np.concatenate([normalizer.mean.detach().cpu().numpy(), normalizer.std.detach().cpu().numpy()])
    theirs = np.asarray(pose["mean"] + pose["std"], dtype=np.float64)
    if ours.shape != theirs.shape or not np.allclose(ours, theirs, rtol=1e-6, atol=1e-9):
        raise WalkdiffError(
            f"--onnx: {graph.name} was exported from another model (its pose normaliser is not this "
            "checkpoint's); export this checkpoint",
            path=folder,
        )
    return graph.read_bytes()
