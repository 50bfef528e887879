"""Labels that know left from right (walkdiff.data.laterality): a mirrored training copy of a left turn
is a right turn, and must be labelled one.

The folder tests use real Xia turning clips, disguised as another lab's capture (tests/disguise.py:
Unreal names, a static root, metres, Z up, 60 fps) and labelled `walk-turn-left` / `walk-turn-right` by
the way they really turn. Xia's own content ids do not tell it: measured by the heading, about half the
clips of `walk_lturn_l1` (05) turn right, so the clips here are named one by one.
"""

from __future__ import annotations

import re
import shutil
import warnings
from pathlib import Path

import disguise
import numpy as np
import pytest
from omegaconf import OmegaConf

from walkdiff.cli.main import main
from walkdiff.common.errors import WalkdiffError
from walkdiff.data import humanact12, xia
from walkdiff.data.datamodule import MotionDataModule
from walkdiff.data.laterality import lateral_tokens, mirror_labels, mirrored_name
from walkdiff.data.scan import scan
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.representation import FeatureLayout

# Measured turns (degrees, to the body's own left) of whole clips: 89, 92, 71 and -89, -94, -94.
LEFT = ("angry_05_000", "neutral_06_000", "depressed_12_000")
RIGHT = ("angry_05_001", "neutral_05_002", "childlike_12_001")
STRAIGHT = ("old_01_000", "sexy_01_000", "proud_01_000")  # the last one is the test split
LABELS = {**dict.fromkeys(LEFT, "walk-turn-left"), **dict.fromkeys(RIGHT, "walk-turn-right")}
HEADING = FeatureLayout.heading_vel.start  # the heading rate: radians per frame, positive to the left
TURNED = 0.8  # radians (46 degrees): the least a turning clip (or its mirror) turns


def _write_labels(folder: Path, files: dict[str, str]) -> None:
    """labels.csv: Xia name -> file; style from the name, content by how the clip turns."""
    rows = ["file,style,content,split"]
    for original, take in sorted(files.items(), key=lambda item: item[1]):
        stem = original.removesuffix(".bvh")
        split = "test" if stem == STRAIGHT[-1] else "train"
        rows.append(f"{take},{stem.split('_')[0]},{LABELS.get(stem, 'walk')},{split}")
    (folder / "labels.csv").write_text("\n".join(rows) + "\n")


@pytest.fixture(scope="module")
def turning(xia_dir, tmp_path_factory) -> tuple[Path, disguise.DisguiseRecord]:
    folder = tmp_path_factory.mktemp("turning") / "turns"
    record = disguise.disguised_folder(xia_dir, folder, LEFT + RIGHT + STRAIGHT)
    _write_labels(folder, record.files)
    return folder, record


def _module(folder: Path, cache: Path, **options) -> MotionDataModule:
    return MotionDataModule(
        dataset="folder",
        root=str(folder),
        contents="all",
        cache_dir=str(cache),
        preprocess_workers=1,
        **options,
    )


def _turn_to_the_left(motion, profile, names: dict[str, str]) -> float:
    """Radians the body turns towards its own left over the clip, from the hips (world positions)."""
    canonical = profile.to_canonical(motion)
    world = motion_world_positions(canonical)
    joints = canonical.skeleton.names
    left = world[:, joints.index(names["LeftUpLeg"])] - world[:, joints.index(names["RightUpLeg"])]
    left[:, 1] = 0.0
    forward = np.cross(left, [0.0, 1.0, 0.0])  # up x forward = left
    return float(np.arctan2(np.cross(forward[0], forward[-1])[1], np.dot(forward[0], forward[-1])))


# ---------------------------------------------------------------- names


@pytest.mark.parametrize(
    "label,mirrored",
    [
        ("walk-turn-left", "walk-turn-right"), ("Turn Right", "Turn Left"), ("TURN_LEFT", "TURN_RIGHT"),
        ("walk_lturn_s1", "walk_rturn_s1"), ("run_rturn", "run_lturn"), ("LTurn", "RTurn"),
        ("walkTurnLeft", "walkTurnRight"), ("punch_l", "punch_r"), ("kick_R", "kick_L"), ("step-L", "step-R"),
        ("turnleft", "turnright"), ("left_to_right", "right_to_left"), ("circle_cw", "circle_ccw"),
        ("Circle-CCW", "Circle-CW"),
        # not a side: letters inside a word, or a letter with digits (Xia's walk_l1 is a long walk)
        ("stroll", None), ("bright", None), ("upright", None), ("leftover", None), ("walk_l1", None),
        ("punch_qr", None), ("Lr", None), ("roll", None), ("walk", None), ("proud", None),
    ],
)  # fmt: skip
def test_sides_are_found_in_tokens_in_any_spelling(label, mirrored):
    assert mirrored_name(label) == mirrored
    assert bool(lateral_tokens(label)) == (mirrored is not None)


def test_partners_are_found_in_the_labels_or_left_out():
    labels = mirror_labels(
        ("angry", "limp_left"),
        ("walk", "walk-turn-left", "walk-turn-right", "turn_L", "turn_right", "punch_l"),
    )
    assert labels.styles == (0, None)  # no limp_right: the mirrored limp is left out
    # turn_L finds turn_right though spelled another way; punch_l has no punch_r.
    assert labels.contents == (0, 2, 1, 4, 3, None)
    assert [f"{s.kind} {s.label}" for s in labels.unpaired] == ["style limp_left", "content punch_l"]
    described = labels.describe()
    assert "content walk-turn-left <-> walk-turn-right" in described
    assert "content turn_L <-> turn_right" in described
    assert any(
        line.startswith("content punch_l: no content 'punch_r' among the labels") for line in described
    )
    warning = labels.warning()
    assert "data.mirror_labels {punch_l: PARTNER}" in warning and "{punch_l: punch_l}" in warning

    # A partner outside data.contents is no partner; a given mapping holds both ways.
    selected = mirror_labels(("none",), ("walk-turn-left", "walk-turn-right"), selected=("walk-turn-left",))
    assert selected.contents == (None, 0)
    assert selected.describe()[0].startswith(
        "content walk-turn-left: content 'walk-turn-right' is not in data.contents"
    )
    given = mirror_labels(("none",), ("spin_a", "spin_b", "punch_l"), {"spin_a": "spin_b", "punch_l": None})
    assert given.contents == (1, 0, None) and not given.unpaired  # asked for: no warning
    kept = mirror_labels(("none",), ("walk_l", "walk"), {"walk_l": "walk_l"})  # l is 'long' here
    assert kept.contents == (0, 1) and kept.describe() == [
        "content walk_l: kept (data.mirror_labels: not lateral)"
    ]


@pytest.mark.parametrize(
    "given,expected",
    [
        ({"nope": "walk"}, "unknown label 'nope': expected a style or content label"),
        ({"walk-turn-left": "angry"}, "'walk-turn-left' is a content label and 'angry' is not"),
        ({"a": "b", "c": "b"}, "content 'b' would be mirrored to both 'a' and 'c'"),
        (["a", "b"], "expected a mapping {label: mirrored label}"),
        ({"a": 3}, "'a': 3: expected a mapping"),
    ],
)
def test_mirror_labels_errors_name_the_option_and_what_was_expected(given, expected):
    with pytest.raises(WalkdiffError, match=re.escape(expected)) as error:
        mirror_labels(("angry",), ("a", "b", "c", "walk-turn-left"), given)
    assert str(error.value).startswith("data.mirror_labels: ")


def test_published_datasets_have_no_lateral_labels():
    """Xia's labels are its six content groups, HumanAct12's its actions: nothing to swap. Xia's per-id
    names would be (walk_lturn_s1 <-> walk_rturn_s1), but they are not labels, and they do not even tell
    the direction: see the module docstring."""
    for module in (xia, humanact12):
        assert mirror_labels(module.STYLES, module.GROUPS).swaps == ()
    names = mirror_labels(("none",), xia.CONTENT_NAMES)
    assert "content walk_lturn_s1 <-> walk_rturn_s1" in names.describe()
    assert {s.label for s in names.unpaired} == {"walk_lturn_l2", "walk_lturn_l3"}


# ---------------------------------------------------------------- on turning clips


def test_mirrored_left_turns_are_labelled_right_turns_and_turn_right(turning, tmp_path):
    folder, record = turning
    dm = _module(folder, tmp_path / "cache")
    groups = dm.source.groups
    assert groups == ("walk", "walk-turn-left", "walk-turn-right")
    dm.setup()
    original = {take: name.removesuffix(".bvh") for name, take in record.files.items()}
    seen = {"walk-turn-left": [0, 0], "walk-turn-right": [0, 0], "walk": [0, 0]}  # originals, copies
    for clip, name, features in dm.split_features("train", mirrored=True):
        label, turn = groups[clip.content], float(features[:, HEADING].sum())
        stem = original[clip.path.name]
        copy = name.endswith("#mirror")
        seen[label][copy] += 1
        assert dm.source.styles[clip.style] == stem.split("_")[0]  # a style names no side: kept
        if label == "walk-turn-left":
            assert turn > TURNED, (name, stem, turn)
        elif label == "walk-turn-right":
            assert turn < -TURNED, (name, stem, turn)
        else:
            assert abs(turn) < 0.35, (name, stem, turn)
        assert (stem in LEFT) == (label == ("walk-turn-right" if copy else "walk-turn-left"))
    assert seen == {"walk-turn-left": [3, 3], "walk-turn-right": [3, 3], "walk": [2, 2]}
    # What training batches carry.
    labels = {name: content for _, content, name in dm.datasets["train"].labels}
    take = record.files[f"{LEFT[0]}.bvh"].removesuffix(".bvh")
    assert (groups[labels[take]], groups[labels[f"{take}#mirror"]]) == ("walk-turn-left", "walk-turn-right")

    # "Left" is the body's own left: the hips of the original clips turn that way in the world.
    for stem in LEFT + RIGHT:
        motion = read_bvh(folder / record.files[f"{stem}.bvh"])
        turn = _turn_to_the_left(motion, dm.profile, record.names)
        assert turn > TURNED if stem in LEFT else turn < -TURNED, (stem, turn)


def test_scan_shows_which_labels_mirroring_swaps(turning, tmp_path, capsys):
    folder, _ = turning
    text = scan(folder)
    assert "Mirrored copies swap the labels that name a side (a mirrored left turn turns right):" in text
    assert "\n  content walk-turn-left <-> walk-turn-right\n" in text
    assert "no partner" not in text

    # A mapping given on the command line is shown, and written into the configs.
    out = tmp_path / "conf"
    assert (
        main(["data", "scan", str(folder), "--out", str(out), "--mirror-labels", "walk=walk", "--no-timing"])
        == 0
    )
    assert "\n  content walk: kept (data.mirror_labels: not lateral)\n" in capsys.readouterr().out
    data = OmegaConf.to_container(OmegaConf.load(out / "turns.yaml")).get("data")["init_args"]
    assert data["mirror"] is True and data["mirror_labels"] == {"walk": "walk"}
    assert MotionDataModule(**data).mirror_map.contents == (0, 2, 1)


def test_a_left_turn_without_a_right_turn_label_loses_its_mirrored_copies(turning, tmp_path):
    """A mirrored left turn labelled walk-turn-left would teach the model a left turn that turns right,
    and no clip has the label walk-turn-right: those copies are left out, with the reason and the fix."""
    source, record = turning
    folder = tmp_path / "lefts"
    folder.mkdir()
    kept = {name: take for name, take in record.files.items() if name.removesuffix(".bvh") not in RIGHT}
    for take in kept.values():
        shutil.copyfile(source / take, folder / take)
    _write_labels(folder, kept)

    text = scan(folder)
    assert (
        "1 label(s) name a side but have no partner (content walk-turn-left): their mirrored copies" in text
    )
    assert (
        "  content walk-turn-left: no content 'walk-turn-right' among the labels: its mirrored copies are "
        "left out (a mirrored walk-turn-left is not a walk-turn-left); name its partner with "
        "data.mirror_labels {walk-turn-left: PARTNER}"
    ) in text

    dm = _module(folder, tmp_path / "cache")
    with pytest.warns(
        UserWarning, match=r"mirrored copies left out of training: content walk-turn-left"
    ) as w:
        dm.setup()
    assert "(3 of 5 training clips)" in str(w[0].message)
    names = [name for _, name, _ in dm.split_features("train", mirrored=True)]
    copies = [n for n in names if n.endswith("#mirror")]
    assert len(names) == 7 and len(copies) == 2  # 5 originals, the 2 straight walks mirrored
    left_takes = {record.files[f"{stem}.bvh"].removesuffix(".bvh") for stem in LEFT}
    assert not {c.removesuffix("#mirror") for c in copies} & left_takes

    # Said in data.mirror_labels: no warning. Declared not lateral: copies kept, labels as they are.
    for given, copies_expected in (({"walk-turn-left": None}, 2), ({"walk-turn-left": "walk-turn-left"}, 5)):
        dm = _module(folder, tmp_path / "cache", mirror_labels=given)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            dm.setup()
        assert (
            sum(n.endswith("#mirror") for _, n, _ in dm.split_features("train", mirrored=True))
            == copies_expected
        )


def test_bench_turns_measures_sampled_and_transferred_turns(turning, tmp_path):
    """`walkdiff bench turns` on a tiny generator trained briefly on the turning clips (a left and a right
    turn held out to test): each side label gets its rows. Its training windows turn the label's way,
    mirrored copies included (unswapped copies or a sign error would put half of them the other way);
    both test turns are transferred into every other style."""
    import tiny

    from walkdiff.bench.turns import bench_turns, format_turns

    source, record = turning
    folder = tmp_path / "turns"
    folder.mkdir()
    for take in record.files.values():
        shutil.copyfile(source / take, folder / take)
    held = {LEFT[0], RIGHT[0], STRAIGHT[-1]}
    rows = ["file,style,content,split"] + [
        f"{take},{stem.split('_')[0]},{LABELS.get(stem, 'walk')},{'test' if stem in held else 'train'}"
        for stem, take in ((name.removesuffix(".bvh"), take) for name, take in sorted(record.files.items()))
    ]
    (folder / "labels.csv").write_text("\n".join(rows) + "\n")
    ckpt = tiny.generator(
        tmp_path, epochs=2, name="turner", data_options={"dataset": "folder", "root": str(folder),
                                                         "contents": "all", "mirror": True},
    )  # fmt: skip
    result = bench_turns(ckpt, tmp_path / "turns.json", num=1, frames=24, steps=2)
    assert set(result["labels"]) == {"walk-turn-left", "walk-turn-right"}
    styles = {stem.split("_")[0] for stem in LEFT + RIGHT + STRAIGHT}
    for label, row in result["labels"].items():
        assert row["side"] == label.rsplit("-", 1)[1]
        assert row["training_windows"]["share"] >= 0.9 and row["training_clips"]["share"] == 1.0
        assert row["training_clips"]["count"] == 4  # two of its own, two mirrored of the other side
        assert set(row["sampled"]) == styles and all(r["count"] == 1 for r in row["sampled"].values())
        assert 0.0 <= row["sampled_all"]["share"] <= 1.0
        assert row["transfers"]["count"] == len(row["sampled"]) - 1  # one test clip, every other style
    walk = result["no_side"]["walk"]  # the straight walks: how much a window turns, sampled and real
    assert walk["sampled_windows"] == len(styles) and walk["training_windows"] > 0
    assert 0 <= walk["training_window_abs_deg"] < 45 and walk["sampled_window_abs_deg"] >= 0
    assert (tmp_path / "turns.json").is_file() and len(format_turns(result)) == 4


def test_disguise_labels_walks_by_how_they_turn(xia_dir):
    """`python tests/disguise.py ... --turns 45` (the folder `bench turns` is measured on) labels Xia's
    walks by their measured turn, not by their content ids."""
    from types import SimpleNamespace

    clips = [SimpleNamespace(name=stem) for stem in LEFT + RIGHT + STRAIGHT]
    labels, splits = disguise.turn_labels(xia_dir, clips, 45.0)
    expected = {f"{s}.bvh": LABELS.get(s, "walk") for s in LEFT + RIGHT + STRAIGHT}
    assert labels == expected
    assert set(splits.values()) == {"train"}  # no style and label with three clips: none held out


def test_scan_counts_the_training_windows_per_content_as_the_data_module_draws_them(turning, tmp_path):
    """The content shares `data scan` reports are those of the windows training sees, mirrored copies
    under their own labels: a left turn's mirrored copy adds to the right turns."""
    from collections import Counter

    from walkdiff.data import laterality
    from walkdiff.data.clips import ContentSelection
    from walkdiff.data.folder import FolderSource
    from walkdiff.data.scan import _read_clips, _suggest, training_windows

    folder, _ = turning
    source = FolderSource(folder)
    clips = source.list_clips()
    splits = source.split_clips(clips, ContentSelection(tuple(source.groups)))
    suggested = _suggest(_read_clips(source, clips), None)
    swaps = laterality.mirror_labels(source.styles, source.groups, None)
    counted = Counter()
    for (_, content), n in training_windows(clips, splits, suggested, swaps).items():
        counted[source.groups[content]] += n

    dm = _module(folder, tmp_path / "cache", fps=suggested.fps, window=suggested.window,
                 stride=suggested.stride, mirror=True)  # fmt: skip
    dm.setup("fit")
    data = dm.datasets["train"]
    names = dm.spec.contents
    drawn = Counter(names[data.labels[clip][1]] for clip, _ in data.index)
    assert counted == drawn and drawn["walk-turn-left"] > 0 and drawn["walk-turn-right"] > 0
    line = next(row for row in scan(folder).splitlines() if row.startswith("Training windows per content"))
    for name, n in drawn.items():
        assert f"{name} {n / sum(drawn.values()):.0%}" in line
