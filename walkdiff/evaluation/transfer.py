"""The transfer protocol of `walkdiff score --transfer manifest.csv` and `bench protocol`.

The manifest (columns file, source, style[, content]) names each output, the clip it was made from and its
target style; its paths are relative to its folder and must stay inside it unless the user allows others
(`--allow-outside`), so a manifest cannot make `score` read files its user did not mean to give.

Of each output the protocol asks: is the target style recognised, is the source's content kept
(recognised, and near the source in the evaluator's feature space, window by window), does it look real
(FMD/KID)? Two baselines are scored the same way: the unchanged source labelled with the target style,
and a real test clip of the target style (of the source's content) in place of each output. A method is
a style transfer when it beats both; each check's margin gets a 95% interval from a bootstrap over the
manifest's rows, resampled alike in the three rows, and a verdict is given only when the clips are
enough to tell (`transfer_verdict`).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import read_utf8
from walkdiff.common.progress import progress
from walkdiff.evaluation.clips import Clip, ClipScorer
from walkdiff.evaluation.scorer import WindowSet
from walkdiff.metrics.bootstrap import ClipStatistics, resample_weights

TRANSFER_COLUMNS = ("file", "source", "style", "content")
TARGET_STYLE_RATIO = 0.8  # of real target-style clips' recognition: the bar of a style transfer
CONTENT_KEPT = 0.95
# Fewer source clips than this for a target style and the verdict is "inconclusive": on 4 clips a single
# clip flips it, and a bootstrap over so few clips has too few distinct resamples to be trusted.
MIN_SOURCES_PER_STYLE = 5
BASELINES = ("baseline: source unchanged", "baseline: real target-style clips")


@dataclass
class ScoredRow:
    """A row of the report: its bootstrapped metrics, and the per-clip statistics they came from."""

    summary: dict[str, dict[str, float]]  # metric -> {value, low, high, n}
    statistics: ClipStatistics
    windows: WindowSet


# ---------------------------------------------------------------- the manifest


def read_transfer_manifest(path: Path, allow_outside: bool = False) -> list[dict]:
    """Rows {file, source, style[, content], line} of a transfer manifest; paths relative to its folder,
    and inside it unless `allow_outside`; every output once."""
    path = Path(path)
    text = read_utf8(path, "the transfer manifest")
    expected = "expected a CSV header with columns file, source, style (and optionally content)"
    reader = csv.DictReader(io.StringIO(text))
    header = [h.strip().lower() for h in reader.fieldnames or []]
    missing = [c for c in ("file", "source", "style") if c not in header]
    unknown = [c for c in header if c not in TRANSFER_COLUMNS]
    if missing or unknown:
        # A header without the needed columns may be any file's first line: it is not quoted.
        problem = f"missing column {missing[0]!r}" if missing else f"unknown column {unknown[0]!r}"
        raise WalkdiffError(f"{problem}: {expected}", path=path, line=1)
    reader.fieldnames = header
    rows, outputs = [], {}
    for row in reader:
        line = reader.line_num
        values = {k: (v or "").strip() for k, v in row.items() if k is not None}
        if None in row:
            raise WalkdiffError(f"more fields than the header's {len(header)}", path=path, line=line)
        for column in ("file", "source", "style"):
            if not values.get(column):
                raise WalkdiffError(f"empty {column} field: {expected}", path=path, line=line)
        for column in ("file", "source"):
            values[column] = _manifest_file(path, line, column, values[column], allow_outside)
        first = outputs.setdefault(values["file"].resolve(), line)
        if first != line:
            raise WalkdiffError(
                f"file {row['file'].strip()!r} is the output of line {first} too: expected each output "
                "once (a repeated row would count twice)",
                path=path,
                line=line,
            )
        values["line"] = line
        rows.append(values)
    if not rows:
        raise WalkdiffError(f"no rows: {expected}", path=path)
    return rows


def _manifest_file(manifest: Path, line: int, column: str, value: str, allow_outside: bool) -> Path:
    """A path field as a file in the manifest's folder (or anywhere, `allow_outside`)."""
    folder = manifest.parent
    if allow_outside:
        given = Path(value).expanduser()
        path = given if given.is_absolute() else folder / given
    else:
        path = folder / value
        outside = value.startswith("~") or Path(value).is_absolute()
        # resolve() follows links and '..': a link that leaves the folder is outside too.
        if outside or not path.resolve().is_relative_to(folder.resolve()):
            raise WalkdiffError(
                f"{column} {value!r} is outside the manifest's folder: expected a path relative to it "
                "and inside it (--allow-outside takes absolute, ~ and .. paths and links out of it)",
                path=manifest,
                line=line,
            )
    if not path.is_file():
        raise WalkdiffError(f"{column} {value!r}: no such file", path=manifest, line=line)
    return path


# ---------------------------------------------------------------- scoring


def score_transfer(scorer: ClipScorer, entries: list[dict], manifest: Path, bootstrap: int, seed: int):
    """(rows, per-output table, verdict) of a manifest's outputs beside both baselines."""
    sources: dict[Path, Clip] = {}
    for entry in progress(entries, desc="reading sources", unit="clip"):
        scorer.label_id("style", entry["style"], f"{manifest}:{entry['line']}")
        if entry["source"] not in sources:
            sources[entry["source"]] = scorer.read(entry["source"], str(entry["source"]))
    # Each row's source as a clip of its own: rows of one source may name different contents.
    source_clips = [Clip(**vars(sources[e["source"]])) for e in entries]
    _source_contents(scorer, entries, source_clips, manifest)
    targets = [e["style"] for e in entries]
    # Checked before the outputs are read and scored: a missing baseline clip is named at once.
    real = real_targets(scorer, targets, source_clips)
    real_contents = [c.content for c in real]  # before the baseline labels them with the sources'
    outputs = []
    for entry in progress(entries, desc="reading outputs", unit="clip"):
        clip = scorer.read(entry["file"], str(entry["file"]))
        clip.style = entry["style"]
        outputs.append(clip)
    short = [
        f"{o.name} ({min(len(o.positions), len(s.positions))} frames)"
        for o, s in zip(outputs, source_clips, strict=True)
        if min(len(o.positions), len(s.positions)) < scorer.window
    ]
    if short:
        raise WalkdiffError(
            f"{len(short)} output/source pair(s) shorter than the evaluator's {scorer.window}-frame "
            f"window (at {scorer.fps:g} fps): {', '.join(short[:5])}",
            path=manifest,
        )
    output = transfer_row(scorer, outputs, source_clips, bootstrap, seed)
    rows = {"output": output} | transfer_baselines(scorer, source_clips, targets, real, bootstrap, seed)
    table = scorer.clip_table(outputs, output.windows)
    for row, entry, chosen, content in zip(table, entries, real, real_contents, strict=True):
        row |= {
            "source": str(entry["source"]),
            "baseline_real_clip": chosen.name,
            "baseline_real_content": content,
        }
    per_style = sources_per_style(targets, [e["source"].resolve() for e in entries])
    verdict = transfer_verdict(rows, per_style, bootstrap, seed)
    return {name: row.summary for name, row in rows.items()}, table, verdict


def _source_contents(scorer: ClipScorer, entries: list[dict], sources: list[Clip], manifest: Path) -> None:
    """Each source's content: the manifest's, else what the evaluator recognises in the source."""
    windows = None
    for i, (entry, source) in enumerate(zip(entries, sources, strict=True)):
        if entry.get("content"):
            scorer.label_id("content", entry["content"], f"{manifest}:{entry['line']}")
            source.content = entry["content"]
            continue
        if len(source.positions) < scorer.window:
            raise WalkdiffError(
                f"source {source.name} has {len(source.positions)} frames, shorter than the evaluator's "
                f"{scorer.window}-frame window (at {scorer.fps:g} fps)",
                path=manifest,
                line=entry["line"],
            )
        if windows is None:
            windows = scorer.windows(sources)
        votes = torch.bincount(windows.content_logits[windows.clip == i].argmax(-1))
        source.content = scorer.contents[int(votes.argmax())]


def sources_per_style(targets: list[str], sources: list) -> dict[str, int]:
    """Distinct `sources` (anything that tells them apart) per target style."""
    out: dict[str, set] = {}
    for style, source in zip(targets, sources, strict=True):
        out.setdefault(style, set()).add(source)
    return {style: len(found) for style, found in out.items()}


def _paired_starts(scorer: ClipScorer, clips: list[Clip], sources: list[Clip]) -> list[list[int]]:
    return [
        scorer.starts(min(len(c.positions), len(s.positions))) for c, s in zip(clips, sources, strict=True)
    ]


def transfer_row(
    scorer: ClipScorer, clips: list[Clip], sources: list[Clip], bootstrap: int, seed: int
) -> ScoredRow:
    """The transfer metrics of `clips` (labelled with their target styles) against their `sources`
    (labelled with their contents), window by window at the same times; the clips take their sources'
    contents."""
    for clip, source in zip(clips, sources, strict=True):
        clip.content = source.content
    starts = _paired_starts(scorer, clips, sources)
    windows = scorer.windows(clips, starts)
    paired = scorer.windows(sources, starts)
    per_window = {
        "target_style_acc": windows.style_logits.argmax(-1) == windows.style,
        "content_kept": windows.content_logits.argmax(-1) == windows.content,
        "content_distance": (windows.features - paired.features).norm(dim=-1) / scorer.real_spread,
    }
    statistics = scorer.statistics(windows, per_window)
    return ScoredRow(statistics.bootstrap(bootstrap, seed), statistics, windows)


def transfer_baselines(
    scorer: ClipScorer, sources: list[Clip], targets: list[str], real: list[Clip], bootstrap: int, seed: int
) -> dict[str, ScoredRow]:
    """The two rows every transfer is compared with: each source unchanged but labelled with its target
    style, and the `real` clips (`real_targets`) in its place."""
    unchanged = [Clip(s.name, s.positions, t) for s, t in zip(sources, targets, strict=True)]
    return {
        BASELINES[0]: transfer_row(scorer, unchanged, sources, bootstrap, seed),
        BASELINES[1]: transfer_row(scorer, real, sources, bootstrap, seed),
    }


def real_targets(scorer: ClipScorer, targets: list[str], sources: list[Clip]) -> list[Clip]:
    """For every target style, a real test clip of that style at least a window long, of the source's
    content (of another content only where the test split holds none of it); targets of one (style,
    content) take the candidates in turn."""
    real = scorer.real_clips("test")
    taken: dict[tuple[str, str], int] = {}
    out = []
    for style, source in zip(targets, sources, strict=True):
        pool = [c for c in real if c.style == style and c.content == source.content] or [
            c for c in real if c.style == style
        ]
        usable = [c for c in pool if len(c.positions) >= scorer.window]
        if not usable:
            raise WalkdiffError(_no_real_target(scorer, style, source, pool))
        k = taken.get((style, source.content), 0)
        taken[(style, source.content)] = k + 1
        chosen = usable[k % len(usable)]
        out.append(Clip(chosen.name, chosen.positions, style, chosen.content))
    return out


def _no_real_target(scorer: ClipScorer, style: str, source: Clip, pool: list[Clip]) -> str:
    contents = ", ".join(scorer.data.selection.names)
    if not pool:
        return f"the evaluator's test split ({contents}) has no clip of style {style!r} to compare with"
    short = ", ".join(f"{c.name} ({c.content}, {len(c.positions)} frames)" for c in pool[:5])
    return (
        f"the evaluator's test split ({contents}) has no {style!r} clip at least {scorer.window} frames "
        f"long (a window at {scorer.fps:g} fps) to stand in for source {source.name} ({source.content}): "
        f"{short}; give that row another target style, or leave {source.content!r} out of --contents"
    )


# ---------------------------------------------------------------- the verdict

# check -> strict (the margin must be > 0, not >= 0)
CHECKS = {
    "target_style_vs_real": False,
    "target_style_vs_source": True,
    "content_kept": False,
    "nearer_source_than_real": True,
}


def _margins(rows: dict[str, ScoredRow], weights: torch.Tensor) -> dict[str, float]:
    """How far each check clears its bar (< 0: it fails) on the resample `weights` of the manifest's
    rows: the three rows hold one clip per row, so one weight vector resamples them alike."""
    out, source, real = (rows[k].statistics for k in ("output", *BASELINES))
    style = out.share("target_style_acc", weights)
    return {
        "target_style_vs_real": style - TARGET_STYLE_RATIO * real.share("target_style_acc", weights),
        "target_style_vs_source": style - source.share("target_style_acc", weights),
        "content_kept": out.share("content_kept", weights) - CONTENT_KEPT,
        "nearer_source_than_real": real.share("content_distance", weights)
        - out.share("content_distance", weights),
    }


def transfer_verdict(
    rows: dict[str, ScoredRow], per_style: dict[str, int], bootstrap: int, seed: int
) -> dict:
    """Does the output beat both baselines? Target style recognised at least 80% as often as in real
    target-style clips and more often than in the unchanged source; content kept in >= 95% of windows and
    nearer the source than real clips of the target style are.

    "yes" or "no" only when every target style has at least MIN_SOURCES_PER_STYLE source clips and the 95%
    interval of each check's margin lies on one side of its bar ("no" needs one failing check whose
    interval lies wholly below it); else "inconclusive", saying why.
    """
    clips = rows["output"].statistics.num_clips
    point = _margins(rows, torch.ones(clips))
    draws = [_margins(rows, w) for w in resample_weights(clips, bootstrap, seed)]
    margins, checks = {}, {}
    for name, strict in CHECKS.items():
        low, high = np.percentile([d[name] for d in draws], [2.5, 97.5])
        passed = point[name] > 0 if strict else point[name] >= 0
        settled = (low > 0 if strict else low >= 0) if passed else (high <= 0 if strict else high < 0)
        checks[name] = bool(passed)
        margins[name] = {
            "value": point[name],
            "low": float(low),
            "high": float(high),
            "settled": bool(settled),
        }
    few = {style: n for style, n in sorted(per_style.items()) if n < MIN_SOURCES_PER_STYLE}
    unsettled = [name for name, m in margins.items() if not m["settled"]]
    if few:
        verdict = "inconclusive"
        warning = (
            f"too few clips to tell: fewer than {MIN_SOURCES_PER_STYLE} source clips for target style "
            + ", ".join(f"{style} ({n})" for style, n in few.items())
        )
    elif any(not checks[name] and margins[name]["settled"] for name in CHECKS):
        verdict, warning = "no", None
    elif not unsettled:
        verdict, warning = "yes", None
    else:
        verdict = "inconclusive"
        warning = "the 95% interval of the margin of " + ", ".join(unsettled) + " holds its bar"
    style = {k: rows[k].summary["target_style_acc"]["value"] for k in ("output", BASELINES[1])}
    return {
        "verdict": verdict,
        "style_transfer": {"yes": True, "no": False}.get(verdict),
        "warning": warning,
        "checks": checks,
        "margins": margins,
        "target_style_over_real": style["output"] / max(style[BASELINES[1]], 1e-9),
        "sources_per_style": dict(sorted(per_style.items())),
    }


def verdict_lines(verdict: dict) -> list[str]:
    """The verdict in words for a report."""
    checks = ", ".join(
        f"{name} {m['value']:+.3f} [{m['low']:+.3f}, {m['high']:+.3f}] "
        + ("✓" if verdict["checks"][name] else "✗")
        for name, m in verdict["margins"].items()
    )
    lines = [
        f"Style transfer: **{verdict['verdict']}** (target style recognised "
        f"{verdict['target_style_over_real']:.2f}x as often as in real clips of that style; each check's "
        f"margin over its bar [95% interval]: {checks})",
        "",
    ]
    if verdict["warning"]:
        lines += [
            f"Warning: {verdict['warning']}. A verdict needs at least {MIN_SOURCES_PER_STYLE} source clips "
            "per target style and every check's interval on one side of its bar.",
            "",
        ]
    return lines
