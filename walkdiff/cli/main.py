"""The `walkdiff` command: Lightning's fit/validate/test plus the tools users run on their motion."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from walkdiff.callbacks.fit import lightning_cli
from walkdiff.common.arguments import Parser, count, counts, number
from walkdiff.common.errors import WalkdiffError

# diffusion.SAMPLERS, repeated so that building the parser imports no torch (a test keeps them equal).
SAMPLERS = ("ddpm", "ddim", "dpmpp")
SAMPLER_HELP = (
    "ddpm: ancestral, all T steps (default); ddim: DDIM over --steps; dpmpp: DPM-Solver++(2M), DDIM's ODE "
    "solved to second order, closer to DDPM at 10 steps for the same cost"
)

FRAME_SAMPLER_HELP = (
    "per frame: ddpm, ancestral over all N trained steps (default); ddim over --steps of them (--eta its "
    "noise); dpmpp, DPM-Solver++(2M) over --steps (see the README's speed and quality table)"
)

LIGHTNING_VERBS = ("fit", "validate", "test")
PREVIEW_HELP = "seconds of each clip the GIF preview shows, from its start (default 20)"
PROFILE_HELP = (
    "YAML/JSON of skeleton profile overrides (root, left_heel, left_toe, right_heel, right_toe, up, forward, "
    "units, body_height, contact_speed, contact_height, mirror_pairs); the rest is found from the file"
)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="walkdiff",
        description="Diffusion-based motion synthesis. Training verbs: "
        + ", ".join(LIGHTNING_VERBS)
        + " (LightningCLI; `walkdiff fit --help`).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser(
        "inspect", help="summarise a BVH file: joints, frames, fps, contacts, anything suspicious"
    )
    p.add_argument("file")
    p.add_argument("--profile", default=None, help=PROFILE_HELP)

    p = sub.add_parser(
        "convert",
        help="BVH -> features -> BVH, or BVH -> binary glTF (.glb); optionally resampled and/or mirrored",
    )
    p.add_argument("input")
    p.add_argument("output")
    p.add_argument("--fps", type=number(0, above=True), default=None, help="resample to this frame rate")
    p.add_argument("--mirror", action="store_true", help="swap left and right (in world space)")
    p.add_argument("--profile", default=None, help=PROFILE_HELP)
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")

    p = sub.add_parser("view", help="play BVH files side by side in 3-D in the browser (orbit, scrub, play)")
    p.add_argument("files", nargs="+", help="BVH files (any skeleton; shown Y up in metres)")
    p.add_argument("--port", type=count(0), default=8080, help="port (default 8080; 0: any free port)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default: this machine only)")
    p.add_argument("--profile", default=None, help=PROFILE_HELP)

    p = sub.add_parser("data", help="your own motion capture: `walkdiff data scan DIR`")
    data = p.add_subparsers(dest="what", metavar="WHAT", required=True)
    d = data.add_parser(
        "scan",
        help="a folder of BVH files: skeleton profile, frame rates, labels, clip lengths, suggested window; "
        "with --out, the evaluator and generator configs that `walkdiff fit --config` runs",
    )
    d.add_argument("folder", help="folder of BVH files (searched recursively)")
    d.add_argument("--labels", default=None, help="CSV/JSON manifest: file, style, content, split columns")
    d.add_argument("--pattern", default=None, help="regular expression with named groups style / content")
    d.add_argument("--default-style", default=None, help="style of clips without one")
    d.add_argument("--default-content", default=None, help="content of clips without one")
    d.add_argument(
        "--val-fraction",
        type=number(0, 1, below=True),
        default=None,
        help="per label, held out for validation",
    )
    d.add_argument(
        "--test-fraction", type=number(0, 1, below=True), default=None, help="per label, held out for testing"
    )
    d.add_argument("--profile", default=None, help=PROFILE_HELP)
    d.add_argument(
        "--fps",
        type=number(0, above=True),
        default=None,
        help="training frame rate (default: 30, or the data's)",
    )
    d.add_argument("--name", default=None, help="config name (default: the folder's name)")
    d.add_argument("--out", default=None, help="folder to write the two configs into")
    d.add_argument("--overwrite", action="store_true", help="replace existing configs")

    p = sub.add_parser(
        "score",
        help="score any folder of BVH files (or a transfer's outputs) with an evaluator: report.json/.md",
    )
    p.add_argument("folder", nargs="?", default=None, help="folder of BVH files (not with --transfer)")
    p.add_argument("--evaluator", required=True, help="MotionEvaluator checkpoint")
    p.add_argument("--out", required=True, help="folder for report.json and report.md")
    p.add_argument("--labels", default=None, help="label manifest (CSV/JSON: file, style, content)")
    p.add_argument("--pattern", default=None, help="regex with (?P<style>...) / (?P<content>...) groups")
    p.add_argument(
        "--transfer", default=None,
        help="transfer manifest CSV: file, source, style[, content] (paths relative to it)",
    )  # fmt: skip
    p.add_argument(
        "--stride", type=count(1), default=None, help="frames between windows (default: half a window)"
    )
    p.add_argument("--bootstrap", type=count(0), default=500, help="resamples of the clips (default 500)")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--contents", default=None, help="real reference contents (default: the protocol's)")
    p.add_argument("--root", default=None, help="data root (default: as in the evaluator checkpoint)")
    p.add_argument("--cache-dir", default=None, help="feature cache (default: as in the checkpoint)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing report")

    p = sub.add_parser(
        "evaluate", help="FMD, recognition accuracy, diversity, skating, jitter over repeats: report.json/.md"
    )
    p.add_argument(
        "--ckpt",
        help="generator checkpoint (not needed with --real-only); a DiffMotion checkpoint is scored with "
        "the gesture metrics of evaluate-gesture, --repeats samples of each held-out take",
    )
    p.add_argument("--evaluator", help="MotionEvaluator checkpoint (walking and action models)")
    p.add_argument("--out", required=True, help="folder for report.json and report.md")
    p.add_argument("--num", type=count(1), default=1000, help="windows per repeat (default 1000)")
    p.add_argument("--repeats", type=count(1), default=20, help="repeats (default 20)")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--real-only", action="store_true", help="only the real reference rows")
    p.add_argument("--sampler", choices=SAMPLERS, default="ddpm", help=SAMPLER_HELP)
    p.add_argument("--steps", type=count(1), default=None, help="DDIM / DPM-Solver++ steps (default 10)")
    p.add_argument("--guidance", type=number(0), default=1.0, help="classifier-free guidance weight")
    p.add_argument("--split", choices=("test", "val"), default="test", help="real reference split")
    p.add_argument("--contents", default=None, help="content groups (default: the model's; or walk)")
    p.add_argument("--root", default=None, help="data root (default: as in the checkpoint)")
    p.add_argument("--cache-dir", default=None, help="feature cache (default: as in the checkpoint)")
    p.add_argument("--stride", type=count(1), default=1, help="frames between real windows (default 1)")
    p.add_argument("--batch-size", type=count(1), default=500, help="windows generated / scored at once")
    p.add_argument("--device", default="auto", help="auto, cpu or cuda")
    p.add_argument(
        "--no-ground", dest="ground", action="store_false",
        help="score the windows as sampled, without grounding their feet (reported beside them otherwise)",
    )  # fmt: skip
    p.add_argument("--mlflow-experiment", default=None, help="log metrics and reports into an MLflow run")
    p.add_argument("--overwrite", action="store_true", help="replace an existing report")

    def sampling_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("--ckpt", required=True, help="StyledMotionDiffusion checkpoint")
        p.add_argument("--out", required=True, help="output folder")
        p.add_argument("--style", required=True, help="a style, or a mix: angry:0.7,old:0.3")
        p.add_argument("--content", default="walk", help="content group (default walk)")
        p.add_argument("--seed", type=count(0), default=0)
        p.add_argument("--sampler", choices=SAMPLERS, default="ddpm", help=SAMPLER_HELP)
        p.add_argument("--steps", type=count(1), default=None, help="DDIM / DPM-Solver++ steps (default 10)")
        p.add_argument("--eta", type=number(0, 1), default=0.0, help="DDIM noise (0: deterministic)")
        p.add_argument("--guidance", type=number(0), default=1.0, help="classifier-free guidance (1: none)")
        p.add_argument(
            "--overlap",
            type=count(0),
            default=None,
            help="frames shared by consecutive windows (default: half a window)",
        )
        p.add_argument(
            "--blend", type=count(0), default=None, help="of those, frames cross-faded (default: half)"
        )
        p.add_argument("--fix-feet", action="store_true", help="pin feet during predicted contacts (IK)")
        p.add_argument(
            "--no-ground", dest="ground", action="store_false",
            help="keep the height as sampled (default: planted feet lifted or lowered onto the floor)",
        )  # fmt: skip
        p.add_argument("--no-gif", dest="gif", action="store_false", help="skip the GIF previews")
        p.add_argument("--preview-seconds", type=number(0, above=True), default=20.0, help=PREVIEW_HELP)
        p.add_argument("--overwrite", action="store_true", help="replace existing output files")
        p.add_argument("--device", default="cpu", help="cpu or cuda")

    p = sub.add_parser("sample", help="generate styled motion of any length: BVH + GIF + manifest.json")
    sampling_options(p)
    p.add_argument("--num", type=count(1), default=8, help="clips (default 8)")
    p.add_argument(
        "--frames", type=count(1), default=300, help="frames per clip at the model's fps (default 300)"
    )

    p = sub.add_parser("transfer", help="restyle a BVH clip (noise to strength*T, denoise in the new style)")
    sampling_options(p)
    p.add_argument("--input", required=True, help="BVH clip on the model's skeleton (any frame rate)")
    p.add_argument(
        "--strength", type=number(0, 1, above=True), default=0.6, help="noise level in (0, 1] (default 0.6)"
    )
    p.add_argument("--keep-trajectory", action="store_true", help="keep the source's root path exactly")

    def frame_sampler_options(p: argparse.ArgumentParser) -> None:
        """Options of the per-frame sampler of DiffMotion and the path walker."""
        p.add_argument("--sampler", choices=SAMPLERS, default="ddpm", help=FRAME_SAMPLER_HELP)
        p.add_argument("--steps", type=count(1), default=None, help="DDIM / DPM-Solver++ steps (default 10)")
        p.add_argument("--eta", type=number(0, 1), default=0.0, help="DDIM noise (0: deterministic)")

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
    p.add_argument("--streams", type=count(1), default=1, help="samples generated together (default 1)")
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

    p = sub.add_parser("walk", help="walking of a style along a 2-D path (JSON): BVH + GIF + plot + error")
    p.add_argument("--ckpt", required=True, help="PathWalker checkpoint (conf/walk_xia.yaml)")
    p.add_argument("--style", required=True, help="walking style, e.g. proud")
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

    p = sub.add_parser(
        "distill", help="train a student of a generator that samples with DDIM in few steps (default 10)"
    )
    p.add_argument("--ckpt", required=True, help="teacher: a StyledMotionDiffusion checkpoint")
    p.add_argument("--out", required=True, help="student checkpoint to write")
    p.add_argument(
        "--steps", type=counts(1), default=[10],
        help="DDIM step counts the student is made for, one or several: 10 (default), 1,2",
    )  # fmt: skip
    p.add_argument(
        "--teacher-steps", type=count(1), default=None,
        help="the teacher's DPM-Solver++ steps over all of T for the targets (default: every trained step); "
        "a 1-step target then costs this many teacher passes instead of T",
    )  # fmt: skip
    p.add_argument(
        "--lambda-accel", type=number(0), default=0.0,
        help="weight of the squared error of the output's frame-to-frame acceleration beside the plain "
        "squared error (default 0): keeps a 1- or 2-step student's samples from jittering",
    )  # fmt: skip
    p.add_argument(
        "--iterations", type=count(1), default=1000,
        help="batches to train (default 1000): the bound, so the same command and seed give the same student "
        "on any machine",
    )  # fmt: skip
    p.add_argument(
        "--minutes", type=number(0, above=True), default=None,
        help="optional safety net: stop after this many minutes (says how many of the batches were done, "
        "and records it in the student's checkpoint; the student then depends on the machine's speed)",
    )  # fmt: skip
    p.add_argument("--lr", type=number(0, above=True), default=3e-5, help="Adam learning rate (default 3e-5)")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out")

    p = sub.add_parser("bench", help="benchmarks; results written as JSON")
    bench = p.add_subparsers(dest="what", metavar="WHAT", required=True)
    b = bench.add_parser("data", help="cold/warm preprocessing of the dataset and DataLoader throughput")
    b.add_argument("--out", required=True)
    b.add_argument("--dataset", default="xia")
    b.add_argument("--root", default=None)
    b = bench.add_parser("train", help="training windows/s under Lightning vs a plain PyTorch loop")
    b.add_argument("--out", required=True)
    b.add_argument("--config", default="conf/xia_cpu.yaml")
    b.add_argument("--batches", type=count(1), default=30, help="batches timed per repeat")
    b.add_argument(
        "--to-bar", action="store_true",
        help="train the config to its epoch bound and report when its metrics reach the quality bar",
    )  # fmt: skip
    b.add_argument(
        "--evaluator",
        default=None,
        help="with --to-bar: the metrics callback's evaluator (default: the config's)",
    )
    b.add_argument(
        "--repeats", type=count(1), default=5, help="with --to-bar: draws of real held-out windows"
    )
    b.add_argument(
        "fit_args", nargs="*", metavar="-- FIT_OPTION",
        help="with --to-bar, after --: `walkdiff fit` overrides of the config (-- --model.lr 1e-3)",
    )  # fmt: skip
    b = bench.add_parser(
        "gesture", help="DiffMotion s/frame (1 stream: DDPM and few-step, plain and fused), batched streams"
    )
    b.add_argument("--out", required=True)
    b.add_argument(
        "--ckpt", default=None, help="DiffMotion checkpoint (default: an untrained ZEGGS-sized one)"
    )
    b.add_argument("--frames", type=count(1), default=40, help="frames timed per setting (default 40)")
    b.add_argument("--repeats", type=count(1), default=5, help="interleaved rounds (default 5)")
    b.add_argument("--sampler", choices=SAMPLERS, default="ddim", help="the few-step sampler (default ddim)")
    b.add_argument("--steps", type=count(1), default=10, help="its steps (default 10)")
    b.add_argument("--eta", type=number(0, 1), default=1.0, help="DDIM noise (default 1: as DDPM's steps)")
    b.add_argument("--streams", default="16,64,128", help="batched streams timed (default 16,64,128)")
    b = bench.add_parser(
        "stream", help="streaming latency (audio in -> pose out, path point -> frame) and real-time streams"
    )
    b.add_argument("--out", required=True)
    b.add_argument(
        "--ckpt", default=None, help="DiffMotion checkpoint (default: an untrained ZEGGS-sized one)"
    )
    b.add_argument(
        "--walker", default=None, help="PathWalker checkpoint (default: an untrained Xia-sized one)"
    )
    b.add_argument(
        "--seconds",
        type=number(0, above=True),
        default=6.0,
        help="audio / walking fed in real time (default 6)",
    )
    b.add_argument("--chunk-ms", type=number(0, above=True), default=20.0, help="audio chunk (default 20 ms)")
    b.add_argument(
        "--rate", type=count(1), default=16000, help="sample rate when the model records none (default 16000)"
    )
    b.add_argument("--frames", type=count(1), default=6, help="frames timed per stream count (default 6)")
    b.add_argument("--most", type=count(1), default=256, help="most streams tried (default 256)")
    b.add_argument(
        "--threads",
        default="1,2",
        help="torch thread counts the streams are timed at (default 1,2; latency: 1)",
    )
    frame_sampler_options(b)
    b = bench.add_parser("memory", help="peak memory of `walkdiff sample --frames N --num 1` per N")
    b.add_argument("--ckpt", required=True, help="StyledMotionDiffusion checkpoint")
    b.add_argument("--out", required=True, help="JSON file")
    b.add_argument("--frames", default="300,10000,100000", help="frame counts (default 300,10000,100000)")
    b.add_argument("--walker", default=None, help="PathWalker checkpoint: also `walk` along long paths")
    b.add_argument("--gesture", default=None, help="DiffMotion checkpoint: also `gesture` on long audio")
    b.add_argument("--audio", default=None, help="speech WAV, repeated to each of --seconds (with --gesture)")
    b.add_argument("--seconds", default="10,120", help="walk / speech seconds (default 10,120)")
    b = bench.add_parser(
        "view", help="seconds until `walkdiff view` shows its skeletons in headless Chromium"
    )
    b.add_argument("files", nargs="*", help="BVH files (default: the first two of the data root's xia/)")
    b.add_argument("--out", required=True, help="JSON file")
    b.add_argument(
        "--repeats", type=count(1), default=5, help="page loads, each in a fresh browser (default 5)"
    )
    b = bench.add_parser("walk", help="path-following error and style accuracy of walks along test paths")
    b.add_argument("--ckpt", required=True, help="PathWalker checkpoint")
    b.add_argument("--evaluator", required=True, help="MotionEvaluator checkpoint (style accuracy)")
    b.add_argument("--out", required=True, help="JSON file; the plot goes next to it as .png")
    b.add_argument("--seed", type=count(0), default=0)

    def quality_options(b: argparse.ArgumentParser, num: int) -> None:
        b.add_argument("--evaluator", required=True, help="MotionEvaluator checkpoint")
        b.add_argument(
            "--num", type=count(1), default=num, help=f"windows per setting and seed (default {num})"
        )
        b.add_argument("--seed", type=count(0), default=0, help="first seed (default 0)")
        b.add_argument("--seeds", type=count(1), default=3, help="seeds averaged per setting (default 3)")
        b.add_argument(
            "--no-ground", dest="ground", action="store_false",
            help="score windows as sampled (needed for checkpoints saved before grounding existed)",
        )  # fmt: skip

    b = bench.add_parser("distill", help="a distilled student's DDIM FMD against its teacher's DDPM")
    b.add_argument("--teacher", required=True, help="the checkpoint the student was distilled from")
    b.add_argument("--student", required=True, help="the checkpoint `walkdiff distill` wrote")
    b.add_argument("--out", required=True, help="JSON file")
    quality_options(b, 256)
    b = bench.add_parser("sample", help="FMD/style accuracy vs sampling steps, speed, --fix-feet, transfer")
    b.add_argument("--ckpt", required=True, help="StyledMotionDiffusion checkpoint")
    b.add_argument("--out", required=True, help="folder for sample.json and sample.png")
    b.add_argument(
        "--strength", type=number(0, 1, above=True), default=0.6, help="transfer noise level (default 0.6)"
    )
    quality_options(b, 400)
    b = bench.add_parser(
        "protocol", help="sampling and transfer rows of the evaluation protocol beside its baselines"
    )
    b.add_argument("--ckpt", required=True, help="StyledMotionDiffusion checkpoint")
    b.add_argument("--evaluator", required=True, help="MotionEvaluator checkpoint")
    b.add_argument(
        "--student",
        default=None,
        help="a distilled student's checkpoint (a row for each of its DDIM step counts)",
    )
    b.add_argument("--out", required=True, help="folder for protocol.json and protocol.md")
    b.add_argument("--strengths", default="0.4,0.6,0.8", help="transfer strengths (default 0.4,0.6,0.8)")
    b.add_argument("--samples", type=count(1), default=256, help="windows per sampling row (default 256)")
    b.add_argument("--bootstrap", type=count(0), default=200, help="resamples of the clips (default 200)")
    b.add_argument("--seed", type=count(0), default=0)
    for b in bench.choices.values():
        b.add_argument("--overwrite", action="store_true", help="replace the results of an earlier run")
    return parser


def main(argv: list[str] | None = None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in words
    if debug:
        words.remove("--debug")
        argv = words
    try:
        if words and words[0] in LIGHTNING_VERBS:
            lightning_cli(argv)  # None: LightningCLI reads sys.argv itself
            return 0
        args = build_parser().parse_args(words)
        if args.command is None:
            build_parser().print_help()
            return 2
        output = command_output(args)
        if output is None:
            return run_command(args)
        from walkdiff.common.files import check_free, output_lock

        path, guarded = output
        with output_lock(path, " ".join(filter(None, (args.command, getattr(args, "what", None))))):
            if guarded:  # the CLI guards these outputs itself: the function underneath has no such option
                check_free([path / name for name in guarded], args.overwrite)
                del args.overwrite
            return run_command(args)
    except WalkdiffError as error:
        if debug:
            raise
        print(f"walkdiff: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("walkdiff: interrupted", file=sys.stderr)
        return 130
    except SystemExit as stop:
        # Lightning ends a fit on SIGTERM with a bare SystemExit (status 0): say so, and fail.
        if type(stop).__name__ != "SIGTERMException":
            raise
        print("walkdiff: stopped by SIGTERM; its MLflow run, if any, is marked FAILED", file=sys.stderr)
        return 143
    except Exception as error:  # the boundary: no bare traceback for users; --debug shows it
        if debug:
            raise
        cause = _walkdiff_cause(error)
        if cause is not None:  # raised while LightningCLI built a model or data module: say it plainly
            message = str(cause)
        elif type(error).__name__ == "ArgumentError":  # LightningCLI's option and config errors
            message = f"{option_error(str(error))}; see `walkdiff {words[0]} --help`"
        else:
            message = f"{type(error).__name__}: {error} (run again with --debug for the traceback)"
        print(f"walkdiff: error: {message}", file=sys.stderr)
        return 1


# Folder outputs of the bench verbs; the others write one JSON file.
BENCH_FOLDERS = ("sample", "protocol")
# The files that mark an earlier run, for commands whose own code does not check what it would replace.
REPORTS = {"evaluate": ("report.json", "report.md"), "evaluate-gesture": ("report.json",)}
BENCH_REPORTS = {"sample": ("sample.json", "sample.png"), "protocol": ("protocol.json", "protocol.md")}


def command_output(args: argparse.Namespace) -> tuple[Path, tuple[str, ...]] | None:
    """The output a command writes, locked while it runs, and the files there that need --overwrite.

    Commands that write check their own outputs (by name) unless listed here; a file output is guarded
    as a whole ("" names the file itself).
    """
    if args.command == "convert":
        return Path(args.output), ()
    if args.command == "bench":
        folder = args.what in BENCH_FOLDERS
        return Path(args.out), BENCH_REPORTS[args.what] if folder else ("",)
    out = getattr(args, "out", None)
    if out is None:  # inspect; data scan without --out
        return None
    return Path(out), REPORTS.get(args.command, ())


def _walkdiff_cause(error: BaseException) -> WalkdiffError | None:
    """The WalkdiffError an exception was raised from (jsonargparse wraps those of __init__), if any."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, WalkdiffError):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def option_error(text: str) -> str:
    """jsonargparse's nested explanation -> 'key: the most specific problem'."""
    lines = [line.strip(" -") for line in text.splitlines() if line.strip(" -")]
    if not lines:
        return text
    specific = ("not accepted", "does not exist", "not found", "Unable to", "unexpected value", "Expected a")
    detail = next(
        (line for line in lines[1:] if any(s in line for s in specific) and "NoneType" not in line), None
    )
    return lines[0] if detail is None else f"{lines[0].rstrip(':')}: {detail}"


def stream_only(options: dict, names: tuple[str, ...]) -> None:
    """Drop the --stream options from `options`, refusing any that was given without --stream."""
    defaults = {"rate": None, "seconds": None, "idle": 2.0}
    for name in names:
        if options.pop(name) != defaults[name]:
            raise WalkdiffError(f"--{name} needs --stream")
    del options["stream"]


def run_command(args: argparse.Namespace) -> int:
    if args.command == "inspect":
        from walkdiff.motion.conversion import inspect_file

        print(inspect_file(args.file, args.profile))
    elif args.command == "convert":
        from walkdiff.motion.conversion import convert_file

        print(
            convert_file(
                args.input,
                args.output,
                fps=args.fps,
                mirror_sides=args.mirror,
                profile=args.profile,
                overwrite=args.overwrite,
            )  # fmt: skip
        )
    elif args.command == "view":
        from walkdiff.preview.view import view

        view(args.files, host=args.host, port=args.port, profile=args.profile)
    elif args.command == "data":
        from walkdiff.common.files import read_config
        from walkdiff.data.scan import scan

        options = vars(args).copy()
        for key in ("command", "what"):
            del options[key]
        if options["profile"]:
            options["profile"] = read_config(options["profile"], "--profile")
        print(scan(**options))
    elif args.command == "evaluate":
        from walkdiff.common.checkpoints import checkpoint_class
        from walkdiff.evaluation.evaluate import evaluate

        if args.ckpt and checkpoint_class(args.ckpt) == "walkdiff.models.diffmotion.DiffMotion":
            from walkdiff.autoregressive.gesture import evaluate_gesture

            evaluate_gesture(
                args.ckpt, args.out, samples=args.repeats, seed=args.seed, root=args.root,
                sampler=args.sampler, steps=args.steps,
            )  # fmt: skip
            print(f"wrote {args.out}/report.json")
            return 0
        if args.evaluator is None:
            raise WalkdiffError(
                "--evaluator is required to score a walking or action model (a MotionEvaluator checkpoint)"
            )
        options = vars(args).copy()
        del options["command"]
        report = evaluate(**options)
        print(f"wrote {args.out}/report.json and report.md in {report['elapsed_s']} s")
    elif args.command in ("sample", "transfer"):
        from walkdiff.styled import generation

        options = vars(args).copy()
        del options["command"]
        report = getattr(generation, args.command)(**options)
        print(f"wrote {args.out}: " + ", ".join(f"{k} {v}" for k, v in report["timing"].items()))
        if report["preview"] is not None:
            print(f"preview: {report['preview']['note']}")
    elif args.command in ("gesture", "evaluate-gesture"):
        from walkdiff.autoregressive import gesture
        from walkdiff.common.files import strict_json

        options = vars(args).copy()
        del options["command"]
        if args.command == "gesture" and args.stream:
            del options["stream"], options["preview_seconds"]
            gesture.gesture_stream(**options)  # prints its own JSON lines
        elif args.command == "gesture":
            stream_only(options, ("rate", "seconds", "idle"))
            print(json.dumps(strict_json(gesture.gesture(**options)), indent=2))
        else:
            gesture.evaluate_gesture(**options)
            print(f"wrote {args.out}/report.json")
    elif args.command == "walk":
        from walkdiff.autoregressive.walk import walk, walk_stream
        from walkdiff.common.files import strict_json

        options = vars(args).copy()
        del options["command"]
        if args.stream:
            for key in ("stream", "gif", "preview_seconds"):
                del options[key]
            walk_stream(**options)  # prints its own JSON lines
        else:
            stream_only(options, ("idle",))
            print(json.dumps(strict_json(walk(**options)), indent=2))
    elif args.command == "score":
        from walkdiff.evaluation.score import score

        options = vars(args).copy()
        del options["command"]
        report = score(**options)
        print(f"wrote {args.out}/report.json and report.md in {report['elapsed_s']} s")
    elif args.command == "distill":
        from walkdiff.styled.distill import distill

        options = vars(args).copy()
        del options["command"]
        distill(**options)
    elif args.command == "bench":
        from walkdiff.bench import benchmarks as bench

        bench.run(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
