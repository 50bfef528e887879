"""Commands on motion files as they are: `inspect`, `convert`, `view`, `data scan` and `data split`."""

from __future__ import annotations

import argparse

from walkdiff.cli.options import PROFILE_HELP, keyword_options, rig_options
from walkdiff.common.arguments import count, number


def add_parsers(sub) -> None:
    p = sub.add_parser(
        "inspect", help="summarise a BVH file: joints, frames, fps, contacts, anything suspicious"
    )
    p.add_argument("file")
    p.add_argument("--profile", default=None, help=PROFILE_HELP)
    p.set_defaults(run=run_inspect)

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
    rig_options(p)
    p.set_defaults(run=run_convert)

    p = sub.add_parser(
        "retarget", help="play a BVH clip on another humanoid rig: your rig's BVH or mixamo, unreal, smpl"
    )
    p.add_argument("input", help="the clip to retarget (BVH)")
    rig_options(p, required=True)
    p.add_argument("--out", required=True, help="the output, .bvh (the target's skeleton) or .glb")
    p.add_argument(
        "--feet", choices=("follow", "pin", "off"), default="follow",
        help="planted feet: move as the source's did (follow, default), held still (pin), no foot IK (off)",
    )  # fmt: skip
    p.add_argument("--source-map", default=None, help="YAML/JSON overrides of the input's humanoid map")
    p.add_argument(
        "--reference-frame", type=count(0), default=None,
        help="the input's frame to align on (default: its rest pose; a standing frame when that is no pose)",
    )  # fmt: skip
    p.add_argument(
        "--force", action="store_true",
        help="retarget a source or target that does not stand like a biped (refused by default, with what "
        "was measured)",
    )  # fmt: skip
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.set_defaults(run=run_retarget)

    p = sub.add_parser("view", help="play BVH files side by side in 3-D in the browser (orbit, scrub, play)")
    p.add_argument("files", nargs="+", help="BVH files (any skeleton; shown Y up in metres)")
    p.add_argument("--port", type=count(0), default=8080, help="port (default 8080; 0: any free port)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default: this machine only)")
    p.add_argument("--profile", default=None, help=PROFILE_HELP)
    rig_options(p)
    p.set_defaults(run=run_view)

    p = sub.add_parser("data", help="your own motion capture: `data scan DIR`, `data split DIR`")
    data = p.add_subparsers(dest="what", metavar="WHAT", required=True)
    add_scan(data)
    add_split(data)


def label_options(d: argparse.ArgumentParser) -> None:
    """How a folder's clips are labelled and split: the options `data scan` and `data split` share."""
    d.add_argument("--labels", default=None, help="CSV/JSON manifest: file, style, content, split columns")
    d.add_argument("--pattern", default=None, help="regular expression with named groups style / content")
    d.add_argument("--default-style", default=None, help="style of clips without one")
    d.add_argument("--default-content", default=None, help="content of clips without one")
    d.add_argument(
        "--val-fraction",
        type=number(0, 1, below=True),
        default=None,
        help="per label, held out for validation (0: none; data scan then writes configs without validation)",
    )
    d.add_argument(
        "--test-fraction", type=number(0, 1, below=True), default=None, help="per label, held out for testing"
    )


def mirror_pair(text: str) -> tuple[str, str | None]:
    """argparse type of --mirror-labels: LABEL=PARTNER (LABEL=LABEL: not lateral; LABEL=: no partner)."""
    label, equals, partner = text.partition("=")
    if not equals or not label.strip():
        raise argparse.ArgumentTypeError(f"expected LABEL=PARTNER (or LABEL= for none), got {text!r}")
    return label.strip(), partner.strip() or None


def add_scan(data) -> None:
    d = data.add_parser(
        "scan",
        help="a folder of BVH files: skeleton profile, frame rates, labels, clip lengths, suggested window; "
        "with --out, the evaluator and generator configs that `walkdiff fit --config` runs",
    )
    d.add_argument("folder", help="folder of BVH files (searched recursively)")
    label_options(d)
    d.add_argument(
        "--mirror-labels",
        type=mirror_pair,
        action="append",
        default=None,
        metavar="LABEL=PARTNER",
        help="the label of a LABEL clip's mirrored copy, over what the names say (walk_lturn=walk_rturn; "
        "LABEL=LABEL: not lateral; LABEL=: no partner, copies left out); repeat for more",
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
    d.add_argument(
        "--no-timing", dest="timing", action="store_false",
        help="with --out: do not time a few batches of each config to print the expected training time",
    )  # fmt: skip
    d.set_defaults(run=run_scan)


def add_split(data) -> None:
    d = data.add_parser(
        "split",
        help="the train/val/test clips of a folder of BVH files (or of xia, humanact12) with their labels; "
        "with --out, a labels manifest that fixes every clip's split",
    )
    d.add_argument("folder", help="folder of BVH files (searched recursively), or a dataset: xia, humanact12")
    label_options(d)
    d.add_argument("--contents", default="all", help="content labels to list: 'all' (default) or a list")
    d.add_argument("--out", default=None, help="CSV file to write: file, style, content, split of every clip")
    d.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    d.set_defaults(run=run_split)


def run_inspect(args: argparse.Namespace) -> None:
    from walkdiff.motion.conversion import inspect_file

    print(inspect_file(args.file, args.profile))


def run_convert(args: argparse.Namespace) -> None:
    from walkdiff.retarget.files import convert_file

    print(
        convert_file(
            args.input,
            args.output,
            fps=args.fps,
            mirror_sides=args.mirror,
            profile=args.profile,
            overwrite=args.overwrite,
            to=args.to,
            to_map=args.to_map,
        )  # fmt: skip
    )


def run_retarget(args: argparse.Namespace) -> None:
    from walkdiff.retarget.files import retarget_file

    print(
        retarget_file(
            args.input,
            args.to,
            args.out,
            feet=args.feet,
            source_map=args.source_map,
            target_map=args.to_map,
            reference_frame=args.reference_frame,
            overwrite=args.overwrite,
            force=args.force,
        )  # fmt: skip
    )


def run_view(args: argparse.Namespace) -> None:
    from walkdiff.preview.view import view

    view(args.files, host=args.host, port=args.port, profile=args.profile, to=args.to, to_map=args.to_map)


def run_scan(args: argparse.Namespace) -> None:
    from walkdiff.common.files import read_config
    from walkdiff.data.scan import scan

    options = keyword_options(args)
    if options["profile"]:
        options["profile"] = read_config(options["profile"], "--profile")
    if options["mirror_labels"] is not None:
        options["mirror_labels"] = dict(options["mirror_labels"])
    timing = options.pop("timing")
    print(scan(**options), flush=True)
    if args.out is not None and timing:
        from walkdiff.callbacks.plan import plan, plan_lines
        from walkdiff.data.scan import config_paths

        print("\n".join(plan_lines(plan(list(config_paths(args.folder, args.out, args.name))))))


def run_split(args: argparse.Namespace) -> None:
    from walkdiff.data.splits import split_report

    print(split_report(**keyword_options(args)))
