"""`walkdiff score`: judge any folder of BVH files with a trained evaluator, and the transfer protocol.

Clips are read as world joint positions (`SkeletonProfile.body_positions`), so motion from any pipeline
scores alike: any frame rate (resampled to the evaluator's), any rotation convention or channel order,
any root layout, as long as the body is the evaluator's skeleton. Each clip is cut into windows of the
evaluator's length; every metric comes with a 95% interval by bootstrap over clips
(`walkdiff.metrics.bootstrap`). FMD and KID are measured against the real test windows of the
evaluator's data (stride 1), as `walkdiff evaluate` does.

The transfer protocol (`--transfer manifest.csv`, columns file, source, style[, content]) asks of each
output: is the target style recognised, is the source's content kept (recognised, and near the source
in the evaluator's feature space, window by window), does it look real (FMD/KID)? Two baselines are
scored the same way: the unchanged source labelled with the target style, and real test clips of the
target style. A method must beat both to be called a style transfer.
"""

from __future__ import annotations

import csv
import io
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import output_folder, read_utf8, write_json, write_text
from walkdiff.common.progress import progress
from walkdiff.evaluation.scorer import MotionScorer, WindowSet, load_evaluator, window_set
from walkdiff.metrics import Diversity
from walkdiff.metrics.bootstrap import ClipStatistics, Reference
from walkdiff.metrics.physics import jerk_sums, skating_sums
from walkdiff.motion.body_features import resample_positions
from walkdiff.motion.bvh import read_bvh

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
TRANSFER_COLUMNS = ("file", "source", "style", "content")
TARGET_STYLE_RATIO = 0.8  # of real target-style clips' recognition: the bar of a style transfer
CONTENT_KEPT = 0.95


@dataclass
class Clip:
    """One scored file: its positions at the evaluator's frame rate and labels (None: unlabelled)."""

    name: str
    positions: np.ndarray  # (F, J, 3)
    style: str | None = None
    content: str | None = None


class ClipScorer:
    """An evaluator with its real reference windows: turns lists of clips into bootstrapped metrics."""

    def __init__(self, evaluator_path, root=None, cache_dir=None, contents=None, stride=None, batch_size=512):
        from walkdiff.common.checkpoints import read_checkpoint
        from walkdiff.data.datamodule import MotionDataModule, data_settings
        from walkdiff.data.datasets import protocol_contents

        self.evaluator = load_evaluator(evaluator_path)
        spec = self.evaluator.spec
        self.fps, self.window = float(spec["fps"]), int(spec["window"])
        if stride is not None and stride < 1:
            raise WalkdiffError(f"--stride: expected a whole number of frames >= 1, got {stride}")
        self.stride = stride or max(1, self.window // 2)
        self.styles, self.contents = list(spec["styles"]), list(spec["contents"])
        overrides = {"root": root, "cache_dir": cache_dir}
        checkpoint = read_checkpoint(evaluator_path, "evaluator", mmap=False)
        contents = contents or protocol_contents(spec["dataset"])
        self.data = MotionDataModule(**data_settings(checkpoint, contents=contents, **overrides))
        self.scorer = MotionScorer(self.evaluator, self.data.skeleton, self.fps, batch_size=batch_size)
        reference = self.scorer.embed(window_set(self.data.split_features("test"), self.window))
        self.scorer.set_reference(reference)
        self.reference = Reference.of(reference.features)
        spread = Diversity(num_pairs=1000, seed=0)
        spread.update(reference.features)
        self.real_spread = float(spread.compute())  # mean feature distance of two real windows

    # ------------------------------------------------------------ reading

    def read(self, path: Path, name: str) -> Clip:
        motion = read_bvh(path)
        positions = self.evaluator.profile.body_positions(motion, path)
        return Clip(name, resample_positions(positions, motion.fps, self.fps))

    def real_clips(self, split: str) -> list[Clip]:
        """The evaluator data's clips of a split, as positions, with their labels."""
        out = []
        for info, name, features in self.data.split_features(split):
            raw = torch.from_numpy(features)[None]
            positions = self.scorer.positions(raw)[0].numpy()
            out.append(
                Clip(name, positions, self.styles[info.style], self.data.selection.names[info.content])
            )
        return out

    def label_id(self, kind: str, value: str, where: str) -> int:
        known = self.styles if kind == "style" else self.contents
        if value not in known:
            raise WalkdiffError(
                f"{kind} {value!r} of {where} is not one of the evaluator's ({', '.join(known)})"
            )
        return known.index(value)

    # ------------------------------------------------------------ scoring

    def starts(self, frames: int) -> list[int]:
        return list(range(0, frames - self.window + 1, self.stride))

    def windows(self, clips: list[Clip], starts: list[list[int]] | None = None) -> WindowSet:
        """Embedded windows of the clips (at `starts` per clip, default every stride)."""
        cut, style, content, index = [], [], [], []
        root = self.evaluator.body.root
        for i, clip in enumerate(clips):
            begin = starts[i] if starts is not None else self.starts(len(clip.positions))
            for s in begin:
                w = clip.positions[s : s + self.window].astype(np.float64)
                cut.append(w - w[:1, root : root + 1] * np.array([1.0, 0.0, 1.0]))
            style += [-1 if clip.style is None else self.label_id("style", clip.style, clip.name)] * len(
                begin
            )
            content += [
                -1 if clip.content is None else self.label_id("content", clip.content, clip.name)
            ] * len(begin)
            index += [i] * len(begin)
        windows = WindowSet(
            None,
            torch.tensor(style),
            torch.tensor(content),
            torch.tensor(index),
            positions=torch.from_numpy(np.stack(cut)).float(),
        )
        return self.scorer.embed(windows)

    def statistics(self, windows: WindowSet, per_window: dict[str, torch.Tensor]) -> ClipStatistics:
        positions = windows.positions
        s = self.scorer
        skating = skating_sums(
            positions, s.ground_contacts(positions), s.foot_joints, self.fps, s.speed_threshold
        )
        return ClipStatistics.of(
            windows.features,
            windows.clip,
            self.reference,
            per_window,
            skating,
            jerk_sums(positions, self.fps),
        )

    def recognition(self, windows: WindowSet) -> dict[str, torch.Tensor]:
        """Per-window correctness against the labels the windows carry (none for unlabelled sets)."""
        out = {}
        for kind, labels, logits in (
            ("style", windows.style, windows.style_logits),
            ("content", windows.content, windows.content_logits),
        ):
            if len(getattr(self, f"{kind}s")) > 1 and (labels >= 0).all():
                out[f"{kind}_acc"] = logits.argmax(-1) == labels
        return out


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


def read_transfer_manifest(path: Path) -> list[dict]:
    """Rows {file, source, style[, content]} of a transfer manifest; paths relative to its folder."""
    path = Path(path)
    text = read_utf8(path, "the transfer manifest")
    expected = "expected a CSV header with columns file, source, style (and optionally content)"
    reader = csv.DictReader(io.StringIO(text))
    header = [h.strip().lower() for h in reader.fieldnames or []]
    missing = [c for c in ("file", "source", "style") if c not in header]
    unknown = [c for c in header if c not in TRANSFER_COLUMNS]
    if missing or unknown:
        problem = f"missing column {missing[0]!r}" if missing else f"unknown column {unknown[0]!r}"
        raise WalkdiffError(f"{problem}: {expected}", path=path, line=1)
    reader.fieldnames = header
    rows = []
    for row in reader:
        line = reader.line_num
        values = {k: (v or "").strip() for k, v in row.items() if k is not None}
        if None in row:
            raise WalkdiffError(f"more fields than the header's {len(header)}", path=path, line=line)
        for column in ("file", "source", "style"):
            if not values.get(column):
                raise WalkdiffError(f"empty {column} field: {expected}", path=path, line=line)
        for column in ("file", "source"):
            p = Path(values[column]).expanduser()
            values[column] = p if p.is_absolute() else path.parent / p
            if not values[column].is_file():
                raise WalkdiffError(f"{column} {row[column]!r}: no such file", path=path, line=line)
        values["line"] = line
        rows.append(values)
    if not rows:
        raise WalkdiffError(f"no rows: {expected}", path=path)
    return rows


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
    if transfer is not None and (labels or pattern):
        raise WalkdiffError(
            "--labels and --pattern do not apply to --transfer: the manifest labels every output"
        )
    # Labels and manifests are checked before the evaluator's data is loaded.
    inputs = (
        folder_labels(Path(folder), labels, pattern) if transfer is None else read_transfer_manifest(transfer)
    )
    scorer = ClipScorer(evaluator, root, cache_dir, contents, stride)
    if transfer is None:
        rows, clips, skipped = _score_folder(scorer, inputs, bootstrap, seed)
        verdict = None
    else:
        rows, clips, skipped, verdict = _score_transfer(scorer, inputs, Path(transfer), bootstrap, seed)
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


def _clip_table(clips: list[Clip], windows: WindowSet, scorer: ClipScorer) -> list[dict]:
    """Per clip: frames, windows and the majority recognised style and content."""
    out = []
    for i, clip in enumerate(clips):
        mine = windows.clip == i
        row = {"file": clip.name, "frames": len(clip.positions), "windows": int(mine.sum())}
        for kind, logits in (("style", windows.style_logits), ("content", windows.content_logits)):
            votes = torch.bincount(logits[mine].argmax(-1), minlength=len(getattr(scorer, f"{kind}s")))
            row[kind] = getattr(clip, kind)
            row[f"recognised_{kind}"] = getattr(scorer, f"{kind}s")[int(votes.argmax())]
        out.append(row)
    return out


def _score_folder(scorer: ClipScorer, files: list[tuple[str, Path, dict]], bootstrap: int, seed: int):
    clips = []
    for name, path, values in progress(files, desc="reading", unit="clip"):
        clip = scorer.read(path, name)
        clip.style, clip.content = values.get("style"), values.get("content")
        clips.append(clip)
    clips, skipped = _check_lengths(clips, scorer.window)
    rows = {}
    for row, row_clips in (("scored", clips), ("real train", scorer.real_clips("train"))):
        windows = scorer.windows(row_clips)
        stats = scorer.statistics(windows, scorer.recognition(windows))
        rows[row] = stats.bootstrap(bootstrap, seed)
        if row == "scored":
            table = _clip_table(row_clips, windows, scorer)
    return rows, table, skipped


def _score_transfer(scorer: ClipScorer, entries: list[dict], manifest: Path, bootstrap: int, seed: int):
    outputs, sources = [], {}
    for entry in progress(entries, desc="reading", unit="clip"):
        scorer.label_id("style", entry["style"], f"{manifest}:{entry['line']}")
        clip = scorer.read(entry["file"], str(entry["file"]))
        clip.style = entry["style"]
        outputs.append(clip)
        if entry["source"] not in sources:
            sources[entry["source"]] = scorer.read(entry["source"], str(entry["source"]))
    source_clips = [sources[e["source"]] for e in entries]
    short = [
        o.name
        for o, s in zip(outputs, source_clips, strict=True)
        if min(len(o.positions), len(s.positions)) < scorer.window
    ]
    if short:
        raise WalkdiffError(
            f"{len(short)} output/source pair(s) shorter than the evaluator's {scorer.window}-frame "
            f"window: {short[:5]}",
            path=manifest,
        )

    # The source's content: the manifest's, else what the evaluator recognises in the source.
    source_windows = scorer.windows(source_clips)
    for i, (entry, source) in enumerate(zip(entries, source_clips, strict=True)):
        if entry.get("content"):
            scorer.label_id("content", entry["content"], f"{manifest}:{entry['line']}")
            source.content = entry["content"]
        else:
            votes = torch.bincount(source_windows.content_logits[source_windows.clip == i].argmax(-1))
            source.content = scorer.contents[int(votes.argmax())]

    targets = [e["style"] for e in entries]
    output, windows = transfer_row(scorer, outputs, source_clips, bootstrap, seed)
    rows = {"output": output} | transfer_baselines(scorer, source_clips, targets, bootstrap, seed)
    return rows, _clip_table(outputs, windows, scorer), [], transfer_verdict(rows)


def _paired_starts(scorer: ClipScorer, clips: list[Clip], sources: list[Clip]) -> list[list[int]]:
    return [
        scorer.starts(min(len(c.positions), len(s.positions))) for c, s in zip(clips, sources, strict=True)
    ]


def transfer_row(
    scorer: ClipScorer, clips: list[Clip], sources: list[Clip], bootstrap: int, seed: int
) -> tuple[dict, WindowSet]:
    """The transfer metrics of `clips` (labelled with their target styles) against their `sources`
    (labelled with their contents), window by window at the same times; and the scored windows."""
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
    return scorer.statistics(windows, per_window).bootstrap(bootstrap, seed), windows


def transfer_baselines(
    scorer: ClipScorer, sources: list[Clip], targets: list[str], bootstrap: int, seed: int
) -> dict[str, dict]:
    """The two rows every transfer is compared with: each source unchanged but labelled with its target
    style, and a real test clip of the target style in its place."""
    unchanged = [Clip(s.name, s.positions, t) for s, t in zip(sources, targets, strict=True)]
    real = _real_targets(scorer, targets, sources)
    return {
        "baseline: source unchanged": transfer_row(scorer, unchanged, sources, bootstrap, seed)[0],
        "baseline: real target-style clips": transfer_row(scorer, real, sources, bootstrap, seed)[0],
    }


def _real_targets(scorer: ClipScorer, targets: list[str], sources: list[Clip]) -> list[Clip]:
    """For every target style, a real test clip of that style, of the source's content when the test
    split has one; targets of one (style, content) take the candidates in turn."""
    real = scorer.real_clips("test")
    taken: dict[tuple[str, str], int] = {}
    out = []
    for style, source in zip(targets, sources, strict=True):
        pool = [c for c in real if c.style == style and c.content == source.content] or [
            c for c in real if c.style == style
        ]
        pool = [c for c in pool if len(c.positions) >= scorer.window]
        if not pool:
            raise WalkdiffError(f"the evaluator's test split has no clip of style {style!r} to compare with")
        k = taken.get((style, source.content), 0)
        taken[(style, source.content)] = k + 1
        chosen = pool[k % len(pool)]
        out.append(Clip(chosen.name, chosen.positions, style))
    return out


def transfer_verdict(rows: dict) -> dict:
    """Does the output beat both baselines? Target style recognised at least 80% as often as in real
    target-style clips and more often than in the unchanged source; content kept in >= 95% of windows and
    nearer the source than real clips of the target style are."""
    out, source, real = (
        rows[k] for k in ("output", "baseline: source unchanged", "baseline: real target-style clips")
    )
    checks = {
        "target_style_vs_real": out["target_style_acc"]["value"]
        >= TARGET_STYLE_RATIO * real["target_style_acc"]["value"],
        "target_style_vs_source": out["target_style_acc"]["value"] > source["target_style_acc"]["value"],
        "content_kept": out["content_kept"]["value"] >= CONTENT_KEPT,
        "nearer_source_than_real": out["content_distance"]["value"] < real["content_distance"]["value"],
    }
    ratio = out["target_style_acc"]["value"] / max(real["target_style_acc"]["value"], 1e-9)
    return {"checks": checks, "target_style_over_real": ratio, "style_transfer": all(checks.values())}


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
        v = report["verdict"]
        lines += [
            f"Style transfer: **{'yes' if v['style_transfer'] else 'no'}** (target style recognised "
            f"{v['target_style_over_real']:.2f}x as often as in real clips of that style; checks: "
            + ", ".join(f"{k} {'✓' if ok else '✗'}" for k, ok in v["checks"].items())
            + ")",
            "",
        ]
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
