"""`--to RIG` wherever motion is written (sample, transfer, walk, gesture, convert, view) and `to=` in the
Python API: the files are on the rig's own skeleton, the API's takes are the commands' files byte for byte,
the manifests say which rig, and what cannot be retargeted is refused naming why."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import walkdiff
from walkdiff.cli.main import main
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.rigs import RIGS, SPECS, rig
from walkdiff.preview.view import load_clips
from walkdiff.styled import commands
from walkdiff.walker.commands import walk

FAST = dict(sampler="ddim", steps=2)


@pytest.fixture(scope="module")
def my_rig(tmp_path_factory) -> Path:
    """A user's rig as a BVH: the built-in Unreal-like rig (Z up, cm, a static root) written out."""
    path = tmp_path_factory.mktemp("rig") / "my_rig.bvh"
    write_bvh(path, rig("unreal"))
    return path


def standing(motion: walkdiff.Motion, name: str) -> bool:
    """Feet on the rig's floor: the lowest joint's median height within 5% of its stature."""
    up = "xyz".index(SPECS[name].up[1])
    heights = motion_world_positions(motion)[..., up]
    stature = motion_world_positions(rig(name))[0, :, up].max()
    return abs(np.median(heights.min(axis=1))) < 0.05 * stature


def travelled(take: walkdiff.Take) -> float:
    """Metres along the ground the root travels."""
    root = take.canonical().root_positions[:, [0, 2]] * take.metres_per_unit
    return float(np.linalg.norm(np.diff(root, axis=0), axis=1).sum())


def test_sample_to_a_built_in_rig_is_the_commands_bvh(xia_tiny, tmp_path, empty_folder):
    model = walkdiff.load(xia_tiny["generator"])
    target = walkdiff.TargetRig("mixamo")
    takes = model.sample("old", num=2, frames=40, seed=1, to=target, **FAST)
    names = rig("mixamo").skeleton.names
    for take in takes:
        assert take.skeleton.names == names and take.num_frames == 40 and standing(take.motion, "mixamo")
    assert len(target.record()["leg_ratio"]) == 1, "one preparation for both takes"
    assert not list(empty_folder.iterdir()), "nothing written unasked"
    out = tmp_path / "sampled"
    manifest = commands.sample(xia_tiny["generator"], out, "old", num=2, frames=40, seed=1, to="mixamo",
                               preview_seconds=0.5, **FAST)  # fmt: skip
    assert manifest["retarget"]["target"] == "built-in rig mixamo"
    assert manifest["retarget"]["leg_ratio"][0] > 1  # Xia's units are 5.6 cm, Mixamo's 1 cm
    for name, take in zip(manifest["files"], takes, strict=True):
        assert take.to_bvh(tmp_path / name).read_text() == (out / name).read_text()
        assert (out / name).with_suffix(".gif").stat().st_size > 0


def test_transfer_onto_a_users_rig_file(xia_tiny, xia_dir, my_rig, tmp_path, capsys):
    """The command and the API agree; the preview shows the source on the rig too; the rig's static root
    is named as left in its reference pose."""
    source = xia_dir / "neutral_01_000.bvh"
    out = tmp_path / "transfer"
    argv = ["transfer", "--ckpt", str(xia_tiny["generator"]), "--input", str(source), "--style", "old",
            "--out", str(out), "--to", str(my_rig), "--sampler", "ddim", "--steps", "2",
            "--preview-seconds", "0.5"]  # fmt: skip
    assert main(argv) == 0
    report = json.loads((out / "neutral_01_000_to_old.json").read_text())
    assert report["retarget"]["target"] == str(my_rig) and report["retarget"]["rest_joints"] == ["root"]
    written = read_bvh(out / report["file"])
    assert written.skeleton.names == rig("unreal").skeleton.names and standing(written, "unreal")
    api = walkdiff.load(xia_tiny["generator"]).transfer(source, "old", to=my_rig, **FAST)
    assert api.to_bvh(tmp_path / "api.bvh").read_text() == (out / report["file"]).read_text()
    assert (out / "neutral_01_000_to_old.gif").exists()
    assert main(argv[:-4] + ["--to", "maya"]) == 1
    assert (
        "--to: expected a BVH file of your rig or a built-in rig (mixamo, unreal, smpl)"
        in capsys.readouterr().err
    )


def test_walk_to_a_rig_scales_the_path_by_the_legs(xia_tiny, tmp_path):
    """The walk on SMPL (metres) travels the model's path times the legs' ratio in metres: the plot and
    the manifest say so, and the API's take is the command's BVH."""
    path = tmp_path / "line.json"
    path.write_text(json.dumps({"points": [[0, 0], [0.6, 0]], "speed": 1.2}))
    manifest = walk(str(xia_tiny["walker"]), "old", str(path), str(tmp_path / "out"), seed=1, to="smpl",
                    gif=False, **FAST)  # fmt: skip
    assert manifest["retarget"]["target"] == "built-in rig smpl"
    assert len(manifest["retarget"]["leg_ratio"]) == 1  # one preparation: the model's skeleton onto smpl
    written = read_bvh(manifest["files"][0])
    assert written.skeleton.names == rig("smpl").skeleton.names and standing(written, "smpl")
    follower = walkdiff.load(xia_tiny["walker"])
    take = follower.follow(path, "old", seed=1, to="smpl", **FAST)
    assert take.to_bvh(tmp_path / "api.bvh").read_text() == Path(manifest["files"][0]).read_text()
    own = follower.follow(path, "old", seed=1, **FAST)
    ratio = walkdiff.TargetRig("smpl").retargeter(own.motion, own.profile).metric_leg_ratio
    assert travelled(take) == pytest.approx(travelled(own) * ratio, rel=0.01)
    assert manifest["retarget"]["leg_ratio"][0] == pytest.approx(ratio * own.metres_per_unit, rel=1e-4)
    assert any(f.endswith("_path.png") for f in manifest["files"])


def test_convert_to_a_rig(xia_dir, my_rig, tmp_path, capsys):
    source = xia_dir / "neutral_01_000.bvh"
    frames = read_bvh(source).num_frames
    out = tmp_path / "smpl.bvh"
    assert main(["convert", str(source), str(out), "--to", "smpl", "--fps", "30"]) == 0
    assert "on built-in rig smpl (24 joints)" in capsys.readouterr().out
    written = read_bvh(out)
    assert written.fps == pytest.approx(30.0) and written.num_frames == pytest.approx(frames / 4, abs=1)
    assert standing(written, "smpl")
    glb = tmp_path / "mine.glb"
    assert main(["convert", str(source), str(glb), "--to", str(my_rig), "--mirror"]) == 0
    assert glb.read_bytes()[:4] == b"glTF"
    assert main(["convert", str(tmp_path / "missing.bvh"), str(tmp_path / "x.bvh"), "--to", "maya"]) == 1
    assert "--to: expected a BVH file of your rig" in capsys.readouterr().err  # said before the input


def test_view_shows_each_clip_beside_its_retargeted_copy(xia_dir):
    clips = load_clips(xia_dir / "proud_01_000.bvh", rig=walkdiff.TargetRig("smpl"))
    assert [c.name for c in clips] == ["proud_01_000", "proud_01_000 on built-in rig smpl"]
    heights = [np.ptp(c.positions[0, :, 1]) for c in clips]  # metres, Y up in the viewer
    assert 1.3 < heights[1] < 2.0 and heights[1] == pytest.approx(heights[0], rel=0.25)
    assert sorted(RIGS) == sorted(("mixamo", "unreal", "smpl"))


def test_play_script_and_control_write_their_take_on_the_rig(xia_tiny, tmp_path, capsys, monkeypatch):
    """--to on the live walker's commands: the take written at the end is on the rig; the page and a
    control without --out refuse it, saying why."""
    import io

    script = tmp_path / "s.jsonl"
    script.write_text('{"t": 0, "key": "ArrowUp"}\n{"t": 0.5}\n')
    out = tmp_path / "play"
    walker = ["--ckpt", str(xia_tiny["walker"]), "--style", "old", "--steps", "2", "--to", "mixamo"]
    assert main(["play", *walker, "--script", str(script), "--out", str(out)]) == 0
    assert read_bvh(out / "take.bvh").skeleton.same_hierarchy(rig("mixamo").skeleton)
    assert json.loads((out / "take.json").read_text())["retarget"]["target"] == "built-in rig mixamo"
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(b'{"frames": 5}\n')))
    assert main(["control", *walker, "--out", str(tmp_path / "control")]) == 0
    assert read_bvh(tmp_path / "control" / "take.bvh").skeleton.same_hierarchy(rig("mixamo").skeleton)
    capsys.readouterr()
    assert (
        main(["control", *walker]) == 1
        and "--to plays the take written with --out" in capsys.readouterr().err
    )
    assert main(["play", *walker]) == 1 and "--to is for play --script" in capsys.readouterr().err
