"""`walkdiff export --format onnx`: one frame of a path walker or a gesture model as OUT/KIND.onnx, and
beside it OUT/KIND.json, the contract an engine follows to run it (`contract.py`).

The graph is traced with torch's TorchScript-based exporter (`dynamo=False`): it needs only the `onnx`
package, where the torch.export-based one needs `onnxscript` too, and it gives fixed shapes for every
axis but the batch. Opset 17 runs on ONNX Runtime's C, C# and JavaScript (WASM) builds alike.
"""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path

import torch

from walkdiff.common.checkpoints import checkpoint_class
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import check_free, output_folder, output_set, write_atomic, write_text
from walkdiff.diffusion import SamplerChoice
from walkdiff.export.contract import contract
from walkdiff.export.graphs import OUTPUTS, frame_graph, frame_kind

OPSET = 17
DEFAULT_SAMPLER = SamplerChoice("ddim", 10, 1.0)  # the live walker's and `bench gesture`'s fast frame


def load_frame_model(ckpt: str | Path):
    """A trained path walker or DiffMotion from its checkpoint (or exported folder), on the CPU."""
    found = checkpoint_class(ckpt)
    if found.endswith(".PathWalker"):
        from walkdiff.models.path_walker import PathWalker

        return PathWalker.from_trained(ckpt, "path-walker")
    if found.endswith(".DiffMotion"):
        from walkdiff.models.diffmotion import DiffMotion

        model = DiffMotion.from_trained(ckpt, "DiffMotion")
        if model.neutral is None:
            raise WalkdiffError(
                "the checkpoint has no neutral pose; was it saved by `walkdiff fit`?", path=ckpt
            )
        return model
    raise WalkdiffError(
        f"--format onnx exports a path walker or a gesture model (DiffMotion); this checkpoint is a {found}",
        path=ckpt,
    )


def graph_bytes(model, sampler: SamplerChoice = DEFAULT_SAMPLER) -> bytes:
    """The frame of `model` under `sampler` as a serialised ONNX model, batch size free."""
    graph = frame_graph(model.cpu().eval(), sampler)
    names = list(graph.inputs)
    batch = {name: {1 if name in ("h", "c", "noise") else 0: "batch"} for name in names}
    batch |= {name: {1 if name in ("h_out", "c_out") else 0: "batch"} for name in OUTPUTS}
    buffer = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        # The TorchScript exporter is deprecated in torch 2.13 but kept for its single dependency (see the
        # module docstring); its constant-folding notes about strided slices are harmless.
        warnings.filterwarnings("ignore", message=".*legacy TorchScript-based ONNX export.*")
        warnings.filterwarnings("ignore", message=".*feature will be removed.*")
        warnings.filterwarnings("ignore", message=".*Constant folding.*")
        # The LSTM step loops over its layers' states: a fixed count, which the trace rightly keeps.
        warnings.filterwarnings("ignore", message="Iterating over a tensor", category=torch.jit.TracerWarning)
        torch.onnx.export(
            graph, graph.examples(2), buffer, dynamo=False, opset_version=OPSET, input_names=names,
            output_names=list(OUTPUTS), dynamic_axes=batch, do_constant_folding=True,
        )  # fmt: skip
    return buffer.getvalue()


def export_onnx(
    ckpt: str | Path,
    out: str | Path,
    sampler: str = "ddim",
    steps: int | None = None,
    eta: float | None = None,
    overwrite: bool = False,
) -> dict:
    """OUT/walker.onnx and OUT/walker.json (or gesture.*) for the checkpoint's model: one frame under the
    sampler (ddim: 10 steps, eta 1 unless given); returns the contract."""
    import onnx

    choice = sampler_choice(sampler, steps, eta)
    model = load_frame_model(ckpt)
    kind = frame_kind(model)
    out = output_folder(out)
    graph_path, contract_path = out / f"{kind}.onnx", out / f"{kind}.json"
    check_free([graph_path, contract_path], overwrite)
    data = graph_bytes(model, choice)
    onnx.checker.check_model(onnx.load_from_string(data))
    terms = contract(model, choice, graph_path.name) | {"exported_from": str(ckpt)}
    with output_set(out):  # both or neither
        write_atomic(graph_path, lambda f: f.write(data))
        write_text(contract_path, json.dumps(terms, indent=1) + "\n")
    return terms


def sampler_choice(
    sampler: str = "ddim", steps: int | None = None, eta: float | None = None
) -> SamplerChoice:
    """The sampler as the command line names it: ddim is 10 steps with eta 1 unless given (the live
    walker's default)."""
    if sampler == "ddim":
        steps, eta = steps or 10, 1.0 if eta is None else eta
    return SamplerChoice(sampler, steps, eta or 0.0)
