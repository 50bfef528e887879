"""`walkdiff data split DIR`: which clips train, validate and test, with their labels.

The same listing and labelling as training (`FolderSource.split_clips`, or a named dataset's published
split), without reading any motion: a folder of thousands of files lists in a moment. With `out`, a
labels manifest (file, style, content, split) that fixes every clip's split: edit it and train on it
with `data.labels` (or `data scan --labels`).
"""

from __future__ import annotations

import csv
import io
from collections import Counter
from pathlib import Path

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_text
from walkdiff.data.clips import ClipInfo, ContentSelection
from walkdiff.data.datasets import MODULES, open_source
from walkdiff.data.folder import NO_CONTENT, NO_STYLE, SPLITS, FolderSource

_LABELS_SHOWN = 8  # label counts named per split line


def split_report(
    folder: str | Path,
    labels: str | None = None,
    pattern: str | None = None,
    default_style: str | None = None,
    default_content: str | None = None,
    val_fraction: float | None = None,
    test_fraction: float | None = None,
    contents: str = "all",
    out: str | Path | None = None,
    overwrite: bool = False,
) -> str:
    """The train/val/test clips of `folder` (a folder of BVH files, or a dataset name: xia, humanact12,
    found in $WALKDIFF_DATA) as text to print; with `out`, also a CSV manifest of every clip's split.

    The options are the folder dataset's (`walkdiff.data.folder`) and `data.contents`."""
    options = {
        "labels": labels, "pattern": pattern, "default_style": default_style,
        "default_content": default_content, "val_fraction": val_fraction, "test_fraction": test_fraction,
    }  # fmt: skip
    options = {k: v for k, v in options.items() if v is not None}
    path = Path(folder).expanduser()
    if not path.is_dir() and str(folder) in MODULES:
        source = open_source(str(folder), None, None, **options)
    elif path.is_dir():
        source = FolderSource(path.resolve(), **options)
    else:
        raise WalkdiffError(
            f"folder of BVH files not found (or a dataset name: {', '.join(MODULES)})", path=path
        )
    out_path = None if out is None else Path(out).expanduser()
    if out_path is not None and out_path.exists() and not overwrite:
        raise WalkdiffError("manifest exists: pass overwrite (--overwrite) to replace it", path=out_path)
    clips = source.list_clips()
    selection = ContentSelection.parse(contents, source.groups)
    splits = source.split_clips(clips, selection)
    lines = _header(source, clips, splits, selection)
    for split in SPLITS:
        lines += _split_lines(source, split, splits[split])
    lines.append("Total: " + ", ".join(f"{split} {len(splits[split])}" for split in SPLITS))
    if out_path is not None:
        every = source.split_clips(clips, ContentSelection(tuple(source.groups)))
        write_text(out_path, _manifest(source, every))
        lines.append(
            f"Wrote {out_path}: every clip's labels and split; train on it with data.labels (--labels)"
        )
    return "\n".join(lines)


def _file(source, clip: ClipInfo) -> str:
    """The clip as a manifest's `file` column names it: its path relative to the folder."""
    if clip.item != -1:  # a clip inside a multi-clip file (HumanAct12)
        return clip.name
    try:
        return clip.path.relative_to(source.folder).as_posix()
    except ValueError:
        return clip.name


def _has(source) -> tuple[bool, bool]:
    """Whether the dataset has style and content labels (a folder without them has one of each)."""
    styles = source.styles != (NO_STYLE,) or getattr(source, "default_style", None) is not None
    contents = source.groups != (NO_CONTENT,) or getattr(source, "default_content", None) is not None
    return styles, contents


def _header(source, clips: list[ClipInfo], splits: dict, selection: ContentSelection) -> list[str]:
    chosen = sum(len(members) for members in splits.values())
    names = ", ".join(selection.names)
    picked = "" if chosen == len(clips) else f", {chosen} of them in data.contents {names}"
    if isinstance(source, FolderSource):
        given = sum(1 for members in splits.values() for c in members if c.name in source.index.splits)
        how = (
            f"per (style, content) label pair, ranked by a hash of the clip name: test_fraction "
            f"{source.test_fraction:g}, val_fraction {source.val_fraction:g}, the rest trains"
        )
        if given == chosen:
            how = "by the manifest's split column, every clip (marked *)"
        elif given:
            how = f"by the manifest's split column for {given} clips (marked *); the rest {how}"
        how = f"Split {how}."
        labelled = f"labels from {source.labelled_by}"
    else:
        doc = (source.module.split_clips.__doc__ or "").strip().splitlines()
        how = f"Split as {source.name} is split" + (f": {doc[0][:1].lower()}{doc[0][1:]}" if doc else ".")
        labelled = "labels from the file names"
    return [
        f"Splits of {source.folder} ({len(clips)} clips{picked}; {labelled})",
        how,
    ]


def _split_lines(source, split: str, clips: list[ClipInfo]) -> list[str]:
    has_styles, has_contents = _has(source)
    counts = []
    for shown, kind, names, index in (
        (has_styles, "style", source.styles, lambda c: c.style),
        (has_contents, "content", source.groups, lambda c: c.content),
    ):
        if not shown:
            continue
        tally = Counter(names[index(c)] for c in clips)
        listed = ", ".join(f"{name} {n}" for name, n in sorted(tally.items())[:_LABELS_SHOWN])
        counts.append(f"{kind}: " + listed + (" ..." if len(tally) > _LABELS_SHOWN else ""))
    label_counts = f" ({'; '.join(counts)})" if clips and counts else ""
    lines = [f"{split}: {len(clips)} clip{'s' * (len(clips) != 1)}{label_counts}"]
    if not clips:
        advice = source.empty_split_advice([split])
        if split == "val":
            advice = f"`data scan` writes configs that do not validate; to validate: {advice}"
        lines.append(f"  (none: {advice})")
        return lines
    given = source.index.splits if isinstance(source, FolderSource) else {}
    rows = []
    for clip in sorted(clips, key=lambda c: _file(source, c)):
        row = [("* " if clip.name in given else "  ") + _file(source, clip)]
        row += [source.styles[clip.style]] if has_styles else []
        row += [source.groups[clip.content]] if has_contents else []
        rows.append(row)
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines += ["  " + "  ".join(v.ljust(w) for v, w in zip(row, widths)).rstrip() for row in rows]
    return lines


def _manifest(source, splits: dict) -> str:
    """CSV: file, (style), (content), split; one row per clip, in file order."""
    has_styles, has_contents = _has(source)
    columns = ["file", *(["style"] if has_styles else []), *(["content"] if has_contents else []), "split"]
    rows = []
    for split, clips in splits.items():
        for clip in clips:
            if clip.item != -1:
                raise WalkdiffError(
                    "--out: a manifest names files, and this dataset holds several clips in one file",
                    path=clip.path,
                )
            values = {"file": _file(source, clip), "split": split}
            values |= {"style": source.styles[clip.style], "content": source.groups[clip.content]}
            rows.append([values[c] for c in columns])
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(columns)
    writer.writerows(sorted(rows))
    return buffer.getvalue()
