"""Any folder of BVH files as a dataset (`data.dataset: folder`): one folder, one command.

What to put in the folder:

- BVH files (`.bvh`, any case), at any depth: every file below the folder is a clip, except under hidden
  folders and hidden files (names starting with `.`, such as macOS's `._take.bvh`). A clip's name is its
  path relative to the folder without the suffix (`walks/take_007`): stable across machines, and what
  manifests, splits and caches refer to. All files must share one skeleton hierarchy (`walkdiff data
  scan DIR` checks it and finds the root, feet, axes and units: `walkdiff.motion.profile`). A symbolic
  link among them (or a manifest that is one) must point inside the folder: one that leads out is refused.
- Optionally labels, found in this order for each clip and each of style and content:
  1. a manifest (`data.labels`: a path, relative to the folder unless absolute; without it a `labels.csv`
     or `labels.json` directly in the folder is used). CSV: a header line, then one row per clip;
     columns `file` (required: the path relative to the folder with or without `.bvh`, or the bare file
     name when no other clip has it), `style`, `content` and `split` (`train`, `val` or `test`), each
     optional and possibly empty. JSON: a list of such objects, or an object {file: {style, content,
     split}}. Every entry must name an existing clip, once.
  2. a regular expression (`data.pattern`) with named groups `style` and/or `content`, searched
     (`re.search`) in the clip's name, e.g. `(?P<style>[a-z]+)_(?P<content>\\d+)_\\d+$`.
  3. `data.default_style` / `data.default_content`.
  A clip without a label that other clips have is an error (use the defaults to label the rest). A
  dataset without style labels has one style, `none`; without content labels one content group, `all`.
  Label values are sorted, so their indices do not depend on file order.

Splits are made per clip, never per window. A manifest's `split` column decides where it is given;
every other clip is placed per (style, content) pair: the pair's clips are ranked by a hash of their name
(`deterministic_order`), the first round(test_fraction * n) go to test, the next round(val_fraction * n)
to validation and the rest to training, with at least one test and one validation clip for a pair of 3 or
more clips (when the fraction is not 0), one test and one training clip for a pair of 2 and the training
set for a single clip. A split therefore depends neither on file order nor on the clips of other labels.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import read_utf8
from walkdiff.common.paths import refuse_link_out
from walkdiff.data.clips import ClipInfo, ContentSelection, deterministic_order
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.skeleton import Motion

MANIFEST_NAMES = ("labels.csv", "labels.json")
MANIFEST_COLUMNS = ("file", "style", "content", "split")
SPLITS = ("train", "val", "test")
NO_STYLE = "none"
NO_CONTENT = "all"
LABEL_COLUMNS = ("style", "content")
_EXAMPLES = 5  # clips named in an error message


@dataclass
class _Entry:
    """One manifest row: where it was (for errors) and its non-empty values."""

    where: int | str  # CSV line number, or a description of the JSON entry
    file: str
    values: dict[str, str]


@dataclass
class _Index:
    """What listing the folder finds: the clips, their label names and the manifest's splits."""

    clips: list[ClipInfo]
    styles: tuple[str, ...]
    groups: tuple[str, ...]
    splits: dict[str, str]  # clip name -> train/val/test, from the manifest
    manifest: Path | None
    labelled_by: str  # how the labels were found, for `walkdiff data scan`


@dataclass
class FolderSource:
    """A folder of BVH files with labels from a manifest, a file-name pattern or defaults.

    Picklable (workers get it whole); the listing is made once, on first use, and kept.
    """

    name: ClassVar[str] = "folder"

    folder: Path
    profile: dict = field(default_factory=dict)
    labels: str | None = None
    pattern: str | None = None
    default_style: str | None = None
    default_content: str | None = None
    val_fraction: float = 0.1
    test_fraction: float = 0.1
    _index: _Index | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.folder = Path(self.folder)
        self.profile = dict(self.profile or {})
        check_fractions(self.val_fraction, self.test_fraction)
        if self.pattern is not None:
            _compile(self.pattern)
        for option in ("default_style", "default_content"):
            value = getattr(self, option)
            if value is not None and not str(value).strip():
                raise WalkdiffError(f"data.{option}: expected a label name, got an empty string")
            if value is not None:
                setattr(self, option, str(value).strip())

    # ------------------------------------------------------------ MotionSource

    @property
    def styles(self) -> tuple[str, ...]:
        return self.index.styles

    @property
    def groups(self) -> tuple[str, ...]:
        return self.index.groups

    def list_clips(self) -> list[ClipInfo]:
        return list(self.index.clips)

    def split_clips(self, clips: list[ClipInfo], selection: ContentSelection) -> dict[str, list[ClipInfo]]:
        """train/val/test clips of the selected contents (see the module docstring); each sorted by name."""
        check_fractions(self.val_fraction, self.test_fraction)
        given = self.index.splits
        splits: dict[str, list[ClipInfo]] = {s: [] for s in SPLITS}
        pairs: dict[tuple[int, int], list[ClipInfo]] = {}
        for clip in clips:
            if clip.name in given:
                splits[given[clip.name]].append(clip)
            else:
                pairs.setdefault((clip.style, clip.content), []).append(clip)
        for members in pairs.values():
            n_test, n_val = split_counts(len(members), self.val_fraction, self.test_fraction)
            ranked = deterministic_order(members)
            splits["test"] += ranked[:n_test]
            splits["val"] += ranked[n_test : n_test + n_val]
            splits["train"] += ranked[n_test + n_val :]
        groups = self.groups
        return {
            split: sorted((c for c in members if groups[c.content] in selection.names), key=lambda c: c.name)
            for split, members in splits.items()
        }

    def load(self, clip: ClipInfo) -> Motion:
        return read_bvh(clip.path)

    def empty_split_advice(self, splits: list[str]) -> str:
        """How to give clips to `splits` that have none (`fit`'s error, `data scan`'s notes)."""
        manifest = (
            f"give clips the split {' or '.join(splits)} in a labels manifest's split column (file,split)"
        )
        if "train" in splits:  # only a manifest takes every clip of a label pair out of training
            return f"the labels manifest's split column leaves no clip to train on: {manifest}"
        zero = [f"data.{s}_fraction" for s in splits if getattr(self, f"{s}_fraction") == 0]
        if zero:
            verb, it = ("is", "it") if len(zero) == 1 else ("are", "them")
            return f"{' and '.join(zero)} {verb} 0: set {it} above 0, or {manifest}"
        return (
            "clips are split per (style, content) label pair, and a pair needs 2 clips to give one to test "
            f"and 3 to give one to val: add clips, or {manifest}"
        )

    # ------------------------------------------------------------ listing and labels

    @property
    def index(self) -> _Index:
        if self._index is None:
            self._index = self._build_index()
        return self._index

    @property
    def manifest(self) -> Path | None:
        return self.index.manifest

    @property
    def labelled_by(self) -> str:
        return self.index.labelled_by

    def _build_index(self) -> _Index:
        files = list_bvh_files(self.folder)
        names = [name for name, _ in files]
        manifest = self._find_manifest()
        entries = _read_manifest(manifest) if manifest is not None else []
        by_clip = _resolve_entries(entries, names, manifest) if manifest is not None else {}
        regex = _compile(self.pattern) if self.pattern is not None else None

        labels: dict[str, dict[str, str]] = {n: {} for n in names}
        matches = {n: regex.search(n) for n in names} if regex is not None else {}
        if regex is not None and not any(matches.values()):
            raise WalkdiffError(
                f"data.pattern {self.pattern!r} matches none of the {len(names)} clip names (e.g. "
                f"{', '.join(names[:3])}): it is searched in the path relative to the folder, without .bvh",
                path=self.folder,
            )
        for name in names:
            values = by_clip.get(name, {})
            match = matches.get(name)
            for column in LABEL_COLUMNS:
                value = values.get(column)
                if value is None and match is not None and column in regex.groupindex:
                    value = (match.group(column) or "").strip() or None
                if value is not None:
                    labels[name][column] = value

        defaults = {"style": self.default_style, "content": self.default_content}
        used = {column: any(column in labels[n] for n in names) for column in LABEL_COLUMNS}
        for column in LABEL_COLUMNS:
            missing = [n for n in names if column not in labels[n]]
            if used[column] and missing and defaults[column] is None:
                raise self._missing_error(column, missing, len(names), manifest)
            for n in missing:
                if defaults[column] is not None:
                    labels[n][column] = defaults[column]
        styles = tuple(sorted({v["style"] for v in labels.values() if "style" in v})) or (NO_STYLE,)
        groups = tuple(sorted({v["content"] for v in labels.values() if "content" in v})) or (NO_CONTENT,)
        clips = [
            ClipInfo(
                path=path,
                name=name,
                style=styles.index(labels[name]["style"]) if "style" in labels[name] else 0,
                content=groups.index(labels[name]["content"]) if "content" in labels[name] else 0,
            )
            for name, path in files
        ]
        splits = {name: values["split"] for name, values in by_clip.items() if "split" in values}
        how = []
        if manifest is not None:
            how.append(f"manifest {manifest}")
        if regex is not None:
            how.append(f"pattern {self.pattern!r}")
        how += [f"default {column} {defaults[column]!r}" for column in LABEL_COLUMNS if defaults[column]]
        return _Index(clips, styles, groups, splits, manifest, ", then ".join(how) or "none (no labels)")

    def _find_manifest(self) -> Path | None:
        if self.labels is not None:
            path = Path(self.labels).expanduser()
            path = path if path.is_absolute() else self.folder / path
            if not path.is_file():
                raise WalkdiffError("data.labels: manifest not found (relative: in the folder)", path=path)
            if path.suffix.lower() not in (".csv", ".json"):
                raise WalkdiffError("data.labels: expected a .csv or .json manifest", path=path)
            refuse_link_out(self.folder, path, "the manifest")
            return path
        found = [self.folder / n for n in MANIFEST_NAMES if (self.folder / n).is_file()]
        if len(found) > 1:
            raise WalkdiffError(
                "both labels.csv and labels.json found: set data.labels to the one to use", path=self.folder
            )
        for path in found:
            refuse_link_out(self.folder, path, "the manifest")
        return found[0] if found else None

    def _missing_error(self, column: str, missing: list[str], total: int, manifest) -> WalkdiffError:
        examples = ", ".join(missing[:_EXAMPLES]) + (" ..." if len(missing) > _EXAMPLES else "")
        sources = []
        if manifest is not None:
            sources.append(f"give them a {column} in the manifest {manifest}")
        if self.pattern is not None:
            sources.append(f"make data.pattern {self.pattern!r} match them with a group (?P<{column}>...)")
        sources.append(f"set data.default_{column} to label the rest")
        return WalkdiffError(
            f"{len(missing)} of {total} clips have no {column} label while other clips have one "
            f"({examples}): {'; or '.join(sources)}",
            path=manifest if manifest is not None else self.folder,
        )


# ---------------------------------------------------------------- helpers


def list_bvh_files(folder: Path) -> list[tuple[str, Path]]:
    """(clip name, path) of every BVH file below `folder`, sorted by relative POSIX path."""
    folder = Path(folder)
    if not folder.is_dir():
        raise WalkdiffError("folder of BVH files not found", path=folder)
    found: dict[str, Path] = {}
    for path in sorted(folder.rglob("*"), key=lambda p: p.relative_to(folder).as_posix()):
        relative = path.relative_to(folder)
        if path.suffix.lower() != ".bvh" or any(part.startswith(".") for part in relative.parts):
            continue
        if not path.is_file():
            continue
        refuse_link_out(folder, path, "a clip")
        name = relative.with_suffix("").as_posix()
        if name in found:
            raise WalkdiffError(
                f"two files give the clip name {name!r} ({found[name].name} and {path.name}): rename one",
                path=path.parent,
            )
        found[name] = path
    if not found:
        raise WalkdiffError("no .bvh files found in this folder or below it", path=folder)
    return list(found.items())


def check_fractions(val_fraction: float, test_fraction: float) -> None:
    """WalkdiffError unless both are finite, >= 0 and sum to less than 1."""
    for option, value in (("data.val_fraction", val_fraction), ("data.test_fraction", test_fraction)):
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if not number or not math.isfinite(value) or value < 0:
            raise WalkdiffError(f"{option}: expected a finite number >= 0, got {value!r}")
    if val_fraction + test_fraction >= 1:
        raise WalkdiffError(
            f"data.val_fraction + data.test_fraction: expected a sum below 1 (some clips must train), "
            f"got {val_fraction} + {test_fraction}"
        )


def split_counts(n: int, val_fraction: float, test_fraction: float) -> tuple[int, int]:
    """(test, val) clips of a label pair of `n` clips; the rest trains (see the module docstring)."""
    if n <= 1:
        return 0, 0
    if n == 2:
        return (1 if test_fraction > 0 else 0), 0
    n_test = max(1 if test_fraction > 0 else 0, round(test_fraction * n))
    n_val = max(1 if val_fraction > 0 else 0, round(val_fraction * n))
    while n_test + n_val > n - 1:  # at least one training clip
        if n_val >= n_test and n_val > 0:
            n_val -= 1
        else:
            n_test -= 1
    return n_test, n_val


def _compile(pattern: str) -> re.Pattern:
    try:
        regex = re.compile(pattern)
    except re.error as e:
        raise WalkdiffError(f"data.pattern: not a regular expression ({e}): {pattern!r}") from None
    if not set(regex.groupindex) & set(LABEL_COLUMNS):
        raise WalkdiffError(
            f"data.pattern: expected a named group (?P<style>...) and/or (?P<content>...), got {pattern!r}"
        )
    return regex


def _clean_file(value: str) -> str:
    file = value.strip().replace("\\", "/")
    while file.startswith("./"):
        file = file[2:]
    if file.lower().endswith(".bvh"):
        file = file[:-4]
    return file


def _read_manifest(path: Path) -> list[_Entry]:
    text = read_utf8(path, "the manifest")
    return _read_json(text, path) if path.suffix.lower() == ".json" else _read_csv(text, path)


def _read_csv(text: str, path: Path) -> list[_Entry]:
    expected = f"expected a header line with columns {', '.join(MANIFEST_COLUMNS)} (file required)"
    reader = csv.reader(io.StringIO(text))
    header: list[str] | None = None
    entries = []
    for row in reader:
        line = reader.line_num
        if not any(cell.strip() for cell in row) or row[0].lstrip().startswith("#"):
            continue
        if header is None:
            header = [cell.strip().lower() for cell in row]
            unknown = [c for c in header if c not in MANIFEST_COLUMNS]
            if unknown:
                raise WalkdiffError(f"unknown column {unknown[0]!r}: {expected}", path=path, line=line)
            if "file" not in header:
                raise WalkdiffError(f"no 'file' column: {expected}", path=path, line=line)
            twice = [c for c in header if header.count(c) > 1]
            if twice:
                raise WalkdiffError(f"column {twice[0]!r} given twice: {expected}", path=path, line=line)
            continue
        if len(row) > len(header):
            raise WalkdiffError(
                f"{len(row)} fields, the header has {len(header)} ({', '.join(header)})", path=path, line=line
            )
        values = {c: v.strip() for c, v in zip(header, row) if v.strip()}
        entries.append(_entry(values, line, path))
    if header is None:
        raise WalkdiffError(f"empty manifest: {expected}", path=path, line=1)
    return entries


def _read_json(text: str, path: Path) -> list[_Entry]:
    expected = "expected a list of {file, style, content, split} objects or an object {file: {style, ...}}"
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise WalkdiffError(f"not valid JSON ({e.msg}): {expected}", path=path, line=e.lineno) from None
    if isinstance(data, dict):
        items = [(f"entry {key!r}", {"file": key, **value} if isinstance(value, dict) else value)
                 for key, value in data.items()]  # fmt: skip
    elif isinstance(data, list):
        items = [(f"entry {i + 1}", value) for i, value in enumerate(data)]
    else:
        raise WalkdiffError(expected, path=path)
    entries = []
    for where, value in items:
        if not isinstance(value, dict):
            raise WalkdiffError(f"{where}: {expected}, got {json.dumps(value)[:60]}", path=path)
        unknown = [k for k in value if k not in MANIFEST_COLUMNS]
        if unknown:
            raise WalkdiffError(
                f"{where}: unknown key {unknown[0]!r}: expected {', '.join(MANIFEST_COLUMNS)}", path=path
            )
        values = {}
        for key, v in value.items():
            if v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, str | int):
                raise WalkdiffError(f"{where}: {key} must be a string, got {json.dumps(v)[:60]}", path=path)
            if str(v).strip():
                values[key] = str(v).strip()
        entries.append(_entry(values, where, path))
    return entries


def _entry(values: dict[str, str], where: int | str, path: Path) -> _Entry:
    line = where if isinstance(where, int) else None
    prefix = "" if line is not None else f"{where}: "
    file = _clean_file(values.pop("file", ""))
    if not file:
        msg = f"{prefix}empty file field: expected a BVH path relative to the folder"
        raise WalkdiffError(msg, path=path, line=line)
    split = values.get("split")
    if split is not None:
        values["split"] = split.lower()
        if values["split"] not in SPLITS:
            raise WalkdiffError(
                f"{prefix}split {split!r} of {file!r}: expected one of {', '.join(SPLITS)} (or empty)",
                path=path,
                line=line,
            )
    return _Entry(where, file, values)


def _resolve_entries(entries: list[_Entry], names: list[str], path: Path) -> dict[str, dict[str, str]]:
    """Clip name -> the values of its manifest entry; unknown, ambiguous and repeated files are errors."""
    known = set(names)
    by_stem: dict[str, list[str]] = {}
    for name in names:
        by_stem.setdefault(name.rsplit("/", 1)[-1], []).append(name)
    out: dict[str, dict[str, str]] = {}
    first: dict[str, _Entry] = {}
    for entry in entries:
        line = entry.where if isinstance(entry.where, int) else None
        prefix = "" if line is not None else f"{entry.where}: "
        if entry.file in known:
            name = entry.file
        elif "/" not in entry.file and len(by_stem.get(entry.file, [])) == 1:
            name = by_stem[entry.file][0]
        elif "/" not in entry.file and by_stem.get(entry.file):
            raise WalkdiffError(
                f"{prefix}file {entry.file!r} is ambiguous ({', '.join(by_stem[entry.file][:_EXAMPLES])}): "
                "give its path relative to the folder",
                path=path,
                line=line,
            )
        else:
            raise WalkdiffError(
                f"{prefix}file {entry.file!r}: no such BVH file in the folder (expected a path relative to "
                "the folder, with or without .bvh, or a unique file name)",
                path=path,
                line=line,
            )
        if name in first:
            before = first[name].where
            before = f"line {before}" if isinstance(before, int) else before
            msg = f"{prefix}file {name!r} listed twice (first at {before})"
            raise WalkdiffError(msg, path=path, line=line)
        first[name] = entry
        out[name] = entry.values
    return out
