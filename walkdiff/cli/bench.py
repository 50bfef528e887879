"""`walkdiff bench WHAT`: each benchmark's options beside the call that runs it (walkdiff.bench holds the
benchmarks themselves)."""

from __future__ import annotations

import argparse
import json

from walkdiff.cli.options import (
    FILL_CANDIDATES,
    FILL_SAMPLER_OPTIONS,
    SAMPLERS,
    frame_sampler_options,
    runtime_options,
    sampler_options,
    steering_options,
)
from walkdiff.common.arguments import count, number
from walkdiff.common.errors import WalkdiffError


def add_parsers(sub) -> None:
    p = sub.add_parser("bench", help="benchmarks; results written as JSON")
    bench = p.add_subparsers(dest="what", metavar="WHAT", required=True)
    for add in (
        add_data, add_train, add_gesture, add_stream, add_memory, add_view, add_walk, add_distill, add_sample,
        add_protocol, add_style, add_retarget, add_play, add_turns, add_ablate, add_inbetween, add_edit,
    ):  # fmt: skip
        add(bench)
    for b in bench.choices.values():
        b.add_argument("--overwrite", action="store_true", help="replace the results of an earlier run")


def frame_counts(text: str, option: str) -> tuple[int, ...]:
    """Comma-separated whole numbers >= 1, in the order given."""
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        values = ()
    if not values or min(values) < 1:
        raise WalkdiffError(f"{option}: expected comma-separated whole numbers >= 1, got {text!r}")
    return values


def strengths(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if not values or not all(0 < v <= 1 for v in values):
        raise WalkdiffError(f"--strengths: expected comma-separated numbers in (0, 1], got {text!r}")
    return values


def quality_options(b: argparse.ArgumentParser, num: int) -> None:
    """What the benchmarks that score samples with an evaluator share."""
    b.add_argument("--evaluator", required=True, help="MotionEvaluator checkpoint")
    b.add_argument("--num", type=count(1), default=num, help=f"windows per setting and seed (default {num})")
    b.add_argument("--seed", type=count(0), default=0, help="first seed (default 0)")
    b.add_argument("--seeds", type=count(1), default=3, help="seeds averaged per setting (default 3)")
    b.add_argument(
        "--no-ground", dest="ground", action="store_false",
        help="score windows as sampled (needed for checkpoints saved before grounding existed)",
    )  # fmt: skip


def add_data(bench) -> None:
    b = bench.add_parser("data", help="cold/warm preprocessing of the dataset and DataLoader throughput")
    b.add_argument("--out", required=True)
    b.add_argument("--dataset", default="xia")
    b.add_argument("--root", default=None)
    b.set_defaults(run=run_data)


def run_data(args: argparse.Namespace) -> None:
    from walkdiff.bench.data import bench_data

    bench_data(args.out, args.dataset, args.root)


def add_ablate(bench) -> None:
    b = bench.add_parser(
        "ablate", help="variants of a config trained at one batch budget and scored alike, in one table"
    )
    b.add_argument("--out", required=True, help="folder: a sub-folder per variant, ablation.json and .md")
    b.add_argument("--config", default=None, help="the config the variants change (unless each names one)")
    b.add_argument("--grid", required=True, help="YAML naming the variants (conf/ablation/*.yaml)")
    b.add_argument("--evaluator", default=None, help="default: the config's metrics callback's")
    b.add_argument("--only", default=None, help="comma-separated variant names to run (default: all)")
    b.set_defaults(run=run_ablate)


def run_ablate(args: argparse.Namespace) -> None:
    import torch

    from walkdiff.bench.ablate import bench_ablate

    only = args.only.split(",") if args.only else None
    result = bench_ablate(
        args.out, args.config, args.grid, args.evaluator, only, torch.get_num_threads(), args.overwrite
    )
    print(f"{len(result['variants'])} variants in {args.out}/ablation.md")


def add_train(bench) -> None:
    b = bench.add_parser("train", help="training windows/s under Lightning vs a plain PyTorch loop")
    b.add_argument("--out", required=True)
    b.add_argument("--config", default="conf/xia_cpu.yaml")
    b.add_argument("--batches", type=count(1), default=30, help="batches timed per repeat")
    b.add_argument(
        "--to-bar", action="store_true",
        help="train the config to its epoch bound and report when its metrics reach the quality bar",
    )  # fmt: skip
    b.add_argument(
        "--suite",
        default=None,
        help="with --to-bar: a YAML of folders (each a variant naming its config, as `bench ablate`'s grid) "
        "trained and scored into one table; --out is then a folder",
    )
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
        help="after --: `walkdiff fit` overrides of the config (-- --model.lr 1e-3); without --to-bar, "
        "seconds per batch with them beside the config as it is, timed in one run",
    )  # fmt: skip
    b.set_defaults(run=run_train)


def run_train(args: argparse.Namespace) -> None:
    """Seconds per batch, or with --to-bar a whole run timed to the quality bar."""
    if args.suite and not args.to_bar:
        raise WalkdiffError(
            "--suite is a --to-bar option: walkdiff bench train --to-bar --suite FILE --out DIR"
        )
    if args.suite:
        import torch

        from walkdiff.bench.ablate import bench_ablate

        result = bench_ablate(
            args.out, None, args.suite, args.evaluator, None, torch.get_num_threads(), args.overwrite
        )
        print(f"{len(result['variants'])} folders in {args.out}/ablation.md")
    elif args.to_bar:
        from walkdiff.bench.time_to_bar import bench_time_to_bar

        bench_time_to_bar(args.out, args.config, args.evaluator, args.repeats, args.fit_args)
    elif args.fit_args:
        from walkdiff.bench.train import bench_train_recipe

        bench_train_recipe(args.out, args.config, args.fit_args, args.batches)
    else:
        from walkdiff.bench.train import bench_train

        bench_train(args.out, args.config, args.batches)


def add_gesture(bench) -> None:
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
    runtime_options(b, graph=False)
    b.set_defaults(run=run_gesture)


def run_gesture(args: argparse.Namespace) -> None:
    from walkdiff.bench.gesture import bench_gesture

    bench_gesture(
        args.out, args.ckpt, args.frames, args.repeats, args.sampler, args.steps, args.eta,
        frame_counts(args.streams, "--streams"), args.runtime,
    )  # fmt: skip


def add_stream(bench) -> None:
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
    runtime_options(b, graph=False)
    b.set_defaults(run=run_stream)


def run_stream(args: argparse.Namespace) -> None:
    from walkdiff.bench.stream import bench_stream

    bench_stream(
        args.out, args.ckpt, args.walker, args.seconds, args.chunk_ms, args.rate, args.frames, args.most,
        threads=frame_counts(args.threads, "--threads"), sampler=args.sampler, steps=args.steps, eta=args.eta,
        runtime=args.runtime,
    )  # fmt: skip


def add_memory(bench) -> None:
    b = bench.add_parser("memory", help="peak memory of `walkdiff sample --frames N --num 1` per N")
    b.add_argument("--ckpt", required=True, help="StyledMotionDiffusion checkpoint")
    b.add_argument("--out", required=True, help="JSON file")
    b.add_argument("--frames", default="300,10000,100000", help="frame counts (default 300,10000,100000)")
    b.add_argument("--walker", default=None, help="PathWalker checkpoint: also `walk` along long paths")
    b.add_argument("--gesture", default=None, help="DiffMotion checkpoint: also `gesture` on long audio")
    b.add_argument("--audio", default=None, help="speech WAV, repeated to each of --seconds (with --gesture)")
    b.add_argument("--seconds", default="10,120", help="walk / speech seconds (default 10,120)")
    b.set_defaults(run=run_memory)


def run_memory(args: argparse.Namespace) -> None:
    from walkdiff.bench.memory import bench_memory

    bench_memory(
        args.out, args.ckpt, frame_counts(args.frames, "--frames"), args.walker, args.gesture,
        args.audio, frame_counts(args.seconds, "--seconds"),
    )  # fmt: skip


def add_view(bench) -> None:
    b = bench.add_parser(
        "view", help="seconds until `walkdiff view` shows its skeletons in headless Chromium"
    )
    b.add_argument("files", nargs="*", help="BVH files (default: the first two of the data root's xia/)")
    b.add_argument("--out", required=True, help="JSON file")
    b.add_argument(
        "--repeats", type=count(1), default=5, help="page loads, each in a fresh browser (default 5)"
    )
    b.set_defaults(run=run_view)


def run_view(args: argparse.Namespace) -> None:
    from walkdiff.bench.view import bench_view

    bench_view(args.out, args.files, args.repeats)


def add_walk(bench) -> None:
    b = bench.add_parser("walk", help="path-following error and style accuracy of walks along test paths")
    b.add_argument("--ckpt", required=True, help="PathWalker checkpoint")
    b.add_argument("--evaluator", required=True, help="MotionEvaluator checkpoint (style accuracy)")
    b.add_argument("--out", required=True, help="JSON file; the plot goes next to it as .png")
    b.add_argument("--seed", type=count(0), default=0)
    b.set_defaults(run=run_walk)


def run_walk(args: argparse.Namespace) -> None:
    from walkdiff.bench.walk import bench_walk
    from walkdiff.common.files import strict_json

    print(json.dumps(strict_json(bench_walk(args.out, args.ckpt, args.evaluator, args.seed)), indent=2))


def add_distill(bench) -> None:
    b = bench.add_parser("distill", help="a distilled student's DDIM FMD against its teacher's DDPM")
    b.add_argument("--teacher", required=True, help="the checkpoint the student was distilled from")
    b.add_argument("--student", required=True, help="the checkpoint `walkdiff distill` wrote")
    b.add_argument("--out", required=True, help="JSON file")
    quality_options(b, 256)
    b.set_defaults(run=run_distill)


def run_distill(args: argparse.Namespace) -> None:
    from walkdiff.bench.distill import bench_distill

    bench_distill(
        args.out, args.teacher, args.student, args.evaluator, num=args.num, seed=args.seed,
        seeds=args.seeds, ground=args.ground,
    )  # fmt: skip


def add_sample(bench) -> None:
    b = bench.add_parser("sample", help="FMD/style accuracy vs sampling steps, speed, --fix-feet, transfer")
    b.add_argument("--ckpt", required=True, help="StyledMotionDiffusion checkpoint")
    b.add_argument("--out", required=True, help="folder for sample.json and sample.png")
    b.add_argument(
        "--strength", type=number(0, 1, above=True), default=0.6, help="transfer noise level (default 0.6)"
    )
    quality_options(b, 400)
    b.set_defaults(run=run_sample)


def run_sample(args: argparse.Namespace) -> None:
    from walkdiff.bench.sample import bench_sample

    bench_sample(
        args.out, args.ckpt, args.evaluator, num=args.num, seed=args.seed, seeds=args.seeds,
        strength=args.strength, ground=args.ground,
    )  # fmt: skip


def add_protocol(bench) -> None:
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
    b.set_defaults(run=run_protocol)


def run_protocol(args: argparse.Namespace) -> None:
    from walkdiff.bench.protocol import bench_protocol

    bench_protocol(
        args.out, args.ckpt, args.evaluator, args.student, strengths(args.strengths), args.samples,
        args.bootstrap, args.seed,
    )  # fmt: skip
    print(f"wrote {args.out}/protocol.json and protocol.md")


def add_style(bench) -> None:
    b = bench.add_parser(
        "style",
        help="style from example clips: seen styles against their labels and the label-only model, unseen "
        "styles against the ceiling, the baselines and the real floor",
    )
    b.add_argument(
        "--ckpt", required=True, help="StyledMotionDiffusion checkpoint with a style encoder (style codes)"
    )
    b.add_argument(
        "--unseen-ckpt",
        default=None,
        help="the same trained with data.leave_out_styles: rows of the styles it left out",
    )
    b.add_argument(
        "--labels-ckpt",
        default=None,
        help="a label-only checkpoint trained on every style: its rows beside the code model's, the ceiling",
    )
    b.add_argument("--evaluator", required=True, help="MotionEvaluator checkpoint (its test clips: examples)")
    b.add_argument("--out", required=True, help="folder for style.json and style.md")
    b.add_argument(
        "--per-example", type=count(1), default=8, help="windows sampled per example clip (default 8)"
    )
    b.add_argument("--sampler", choices=SAMPLERS, default="ddim", help="sampler (default ddim)")
    b.add_argument("--steps", type=count(1), default=None, help="DDIM / DPM-Solver++ steps (default 10)")
    b.add_argument("--seed", type=count(0), default=0)
    b.add_argument("--bootstrap", type=count(0), default=200, help="resamples of the clips (default 200)")
    b.add_argument(
        "--timeline-clips", type=count(1), default=32, help="clips of three styles for the transitions (32)"
    )
    b.add_argument(
        "--match-clips",
        type=number(0, 1),
        default=1.0,
        metavar="W",
        help="how far samples from example clips match the clips' pose statistics (default 1, as sample)",
    )
    b.set_defaults(run=run_style)


def run_style(args: argparse.Namespace) -> None:
    from walkdiff.bench.style import bench_style, format_style

    result = bench_style(
        args.out, args.ckpt, args.evaluator, args.unseen_ckpt, args.labels_ckpt, args.per_example,
        args.sampler, args.steps, args.seed, args.bootstrap, timeline_clips=args.timeline_clips,
        match_clips=args.match_clips,
    )  # fmt: skip
    print(format_style(result))
    print(f"wrote {args.out}/style.json and style.md")


def add_retarget(bench) -> None:
    b = bench.add_parser(
        "retarget",
        help="retargeting onto re-posed and re-proportioned copies of Xia's rig, ZEGGS and the built-in "
        "rigs: positions, bone directions, feet, speed",
    )
    b.add_argument("--out", required=True, help="JSON file")
    b.add_argument(
        "--clips", type=count(1), default=8, help="Xia clips, of different styles and contents (default 8)"
    )
    b.add_argument("--frames", type=count(2), default=300, help="frames per clip, at most (default 300)")
    b.add_argument(
        "--data", default=None, help="data root holding xia/ and zeggs/ (default $WALKDIFF_DATA, else ./data)"
    )
    b.set_defaults(run=run_retarget)


def run_retarget(args: argparse.Namespace) -> None:
    from walkdiff.bench.retarget import bench_retarget, load_clips

    clips, zeggs = load_clips(args.data, args.clips)
    bench_retarget(clips, zeggs, args.out, frames=args.frames)


def add_play(bench) -> None:
    b = bench.add_parser(
        "play", help="a steered walker on scripted takes: latency, speed, following, style, skating, seams"
    )
    b.add_argument("--ckpt", required=True, help="PathWalker checkpoint")
    b.add_argument("--evaluator", required=True, help="MotionEvaluator checkpoint")
    b.add_argument("--out", required=True, help="JSON file")
    b.add_argument(
        "--seeds", type=count(1), default=2, help="seeds each scripted take is walked with (default 2)"
    )
    b.add_argument(
        "--switch-seeds", type=count(1), default=6,
        help="seeds the style tour is walked with, for the seams at its switches (default 6)",
    )  # fmt: skip
    b.add_argument(
        "--hold", type=number(2), default=3.0, help="seconds between a take's commands (default 3)"
    )
    b.add_argument("--sampler", choices=SAMPLERS, default="ddim", help="per-frame sampler (default ddim)")
    b.add_argument("--steps", type=count(1), default=None, help="its steps (default 10)")
    b.add_argument("--eta", type=number(0, 1), default=None, help="DDIM noise (default 1)")
    steering_options(b)
    b.add_argument(
        "--characters", default="1,4,8,16,32", help="characters batched, timed (default 1,4,8,16,32)"
    )
    b.add_argument(
        "--frames", type=count(1), default=30, help="frames timed per character count (default 30)"
    )
    runtime_options(b, graph=False)
    b.set_defaults(run=run_play)


def run_play(args: argparse.Namespace) -> None:
    from walkdiff.bench.play import bench_play

    bench_play(
        args.out, args.ckpt, args.evaluator, args.seeds, args.hold, args.sampler, args.steps, args.eta,
        args.transition, frame_counts(args.characters, "--characters"), args.frames,
        switch_seeds=args.switch_seeds, turn_rate=args.turn_rate, heading_assist=args.heading_assist,
        foot_lock=args.foot_lock, runtime=args.runtime,
    )  # fmt: skip


def add_turns(bench) -> None:
    b = bench.add_parser(
        "turns", help="labels that name a side (walk-turn-left): sampled clips and transfers turn that way"
    )
    b.add_argument("--ckpt", required=True, help="StyledMotionDiffusion checkpoint trained on lateral labels")
    b.add_argument("--out", required=True, help="JSON file for the results")
    b.add_argument("--num", type=count(1), default=8, help="clips per label and style (default 8)")
    b.add_argument("--frames", type=count(1), default=None, help="frames per clip (default two windows)")
    b.add_argument("--sampler", choices=SAMPLERS, default="ddim", help="sampler (default ddim)")
    b.add_argument("--steps", type=count(1), default=None, help="DDIM / DPM-Solver++ steps (default 10)")
    b.add_argument(
        "--strength", type=number(0, 1, above=True), default=0.6, help="transfer strength (default 0.6)"
    )
    b.add_argument("--seed", type=count(0), default=0)
    b.add_argument("--root", default=None, help="the data folder (default: the one the checkpoint records)")
    b.set_defaults(run=run_turns)


def run_turns(args: argparse.Namespace) -> None:
    from walkdiff.bench.turns import bench_turns, format_turns

    result = bench_turns(
        args.ckpt,
        args.out,
        args.num,
        args.frames,
        args.seed,
        args.sampler,
        args.steps,
        args.strength,
        args.root,
    )
    print("\n".join(format_turns(result)))


def edit_bench_options(b: argparse.ArgumentParser, **sampler) -> None:
    """What `bench inbetween` and `bench edit` share (`sampler`: sampler_options' defaults where the
    command has its own)."""
    b.add_argument("--ckpt", required=True, help="StyledMotionDiffusion checkpoint (its test split is used)")
    b.add_argument(
        "--evaluator", required=True, help="MotionEvaluator checkpoint (style recognition, skating)"
    )
    b.add_argument("--out", required=True, help="JSON file for the results")
    sampler_options(b, with_eta=False, **sampler)
    b.add_argument("--seed", type=count(0), default=0)
    b.add_argument("--resamples", type=count(1), default=1000, help="bootstrap resamples (default 1000)")
    b.add_argument(
        "--split",
        default="test",
        help="held-out clips of the checkpoint's data: test (default), val or test,val",
    )


def add_inbetween(bench) -> None:
    b = bench.add_parser(
        "inbetween",
        help="in-betweening on held-out clips: L2P, L2Q, NPSS beside interpolation and zero velocity",
    )
    edit_bench_options(b, **FILL_SAMPLER_OPTIONS)
    b.add_argument("--gaps", default="5,15,30,45", help="gap lengths in frames (default 5,15,30,45)")
    b.add_argument("--context", type=count(1), default=10, help="frames of past context (default 10)")
    b.add_argument(
        "--stride",
        type=count(1),
        default=5,
        help="frames between the gaps cut in one clip, every offset at most this far apart (default 5)",
    )
    b.add_argument("--samples", type=count(1), default=1, help="fills per gap, each scored (default 1)")
    b.add_argument(
        "--candidates", type=count(1), default=FILL_CANDIDATES,
        help=f"fills drawn for each, the most typical kept (default {FILL_CANDIDATES}, as `inbetween`)",
    )  # fmt: skip
    b.add_argument(
        "--guide",
        type=number(0),
        default=None,
        help="reconstruction guidance of the fills (default the API's, model.guide; 0: none)",
    )
    b.add_argument("--repeats", type=count(1), default=5, help="timed 45-frame fills (default 5)")
    b.add_argument("--no-fix-feet", dest="fix_feet", action="store_false", help="fills with feet as sampled")
    b.add_argument(
        "--resample", type=count(0), default=0,
        help="RePaint resampling: each step of the noisier half taken this many more times (default 0)",
    )  # fmt: skip
    b.set_defaults(run=run_inbetween)


def run_inbetween(args: argparse.Namespace) -> None:
    from walkdiff.bench.inbetween import bench_inbetween, format_differences, format_inbetween

    result = bench_inbetween(
        args.ckpt, args.evaluator, args.out, frame_counts(args.gaps, "--gaps"), args.context, args.stride,
        args.seed, args.sampler, args.steps, args.resamples, args.repeats, args.fix_feet,
        tuple(args.split.split(",")), args.resample, args.samples, args.guide, args.candidates,
    )  # fmt: skip
    print("\n".join(format_inbetween(result) + [""] + format_differences(result)))


def add_edit(bench) -> None:
    b = bench.add_parser(
        "edit", help="partial-body edits of held-out clips: kept joints' error, style recognised"
    )
    edit_bench_options(b)
    b.add_argument(
        "--keep", default="legs,upper-body", help="kept parts, one edit each (default legs,upper-body)"
    )
    b.set_defaults(run=run_edit_bench)


def run_edit_bench(args: argparse.Namespace) -> None:
    from walkdiff.bench.inbetween import bench_edit

    bench_edit(
        args.ckpt, args.evaluator, args.out, tuple(args.keep.split(",")), args.seed, args.sampler, args.steps,
        args.resamples, tuple(args.split.split(",")),
    )  # fmt: skip
