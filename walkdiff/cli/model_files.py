"""Model files to share: `export` (safetensors and a JSON card, which every `--ckpt` takes) and
`checkpoint upgrade` (a pickled checkpoint you trust, rewritten so that walkdiff opens it weights-only)."""

from __future__ import annotations

import argparse

from walkdiff.cli.options import SAMPLERS
from walkdiff.common.arguments import count, number
from walkdiff.common.errors import WalkdiffError


def add_parsers(sub) -> None:
    p = sub.add_parser(
        "export",
        help="a checkpoint as a shareable model folder: model.safetensors and a model.json card (config, "
        "skeleton profile, labels, data, metrics); every --ckpt and --evaluator takes the folder",
    )
    p.add_argument("--ckpt", required=True, help="the checkpoint to export (any walkdiff model)")
    p.add_argument(
        "--out",
        required=True,
        help="folder for model.safetensors and model.json (onnx: KIND.onnx and KIND.json)",
    )
    p.add_argument(
        "--format",
        choices=("safetensors", "onnx", "web"),
        default="safetensors",
        help="safetensors (default): the whole model; onnx: one frame of a path walker or gesture model for "
        "ONNX Runtime in a game engine (walker.onnx or gesture.onnx, and its JSON contract: "
        "docs/game-engines.md); web: a path walker as a page that needs no server (index.html, the graph, "
        "onnxruntime-web; `make web` fetches it)",
    )
    p.add_argument(
        "--sampler", choices=SAMPLERS, default="ddim", help="onnx, web: the sampler inside the frame"
    )
    p.add_argument(
        "--steps", type=count(1), default=None, help="onnx, web: DDIM / DPM-Solver++ steps (default 10)"
    )
    p.add_argument("--eta", type=number(0, 1), default=None, help="onnx, web: DDIM noise (default 1)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier export in --out")
    p.set_defaults(run=run_export)

    p = sub.add_parser("checkpoint", help="model file upkeep: `walkdiff checkpoint upgrade OLD --trust`")
    what = p.add_subparsers(dest="what", metavar="WHAT", required=True)
    u = what.add_parser(
        "upgrade",
        help="rewrite a checkpoint that holds pickled Python objects as tensors and plain data; it is "
        "unpickled in full (which runs any code it holds), so only with --trust",
    )
    u.add_argument("old", help="the checkpoint walkdiff refused to open")
    u.add_argument("--out", required=True, help="the upgraded checkpoint (a new file; the old is kept)")
    u.add_argument("--trust", action="store_true", help="you trust where the file came from")
    u.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    u.set_defaults(run=run_upgrade)


def run_export(args: argparse.Namespace) -> None:
    if args.format == "web":
        from walkdiff.export.static_page import write_static_page

        terms = write_static_page(args.ckpt, args.out, args.sampler, args.steps, args.eta, args.overwrite)
        print(
            f"wrote {args.out}: index.html, walker.onnx, walker.json and ort/ "
            f"({terms['sampler']['label']} frame)"
        )
        return
    if args.format == "onnx":
        from walkdiff.export.onnx_files import export_onnx

        terms = export_onnx(args.ckpt, args.out, args.sampler, args.steps, args.eta, args.overwrite)
        kind = terms["kind"]
        print(f"wrote {args.out}: {kind}.onnx and {kind}.json ({terms['sampler']['label']} frame)")
        return
    if (args.sampler, args.steps, args.eta) != ("ddim", None, None):
        raise WalkdiffError("--sampler, --steps and --eta are for --format onnx and web")
    from walkdiff.common.model_files import export_model

    card = export_model(args.ckpt, args.out, overwrite=args.overwrite)
    print(f"wrote {args.out}: model.safetensors and model.json ({card['model_class'].rsplit('.', 1)[1]})")


def run_upgrade(args: argparse.Namespace) -> None:
    from walkdiff.common.model_files import upgrade_checkpoint

    print(f"wrote {upgrade_checkpoint(args.old, args.out, trust=args.trust, overwrite=args.overwrite)}")
