"""Commands that score motion with an evaluator network: `score` (any BVH files) and `evaluate` (a
generator)."""

from __future__ import annotations

import argparse

from walkdiff.cli.options import SAMPLER_HELP, keyword_options, sampler_options
from walkdiff.common.arguments import count
from walkdiff.common.errors import WalkdiffError
from walkdiff.evaluation.plan import FULL, QUICK


def add_parsers(sub) -> None:
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
        help="transfer manifest CSV: file, source, style[, content] (paths relative to it, in its folder)",
    )  # fmt: skip
    p.add_argument(
        "--allow-outside", action="store_true",
        help="let the --transfer manifest name files outside its folder (absolute, ~ and .. paths, links)",
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
    p.set_defaults(run=run_score)

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
    p.add_argument(
        "--quick", action="store_true",
        help=f"the quick protocol: {QUICK.repeats} repeats x {QUICK.num} windows with {QUICK.sampler} "
        f"{QUICK.steps} steps, minutes instead of hours (docs/evaluation.md: what it trades); options given "
        "replace its settings",
    )  # fmt: skip
    p.add_argument(
        "--num", type=count(1), default=None,
        help=f"windows per repeat (default {FULL.num}; --quick {QUICK.num})",
    )  # fmt: skip
    p.add_argument(
        "--repeats", type=count(1), default=None,
        help=f"repeats (default {FULL.repeats}; --quick {QUICK.repeats})",
    )  # fmt: skip
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--real-only", action="store_true", help="only the real reference rows")
    # No default sampler here: the full protocol's is ddpm, --quick's its own (walkdiff.evaluation.plan).
    sampler_options(
        p, default=None, guidance=True, with_eta=False,
        help=f"{SAMPLER_HELP} (default ddpm; --quick: {QUICK.sampler}, {QUICK.steps} steps)",
    )  # fmt: skip
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
    p.add_argument(
        "--fix-feet", action="store_true",
        help="also score the windows with their feet pinned while planted, as generate "
        "--fix-feet gives them (a row beside)",
    )  # fmt: skip
    p.add_argument("--mlflow-experiment", default=None, help="log metrics and reports into an MLflow run")
    p.add_argument("--overwrite", action="store_true", help="replace an existing report")
    p.set_defaults(run=run_evaluate)


def run_score(args: argparse.Namespace) -> None:
    from walkdiff.evaluation.score import score

    report = score(**keyword_options(args))
    print(f"wrote {args.out}/report.json and report.md in {report['elapsed_s']} s")


def run_evaluate(args: argparse.Namespace) -> None:
    """The walking protocol, or for a DiffMotion checkpoint the gesture metrics of `evaluate-gesture`."""
    from walkdiff.common.checkpoints import checkpoint_class
    from walkdiff.evaluation.evaluate import evaluate

    if args.ckpt and checkpoint_class(args.ckpt) == "walkdiff.models.diffmotion.DiffMotion":
        from walkdiff.gestures.evaluate import evaluate_gesture

        if args.quick:
            raise WalkdiffError("--quick is the walking protocol's; for gestures give fewer --repeats")
        evaluate_gesture(
            args.ckpt, args.out, samples=args.repeats or FULL.repeats, seed=args.seed, root=args.root,
            sampler=args.sampler or FULL.sampler, steps=args.steps,
        )  # fmt: skip
        print(f"wrote {args.out}/report.json")
        return
    if args.evaluator is None:
        raise WalkdiffError(
            "--evaluator is required to score a walking or action model (a MotionEvaluator checkpoint)"
        )
    report = evaluate(**keyword_options(args))
    print(f"wrote {args.out}/report.json and report.md in {report['elapsed_s']} s")
