"""`walkdiff inbetween` and `walkdiff edit`: the styled generator's edits written as one BVH and a JSON
report beside it (`OUT.json`), all or none. The clips are what `StyledGenerator.inbetween` and `edit`
(styled/pipeline.py, styled/editing.py) return to Python for the same seed and settings;
`walkdiff sample --keys` is `sample` in styled/commands.py."""

from __future__ import annotations

from pathlib import Path

from walkdiff.common.errors import WalkdiffError, command
from walkdiff.common.files import check_free, output_set, write_json
from walkdiff.models.pipeline import Generated, specs_first
from walkdiff.motion.bvh import write_bvh
from walkdiff.styled.edits import CANDIDATES, FILL_SAMPLER, fill_steps
from walkdiff.styled.pipeline import StyledGenerator


def _outputs(out: str | Path, overwrite: bool) -> tuple[Path, Path]:
    out = Path(out)
    if out.suffix.lower() != ".bvh":
        raise WalkdiffError(f"--out: expected the name of the BVH file to write (OUT.bvh), got {str(out)!r}")
    report = out.with_suffix(".json")
    check_free([out, report], overwrite)
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
    overwrite: bool = False,
    device: str = "cpu",
    candidates: int = CANDIDATES,
    **request,
) -> dict:
    """`walkdiff inbetween`: A, a fill of `frames` frames and B as `out` (or the fill alone), and
    `out`.json saying how it was made."""
    sampler = request.setdefault("sampler", FILL_SAMPLER)
    request = specs_first(request | {"steps": fill_steps(sampler, request.get("steps"))})
    out, report = _outputs(out, overwrite)
    generator = StyledGenerator.load(ckpt, device)
    request = generator.request(style, unstyled=True, **request)
    result = generator.fill(request, a, b, frames, seed, place, fill_only, fix_feet, candidates)
    head = {"command": "inbetween", "checkpoint": str(ckpt), "a": str(a), "b": str(b)}
    found = {"fill_frames": list(result.extra["fill"]), "kept_error_body_heights": result.extra["kept_error"]}
    return _written(out, report, head, result, found)


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
    overwrite: bool = False,
    device: str = "cpu",
    **request,
) -> dict:
    """`walkdiff edit`: `clip` with what `keep` does not name made anew, as `out` and `out`.json."""
    request = specs_first(request)
    out, report = _outputs(out, overwrite)
    generator = StyledGenerator.load(ckpt, device)
    request = generator.request(style, unstyled=True, **request)
    result = generator.edited(request, clip, keep, seed, ground, fix_feet)
    head = {"command": "edit", "checkpoint": str(ckpt), "input": str(clip)}
    return _written(out, report, head, result, {"kept_error_body_heights": result.extra["kept_error"]})


def _written(out: Path, report: Path, head: dict, result: Generated, found: dict) -> dict:
    record = {
        **head,
        "settings": result.settings,
        "seed": result.seed,
        "retarget": None if result.rig is None else result.rig.record(),
        "file": out.name,
        **found,
        "timing": result.timing,
    }
    with output_set(out.parent):
        write_bvh(out, result.take.motion)
        write_json(report, record)
    return record
