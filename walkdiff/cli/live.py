"""Walkers steered live: `control` (commands as JSON lines on stdin, poses out) and `play` (a local page to
steer a walker with the keys and record takes; with --script, timed key events replayed headless into a
take)."""

from __future__ import annotations

import argparse
import json

from walkdiff.cli.options import (
    keyword_options,
    rig_options,
    runtime_options,
    sampler_options,
    steering_options,
    walker_clip_options,
)
from walkdiff.common.arguments import count, number
from walkdiff.common.errors import WalkdiffError


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
    walker_clip_options(p)
    p.add_argument("--seed", type=count(0), default=0)
    real_time = "per-frame sampler (default ddim, 10 steps, eta 1: real time with DDPM's quality)"
    sampler_options(p, "ddim", real_time, eta=None)
    steering_options(p)
    runtime_options(p)
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
    rig_options(p)
    p.set_defaults(run=run_control)


def add_play(sub) -> None:
    p = sub.add_parser(
        "play", help="steer a walker with the keys on a local page and record takes; --script replays timed "
        "key events headless into a take",
    )  # fmt: skip
    walker_options(p)
    p.add_argument(
        "--script", default=None,
        help='JSON lines of timed key events {"t": 1.0, "key": "ArrowLeft", "down": true} and commands '
        '{"t": 2.0, "direction": [x, z], "speed": 1.2, "style": "old"}; without it, the page is served',
    )  # fmt: skip
    p.add_argument(
        "--out", default=None, help="output folder (take.bvh, take.glb, take.json; the page's later "
        "recordings take2.*, take3.*, ...); the page records only with it",
    )  # fmt: skip
    p.add_argument(
        "--host", default="127.0.0.1",
        help="the page's address (default 127.0.0.1: this machine only; 0.0.0.0 opens it to the network)",
    )  # fmt: skip
    p.add_argument("--port", type=count(0), default=8081, help="the page's port (default 8081; 0: any free)")
    p.add_argument(
        "--fps", type=number(0, above=True), default=None,
        help="frame rate of the written take (default the model's; it generates at its own)",
    )  # fmt: skip
    p.add_argument(
        "--static", default=None, metavar="OUT",
        help="write a page that needs no server into the folder OUT instead (index.html, walker.onnx, "
        "walker.json, onnxruntime-web): the walker runs in the browser itself; any static file server hosts "
        "it (docs/game-engines.md)",
    )  # fmt: skip
    rig_options(p)
    p.set_defaults(run=run_play)
    PLAY_DEFAULTS.update({a.dest: (a.option_strings[0], a.default) for a in p._actions if a.dest != "help"})


# `play`'s options (dest: flag and default): with --static, one given otherwise is refused.
PLAY_DEFAULTS: dict = {}
STATIC_TAKES = ("ckpt", "static", "sampler", "steps", "eta", "overwrite")


def static_page(options: dict) -> dict:
    """`play --static OUT`: the page that needs no server written into OUT (`write_static_page`), refusing
    the options it cannot take (those of the walker Python serves or replays) and files already in OUT
    unless --overwrite."""
    from walkdiff.export.static_page import write_static_page

    given = [k for k, v in options.items() if k not in STATIC_TAKES and v != PLAY_DEFAULTS[k][1]]
    if given:
        flag = PLAY_DEFAULTS[given[0]][0]
        raise WalkdiffError(
            f"{flag} is not for play --static: the page runs the walker in the browser on its own (its keys "
            "steer it, ?seed=N picks its noise); drop it"
        )
    out = options["static"]
    terms = write_static_page(
        options["ckpt"], out, options["sampler"], options["steps"], options["eta"], options["overwrite"]
    )
    return {
        "static": out, "sampler": terms["sampler"]["label"], "files": ["index.html", "walker.onnx",
        "walker.json", "ort/"], "serve": f"python -m http.server --directory {out} 8000",
    }  # fmt: skip


def run_control(args: argparse.Namespace) -> None:
    from walkdiff.live.play import control

    control(**keyword_options(args))  # prints its own JSON lines


def run_play(args: argparse.Namespace) -> None:
    from walkdiff.common.files import strict_json

    options = keyword_options(args)
    if options["static"] is not None:
        summary = static_page(options)
    elif options["script"] is None:
        from walkdiff.live.page import serve_page

        if options.pop("to") is not None or options.pop("to_map") is not None:
            raise WalkdiffError(
                "--to is for play --script (the page records on the model's skeleton); retarget its takes "
                "with `walkdiff retarget BVH --to RIG --out OUT`"
            )
        del options["script"], options["static"]
        summary = serve_page(**options)
    else:
        from walkdiff.live.play import play

        del options["host"], options["port"], options["static"]
        summary = play(**options)
    print(json.dumps(strict_json(summary), indent=2))
