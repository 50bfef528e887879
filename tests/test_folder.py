"""The folder dataset (walkdiff.data.folder) and `walkdiff data scan` (walkdiff.data.scan) on real Xia clips.

The folders are built here from copies of Xia clips under neutral names (`take_NNN.bvh`, some in
sub-folders), so every label must come from a manifest, a pattern or a default; the Xia file names they
were copied from say what the labels must be.
"""

from __future__ import annotations

import inspect
import json
import pickle
import re
import shutil
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from walkdiff.common.errors import WalkdiffError
from walkdiff.data import xia
from walkdiff.data.clips import ContentSelection
from walkdiff.data.datasets import open_source
from walkdiff.data.folder import SPLITS, FolderSource, split_counts
from walkdiff.data.scan import config_name, scan

STYLES = ("angry", "neutral")
CONTENT_IDS = ("01", "13")  # walk, run
TAKES = 3
XIA_PATTERN = r"(?P<style>[a-z]+)_(?P<content>\d{2})_\d{3}$"


def _relative(number: int) -> str:
    """Where take `number` lies: 0-3 in session_a/, 4-7 two levels down, the rest at the top."""
    folder = "session_a/" if number < 4 else "session_b/day2/" if number < 8 else ""
    return f"{folder}take_{number:03d}"


@pytest.fixture(scope="module")
def takes(xia_dir: Path, tmp_path_factory) -> tuple[Path, dict[str, str]]:
    """12 Xia clips (2 styles x 2 contents x 3 takes) as take_NNN.bvh; clip name -> Xia file stem."""
    root = tmp_path_factory.mktemp("takes") / "My Takes-1"
    origin = {}
    stems = [f"{s}_{c}_{t:03d}" for s in STYLES for c in CONTENT_IDS for t in range(TAKES)]
    for k, stem in enumerate(stems):
        number = (5 * k) % len(stems)  # takes numbered out of label order
        name = _relative(number)
        path = root / (name + (".BVH" if number == 11 else ".bvh"))
        path.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(xia_dir / f"{stem}.bvh", path)
        origin[name] = stem
    return root, origin


@pytest.fixture
def folder(takes, tmp_path) -> Path:
    """A private copy of the takes, for tests that add files."""
    return Path(shutil.copytree(takes[0], tmp_path / "takes"))


def expected_labels(origin: dict[str, str]) -> dict[str, tuple[str, str]]:
    """(style, content group) of each clip, from the Xia name it was copied from."""
    out = {}
    for name, stem in origin.items():
        info = xia.parse_name(Path(f"{stem}.bvh"))
        out[name] = (xia.STYLES[info.style], xia.GROUPS[info.content])
    return out


def labels_of(source: FolderSource) -> dict[str, tuple[str, str]]:
    return {c.name: (source.styles[c.style], source.groups[c.content]) for c in source.list_clips()}


def write_csv(path: Path, rows: list[list[str]]) -> Path:
    path.write_text("\n".join(",".join(row) for row in rows) + "\n")
    return path


def manifest_rows(origin: dict[str, str], columns=("style", "content")) -> list[list[str]]:
    """A CSV manifest with files given every accepted way: path with/without .bvh, bare name."""
    labels = expected_labels(origin)
    rows = [["file", *columns]]
    for i, name in enumerate(sorted(origin)):
        file = [f"{name}.bvh", name, name.rsplit("/", 1)[-1]][i % 3]
        values = {"style": labels[name][0], "content": labels[name][1]}
        rows.append([file, *(values[c] for c in columns)])
    return rows


def all_contents(source: FolderSource) -> ContentSelection:
    return ContentSelection(source.groups)


def split_names(splits) -> dict[str, set[str]]:
    return {split: {c.name for c in clips} for split, clips in splits.items()}


# ---------------------------------------------------------------- listing


def test_clips_are_every_bvh_below_the_folder_by_relative_path(folder, takes, tmp_path):
    (folder / ".cache").mkdir()
    shutil.copyfile(folder / "take_008.bvh", folder / ".cache" / "copy.bvh")
    shutil.copyfile(folder / "take_008.bvh", folder / "._take_008.bvh")  # macOS resource fork
    (folder / "notes.txt").write_text("not a clip")
    source = FolderSource(folder)
    clips = source.list_clips()
    names = [c.name for c in clips]
    assert names == sorted(takes[1]) and len(names) == 12
    assert "session_b/day2/take_005" in names and "take_011" in names  # take_011.BVH: any case
    assert all(c.path == folder / (c.name + c.path.suffix) and c.path.is_file() for c in clips)
    # No labels: one style, one content group.
    assert source.styles == ("none",) and source.groups == ("all",)
    assert {(c.style, c.content) for c in clips} == {(0, 0)}
    # Picklable with its listing (workers get it whole), and equal after the trip.
    again = pickle.loads(pickle.dumps(source))
    assert again == source and [c.name for c in again.list_clips()] == names

    empty = tmp_path / "empty"
    (empty / "sub").mkdir(parents=True)
    with pytest.raises(WalkdiffError, match="no .bvh files") as error:
        FolderSource(empty).list_clips()
    assert error.value.path == str(empty)


def test_links_may_point_inside_the_folder_but_not_out_of_it(folder, tmp_path, capsys):
    """Issue 33: a link out of the folder made scan and fit open (and quote) any file the user can read."""
    from walkdiff.cli.main import main

    (folder / "aliases").mkdir()
    (folder / "aliases" / "same.bvh").symlink_to("../take_008.bvh")  # inside: a clip like any other
    assert "aliases/same" in [c.name for c in FolderSource(folder).list_clips()]

    secret = tmp_path / "outside" / "secret.txt"
    secret.parent.mkdir()
    secret.write_text("token,hunter2\n")
    shutil.copyfile(folder / "take_008.bvh", secret.parent / "walk.bvh")
    for link, target in [("zz_out.bvh", secret.parent / "walk.bvh"), ("zz_secret.bvh", secret)]:
        (folder / link).symlink_to(target)
        with pytest.raises(WalkdiffError, match="symbolic link to .*outside the dataset folder") as error:
            FolderSource(folder).list_clips()
        assert error.value.path == str(folder / link) and str(target) in str(error.value)
        assert main(["data", "scan", str(folder)]) == 1
        err = capsys.readouterr().err
        assert f"{folder / link}: a clip is a symbolic link to {target}" in err and "hunter2" not in err
        (folder / link).unlink()

    (folder / "labels.csv").symlink_to(secret)  # found without being named, or named relative
    for labels in (None, "labels.csv", str(folder / "labels.csv")):
        with pytest.raises(WalkdiffError, match="the manifest is a symbolic link to") as error:
            FolderSource(folder, labels=labels).list_clips()
        assert "hunter2" not in str(error.value) and error.value.path == str(folder / "labels.csv")
    (folder / "labels.csv").unlink()
    # A manifest the user names outside the folder is read: the user chose that file.
    write_csv(tmp_path / "outside" / "labels.csv", [["file", "style"], ["take_008", "x"]])
    source = FolderSource(folder, labels=str(tmp_path / "outside" / "labels.csv"), default_style="y")
    assert source.styles == ("x", "y")


# ---------------------------------------------------------------- labels


def test_csv_manifest_found_in_the_folder_gives_the_labels(folder, takes):
    origin = takes[1]
    write_csv(folder / "labels.csv", manifest_rows(origin))
    source = FolderSource(folder)  # labels.csv is found without being named
    assert source.styles == ("angry", "neutral")  # sorted: indices do not depend on file order
    assert source.groups == ("run", "walk")
    assert labels_of(source) == expected_labels(origin)
    assert str(folder / "labels.csv") in source.labelled_by


def test_json_manifests_list_and_object_give_the_labels(takes, tmp_path):
    root, origin = takes
    labels = expected_labels(origin)
    as_list = [{"file": f"{n}.bvh", "style": s, "content": c} for n, (s, c) in labels.items()]
    as_object = {n: {"style": s, "content": c} for n, (s, c) in labels.items()}
    (tmp_path / "list.json").write_text(json.dumps(as_list))
    (tmp_path / "object.json").write_text(json.dumps(as_object, indent=2))
    for manifest in ("list.json", "object.json"):
        source = FolderSource(root, labels=str(tmp_path / manifest))
        assert labels_of(source) == labels
        assert source.styles == ("angry", "neutral") and source.groups == ("run", "walk")
    # A manifest path relative to the folder, and only one column labelled.
    (tmp_path / "copy").mkdir()
    copy = Path(shutil.copytree(root, tmp_path / "copy" / "takes"))
    (copy / "meta").mkdir()
    (copy / "meta" / "styles.json").write_text(json.dumps({n: {"style": s} for n, (s, _) in labels.items()}))
    source = FolderSource(copy, labels="meta/styles.json")
    assert {n: source.styles[c.style] for n, c in ((c.name, c) for c in source.list_clips())} == {
        n: s for n, (s, _) in labels.items()
    }
    assert source.groups == ("all",)


def test_pattern_on_xia_names_gives_the_labels_of_the_xia_module(xia_dir, tmp_path):
    stems = [
        f"{s}_{c}_{t:03d}" for s in ("angry", "childlike", "old") for c in ("01", "13", "16") for t in (0, 1)
    ]
    for stem in stems:
        shutil.copyfile(xia_dir / f"{stem}.bvh", tmp_path / f"{stem}.bvh")
    source = FolderSource(tmp_path, pattern=XIA_PATTERN)
    assert source.styles == ("angry", "childlike", "old") and source.groups == ("01", "13", "16")
    for clip in source.list_clips():
        info = xia.parse_name(clip.path)
        assert source.styles[clip.style] == xia.STYLES[info.style]
        assert xia.group_of(int(source.groups[clip.content])) == info.content
    with pytest.raises(WalkdiffError, match="matches none of the 18 clip names"):
        FolderSource(tmp_path, pattern=r"(?P<style>take)_\d+").list_clips()
    with pytest.raises(WalkdiffError, match="data.pattern: expected a named group"):
        FolderSource(tmp_path, pattern=r"([a-z]+)_")


def test_missing_labels_are_an_error_that_default_style_fixes(takes, tmp_path):
    root, origin = takes
    rows = manifest_rows(origin, columns=("style",))
    unlabelled = sorted(origin)[:2]
    for row in rows[1:]:
        if row[0].removesuffix(".bvh") in unlabelled or row[0] in [n.rsplit("/", 1)[-1] for n in unlabelled]:
            row[1] = ""
    manifest = write_csv(tmp_path / "labels.csv", rows)
    with pytest.raises(WalkdiffError) as error:
        FolderSource(root, labels=str(manifest)).list_clips()
    message = str(error.value)
    assert message.startswith(str(manifest))
    assert "2 of 12 clips have no style label" in message
    assert all(name in message for name in unlabelled)
    assert "data.default_style" in message

    source = FolderSource(root, labels=str(manifest), default_style="calm")
    assert source.styles == ("angry", "calm", "neutral")
    labels = labels_of(source)
    assert {labels[n][0] for n in unlabelled} == {"calm"}
    assert all(labels[n][0] == expected_labels(origin)[n][0] for n in origin if n not in unlabelled)
    # A default for a column nobody labels is every clip's label.
    assert FolderSource(root, labels=str(manifest), default_style="calm", default_content="walk").groups == (
        "walk",
    )


CSV_ERRORS = [
    ("file,style,mood\ntake_008,angry,happy\n", 1, "unknown column 'mood'"),
    ("style,content\nangry,walk\n", 1, "no 'file' column"),
    ("file,style\ntake_008,angry\n  ,neutral\n", 3, "empty file field"),
    ("file,style\ntake_000,angry\n\nsession_a/take_000.bvh,angry\n", 4, "listed twice (first at line 2)"),
    ("file,style\ntake_008,angry\nwalks/take_099.bvh,angry\n", 3, "'walks/take_099': no such BVH file"),
    ("file,split\ntake_008,train\ntake_009,training\n", 3, "split 'training' of 'take_009': expected one of"),
]


@pytest.mark.parametrize("text,line,expected", CSV_ERRORS)
def test_csv_manifest_errors_name_the_file_and_line(takes, tmp_path, text, line, expected):
    manifest = tmp_path / "labels.csv"
    manifest.write_text(text)
    with pytest.raises(WalkdiffError) as error:
        FolderSource(takes[0], labels=str(manifest)).list_clips()
    assert error.value.path == str(manifest) and error.value.line == line
    assert str(error.value).startswith(f"{manifest}:{line}: ")
    assert expected in str(error.value)


JSON_ERRORS = [
    ([{"file": "take_008", "style": "angry"}, {"file": "", "style": "x"}], "entry 2: empty file field"),
    ({"take_008": {"style": "angry", "mood": "happy"}}, "entry 'take_008': unknown key 'mood'"),
    ([{"file": "take_008", "split": "holdout"}], "entry 1: split 'holdout'"),
    ({"take_008": {}, "take_008.bvh": {}}, "entry 'take_008.bvh': file 'take_008' listed twice"),
    ([{"file": "take_404"}], "entry 1: file 'take_404': no such BVH file"),
    ([["take_008", "angry"]], "entry 1: expected a list of {file"),
]


@pytest.mark.parametrize("data,expected", JSON_ERRORS)
def test_json_manifest_errors_name_the_file_and_entry(takes, tmp_path, data, expected):
    manifest = tmp_path / "labels.json"
    manifest.write_text(json.dumps(data))
    with pytest.raises(WalkdiffError) as error:
        FolderSource(takes[0], labels=str(manifest)).list_clips()
    assert error.value.path == str(manifest) and expected in str(error.value)
    manifest.write_text('[{"file": "take_008",\n "style": }]')
    with pytest.raises(WalkdiffError, match="not valid JSON") as error:
        FolderSource(takes[0], labels=str(manifest)).list_clips()
    assert error.value.line == 2


def test_a_bare_file_name_must_be_unique(folder, tmp_path):
    shutil.copyfile(folder / "session_a" / "take_000.bvh", folder / "session_b" / "take_000.bvh")
    manifest = write_csv(
        tmp_path / "labels.csv", [["file", "style"], ["take_008", "angry"], ["take_000", "old"]]
    )
    with pytest.raises(WalkdiffError, match="'take_000' is ambiguous") as error:
        FolderSource(folder, labels=str(manifest)).list_clips()
    assert error.value.line == 3 and "session_a/take_000, session_b/take_000" in str(error.value)
    rows = [["file", "style"], ["./session_b/take_000.BVH", "angry"], ["session_a\\take_000", "old"]]
    source = FolderSource(folder, labels=str(write_csv(manifest, rows)), default_style="neutral")
    labels = labels_of(source)
    assert (labels["session_b/take_000"][0], labels["session_a/take_000"][0], labels["take_008"][0]) == (
        "angry", "old", "neutral"
    )  # fmt: skip


# ---------------------------------------------------------------- splits


def test_split_column_is_obeyed_and_the_rest_split_by_fractions(takes, tmp_path):
    root, origin = takes
    rows = manifest_rows(origin)
    rows[0].append("split")
    chosen = {}
    for i, row in enumerate(rows[1:]):
        split = ["test", "VAL", "train", "", ""][i % 5] if i < 10 else ""
        row.append(split)
        if split:
            name = next(n for n in origin if row[0].removesuffix(".bvh") in (n, n.rsplit("/", 1)[-1]))
            chosen[name] = split.lower()
    source = FolderSource(root, labels=str(write_csv(tmp_path / "labels.csv", rows)))
    names = split_names(source.split_clips(source.list_clips(), all_contents(source)))
    for name, split in chosen.items():
        assert name in names[split]
    assert set().union(*names.values()) == set(origin)
    assert sum(len(v) for v in names.values()) == len(origin)
    # Every clip put in training by the manifest: no validation or test at all.
    rows = [["file", "split"]] + [[n, "train"] for n in origin]
    source = FolderSource(root, labels=str(write_csv(tmp_path / "all_train.csv", rows)))
    splits = source.split_clips(source.list_clips(), all_contents(source))
    assert len(splits["train"]) == 12 and not splits["val"] and not splits["test"]


def test_splits_are_deterministic_disjoint_and_per_label(folder, takes, xia_dir, tmp_path):
    origin = takes[1]
    manifest = write_csv(tmp_path / "labels.csv", manifest_rows(origin))
    source = FolderSource(folder, labels=str(manifest))
    clips = source.list_clips()
    splits = source.split_clips(clips, all_contents(source))
    names = split_names(splits)
    assert source.split_clips(list(reversed(clips)), all_contents(source)) == splits
    assert not names["train"] & names["val"] and not names["train"] & names["test"]
    assert not names["val"] & names["test"] and set().union(*names.values()) == set(origin)
    labels = expected_labels(origin)
    for split in ("train", "val", "test"):  # 3 clips per label pair: one in each split
        assert sorted(labels[n] for n in names[split]) == sorted(set(labels.values()))
    # Only the selected contents.
    walk = source.split_clips(clips, ContentSelection(("walk",)))
    assert all(source.groups[c.content] == "walk" for s in walk.values() for c in s)
    assert split_names(walk)["test"] == {n for n in names["test"] if labels[n][1] == "walk"}

    # A clip of another label (sorted first: every style index moves) leaves the others where they were.
    (folder / "extra").mkdir()
    shutil.copyfile(xia_dir / "childlike_16_000.bvh", folder / "extra" / "take_100.bvh")
    rows = manifest_rows(origin) + [["extra/take_100", "childlike", "jump"]]
    grown = FolderSource(folder, labels=str(write_csv(tmp_path / "grown.csv", rows)))
    assert grown.styles == ("angry", "childlike", "neutral")
    grown_names = split_names(grown.split_clips(grown.list_clips(), all_contents(grown)))
    assert {s: v - {"extra/take_100"} for s, v in grown_names.items()} == names
    assert "extra/take_100" in grown_names["train"]  # a label pair of one clip trains


def test_split_counts_per_label_pair(takes, tmp_path):
    assert [split_counts(n, 0.1, 0.1) for n in (1, 2, 3, 9, 20, 40)] == [
        (0, 0), (1, 0), (1, 1), (1, 1), (2, 2), (4, 4)
    ]  # fmt: skip
    assert split_counts(9, 0.3, 0.3) == (3, 3) and split_counts(3, 0.45, 0.45) == (1, 1)
    assert split_counts(5, 0.0, 0.2) == (1, 0) and split_counts(2, 0.1, 0.0) == (0, 0)
    # Pairs of 1, 2 and 9 clips over the real folder.
    root, origin = takes
    names = sorted(origin)
    rows = [["file", "style"], [names[0], "a"], [names[1], "b"], [names[2], "b"]]
    rows += [[n, "c"] for n in names[3:]]
    source = FolderSource(root, labels=str(write_csv(tmp_path / "labels.csv", rows)))
    splits = source.split_clips(source.list_clips(), all_contents(source))
    count = {
        s: {style: sum(source.styles[c.style] == style for c in v) for style in "abc"}
        for s, v in splits.items()
    }
    assert count == {
        "train": {"a": 1, "b": 1, "c": 7},
        "val": {"a": 0, "b": 0, "c": 1},
        "test": {"a": 0, "b": 1, "c": 1},
    }
    wide = FolderSource(root, labels=str(tmp_path / "labels.csv"), val_fraction=0.3, test_fraction=0.3)
    splits = wide.split_clips(wide.list_clips(), all_contents(wide))
    assert [len(splits[s]) for s in ("train", "val", "test")] == [2 + 3, 3, 1 + 3]


@pytest.mark.parametrize(
    "val,test,option",
    [
        (0.6, 0.5, "data.val_fraction"),
        (float("nan"), 0.1, "data.val_fraction"),
        (0.1, -0.1, "data.test_fraction"),
    ],
)
def test_fractions_are_validated(takes, val, test, option):
    with pytest.raises(WalkdiffError, match=re.escape(option)):
        FolderSource(takes[0], val_fraction=val, test_fraction=test)


def test_a_folder_without_val_or_test_clips_says_so_and_how_to_fix_it(xia_dir, tmp_path, monkeypatch, capsys):
    """Issue 33: fit of a one-clip folder said "use a shorter data.window"; its val and test splits are
    empty, which no window fixes."""
    import probes

    from walkdiff.cli.main import main

    folder = tmp_path / "one"
    folder.mkdir()
    shutil.copyfile(xia_dir / "angry_01_000.bvh", folder / "take.bvh")
    advice = "clips are split per (style, content) label pair, and a pair needs 2 clips to give one to test"
    text = scan(folder)
    assert f"no test clips, which training needs: {advice}" in text
    assert "no val clips: the written configs do not validate" in text and f"To validate: {advice}" in text

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("sys.argv", ["walkdiff"])
    config = tmp_path / "one.yaml"
    config.write_text(probes.tiny_fit_config(folder, "one", epochs=1, batches=1, callbacks=[]))
    data = ["--data.init_args.dataset", "folder", "--data.init_args.contents", "all"]
    assert main(["fit", "--config", str(config), *data]) == 1
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(
        f"walkdiff: error: {folder}: no val and no test clip: the dataset has 1 clip, split 1 train, 0 val, "
        f"0 test; {advice}"
    )
    assert "add clips, or give clips the split val or test in a labels manifest's split column" in err
    assert "data.window" not in err and not list(tmp_path.glob("checkpoints/one/*/*.ckpt"))

    # The advice names the option that emptied a split.
    source = FolderSource(folder, val_fraction=0, test_fraction=0)
    assert source.empty_split_advice(["val", "test"]).startswith(
        "data.val_fraction and data.test_fraction are 0: set them above 0"
    )
    write_csv(folder / "labels.csv", [["file", "split"], ["take", "test"]])
    assert "split column leaves no clip to train on" in FolderSource(folder).empty_split_advice(["train"])


def test_a_split_whose_clips_were_all_skipped_says_so(xia_dir, tmp_path):
    import lightning as L

    from walkdiff.data.datamodule import MotionDataModule

    folder = tmp_path / "three"
    folder.mkdir()
    # One label pair of 3: d tests, c validates, b trains (and, read first, gives the profile).
    for name in ("b", "c", "d"):
        shutil.copyfile(xia_dir / "angry_01_000.bvh", folder / f"{name}.bvh")
    source = FolderSource(folder)
    (val,) = source.split_clips(source.list_clips(), all_contents(source))["val"]
    val.path.write_text("HIERARCHY\n")
    options = dict(dataset="folder", root=str(folder), contents="all", cache_dir=str(tmp_path / "cache"))
    dm = MotionDataModule(**options, on_error="skip", preprocess_workers=1)
    dm.trainer = L.Trainer(limit_val_batches=1, logger=False, enable_checkpointing=False)  # validates
    with pytest.warns(UserWarning, match=val.name), pytest.raises(WalkdiffError) as error:
        dm.setup()
    assert str(error.value) == (
        f"{folder}: the val split has no readable clip: data.on_error skip left out all its 1 (see the "
        "warning above)"
    )
    dm = MotionDataModule(**options, on_error="skip", preprocess_workers=1)  # no trainer: nothing validates
    dm.setup()
    assert len(dm.datasets["val"]) == 0 and len(dm.datasets["train"]) > 0 and len(dm.datasets["test"]) > 0


def test_open_source_gives_the_folder_source(takes, tmp_path):
    root, origin = takes
    manifest = write_csv(tmp_path / "labels.csv", manifest_rows(origin))
    source = open_source("folder", str(root), {"root": "Hips"}, labels=str(manifest), pattern=None)
    assert isinstance(source, FolderSource) and source.name == "folder" and source.profile == {"root": "Hips"}
    assert labels_of(source) == expected_labels(origin)
    motion = source.load(source.list_clips()[0])
    assert motion.skeleton.num_joints == 31


# ---------------------------------------------------------------- scan


def test_scan_reports_the_folder_and_writes_configs_that_fit_runs(takes, tmp_path):
    root, origin = takes
    manifest = write_csv(tmp_path / "labels.csv", manifest_rows(origin))
    out = tmp_path / "conf"
    text = scan(root, labels=str(manifest), out=out)
    name = config_name(root.name)
    assert name == "my_takes_1"
    assert f"Folder: {root.resolve()} (12 BVH files, one skeleton of 31 joints)" in text
    assert "root:      Hips" in text and "feet:      left LeftFoot / LeftToeBase" in text
    assert "Frame rates: 120 fps: 12 files" in text
    assert "style (2): angry 6, neutral 6" in text and "content (2): run 6, walk 6" in text
    table = text[text.index("style x content:") :].splitlines()
    assert table[1].split() == ["run", "walk"] and table[2].split() == ["angry", "3", "3"]
    assert "Splits (clips, seconds): train 4 (" in text and ", val 4 (" in text and ", test 4 (" in text
    assert re.search(r"Suggested: fps 30, window \d+ \(\d\.\d\d s\), stride \d+, mirror true", text)
    assert text.splitlines()[-2:] == [
        f"  walkdiff fit --config {out / 'evaluator_my_takes_1.yaml'}",
        f"  walkdiff fit --config {out / 'my_takes_1.yaml'}",
    ]
    window = int(re.search(r"window (\d+)", text)[1])
    assert window >= 8 and window % 2 == 0 and window <= 24

    from walkdiff.data.datamodule import MotionDataModule

    accepted = set(inspect.signature(MotionDataModule.__init__).parameters)
    for file, directory in (("evaluator_my_takes_1.yaml", "evaluator_my_takes_1"), ("my_takes_1.yaml", name)):
        assert "dataset: folder" in (out / file).read_text()
        config = OmegaConf.to_container(OmegaConf.load(out / file), resolve=True)
        data = config["data"]["init_args"]
        assert set(data) <= accepted
        assert data["dataset"] == "folder" and data["root"] == str(root.resolve())
        assert data["labels"] == str(manifest) and data["contents"] == "all" and data["mirror"] is True
        assert (data["fps"], data["window"], data["stride"]) == (30, window, max(1, window // 6))
        assert config["trainer"]["default_root_dir"] == f"checkpoints/{directory}"
        assert config["trainer"]["logger"]["init_args"]["experiment_name"] == "walkdiff-my_takes_1"
        # The checkpoints follow default_root_dir (so an override of it moves them): no dirpath of their own.
        assert not [c for c in config["trainer"]["callbacks"] if "dirpath" in c["init_args"]]
    generator = OmegaConf.load(out / "my_takes_1.yaml")
    callbacks = {c.class_path.rsplit(".", 1)[-1]: c.init_args for c in generator.trainer.callbacks}
    assert callbacks["MotionMetrics"].evaluator_ckpt == "checkpoints/evaluator_my_takes_1/last.ckpt"
    assert callbacks["SampleClips"].content == "run"
    # Two contents: the generator draws them alike; the evaluator sees every window once an epoch.
    assert generator.data.init_args.balance == "content"
    assert "balance" not in OmegaConf.load(out / "evaluator_my_takes_1.yaml").data.init_args
    assert "the generator's config draws every content label alike (data.balance: content)" in text
    # The data module takes the written arguments as they are.
    module = MotionDataModule(**OmegaConf.to_container(generator.data.init_args))
    assert module.source.styles == ("angry", "neutral") and len(module.splits["test"]) == 4

    # Existing configs are kept unless overwrite (refused before any clip is read).
    with pytest.raises(WalkdiffError, match="config exists") as error:
        scan(root, labels=str(manifest), out=out)
    assert error.value.path == str(out / "evaluator_my_takes_1.yaml")


def test_scan_without_labels_and_with_a_pattern(xia_dir, tmp_path):
    for stem in ("angry_01_000", "angry_13_000", "old_01_000", "old_01_001"):
        shutil.copyfile(xia_dir / f"{stem}.bvh", tmp_path / f"{stem}.bvh")
    text = scan(tmp_path, fps=24, pattern=r"^(?P<style>[a-z]+)_")
    assert "style (2): angry 2, old 2" in text and "content: none (one content group, 'all')" in text
    assert "style x content" not in text and "Clip length at 24 fps" in text
    assert "Suggested: fps 24," in text and "(--out DIR)" in text.splitlines()[-1]
    out = tmp_path / "conf"
    shutil.copyfile(xia_dir / "old_01_002.bvh", tmp_path / "old_01_002.bvh")  # a val clip: previews written
    scan(tmp_path, pattern=r"^(?P<style>[a-z]+)_\d+_(?P<content>\d)", out=out, name="Xia Bits!")
    config = OmegaConf.load(out / "xia_bits.yaml")
    assert config.data.init_args.pattern == r"^(?P<style>[a-z]+)_\d+_(?P<content>\d)"
    assert [c.init_args.content for c in config.trainer.callbacks if "SampleClips" in c.class_path] == ["0"]
    assert "balance" not in config.data.init_args  # one content: nothing to balance


def _rename_joint(source: Path, target: Path, old: str, new: str) -> None:
    text = source.read_text()
    assert re.search(rf"JOINT {old}\b", text)
    target.write_text(re.sub(rf"JOINT {old}\b", f"JOINT {new}", text))


def test_scan_refuses_a_file_of_another_skeleton(folder, zeggs_dir):
    other = folder / "zz" / "renamed.bvh"
    other.parent.mkdir()
    _rename_joint(folder / "take_008.bvh", other, "LeftToeBase", "LeftToe")
    with pytest.raises(WalkdiffError) as error:
        scan(folder)
    message = str(error.value)
    assert error.value.path == str(other) and message.startswith(f"{other}: another skeleton")
    assert "missing LeftToeBase" in message and "extra LeftToe" in message

    other.unlink()
    shutil.copyfile(zeggs_dir / "067_Speech_2_x_1_0.bvh", folder / "zz" / "speech.bvh")
    with pytest.raises(WalkdiffError) as error:
        scan(folder)
    message = str(error.value)
    assert error.value.path == str(folder / "zz" / "speech.bvh")
    assert "75 joints vs 31" in message and "missing LHipJoint" in message and "extra" in message


# ---------------------------------------------------------------- data split


def _listed(out: str) -> dict[str, dict[str, list[str]]]:
    """`data split` output -> split -> clip file (without .bvh) -> its row's other columns."""
    listed: dict[str, dict[str, list[str]]] = {}
    current = None
    for line in out.splitlines():
        header = re.match(r"^(train|val|test): (\d+) clips?", line)
        if header:
            current = listed.setdefault(header[1], {})
        elif current is not None and line.startswith("  ") and not line.startswith("  ("):
            file, *rest = line.lstrip(" *").split()
            current[re.sub(r"\.bvh$", "", file, flags=re.I)] = rest
    return listed


def test_data_split_lists_each_split_with_labels_and_writes_a_manifest_that_keeps_it(takes, tmp_path, capsys):
    from walkdiff.cli.main import main

    root, origin = takes
    rows = manifest_rows(origin)
    rows[0].append("split")
    for row in rows[1:]:
        row.append("test" if row[0].startswith("take_010") else "")
    manifest = write_csv(tmp_path / "labels.csv", rows)
    assert main(["data", "split", str(root), "--labels", str(manifest), "--val-fraction", "0.34"]) == 0
    out = capsys.readouterr().out
    source = FolderSource(root, labels=str(manifest), val_fraction=0.34)
    splits = source.split_clips(source.list_clips(), all_contents(source))
    listed = _listed(out)
    assert {s: set(listed[s]) for s in listed} == split_names(splits)
    labels = expected_labels(origin)
    assert all(listed[s][name] == list(labels[name]) for s in listed for name in listed[s])
    assert out.splitlines()[0] == f"Splits of {root.resolve()} (12 clips; labels from manifest {manifest})"
    assert "Split by the manifest's split column for 1 clips (marked *); the rest per (style, content)" in out
    assert "\n  * take_010.bvh" in out and "test_fraction 0.1, val_fraction 0.34, the rest trains." in out
    counts = {s: len(splits[s]) for s in SPLITS}
    train = rf"^train: {counts['train']} clips \(style: angry \d, neutral \d; content: run \d, walk \d\)$"
    assert re.search(train, out, re.M)
    assert (
        out.splitlines()[-1] == f"Total: train {counts['train']}, val {counts['val']}, test {counts['test']}"
    )

    # --out: a manifest with every clip's split; trained on, it gives the same splits.
    written = tmp_path / "splits.csv"
    assert main(["data", "split", str(root), "--labels", str(manifest), "--val-fraction", "0.34", "--out",
                 str(written)]) == 0  # fmt: skip
    assert f"Wrote {written}" in capsys.readouterr().out
    assert written.read_text().splitlines()[0] == "file,style,content,split"
    frozen = FolderSource(root, labels=str(written))
    assert split_names(frozen.split_clips(frozen.list_clips(), all_contents(frozen))) == split_names(splits)
    assert labels_of(frozen) == labels
    with pytest.raises(WalkdiffError, match="manifest exists: pass overwrite"):
        from walkdiff.data.splits import split_report

        split_report(root, out=written)


def test_data_split_of_xia_and_of_a_folder_without_labels(xia_dir, tmp_path, monkeypatch, capsys):
    from walkdiff.cli.main import main

    monkeypatch.setenv("WALKDIFF_DATA", str(xia_dir.parent))
    monkeypatch.chdir(tmp_path)  # no folder called xia here
    assert main(["data", "split", "xia", "--contents", "walk"]) == 0
    out = capsys.readouterr().out
    clips = xia.list_clips(xia_dir)
    splits = xia.split_clips(clips, ContentSelection.parse("walk", xia.GROUPS))
    assert (
        out.splitlines()[0]
        == f"Splits of {xia_dir} (572 clips, 277 of them in data.contents walk; labels from the file names)"
    )
    assert {s: set(v) for s, v in _listed(out).items()} == split_names(splits)
    assert main(["data", "split", "xia", "--labels", "x.csv"]) == 1
    assert "only the folder dataset takes labels" in capsys.readouterr().err

    for stem in ("angry_01_000", "angry_01_001"):
        shutil.copyfile(xia_dir / f"{stem}.bvh", tmp_path / f"{stem}.bvh")
    assert main(["data", "split", str(tmp_path), "--test-fraction", "0"]) == 0
    out = capsys.readouterr().out
    assert (
        "\ntrain: 2 clips\n    angry_01_000.bvh\n    angry_01_001.bvh\n"
        "val: 0 clips\n  (none: `data scan` writes configs that do not validate; to validate:" in out
    )
    assert "test: 0 clips\n  (none: data.test_fraction is 0: set it above 0" in out


# ---------------------------------------------------------------- without a validation split


def test_a_folder_without_val_clips_gets_configs_that_do_not_validate(takes, tmp_path, monkeypatch, capsys):
    import lightning as L

    from walkdiff.callbacks.fit import lightning_cli
    from walkdiff.data.datamodule import MotionDataModule

    root, origin = takes
    manifest = write_csv(tmp_path / "labels.csv", manifest_rows(origin))
    out = tmp_path / "conf"
    text = scan(root, labels=str(manifest), val_fraction=0, out=out, name="noval")
    assert "Splits (clips, seconds): train 8 (" in text and ", val 0 (0.0 s), test 4 (" in text
    assert "no val clips: the written configs do not validate (trainer.limit_val_batches 0)" in text
    assert "To validate: data.val_fraction is 0: set it above 0" in text
    monkeypatch.setattr("sys.argv", ["walkdiff"])
    for file in ("evaluator_noval.yaml", "noval.yaml"):
        written = (out / file).read_text()
        config = OmegaConf.to_container(OmegaConf.load(out / file))
        trainer = config["trainer"]
        assert trainer["limit_val_batches"] == 0
        assert "val_check_interval" not in trainer and "check_val_every_n_epoch" not in trainer
        callbacks = [c["class_path"].rsplit(".", 1)[-1] for c in trainer["callbacks"]]
        assert callbacks == ["RunCheckpoint"], file  # last.ckpt only: nothing that follows a validation
        assert "monitor" not in written and "/val" not in written
        with pytest.raises(SystemExit) as stop:
            lightning_cli(["fit", "--config", str(out / file), "--print_config"])
        assert stop.value.code == 0
        assert "limit_val_batches: 0" in capsys.readouterr().out

    # The data module takes an empty val split when nothing validates, and says how to fix it otherwise.
    init = OmegaConf.to_container(OmegaConf.load(out / "noval.yaml").data.init_args)
    module = MotionDataModule(**init)
    assert not module.splits["val"] and module.splits["test"]
    module._check_splits()  # outside a trainer (evaluate, score): nothing validates
    module.trainer = L.Trainer(limit_val_batches=0, logger=False, enable_checkpointing=False)
    module._check_splits()
    module.trainer = L.Trainer(limit_val_batches=4, logger=False, enable_checkpointing=False)
    with pytest.raises(WalkdiffError) as error:
        module._check_splits()
    message = str(error.value)
    assert "no val clip: the dataset has 12 clips, split 8 train, 0 val, 4 test;" in message
    assert message.endswith(
        "or train without validation: trainer.limit_val_batches 0 (what `walkdiff data scan` writes for a "
        "folder without val clips)"
    )


def test_scan_gives_a_varied_folder_twice_the_batches_and_says_why(xia_dir, tmp_path):
    """One-off actions (contents whose root stays in place) beside walks: 3,600 batches; walks and runs
    only: 1,800. Judged on another lab's export (Z up, centimetres, a static root above the hips, 60 fps)."""
    import disguise

    from walkdiff.motion.bvh import read_bvh, write_bvh

    def folder(name: str, contents: dict[str, str]) -> Path:
        root = tmp_path / name
        root.mkdir()
        rows = [["file", "style", "content"]]
        for style in STYLES:
            for content_id, label in contents.items():
                for take in range(TAKES):
                    stem = f"{style}_{content_id}_{take:03d}"
                    motion = disguise.disguise(read_bvh(xia_dir / f"{stem}.bvh"))[0]
                    write_bvh(root / f"clip_{len(rows):02d}.bvh", motion)
                    rows.append([f"clip_{len(rows):02d}.bvh", style, label])
        write_csv(root / "labels.csv", rows)
        return root

    varied = folder("varied", {"01": "walk", "18": "jab", "22": "sidekick"})
    text = scan(varied, out=tmp_path / "varied_conf")
    assert (
        "the generator 3,600 batches of 96 (a varied folder: 2 of its 3 contents stay in place "
        "(one-off actions: jab, sidekick), so twice the batches of a walking folder)"
    ) in text
    config = (tmp_path / "varied_conf" / "varied.yaml").read_text()
    assert OmegaConf.create(config).trainer.max_steps == 3600
    assert "# 3,600 batches: a varied folder: 2 of its 3 contents stay in place" in config
    evaluator = OmegaConf.load(tmp_path / "varied_conf" / "evaluator_varied.yaml")
    assert evaluator.trainer.max_steps == 1800
    # The generator's batches hold 96 windows (64 of them for the discriminator), the evaluator's 64.
    assert OmegaConf.create(config).data.init_args.batch_size == 96
    assert OmegaConf.create(config).model.init_args.discriminator_windows == 64
    assert evaluator.data.init_args.batch_size == 64
    # Every folder's labels enter every layer of the denoiser (adaLN-Zero).
    assert OmegaConf.create(config).model.init_args.conditioning == "adaln"
    assert OmegaConf.create(config).model.init_args.lambda_low_foot == 4.0  # feet the sample puts down stay

    walking = folder("walking", {"01": "walk", "13": "run"})
    text = scan(walking, out=tmp_path / "walking_conf")
    assert "the generator 1,800 batches of 96 (all 2 contents travel (locomotion))" in text
    walking_config = OmegaConf.load(tmp_path / "walking_conf" / "walking.yaml")
    assert walking_config.trainer.max_steps == 1800
    assert walking_config.model.init_args.conditioning == "adaln"
    assert walking_config.model.init_args.lambda_low_foot == 4.0  # every folder's feet
