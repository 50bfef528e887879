"""Your own data: Xia disguised as another lab's capture gives Xia's features, and trains through the CLI.

The disguises (tests/disguise.py) rename every joint to another convention, put a static root above the
hips with the translation moved onto the hips, write metres instead of CMU units, another rotation
order, a Z-up world and 60 fps, and give the labels in a CSV instead of the file names. Nothing of that
may change what walkdiff computes: features (translations after unit scaling), contact labels and world
positions must equal native Xia's.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import disguise
import numpy as np
import pytest
import synthetic
from omegaconf import OmegaConf

from walkdiff.cli.main import main
from walkdiff.data.datamodule import MotionDataModule
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import FeatureLayout, encode
from walkdiff.motion.resample import resample

# One walk per style, a run, a jump and a kick: turning, fast and airborne feet.
CLIPS = [
    "angry_01_000", "childlike_03_000", "depressed_07_000", "neutral_09_000", "old_04_000",
    "proud_02_000", "sexy_05_000", "strutting_11_000", "neutral_13_000", "old_16_000", "sexy_22_000",
]  # fmt: skip
CHAINS = {
    "unreal, static root, metres, XYZ, Z-up, 60 fps": disguise.DEFAULT_STEPS,
    "mixamo, Blender-style turned root, cm, ZXY": ("mixamo", "static_root:X-90", "cm", "order:ZXY"),
    "smpl, position channels everywhere, YXZ": ("smpl", "positions", "order:YXZ"),
}


def _features(motion, profile) -> tuple[np.ndarray, np.ndarray]:
    canonical = resample(profile.to_canonical(motion), 30.0)
    return encode(canonical, profile), motion_world_positions(canonical)


@pytest.mark.parametrize("chain", list(CHAINS))
def test_disguised_xia_has_native_features_contacts_and_positions(xia_dir, tmp_path, chain):
    worst = {"translation": 0.0, "rotation": 0.0, "positions": 0.0}
    agree, frames = 0, 0
    for name in CLIPS:
        native = read_bvh(xia_dir / f"{name}.bvh")
        native_profile = synthetic.xia_profile(native)
        copy, record = disguise.disguise(native, CHAINS[chain])
        path = tmp_path / "take.bvh"
        write_bvh(path, copy, precision=disguise.default_precision(record.scale))
        copy = read_bvh(path)
        profile = SkeletonProfile.detect(copy)  # nothing configured: everything is found
        assert profile.root == record.names["Hips"]
        assert profile.feet["left_heel"] == record.names["LeftFoot"]
        assert profile.feet["right_toe"] == record.names["RightToeBase"]
        assert profile.contacts.speed_threshold == pytest.approx(
            record.scale * native_profile.contacts.speed_threshold, rel=1e-6
        )
        x, world = _features(native, native_profile)
        y, copy_world = _features(copy, profile)
        layout = FeatureLayout(native.skeleton.num_joints)
        assert y.shape == x.shape
        translation = [0, 1, 2]  # root velocity (x, z) and height: lengths, in the copy's units
        worst["translation"] = max(
            worst["translation"], np.abs(y[:, translation] / record.scale - x[:, translation]).max()
        )
        rotations = np.r_[3, np.arange(layout.rotations.start, layout.rotations.stop)]
        worst["rotation"] = max(worst["rotation"], np.abs(y[:, rotations] - x[:, rotations]).max())
        # Canonical world positions: the same motion, Y up, in the copy's units.
        worst["positions"] = max(worst["positions"], np.abs(copy_world / record.scale - world).max() / 24.13)
        agree += (y[:, layout.contacts] == x[:, layout.contacts]).all(axis=1).sum()
        frames += len(x)
    print(f"{chain}: {worst}, contacts agree on {agree}/{frames} frames")
    assert worst["translation"] < 1e-4  # CMU units (~6 mm per 0.1 unit)
    assert worst["rotation"] < 1e-4
    assert worst["positions"] < 1e-5  # of body height
    assert agree >= 0.99 * frames


@pytest.mark.parametrize("chain", list(CHAINS))
def test_inspect_and_convert_round_trip_on_disguised_files(xia_dir, tmp_path, capsys, chain):
    """`inspect` reads, `convert` writes the copy's own skeleton, axes, units and root layout back."""
    for name in CLIPS[:4]:
        copy, record = disguise.disguise(read_bvh(xia_dir / f"{name}.bvh"), CHAINS[chain])
        source = tmp_path / f"{name}.bvh"
        write_bvh(source, copy, precision=9)
        assert main(["inspect", str(source)]) == 0
        assert f"root:      {record.names['Hips']}" in capsys.readouterr().out
        out = tmp_path / f"{name}_out.bvh"
        assert main(["convert", str(source), str(out)]) == 0
        back = read_bvh(out)
        assert back.skeleton.names == copy.skeleton.names
        error = np.abs(motion_world_positions(back) - motion_world_positions(read_bvh(source))).max()
        assert error < 1e-4 * 24.13 * record.scale  # 1e-4 of body height


@pytest.fixture(scope="module")
def disguised_folder(xia_dir, tmp_path_factory) -> Path:
    """24 walks of 4 styles, disguised, with their labels in labels.csv."""
    folder = tmp_path_factory.mktemp("own") / "studio"
    names = sorted(p.stem for p in xia_dir.glob("*.bvh"))
    walks = [n for n in names if int(n.split("_")[1]) <= 12]  # content ids 01-12 are walks
    picked = []
    for style in ("angry", "old", "proud", "sexy"):
        picked += [n for n in walks if n.startswith(style + "_")][::3][:6]
    disguise.disguised_folder(xia_dir, folder, picked)
    return folder


def test_scan_then_fit_sample_and_transfer_on_disguised_xia(disguised_folder, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # the configs' mlruns/ and checkpoints/ land here
    monkeypatch.setattr("sys.argv", ["walkdiff"])  # LightningCLI warns about pytest's own arguments
    # Two test clips per style: `evaluate` splits the real test set into halves for its FMD floor.
    scan = ["data", "scan", str(disguised_folder), "--test-fraction", "0.34", "--val-fraction", "0.17"]
    assert main([*scan, "--out", "conf", "--name", "studio"]) == 0
    report = capsys.readouterr().out
    assert "root:      pelvis (static above it, folded: Root)" in report and "up +z" in report
    # The plan in batches, whatever the folder's size, and what it costs here (timed on a few batches).
    assert "Budget: the evaluator 1,800 batches of 64 windows, the generator 1,800 batches of 96" in report
    assert re.search(r"conf/studio.yaml: 1,800 batches x \d+\.\d\d s = ", report), report
    assert "units:     m" in report and "angry 6" in report
    generator = OmegaConf.load("conf/studio.yaml")
    assert generator.data.init_args.dataset == "folder" and generator.data.init_args.mirror is True

    quick = ["--trainer.enable_progress_bar", "false", "--trainer.log_every_n_steps", "1"]  # fmt: skip
    assert main(["fit", "--config", "conf/evaluator_studio.yaml", "--trainer.max_steps", "3", *quick]) == 0
    assert Path("checkpoints/evaluator_studio/last.ckpt").is_file()
    # The config as written, with a tiny network and a few batches, validated twice.
    tiny = ["--model.d_model", "32", "--model.layers", "1", "--model.heads", "2",
            "--trainer.limit_train_batches", "2", "--trainer.max_steps", "10",
            "--trainer.val_check_interval", "5"]  # fmt: skip
    assert main(["fit", "--config", "conf/studio.yaml", *quick, *tiny]) == 0
    ckpt = "checkpoints/studio/last.ckpt"
    assert Path(ckpt).is_file()
    capsys.readouterr()
    # Stopped by max_time before its first validation: it says so, and last.ckpt is still written.
    shutil.rmtree("checkpoints/studio")
    # (100,000 planned batches: no machine trains them in the 1 s, so max_time always fires.)
    short = [*quick, *tiny[:6], "--trainer.max_steps", "100000", "--trainer.max_time", "00:00:00:01"]
    assert main(["fit", "--config", "conf/studio.yaml", *short]) == 0
    err = capsys.readouterr().err
    assert "max_time stopped training after step" in err and "of 100000" in err and Path(ckpt).is_file()

    sample = ["sample", "--ckpt", ckpt, "--style", "old", "--num", "1", "--frames", "40", "--sampler", "ddim"]
    assert main([*sample, "--steps", "3", "--out", "samples", "--no-gif"]) == 0
    out = read_bvh(next(Path("samples").glob("*.bvh")))
    first = read_bvh(next(disguised_folder.glob("*.bvh")))
    assert out.skeleton.names == first.skeleton.names and out.num_frames == 40
    world = motion_world_positions(out)
    head, feet = out.skeleton.index("head"), [out.skeleton.index(n) for n in ("foot_l", "foot_r")]
    rise = world[:, head] - world[:, feet].mean(axis=1)
    assert (rise[:, 2] > 0.8).all(), "Z up, in metres: the head is ~1 m above the feet"
    np.testing.assert_allclose(out.positions[:, 0], 0.0)  # the static root stays where it was

    source = sorted(disguised_folder.glob("*.bvh"))[0]
    assert main(["transfer", "--ckpt", ckpt, "--input", str(source), "--style", "proud", "--out", "moved",
                 "--sampler", "ddim", "--steps", "3", "--no-gif"]) == 0  # fmt: skip
    moved = read_bvh(next(Path("moved").glob("*.bvh")))
    assert moved.skeleton.names == first.skeleton.names
    report = json.loads(next(Path("moved").glob("*.json")).read_text())
    assert np.isfinite(report["root_path_error"]["mean"])

    # Foot clean-up, evaluation with the folder's own evaluator, and distillation take the checkpoint as is.
    assert main([*sample, "--steps", "3", "--out", "feet", "--no-gif", "--fix-feet"]) == 0
    evaluator = "checkpoints/evaluator_studio/last.ckpt"
    assert main(["evaluate", "--ckpt", ckpt, "--evaluator", evaluator, "--out", "eval", "--num", "16",
                 "--repeats", "2", "--sampler", "ddim", "--steps", "2"]) == 0  # fmt: skip
    rows = json.loads(Path("eval/report.json").read_text())["rows"]
    assert len(rows) >= 2 and all(np.isfinite(row["fmd"]["mean"]) for row in rows.values())
    assert (
        main(["distill", "--ckpt", ckpt, "--out", "student.ckpt", "--iterations", "2", "--steps", "2"]) == 0
    )
    assert main([*sample, "--steps", "2", "--ckpt", "student.ckpt", "--out", "student", "--no-gif"]) == 0
    assert read_bvh(next(Path("student").glob("*.bvh"))).skeleton.names == first.skeleton.names


def test_zeggs_loads_through_the_folder_dataset(zeggs_dir, tmp_path):
    dm = MotionDataModule(
        dataset="folder", root=str(zeggs_dir), contents="all", window=24, cache_dir=str(tmp_path),
        preprocess_workers=1, val_fraction=0.0, test_fraction=0.0,
    )  # fmt: skip
    assert dm.profile.root == "Hips" and dm.profile.units == "cm"
    assert dm.spec.num_joints == 75 and dm.spec.styles == ("none",)
    feet = dm.profile.feet
    assert (feet["left_heel"], feet["left_toe"]) == ("LeftFoot", "LeftToeBase")
    assert (feet["right_heel"], feet["right_toe"]) == ("RightFoot", "RightToeBase")
    features = dm.split_features("train", mirrored=True)
    assert len(features) == 2 and all(np.isfinite(f).all() for _, _, f in features)
    assert features[0][2].shape == (2065, FeatureLayout(75).dim)


def test_gesture_model_on_a_disguised_zeggs_take(zeggs_dir, tmp_path, monkeypatch):
    """DiffMotion on BVH + WAV takes of another skeleton: Unreal names, static root, metres, Z-up."""
    import soundfile
    import torch
    from tiny import GESTURES

    from walkdiff.data.speech import SpeechDataModule, read_wav
    from walkdiff.models.diffmotion import DiffMotion

    monkeypatch.setattr("sys.argv", ["walkdiff"])
    folder = tmp_path / "takes"
    folder.mkdir()
    take = read_bvh(zeggs_dir / "067_Speech_2_x_1_0.bvh").slice(0, 300)  # 10 s at 30 fps
    copy, record = disguise.disguise(take, ("unreal", "static_root", "scale:0.01", "z_up"))  # cm -> m
    write_bvh(folder / "talk.bvh", copy, precision=8)
    samples, rate = read_wav(zeggs_dir / "067_Speech_2_x_1_0.wav")
    soundfile.write(folder / "talk.wav", samples[: 10 * rate], rate)

    dm = SpeechDataModule(str(folder), window=40, stride=10, past=5, lookahead=8, batch_size=4)
    assert dm.profile.root == record.names["Hips"] and dm.profile.units == "m"
    assert np.allclose(dm.profile.up, [0, 0, 1])
    torch.manual_seed(0)
    model = DiffMotion(dm.spec, **GESTURES)
    trainer = synthetic.quiet_trainer(max_steps=2)
    trainer.fit(model, dm)
    ckpt = tmp_path / "gesture.ckpt"
    trainer.save_checkpoint(ckpt)

    out = tmp_path / "out"
    assert main(["gesture", "--ckpt", str(ckpt), "--audio", str(folder / "talk.wav"), "--out", str(out)]) == 0
    motion = read_bvh(out / "talk.bvh")
    assert motion.skeleton.names == copy.skeleton.names
    world = motion_world_positions(motion)
    root = motion.skeleton.index(record.names["Hips"])
    # The neutral root stands where the take's hips stood (Z up, metres), not at the static root's origin.
    np.testing.assert_allclose(
        world[:, root].mean(0), motion_world_positions(copy)[:, root].mean(0), atol=0.05
    )


def test_path_walker_on_disguised_xia_walks_a_path_in_metres(disguised_folder, tmp_path, monkeypatch):
    import torch
    from tiny import WALKER

    from walkdiff.models.path_walker import PathWalker

    monkeypatch.setattr("sys.argv", ["walkdiff"])
    dm = MotionDataModule(
        dataset="folder", root=str(disguised_folder), contents="all", cache_dir=str(tmp_path / "cache"),
        batch_size=8, preprocess_workers=1,
    )  # fmt: skip
    torch.manual_seed(0)
    model = PathWalker(dm.spec, **WALKER)
    trainer = synthetic.quiet_trainer(max_steps=2)
    trainer.fit(model, dm)
    ckpt = tmp_path / "walker.ckpt"
    trainer.save_checkpoint(ckpt)
    path = tmp_path / "line.json"
    path.write_text(json.dumps({"points": [[0, 0], [2.0, 0]], "speed": 1.0}))  # 2 m at 1 m/s
    out = tmp_path / "out"
    assert main(["walk", "--ckpt", str(ckpt), "--style", "old", "--path", str(path), "--out", str(out)]) == 0
    manifest = json.loads((out / "old_line.json").read_text())
    assert manifest["frames"] == 61 and manifest["path_length_m"] == pytest.approx(2.0)
    motion = read_bvh(out / "old_line.bvh")
    assert motion.skeleton.names == read_bvh(next(disguised_folder.glob("*.bvh"))).skeleton.names


def test_a_skeleton_without_feet_or_sides_is_inspected_and_explained(tmp_path, capsys):
    """A rig with no foot names and no left/right pairs: inspect shows it, convert says what to name."""
    skeleton = synthetic.Skeleton(
        ["base", "link1", "link2", "tip"], [-1, 0, 1, 2], [[0, 0, 0], [0, 1, 0], [0, 1, 0], [0, 1, 0]],
        [disguise.ROOT_CHANNELS, ("Zrotation",), ("Zrotation",), ("Zrotation",)],
    )  # fmt: skip
    frames = 20
    rotations = np.repeat(np.eye(3)[None, None], frames, axis=0).repeat(4, axis=1)
    positions = np.repeat(skeleton.offsets[None], frames, axis=0)
    positions[:, 0, 0] = np.linspace(0, 1, frames)
    path = tmp_path / "robot.bvh"
    write_bvh(path, synthetic.Motion(skeleton, rotations, positions, 1 / 30))
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "feet:      none found" in out and "no feet found" in out and "mirroring" in out
    assert main(["convert", str(path), str(tmp_path / "out.bvh")]) == 1
    assert "name them in the profile (left_heel, left_toe, right_heel, right_toe)" in capsys.readouterr().err


def test_a_root_that_stays_while_the_body_walks_is_flagged(xia_dir):
    copy, _ = disguise.disguise(read_bvh(xia_dir / "neutral_01_000.bvh"), ("static_root",))
    assert not any("root does not move" in n for n in SkeletonProfile.detect(copy).notes)
    forced = SkeletonProfile.detect(copy, {"root": "Root"})  # configured on the static joint
    assert forced.root == "Root" and any("root does not move while the body does" in n for n in forced.notes)


def test_profile_overrides_are_checked_and_shown(xia_dir):
    from walkdiff.common.errors import WalkdiffError

    motion = read_bvh(xia_dir / "neutral_01_000.bvh")
    profile = SkeletonProfile.detect(motion, {"up": [0, 1, 0.2], "units": "cm", "contact_speed": 7})
    lines = "\n".join(profile.describe())
    assert "up (0.00, 0.98, 0.20) [config]" in lines and "units:     cm" in lines and "7 units/s" in lines
    for overrides, message in [
        ({"root": "Pelvis"}, "profile.root: joint 'Pelvis' not in the skeleton"),
        ({"up": "sideways"}, "profile.up: expected one of +x"),
        ({"units": -1}, "profile.units"),
        ({"feet": "LeftFoot"}, "profile: unknown field(s) feet"),
    ]:
        with pytest.raises(WalkdiffError, match=re.escape(message)):
            SkeletonProfile.detect(motion, overrides)
