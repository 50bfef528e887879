"""Speech-driven gestures from a DiffMotion checkpoint: `gesture` (a WAV, or speech as it arrives with
--stream) and `evaluate-gesture`."""

from __future__ import annotations

import argparse

from walkdiff.cli.options import (
    PREVIEW_HELP,
    Renamed,
    frame_sampler_options,
    keyword_options,
    rig_options,
    runtime_options,
    whole_or_stream,
)
from walkdiff.common.arguments import count, number


def add_parsers(sub) -> None:
    add_gesture(sub)
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
    runtime_options(p)
    rig_options(p)
    p.set_defaults(run=run_gesture)


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


def run_gesture(args: argparse.Namespace) -> None:
    from walkdiff.gestures.commands import gesture, gesture_stream

    whole_or_stream(args, gesture, gesture_stream, ("preview_seconds",))


def run_evaluate_gesture(args: argparse.Namespace) -> None:
    from walkdiff.gestures.evaluate import evaluate_gesture

    evaluate_gesture(**keyword_options(args))
    print(f"wrote {args.out}/report.json")
