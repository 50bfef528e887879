"""`walkdiff score`: judge any folder of BVH files with a trained evaluator, or a transfer's outputs.

Clips are read as world joint positions and cut into windows of the evaluator's length
(`evaluation.clips`); every metric comes with a 95% interval by bootstrap over clips
(`walkdiff.metrics.bootstrap`). FMD and KID are measured against the real test windows of the evaluator's
data (stride 1), as `walkdiff evaluate` does. `--transfer manifest.csv` scores a transfer's outputs
beside two baselines and gives a verdict (`evaluation.transfer`).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import output_folder, write_json, write_text
from walkdiff.common.progress import progress
from walkdiff.evaluation.clips import Clip, ClipScorer
from walkdiff.evaluation.transfer import read_transfer_manifest, score_transfer, verdict_lines

log = logging.getLogger(__name__)

# name in the report -> (table header, decimals)
METRICS = {
    "style_acc": ("Style acc. ↑", 3),
    "content_acc": ("Content acc. ↑", 3),
    "target_style_acc": ("Target style ↑", 3),
    "content_kept": ("Content kept ↑", 3),
    "content_distance": ("Distance to source ↓", 3),
    "fmd": ("FMD ↓", 2),
    "kid": ("KID ↓", 3),
    "diversity": ("Diversity →", 2),
    "skate_ratio": ("Skate ratio ↓", 3),
    "slide_speed": ("Slide speed ↓", 2),
    "jitter": ("Jitter ↓", 0),
}


def _check_lengths(clips: list[Clip], window: int) -> tuple[list[Clip], list[str]]:
    kept = [c for c in clips if len(c.positions) >= window]
    short = [c.name for c in clips if len(c.positions) < window]
    if short:
        log.warning(
            f"{len(short)} clip(s) shorter than the evaluator's {window}-frame window left out: {short[:5]}"
        )
    if not kept:
        raise WalkdiffError(f"no clip is at least {window} frames long (at the evaluator's frame rate)")
    return kept, short


# ---------------------------------------------------------------- labels


def folder_labels(folder: Path, labels: str | None, pattern: str | None) -> list[tuple[str, Path, dict]]:
    """(name, path, {style, content}) of every BVH file below `folder`, labels as `data.dataset: folder`
    reads them (a manifest, `labels.csv`/`labels.json` in the folder, or a pattern)."""
    from walkdiff.data.folder import NO_CONTENT, NO_STYLE, FolderSource

    source = FolderSource(folder, labels=labels, pattern=pattern)
    index = source.index
    out = []
    for clip in index.clips:
        values = {}
        if index.styles != (NO_STYLE,):
            values["style"] = index.styles[clip.style]
        if index.groups != (NO_CONTENT,):
            values["content"] = index.groups[clip.content]
        out.append((clip.name, clip.path, values))
    return out


# ---------------------------------------------------------------- the command


def score(
    folder: str | Path | None,
    evaluator: str | Path,
    out: str | Path,
    labels: str | None = None,
    pattern: str | None = None,
    transfer: str | Path | None = None,
    stride: int | None = None,
    bootstrap: int = 500,
    seed: int = 0,
    root: str | None = None,
    cache_dir: str | None = None,
    contents: str | None = None,
    allow_outside: bool = False,
    overwrite: bool = False,
) -> dict:
    """Scores a folder (or a transfer manifest's outputs); writes OUT/report.json and OUT/report.md."""
    started = time.perf_counter()
    if bootstrap < 10:
        raise WalkdiffError(f"--bootstrap: expected at least 10 resamples, got {bootstrap}")
    out = output_folder(out)
    existing = [p for p in (out / "report.json", out / "report.md") if p.exists()]
    if existing and not overwrite:
        raise WalkdiffError("a report is already there; pass --overwrite to replace it", path=existing[0])
    if transfer is None and folder is None:
        raise WalkdiffError("score needs a folder of BVH files, or --transfer manifest.csv")
    if transfer is not None and folder is not None:
        raise WalkdiffError(
            f"give a folder of BVH files or --transfer manifest.csv, not both: the manifest names every "
            f"file it scores, so the folder {str(folder)!r} would be left unread"
        )
    if allow_outside and transfer is None:
        raise WalkdiffError("--allow-outside applies to the paths of a --transfer manifest only")
    if transfer is not None and (labels or pattern):
        raise WalkdiffError(
            "--labels and --pattern do not apply to --transfer: the manifest labels every output"
        )
    # Labels and manifests are checked before the evaluator's data is loaded.
    if transfer is None:
        inputs = folder_labels(Path(folder), labels, pattern)
    else:
        inputs = read_transfer_manifest(Path(transfer), allow_outside)
    scorer = ClipScorer(evaluator, root, cache_dir, contents, stride)
    if transfer is None:
        rows, clips, skipped = _score_folder(scorer, inputs, bootstrap, seed)
        verdict = None
    else:
        (rows, clips, verdict), skipped = score_transfer(scorer, inputs, Path(transfer), bootstrap, seed), []
    report = {
        "settings": {
            "folder": None if folder is None else str(folder),
            "transfer": None if transfer is None else str(transfer),
            "evaluator": str(evaluator),
            "labels": labels,
            "pattern": pattern,
            "window": scorer.window,
            "stride": scorer.stride,
            "fps": scorer.fps,
            "bootstrap": bootstrap,
            "seed": seed,
            "allow_outside": allow_outside,
        },
        "reference": {
            "dataset": scorer.evaluator.spec["dataset"],
            "contents": list(scorer.data.selection.names),
            "windows": scorer.reference.features.shape[0],
            "real_spread": scorer.real_spread,
        },
        "rows": rows,
        "verdict": verdict,
        "clips": clips,
        "skipped_short": skipped,
        "elapsed_s": round(time.perf_counter() - started, 1),
    }
    write_json(out / "report.json", report)
    write_text(out / "report.md", format_report(report))
    return report


def _score_folder(scorer: ClipScorer, files: list[tuple[str, Path, dict]], bootstrap: int, seed: int):
    clips = []
    for name, path, values in progress(files, desc="reading", unit="clip"):
        clip = scorer.read(path, name)
        clip.style, clip.content = values.get("style"), values.get("content")
        clips.append(clip)
    clips, skipped = _check_lengths(clips, scorer.window)
    rows = {}
    windows = scorer.windows(clips)
    for row, row_windows in (("scored", windows), ("real train", scorer.real_windows("train"))):
        stats = scorer.statistics(row_windows, scorer.recognition(row_windows))
        rows[row] = stats.bootstrap(bootstrap, seed)
    return rows, scorer.clip_table(clips, windows), skipped


def format_summary(summary: dict, decimals: int) -> str:
    if summary["value"] is None or not np.isfinite(summary["value"]):
        return "–"
    return f"{summary['value']:.{decimals}f} [{summary['low']:.{decimals}f}, {summary['high']:.{decimals}f}]"


def format_report(report: dict) -> str:
    s, r = report["settings"], report["reference"]
    rows = report["rows"]
    shown = [m for m in METRICS if any(m in row for row in rows.values())]
    what = f"transfer manifest `{s['transfer']}`" if s["transfer"] else f"folder `{s['folder']}`"
    lines = [
        "# walkdiff score",
        "",
        f"- scored: {what}, {len(report['clips'])} clips",
        f"- evaluator: `{s['evaluator']}`; {s['window']}-frame windows every {s['stride']} frames at "
        f"{s['fps']:g} fps",
        f"- reference: {r['windows']} real test windows of {r['dataset']} ({', '.join(r['contents'])})",
        f"- every value: on the whole set [95% interval by bootstrap over clips, {s['bootstrap']} resamples]",
        "",
        "| | clips | " + " | ".join(METRICS[m][0] for m in shown) + " |",
        "|---|---:|" + "---:|" * len(shown),
    ]
    for name, row in rows.items():
        n = next(iter(row.values()))["n"]
        cells = [format_summary(row[m], METRICS[m][1]) if m in row else "" for m in shown]
        lines.append(f"| {name} | {n} | " + " | ".join(cells) + " |")
    lines.append("")
    if report["verdict"] is not None:
        lines += verdict_lines(report["verdict"])
        stand_ins = {(c["source"], c["style"]): c for c in report["clips"]}
        lines += ["Real target-style clips of the baseline, per source and target style:", ""]
        lines += [
            f"- `{source}` → {style}: {c['baseline_real_clip']} ({c['baseline_real_content']})"
            for (source, style), c in stand_ins.items()
        ]
        lines.append("")
    if report["skipped_short"]:
        lines += [f"Left out (shorter than a window): {', '.join(report['skipped_short'][:10])}", ""]
    lines += [
        "FMD and KID against the real test windows (KID is unbiased: sets of any size compare; FMD grows "
        "as sets shrink). Distance to source: evaluator-feature distance of each window to the source "
        "window at the same time, over the mean distance of two real windows. Skating: share of "
        "contact steps sliding faster than the contact speed; slide speed and jitter in file units/s, /s³.",
        "",
    ]
    return "\n".join(lines)
