"""A path walker's `walk`: a style along a path file, or along a path still being drawn with --stream."""

from __future__ import annotations

import argparse

from walkdiff.cli.options import (
    frame_sampler_options,
    preview_options,
    rig_options,
    runtime_options,
    walker_clip_options,
    whole_or_stream,
)
from walkdiff.common.arguments import count, number


def add_parsers(sub) -> None:
    add_walk(sub)


def add_walk(sub) -> None:
    p = sub.add_parser("walk", help="walking of a style along a 2-D path (JSON): BVH + GIF + plot + error")
    p.add_argument("--ckpt", required=True, help="PathWalker checkpoint (conf/walk_xia.yaml)")
    p.add_argument(
        "--style", required=True, help="walking style (proud) or a timeline: neutral@0,old@4s,angry+old@8s"
    )
    p.add_argument(
        "--transition", type=number(0), default=1.0,
        help="with a --style timeline: seconds each change is ramped over (default 1)",
    )  # fmt: skip
    walker_clip_options(p)
    p.add_argument(
        "--path", required=True,
        help='JSON: [[x, z], ...] or {"points": [...], "speed": units/s}; --stream: JSON lines (- for stdin)',
    )  # fmt: skip
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument(
        "--speed", type=number(0, above=True), default=None, help="m/s (default: the file's, or the style's)"
    )
    p.add_argument("--seed", type=count(0), default=0)
    frame_sampler_options(p)
    preview_options(p, "skip the GIF and MP4 preview")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument(
        "--stream", action="store_true",
        help='live: --path is JSON lines arriving over time ({"x": metres, "z": metres} each), from stdin '
        "(--path -) or a file still being written; print one JSON line per frame as soon as the path ahead "
        "allows, and write the BVH at the end (no GIF or plot)",
    )  # fmt: skip
    p.add_argument(
        "--idle", type=number(0, above=True), default=2.0,
        help="with --stream and a file: the path has ended once the file has not grown for this many seconds",
    )  # fmt: skip
    runtime_options(p)
    rig_options(p)
    p.set_defaults(run=run_walk)


def run_walk(args: argparse.Namespace) -> None:
    from walkdiff.walker.commands import walk, walk_stream

    whole_or_stream(args, walk, walk_stream, ("gif", "preview_seconds", "transition"))
