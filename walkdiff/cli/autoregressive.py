"""Models that make motion a frame at a time, live or from a file: `gesture` (speech), `walk` (a path), and
`evaluate-gesture`."""

from __future__ import annotations

import argparse
import json

from walkdiff.cli.options import (
    PREVIEW_HELP,
    Renamed,
    frame_sampler_options,
    keyword_options,
    rig_options,
    walker_clip_options,
)
from walkdiff.common.arguments import count, number
from walkdiff.common.errors import WalkdiffError


def add_parsers(sub) -> None:
    add_gesture(sub)
    add_walk(sub)
    add_evaluate_gesture(sub)


def add_gesture(sub) -> None:
    p = sub.add_parser("gesture", help="speech-driven gestures from a WAV with DiffMotion: BVH + GIF")
    p.add_argument("--ckpt", required=True, help="DiffMotion checkpoint")
    p.add_argument(
        "--audio",
        required=True,
        help="speech WAV (any rate; resampled as needed); with --stream, - for stdin",
    )
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--seed", type=count(0), default=0)
    frame_sampler_options(p)
    p.add_argument("--smooth", action="store_true", help="Savitzky-Golay smoothing (window 31, order 4)")
    p.add_argument(
        "--num", "--streams", type=count(1), default=1, action=Renamed,
        help="clips generated together (default 1; --streams is its old name)",
    )  # fmt: skip
    p.add_argument("--preview-seconds", type=number(0, above=True), default=20.0, help=PREVIEW_HELP)
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument(
        "--stream", action="store_true",
        help="live: take the audio as it arrives, from --audio - (raw PCM: s16le, mono, at the sample rate "
        "of the model's training audio or --rate) or from a WAV still being written (16-bit PCM or 32-bit "
        "float, at that rate); print one JSON line per pose as soon as the model's look-ahead allows, and "
        "write the BVH(s) at the end (no GIF)",
    )  # fmt: skip
    p.add_argument(
        "--rate", type=count(1), default=None,
        help="with --stream --audio -: the PCM's sample rate (default: the model's, if its checkpoint says)",
    )  # fmt: skip
    p.add_argument(
        "--idle", type=number(0, above=True), default=2.0,
        help="with --stream and a WAV: it has ended once it has not grown for this many seconds (default 2)",
    )  # fmt: skip
    p.add_argument(
        "--seconds",
        type=number(0, above=True),
        default=None,
        help="with --stream: stop after this much audio",
    )
    rig_options(p)
    p.set_defaults(run=run_gesture)


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
    p.add_argument("--no-gif", dest="gif", action="store_false", help="skip the GIF preview")
    p.add_argument("--preview-seconds", type=number(0, above=True), default=20.0, help=PREVIEW_HELP)
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
    rig_options(p)
    p.set_defaults(run=run_walk)


def add_evaluate_gesture(sub) -> None:
    # Its own verb: `evaluate` is the walking protocol (an evaluator network, FMD, style accuracy);
    # none of its options apply to gestures, which are scored against the held-out motion itself.
    p = sub.add_parser(
        "evaluate-gesture",
        help="DiffMotion on the held-out 20%% of each take: L1, PCK, beats, diversity, jerk",
    )
    p.add_argument("--ckpt", required=True, help="DiffMotion checkpoint")
    p.add_argument("--out", required=True, help="folder for report.json and per-take BVH/GIF")
    p.add_argument("--samples", type=count(1), default=5, help="samples of each take's audio (default 5)")
    p.add_argument("--seed", type=count(0), default=0)
    frame_sampler_options(p)
    p.add_argument(
        "--clip-seconds", type=number(0, above=True), default=2.0, help="diversity clip length (default 2 s)"
    )
    p.add_argument(
        "--pck-threshold",
        type=number(0, above=True),
        default=0.1,
        help="PCK distance in metres (default 0.1)",
    )
    p.add_argument("--root", default=None, help="data root (default: as in the checkpoint)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing report")
    rig_options(p)
    p.set_defaults(run=run_evaluate_gesture)


def stream_only(options: dict, names: tuple[str, ...]) -> None:
    """Drop the --stream options from `options`, refusing any that was given without --stream."""
    defaults = {"rate": None, "seconds": None, "idle": 2.0}
    for name in names:
        if options.pop(name) != defaults[name]:
            raise WalkdiffError(f"--{name} needs --stream")
    del options["stream"]


def no_rig_on_streams(options: dict) -> None:
    """Streams send their poses as they are made, on the training skeleton: --to is refused there."""
    if options.pop("to") is not None or options.pop("to_map") is not None:
        raise WalkdiffError(
            "--to does not work with --stream (the live poses are on the model's skeleton); retarget the "
            "BVH the stream writes with `walkdiff retarget BVH --to RIG --out OUT`"
        )


def run_gesture(args: argparse.Namespace) -> None:
    from walkdiff.autoregressive import gesture
    from walkdiff.common.files import strict_json

    options = keyword_options(args)
    if args.stream:
        no_rig_on_streams(options)
        del options["stream"], options["preview_seconds"]
        gesture.gesture_stream(**options)  # prints its own JSON lines
    else:
        stream_only(options, ("rate", "seconds", "idle"))
        print(json.dumps(strict_json(gesture.gesture(**options)), indent=2))


def run_walk(args: argparse.Namespace) -> None:
    from walkdiff.autoregressive.walk import walk, walk_stream
    from walkdiff.common.files import strict_json

    options = keyword_options(args)
    if args.stream:
        no_rig_on_streams(options)
        for key in ("stream", "gif", "preview_seconds", "transition"):
            del options[key]
        walk_stream(**options)  # prints its own JSON lines
    else:
        stream_only(options, ("idle",))
        print(json.dumps(strict_json(walk(**options)), indent=2))


def run_evaluate_gesture(args: argparse.Namespace) -> None:
    from walkdiff.autoregressive.gesture import evaluate_gesture

    evaluate_gesture(**keyword_options(args))
    print(f"wrote {args.out}/report.json")
