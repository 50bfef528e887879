"""`walkdiff distill`: train a student that samples a generator's motion in a few DDIM steps."""

from __future__ import annotations

import argparse

from walkdiff.cli.options import keyword_options
from walkdiff.common.arguments import count, counts, number


def add_parsers(sub) -> None:
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
    p.set_defaults(run=run_distill)


def run_distill(args: argparse.Namespace) -> None:
    from walkdiff.styled.distill import distill

    distill(**keyword_options(args))
