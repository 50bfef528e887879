"""`walkdiff inbetween` and `walkdiff edit`: the styled generator's edits written as one BVH, a JSON
report beside it (`OUT.json`) and GIF and MP4 previews of the input beside the result, all or none. The
clips are what `StyledGenerator.inbetween` and `edit` (styled/pipeline.py, styled/editing.py) return to
Python for the same seed and settings; `walkdiff sample --keys` is `sample` in styled/commands.py."""

from __future__ import annotations

from pathlib import Path

from walkdiff.common.errors import WalkdiffError, command
from walkdiff.common.files import check_free, output_set, write_json
from walkdiff.models.pipeline import Generated, specs_first
from walkdiff.preview.render import PREVIEW_SECONDS, PreviewCap
from walkdiff.styled.commands import write_clip
from walkdiff.styled.edits import CANDIDATES, FILL_SAMPLER
from walkdiff.styled.pipeline import StyledGenerator


def _outputs(out: str | Path, overwrite: bool, gif: bool) -> tuple[Path, Path]:
    """OUT.bvh and its report OUT.json, refused before any work where they (or the previews) exist."""
    out = Path(out)
    if out.suffix.lower() != ".bvh":
        raise WalkdiffError(f"--out: expected the name of the BVH file to write (OUT.bvh), got {str(out)!r}")
    report = out.with_suffix(".json")
    previews = [out.with_suffix(".gif"), out.with_suffix(".mp4")] if gif else []
    check_free([out, report, *previews], overwrite)
    return out, report


@command
def inbetween(
    ckpt: str | Path,
    a: str | Path,
    b: str | Path,
    out: str | Path,
    frames: int,
    style=None,
    place: bool = False,
    fill_only: bool = False,
    seed: int = 0,
    fix_feet: bool = True,
    gif: bool = True,
    preview_seconds: float = PREVIEW_SECONDS,
    overwrite: bool = False,
    device: str = "cpu",
    candidates: int = CANDIDATES,
    **request,
) -> dict:
    """`walkdiff inbetween`: A, a fill of `frames` frames and B as `out` (or the fill alone), `out`.json
    saying how it was made, and (with `gif`) GIF and MP4 previews of the input beside the result."""
    request = specs_first({"sampler": FILL_SAMPLER} | request)
    out, report = _outputs(out, overwrite, gif)
    cap = PreviewCap(preview_seconds) if gif else None
    generator = StyledGenerator.load(ckpt, device)
    request = generator.request(style, unstyled=True, **request)
    result = generator.fill(request, a, b, frames, seed, place, fill_only, fix_feet, candidates)
    head = {"command": "inbetween", "checkpoint": str(ckpt), "a": str(a), "b": str(b)}
    found = {"fill_frames": list(result.extra["fill"]), "kept_error_body_heights": result.extra["kept_error"]}
    beside = () if fill_only else ((result.extra["source"], "input: A, gap, B"),)
    return _written(out, report, head, result, found, cap, "in-between", beside)


@command
def edit(
    ckpt: str | Path,
    clip: str | Path,
    keep: str,
    out: str | Path,
    style=None,
    seed: int = 0,
    ground: bool = True,
    fix_feet: bool = True,
    gif: bool = True,
    preview_seconds: float = PREVIEW_SECONDS,
    overwrite: bool = False,
    device: str = "cpu",
    **request,
) -> dict:
    """`walkdiff edit`: `clip` with what `keep` does not name made anew, as `out`, `out`.json and (with
    `gif`) GIF and MP4 previews of the input beside the result."""
    request = specs_first(request)
    out, report = _outputs(out, overwrite, gif)
    cap = PreviewCap(preview_seconds) if gif else None
    generator = StyledGenerator.load(ckpt, device)
    request = generator.request(style, unstyled=True, **request)
    result = generator.edited(request, clip, keep, seed, ground, fix_feet)
    head = {"command": "edit", "checkpoint": str(ckpt), "input": str(clip)}
    found = {"kept_error_body_heights": result.extra["kept_error"]}
    beside = ((result.extra["source"], "input"),)
    return _written(out, report, head, result, found, cap, f"kept: {keep}", beside)


def _written(
    out: Path, report: Path, head: dict, result: Generated, found: dict, cap: PreviewCap | None, title: str,
    beside: tuple,
) -> dict:  # fmt: skip
    """The BVH, its previews (`beside`: takes shown to the left of the result) and the report, all or
    none."""
    take = result.take
    record = {
        **head,
        "settings": result.settings,
        "seed": result.seed,
        "retarget": None if result.rig is None else result.rig.record(),
        "file": out.name,
        "preview": None if cap is None else cap.describe(take.num_frames, take.fps, 1 + len(beside)),
        **found,
        "timing": result.timing,
    }
    with output_set(out.parent):
        write_clip(out, take, title, cap, beside)
        write_json(report, record)
    return record
