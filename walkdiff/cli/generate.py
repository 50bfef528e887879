"""Styled motion from a StyledMotionDiffusion checkpoint: `sample` (from noise) and `transfer` (restyling a
clip)."""

from __future__ import annotations

import argparse

from walkdiff.cli.options import (
    keyword_options,
    preview_options,
    rig_options,
    styled_request_options,
)
from walkdiff.common.arguments import count, number


def add_parsers(sub) -> None:
    p = sub.add_parser("sample", help="generate styled motion of any length: BVH + GIF + manifest.json")
    sampling_options(p)
    p.add_argument("--num", type=count(1), default=1, help="clips (default 1, as `model.sample`)")
    p.add_argument(
        "--frames", type=count(1), default=300, help="frames per clip at the model's fps (default 300)"
    )
    p.add_argument(
        "--transition", type=number(0), default=1.0,
        help="with a --style timeline (neutral@0,old@4s): seconds each change is ramped over (default 1)",
    )  # fmt: skip
    p.add_argument(
        "--keys", default=None, metavar="KEYS",
        help="poses and root places the clips pass through: a BVH of key poses on the model's skeleton "
        "(FILE.bvh@F0,F1,... with their frame numbers; without: spread over the clip) or a JSON of keys "
        "(docs/editing.md); --style may then be left out",
    )  # fmt: skip
    p.set_defaults(run=run_generation)

    p = sub.add_parser("transfer", help="restyle a BVH clip (noise to strength*T, denoise in the new style)")
    sampling_options(p)
    p.add_argument("--input", required=True, help="BVH clip on the model's skeleton (any frame rate)")
    p.add_argument(
        "--strength", type=number(0, 1, above=True), default=0.6, help="noise level in (0, 1] (default 0.6)"
    )
    p.add_argument("--keep-trajectory", action="store_true", help="keep the source's root path exactly")
    p.set_defaults(run=run_generation)


def sampling_options(p: argparse.ArgumentParser) -> None:
    """What `sample` and `transfer` share: the model, the style, the sampler and how windows are joined."""
    styled_request_options(
        p, "output folder", "or with sample a timeline: neutral@0,old@4s,angry+old@8s",
        "frames shared by consecutive windows (default: half a window)",
    )  # fmt: skip
    p.add_argument(
        "--blend", type=count(0), default=None, help="of those, frames cross-faded (default: half)"
    )
    p.add_argument(
        "--fix-feet", action=argparse.BooleanOptionalAction, default=None,
        help="pin feet (IK) while planted: predicted contacts and feet the clip puts down; "
        "default: on where --style-clip statistics are matched",
    )  # fmt: skip
    p.add_argument(
        "--no-ground", dest="ground", action="store_false",
        help="keep the height as sampled (default: planted feet lifted or lowered onto the floor)",
    )  # fmt: skip
    preview_options(p)
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    rig_options(p)


def run_generation(args: argparse.Namespace) -> None:
    """`sample` or `transfer`: the styled commands' function of the same name."""
    from walkdiff.styled import commands

    report = getattr(commands, args.command)(**keyword_options(args))
    print(f"wrote {args.out}: " + ", ".join(f"{k} {v}" for k, v in report["timing"].items()))
    if report["preview"] is not None:
        print(f"preview: {report['preview']['note']}")
