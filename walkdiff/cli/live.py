"""Walkers steered live: `control` (commands as JSON lines on stdin, poses out) and `play` (a script of key
events and commands replayed into a take; the interactive page comes later under the same command)."""

from __future__ import annotations

import argparse
import json

from walkdiff.cli.options import SAMPLERS, keyword_options
from walkdiff.common.arguments import count, number


def add_parsers(sub) -> None:
    add_control(sub)
    add_play(sub)


def walker_options(p: argparse.ArgumentParser) -> None:
    """What a steered walker is: its checkpoint, its start, its sampler and how it turns."""
    p.add_argument("--ckpt", required=True, help="PathWalker checkpoint (conf/walk_xia.yaml)")
    p.add_argument(
        "--style", default=None, help="style at the start: a name or a mix angry:0.7,old:0.3 (default: the "
        "model's first style with a known walking speed)",
    )  # fmt: skip
    p.add_argument(
        "--speed", type=number(0), default=None, help="m/s at the start (default: the style's own speed)"
    )
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument(
        "--sampler", choices=SAMPLERS, default="ddim",
        help="per-frame sampler (default ddim, 10 steps, eta 1: real time with DDPM's quality)",
    )  # fmt: skip
    p.add_argument("--steps", type=count(1), default=None, help="DDIM / DPM-Solver++ steps (default 10)")
    p.add_argument("--eta", type=number(0, 1), default=None, help="DDIM noise (default 1)")
    p.add_argument(
        "--transition", type=number(0), default=0.0,
        help="seconds a style change is ramped over (default 0: at once)",
    )  # fmt: skip
    p.add_argument(
        "--turn-rate", type=number(0, above=True), default=180.0,
        help="degrees per second the control's path bends at towards a new direction (default 180)",
    )  # fmt: skip
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")


def add_control(sub) -> None:
    p = sub.add_parser(
        "control", help="steer walkers live: commands as JSON lines on stdin, a pose per frame on stdout"
    )
    walker_options(p)
    p.add_argument(
        "--characters", type=count(1), default=1,
        help='walkers stepped together (default 1); a line\'s "character" commands one of them',
    )  # fmt: skip
    p.add_argument(
        "--out", default=None,
        help="folder for the recorded take at the end (take.bvh, take.glb, take.json); default: none",
    )  # fmt: skip
    p.set_defaults(run=run_control)


def add_play(sub) -> None:
    p = sub.add_parser(
        "play", help="steer a walker with keys: --script replays timed key events headless into a take"
    )
    walker_options(p)
    p.add_argument(
        "--script", default=None,
        help='JSON lines of timed key events {"t": 1.0, "key": "ArrowLeft", "down": true} and commands '
        '{"t": 2.0, "direction": [x, z], "speed": 1.2, "style": "old"}',
    )  # fmt: skip
    p.add_argument("--out", default=None, help="output folder (take.bvh, take.glb, take.json)")
    p.add_argument(
        "--fps", type=number(0, above=True), default=None,
        help="frame rate of the written take (default the model's; it generates at its own)",
    )  # fmt: skip
    p.set_defaults(run=run_play)


def run_control(args: argparse.Namespace) -> None:
    from walkdiff.autoregressive.play import control

    control(**keyword_options(args))  # prints its own JSON lines


def run_play(args: argparse.Namespace) -> None:
    from walkdiff.autoregressive.play import play
    from walkdiff.common.files import strict_json

    print(json.dumps(strict_json(play(**keyword_options(args))), indent=2))
