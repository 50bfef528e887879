"""Help texts and options that several command families share, so each reads the same wherever it appears."""

from __future__ import annotations

import argparse
import json
import sys

from walkdiff.common.arguments import count, number
from walkdiff.common.errors import WalkdiffError

# diffusion.SAMPLERS, repeated so that building the parser imports no torch (a test keeps them equal).
SAMPLERS = ("ddpm", "ddim", "dpmpp")
# diffusion.MAX_GUIDANCE, repeated for the same reason (a test keeps them equal).
MAX_GUIDANCE = 100.0
# retarget.rigs.RIGS, repeated for the same reason (a test keeps them equal).
RIG_NAMES = ("mixamo", "unreal", "smpl")
# export.runtime.RUNTIMES, repeated for the same reason (a test keeps them equal).
RUNTIMES = ("torch", "onnx")
# styled.edits.FILL_SAMPLER, FILL_STEPS and CANDIDATES, the in-between's sampler, repeated for the same reason
# (a test keeps them equal).
FILL_SAMPLER, FILL_STEPS, FILL_CANDIDATES = "dpmpp", 20, 8
GUIDANCE_HELP = f"classifier-free guidance weight in [0, {MAX_GUIDANCE:g}] (1: none; a few at most is useful)"
SAMPLER_HELP = (
    "ddpm: ancestral, all T steps (default); ddim: DDIM over --steps; dpmpp: DPM-Solver++(2M), DDIM's ODE "
    "solved to second order, closer to DDPM at 10 steps for the same cost"
)

FILL_SAMPLER_HELP = (
    f"dpmpp: DPM-Solver++(2M) over --steps (default, {FILL_STEPS} steps for a fill); ddpm: ancestral, all T "
    "steps; ddim: DDIM over --steps"
)
# sampler_options' settings for the commands that fill a gap (`inbetween`, `bench inbetween`).
FILL_SAMPLER_OPTIONS = {"default": FILL_SAMPLER, "help": FILL_SAMPLER_HELP, "steps": FILL_STEPS}

FRAME_SAMPLER_HELP = (
    "per frame: ddpm, ancestral over all N trained steps (default); ddim over --steps of them (--eta its "
    "noise); dpmpp, DPM-Solver++(2M) over --steps (see the README's speed and quality table)"
)

PREVIEW_HELP = "seconds of each clip the GIF preview shows, from its start (default 20)"
PROFILE_HELP = (
    "YAML/JSON of skeleton profile overrides (root, left_heel, left_toe, right_heel, right_toe, up, forward, "
    "units, body_height, contact_speed, contact_height, mirror_pairs); the rest is found from the file"
)


def sampler_options(
    p: argparse.ArgumentParser,
    default: str = "ddpm",
    help: str = SAMPLER_HELP,
    eta: float | None = 0.0,
    guidance: bool = False,
    with_eta: bool = True,
    steps: int = 10,
) -> None:
    """The sampler spec (diffusion.SamplerChoice) as options, the same names and checks on every command:
    --sampler, --steps (`steps`: what the command takes when none are given), --eta (`eta`: its default;
    None: the sampler's own) and, for a model with classifier-free guidance, --guidance."""
    p.add_argument("--sampler", choices=SAMPLERS, default=default, help=help)
    steps_help = f"DDIM / DPM-Solver++ steps (default {steps})"
    p.add_argument("--steps", type=count(1), default=None, help=steps_help)
    if with_eta:
        eta_help = "DDIM noise (0: deterministic)" if eta == 0 else "DDIM noise (default 1)"
        p.add_argument("--eta", type=number(0, 1), default=eta, help=eta_help)
    if guidance:
        p.add_argument("--guidance", type=number(0, MAX_GUIDANCE), default=1.0, help=GUIDANCE_HELP)


def preview_options(p: argparse.ArgumentParser, gif_help: str = "skip the GIF and MP4 previews") -> None:
    """--no-gif and --preview-seconds, the same on every command that writes a preview."""
    p.add_argument("--no-gif", dest="gif", action="store_false", help=gif_help)
    p.add_argument("--preview-seconds", type=number(0, above=True), default=20.0, help=PREVIEW_HELP)


def style_options(p: argparse.ArgumentParser, more: str = "") -> None:
    """The style of a styled generator's request (models.style_spec.Style) as options: --style,
    --style-clip and --match-clips, the same on `sample`, `transfer`, `inbetween` and `edit`."""
    p.add_argument(
        "--style", default=None,
        help="a style or a mix (angry:0.7,old:0.3)" + (f", {more}" if more else ""),
    )  # fmt: skip
    p.add_argument(
        "--style-clip", dest="style_clips", default=None, metavar="FILE[:WEIGHT],...",
        help="take the style from example BVH clips on the model's skeleton (a model with a style encoder), "
        "alone or mixed with --style (which then weighs 1)",
    )  # fmt: skip
    p.add_argument(
        "--match-clips", type=number(0, 1), default=1.0, metavar="W",
        help="how far the sample's pose statistics are moved to the example clips' (default 1: all the way; "
        "0: their style code alone), times the clips' share of the weight",
    )  # fmt: skip


def styled_request_options(p: argparse.ArgumentParser, out: str, style: str, overlap: str, **sampler) -> None:
    """What every command of the styled generator asks for, in one order: the checkpoint, the output
    (`out`: its help), the style (`style`: what else --style takes), content, seed, the sampler with
    guidance (`sampler`: sampler_options' defaults where a command has its own), and the frames
    neighbouring windows share (`overlap`: its help)."""
    p.add_argument("--ckpt", required=True, help="StyledMotionDiffusion checkpoint")
    p.add_argument("--out", required=True, help=out)
    style_options(p, style)
    p.add_argument("--content", default="walk", help="content group (default walk)")
    p.add_argument("--seed", type=count(0), default=0)
    sampler_options(p, guidance=True, **sampler)
    p.add_argument("--overlap", type=count(0), default=None, help=overlap)


def frame_sampler_options(p: argparse.ArgumentParser) -> None:
    """Options of the per-frame sampler of DiffMotion and the path walker (no guidance)."""
    sampler_options(p, help=FRAME_SAMPLER_HELP)


def steering_options(p: argparse.ArgumentParser) -> None:
    """How a steered walker (`WalkController`) answers its commands: the same options and defaults on
    `play`, `control` and `bench play` (the defaults written here so that parsing imports no torch)."""
    p.add_argument(
        "--transition", type=number(0), default=0.5,
        help="seconds a style change is ramped over (default 0.5; 0: at once)",
    )  # fmt: skip
    p.add_argument(
        "--turn-rate", type=number(0, above=True), default=720.0,
        help="degrees per second the control's path bends at towards a new direction (default 720)",
    )  # fmt: skip
    p.add_argument(
        "--heading-assist", type=number(0), default=45.0,
        help="degrees per second the root may be turned beyond the walker's own turn towards the commanded "
        "direction (default 45; 0: the walker's own turning only)",
    )  # fmt: skip
    p.add_argument(
        "--no-foot-lock", dest="foot_lock", action="store_false",
        help="leave the feet where the walker puts them (default: a planted foot is held where it landed, "
        "a free one skimming the floor lifted clear of it)",
    )  # fmt: skip


def runtime_options(p: argparse.ArgumentParser, graph: bool = True) -> None:
    """--runtime (and, with `graph`, --onnx DIR): what makes each frame of a walker or gesture model, the
    same on the live commands (`play`, `control`, `walk --stream`, `gesture --stream`) and the benches."""
    p.add_argument(
        "--runtime", choices=RUNTIMES, default="torch",
        help="what makes each frame: torch (default) or ONNX Runtime running the frame exported as an ONNX "
        "graph, the same frames for the same seed (no example clips; docs/game-engines.md)",
    )  # fmt: skip
    if graph:
        p.add_argument(
            "--onnx", default=None, metavar="DIR",
            help="with --runtime onnx: the folder `walkdiff export --format onnx` wrote for this checkpoint "
            "and the sampler asked for (default: the frame is exported at the start, in memory)",
        )  # fmt: skip


def walker_clip_options(p: argparse.ArgumentParser) -> None:
    """--style-clip and --match-clips of a path walker (`walk`, `play`, `control`): example clips whose pose
    statistics the walker takes on; its style is still the --style label's."""
    p.add_argument(
        "--style-clip", dest="style_clips", default=None, metavar="FILE[:WEIGHT],...",
        help="example BVH clips on the walker's skeleton whose posture and swing the walk takes on",
    )  # fmt: skip
    p.add_argument(
        "--match-clips", type=number(0, 1), default=1.0, metavar="W",
        help="how far the walk's pose statistics are moved to the example clips' (default 1)",
    )  # fmt: skip


def keyword_options(args: argparse.Namespace) -> dict:
    """The parsed options as keyword arguments of the function a command runs: all but the command's name."""
    return {key: value for key, value in vars(args).items() if key not in ("command", "what")}


def rig_options(p: argparse.ArgumentParser, required: bool = False) -> None:
    """--to and --to-map: the rig the written motion is played on (walkdiff.retarget.target_rig), the same
    on every command that writes motion. --target-map, retarget's old name of --to-map, still works (and
    warns)."""
    p.add_argument(
        "--to", default=None, metavar="RIG", required=required,
        help="write the motion on another humanoid rig: a BVH of your rig (its first frame is the pose it is "
        f"aligned on) or a built-in rig ({', '.join(RIG_NAMES)}); see docs/motion.md#retargeting",
    )  # fmt: skip
    p.add_argument(
        "--to-map", "--target-map", default=None, action=Renamed,
        help="with --to: YAML/JSON of humanoid map overrides (role: joint name)",
    )  # fmt: skip


class Renamed(argparse.Action):
    """An option with an old spelling (its second name), which warns and works."""

    def __call__(self, parser, namespace, values, option_string=None):
        new, old = self.option_strings[:2]
        if option_string == old:
            print(f"walkdiff: warning: {old} is deprecated; use {new}", file=sys.stderr)
        setattr(namespace, self.dest, values)


# The options of a command with --stream that only the stream takes, and their defaults.
STREAM_ONLY = {"rate": None, "seconds": None, "idle": 2.0, "runtime": "torch", "onnx": None}


def whole_or_stream(args: argparse.Namespace, whole, stream, whole_only: tuple[str, ...]) -> None:
    """A command with --stream (`walk`, `gesture`): with it, `stream(**options)`, which prints its own JSON
    lines, without the options only the whole input's function takes (`whole_only`: previews, plots) and
    refusing --to (the live poses are on the model's skeleton: retarget what it writes); without it,
    `whole(**options)` with its result printed, refusing the options only a stream takes."""
    from walkdiff.common.files import strict_json

    options = keyword_options(args)
    if options.pop("stream"):
        if options.pop("to") is not None or options.pop("to_map") is not None:
            raise WalkdiffError(
                "--to does not work with --stream (the live poses are on the model's skeleton); retarget "
                "the BVH the stream writes with `walkdiff retarget BVH --to RIG --out OUT`"
            )
        stream(**{k: v for k, v in options.items() if k not in whole_only})
        return
    for name in set(STREAM_ONLY) & set(options):
        if options.pop(name) != STREAM_ONLY[name]:
            raise WalkdiffError(f"--{name} needs --stream")
    print(json.dumps(strict_json(whole(**options)), indent=2))
