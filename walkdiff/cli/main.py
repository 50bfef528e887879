"""The `walkdiff` command: Lightning's fit/validate/test plus the tools users run on their motion."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from walkdiff.callbacks.fit import lightning_cli
from walkdiff.cli import bench, distill, edit, evaluate, files, generate, gestures, live, model_files, walker
from walkdiff.common.arguments import Parser
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.threads import apply_threads, choose_threads

LIGHTNING_VERBS = ("fit", "validate", "test")
# In the order `walkdiff --help` lists their commands; each sets `run`, the handler of what it parsed.
FAMILIES = (files, evaluate, generate, edit, gestures, walker, live, distill, model_files, bench)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="walkdiff",
        description="Diffusion-based motion synthesis. Training verbs: "
        + ", ".join(LIGHTNING_VERBS)
        + " (LightningCLI; `walkdiff fit --help`).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for family in FAMILIES:
        family.add_parsers(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in words
    if debug:
        words.remove("--debug")
        argv = words
    try:
        threads_flag = _pop_threads(words)
        if threads_flag is not None:
            if argv is None:  # LightningCLI reads sys.argv itself
                sys.argv[1:] = words
            else:
                argv = words
        threads, why = choose_threads(threads_flag)
        apply_threads(threads, why)
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
    except KeyboardInterrupt as stop:  # a stream's says what it wrote before it stopped
        print("walkdiff: interrupted" + (f"; {stop}" if str(stop) else ""), file=sys.stderr)
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
        elif isinstance(error, OSError) and error.filename is not None:  # a file or folder we could not use
            from walkdiff.common.files import os_reason

            message = f"{error.filename}: {os_reason(error)}"
        elif type(error).__name__ == "ArgumentError":  # LightningCLI's option and config errors
            message = f"{option_error(str(error))}; see `walkdiff {words[0]} --help`"
        else:
            message = f"{type(error).__name__}: {error} (run again with --debug for the traceback)"
        print(f"walkdiff: error: {message}", file=sys.stderr)
        return 1


# Folder outputs of the bench verbs; the others write one JSON file.
BENCH_FOLDERS = ("sample", "protocol", "style")
# The files that mark an earlier run, for commands whose own code does not check what it would replace.
REPORTS = {"evaluate": ("report.json", "report.md"), "evaluate-gesture": ("report.json",)}
BENCH_REPORTS = {
    "sample": ("sample.json", "sample.png"),
    "protocol": ("protocol.json", "protocol.md"),
    "style": ("style.json", "style.md"),
}


def command_output(args: argparse.Namespace) -> tuple[Path, tuple[str, ...]] | None:
    """The output a command writes, locked while it runs, and the files there that need --overwrite.

    Commands that write check their own outputs (by name) unless listed here; a file output is guarded
    as a whole ("" names the file itself).
    """
    if args.command == "convert":
        return Path(args.output), ()
    resumable = args.command == "bench" and (args.what == "ablate" or getattr(args, "suite", None))
    if resumable:  # a folder of variants it resumes; --overwrite trains them again
        return Path(args.out), ()
    if args.command == "bench":
        folder = args.what in BENCH_FOLDERS
        return Path(args.out), BENCH_REPORTS[args.what] if folder else ("",)
    out = getattr(args, "out", None) or getattr(args, "static", None)  # play --static OUT writes OUT
    if out is None:  # inspect; data scan without --out
        return None
    return Path(out), REPORTS.get(args.command, ())


def _pop_threads(words: list[str]) -> str | None:
    """Removes `--threads N` / `--threads=N` (any command, like --debug) from `words`; returns N."""
    for i, word in enumerate(words):
        if word == "--threads":
            if i + 1 == len(words):
                raise WalkdiffError("--threads: expected a number of threads after it")
            value = words[i + 1]
            del words[i : i + 2]
            return value
        if word.startswith("--threads="):
            del words[i]
            return word.split("=", 1)[1]
    return None


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


def run_command(args: argparse.Namespace) -> int:
    """Call the handler the command's parser chose, with the options alone."""
    run = vars(args).pop("run")
    run(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
