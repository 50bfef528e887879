"""Editing motion with a StyledMotionDiffusion checkpoint: `inbetween` (a gap between two clips filled) and
`edit` (what a clip does not keep made anew). Keyframes are `sample --keys` (cli/generate.py)."""

from __future__ import annotations

import argparse

from walkdiff.cli.options import (
    FILL_CANDIDATES,
    FILL_SAMPLER_OPTIONS,
    keyword_options,
    preview_options,
    rig_options,
    styled_request_options,
)
from walkdiff.common.arguments import count

KEEP_HELP = (
    "what to keep exactly: legs (the root and the legs), upper-body (every other joint), root (the root "
    "joint: its path and orientation) or joint names, comma-separated"
)


def add_parsers(sub) -> None:
    p = sub.add_parser(
        "inbetween", help="fill a gap of N frames between the end of one clip and another's start"
    )
    p.add_argument("a", help="BVH clip before the gap (on the model's skeleton, any frame rate)")
    p.add_argument("b", help="BVH clip after the gap")
    p.add_argument("--frames", type=int, required=True, help="frames of the gap at the model's fps (>= 1)")
    p.add_argument(
        "--place", action="store_true",
        help="let the fill choose where B goes (default: B stays where its file puts it)",
    )  # fmt: skip
    p.add_argument("--fill-only", action="store_true", help="write the fill alone (default: A, fill and B)")
    p.add_argument(
        "--candidates", type=count(1), default=FILL_CANDIDATES,
        help=f"fills drawn together, the most typical kept (default {FILL_CANDIDATES}; 1: the first drawn)",
    )  # fmt: skip
    edit_options(p, **FILL_SAMPLER_OPTIONS)
    p.set_defaults(run=run_edit)

    p = sub.add_parser("edit", help="make anew what a clip does not keep (legs, upper body, root, joints)")
    p.add_argument("clip", help="BVH clip on the model's skeleton (any frame rate)")
    p.add_argument("--keep", required=True, metavar="legs|upper-body|root|JOINTS", help=KEEP_HELP)
    p.add_argument(
        "--no-ground", dest="ground", action="store_false",
        help="keep the height as sampled where the root is made anew (default: planted feet on the floor)",
    )  # fmt: skip
    edit_options(p)
    p.set_defaults(run=run_edit)


def edit_options(p: argparse.ArgumentParser, **sampler) -> None:
    """What `inbetween` and `edit` share: the model, the output, the style, the sampler (`sampler`:
    sampler_options' defaults where the command has its own) and the rig."""
    styled_request_options(
        p, "the BVH file to write (a JSON report is written beside it)",
        "or none: the model's own motion, led by what is kept",
        "frames shared by neighbouring windows of a long edit (default: half a window)", **sampler,
    )  # fmt: skip
    p.add_argument(
        "--no-fix-feet", dest="fix_feet", action="store_false",
        help="leave the made feet as sampled (default: pinned during contacts, the kept ones held)",
    )  # fmt: skip
    preview_options(p, "skip the GIF and MP4 preview (the input beside the result)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    rig_options(p)


def run_edit(args: argparse.Namespace) -> None:
    """`inbetween` or `edit`: the edit commands' function of the same name."""
    from walkdiff.styled import edit_commands

    report = getattr(edit_commands, args.command)(**keyword_options(args))
    kept, seconds = report["kept_error_body_heights"], report["timing"]["generate_s"]
    print(f"wrote {args.out}: kept parts within {kept:.1e} body heights; generate_s {seconds}")
