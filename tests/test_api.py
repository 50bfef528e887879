"""The Python API: `walkdiff.load` and its three objects, the `Take`s they return, and every ```python
block of README.md and docs/*.md run as written."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import synthetic
import torch

import walkdiff
from walkdiff.cli.main import main
from walkdiff.data.speech import read_wav
from walkdiff.gestures.commands import gesture
from walkdiff.gestures.generator import GestureGenerator
from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.path import Polyline
from walkdiff.styled import commands
from walkdiff.styled.pipeline import StyledGenerator
from walkdiff.walker.commands import walk
from walkdiff.walker.follow import PathFollower

ROOT = Path(__file__).resolve().parents[1]
FAST = dict(sampler="ddim", steps=2)  # the machinery is the same for every sampler


# The tiny `styled`, `walker` and `gestures` checkpoints are conftest.py's (tests/test_same_outputs.py
# runs the commands on them too).


def test_import_walkdiff_alone_imports_no_torch():
    code = (
        "import sys, walkdiff, walkdiff.common.errors\n"
        "assert issubclass(walkdiff.WalkdiffError, Exception) and 'load' in dir(walkdiff)\n"
        "assert 'torch' not in sys.modules, 'torch imported'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_styled_sample_returns_takes_on_the_file_skeleton_and_writes_nothing(styled, empty_folder):
    model = walkdiff.load(styled)
    assert isinstance(model, StyledGenerator) and model.fps == 30.0
    assert model.styles[:2] == ("angry", "childlike") and "walk" in model.contents
    takes = model.sample("angry:0.7,old:0.3", num=2, frames=40, seed=5, **FAST)
    assert [type(t) for t in takes] == [walkdiff.Take] * 2
    for take in takes:
        assert take.num_frames == 40 and take.fps == pytest.approx(30.0)
        assert take.skeleton.same_hierarchy(model.skeleton) and take.skeleton.num_joints == 13
        assert take.positions.shape == (40, 13, 3) and np.isfinite(take.positions).all()
    assert not np.allclose(takes[0].positions, takes[1].positions)
    assert repr(takes[0]) == "Take(40 frames at 30 fps, 13 joints)"
    assert not list(empty_folder.iterdir()), "nothing written unasked"


def test_styled_sample_is_the_sample_commands_bvh(styled, tmp_path):
    out = tmp_path / "command"
    options = dict(style="angry:0.7,old:0.3", num=2, frames=40, seed=5, fix_feet=True, **FAST)
    manifest = commands.sample(styled, out, gif=False, **options)
    takes = walkdiff.load(styled).sample(**options)
    for name, take in zip(manifest["files"], takes, strict=True):
        assert take.to_bvh(tmp_path / name).read_text() == (out / name).read_text()


def test_transfer_takes_a_file_a_motion_or_a_take_and_is_the_commands_bvh(styled, tmp_path, empty_folder):
    source = tmp_path / "mine.bvh"
    write_bvh(source, synthetic.walking(200, fps=120.0, seed=3))
    model = walkdiff.load(styled)
    options = dict(style="old", keep_trajectory=True, seed=2, sampler="dpmpp", steps=4)
    from_file = model.transfer(source, **options)
    assert from_file.num_frames == 50 and from_file.fps == pytest.approx(30.0)  # 200 frames at 120 fps
    assert not list(empty_folder.iterdir()), "nothing written unasked"
    motion = walkdiff.read_bvh(source)
    for same in (motion, walkdiff.Take(motion, model.model.profile)):
        np.testing.assert_array_equal(model.transfer(same, **options).positions, from_file.positions)
    report = commands.transfer(styled, source, tmp_path / "command", gif=False, **options)
    written = tmp_path / "command" / report["file"]
    assert from_file.to_bvh(tmp_path / "api.bvh").read_text() == written.read_text()


def test_requests_speak_python_and_give_the_commands_clips(styled, tmp_path):
    """A mix as a dict or weighted list, a timeline as (seconds, style) keys, the sampler as one spec, the
    rig with its map: the same clips as the command line's text; the result carries its settings."""
    model = walkdiff.load(styled).to("cpu")
    assert {"StyledGenerator", "PathFollower", "GestureGenerator", "Style", "SamplerChoice"} <= set(
        dir(walkdiff)
    )
    as_text = model.sample("angry:0.7,old:0.3", num=2, frames=40, seed=5, **FAST)
    fast = walkdiff.SamplerChoice("ddim", 2)
    for style in (
        {"angry": 0.7, "old": 0.3},
        [("angry", 0.7), ("old", 0.3)],
        walkdiff.Style({"angry": 0.7, "old": 0.3}),
    ):
        result = model.sample(style=style, num=2, frames=40, seed=5, sampler=fast)
        for a, b in zip(result, as_text, strict=True):
            np.testing.assert_array_equal(a.positions, b.positions)
    assert result.settings["style"] == "angry:0.7,old:0.3" and result.settings["sampler"] == "ddim"
    assert result.label == "angry70+old30" and set(result.timing) >= {"generate_s"}
    timeline = model.sample(
        [(0, "neutral"), (1, {"old": 1})], frames=60, seed=1, sampler={"name": "ddim", "steps": 2}
    )
    same = model.sample("neutral@0,old:1@1", frames=60, seed=1, **FAST)
    np.testing.assert_array_equal(timeline.take.positions, same.take.positions)
    with pytest.raises(walkdiff.WalkdiffError, match="^style: expected a name"):
        model.sample(42)
    with pytest.raises(walkdiff.WalkdiffError, match="^guidance must be a number"):
        model.sample("old", guidance=1e30)
    with pytest.raises(walkdiff.WalkdiffError, match="^to_map needs to"):
        model.sample("old", to_map={"head": "Head"})


def test_to_bvh_and_to_glb_round_trip_and_refuse_to_overwrite(styled, tmp_path):
    take = walkdiff.load(styled).sample("old", frames=30, **FAST)[0]
    path = take.to_bvh(tmp_path / "clip.bvh")
    back = walkdiff.read_bvh(path)
    assert isinstance(back, walkdiff.Motion) and back.skeleton.same_hierarchy(take.skeleton)
    np.testing.assert_allclose(motion_world_positions(back), take.positions, atol=1e-4)
    glb = take.to_glb(tmp_path / "clip.glb")
    document = pygltflib.GLTF2().load(str(glb))
    assert len(document.animations) == 1 and len(document.nodes) > take.skeleton.num_joints
    for write, target in ((take.to_bvh, path), (take.to_glb, glb)):
        before = target.read_bytes()
        with pytest.raises(
            walkdiff.WalkdiffError, match="would overwrite .*; pass overwrite=True to replace"
        ):
            write(target)
        assert target.read_bytes() == before
        assert write(target, overwrite=True) == target
    in_metres = take.positions * take.metres_per_unit
    assert 0.5 < np.ptp(in_metres[0, :, 1]) < 2.5, "a body about a metre or two tall"


def test_wrong_checkpoints_styles_and_inputs_are_walkdiff_errors(styled, tmp_path):
    evaluator = tmp_path / "evaluator.ckpt"
    checkpoint = torch.load(styled, map_location="cpu", weights_only=False)
    checkpoint["model_class"] = "walkdiff.models.evaluator.MotionEvaluator"
    torch.save(checkpoint, evaluator)
    with pytest.raises(walkdiff.WalkdiffError) as error:
        walkdiff.load(evaluator)
    assert str(error.value) == (
        f"{evaluator}: this is a MotionEvaluator (style + content classifier) checkpoint; walkdiff.load "
        "takes a StyledMotionDiffusion (walking generator), a PathWalker (walking along a path) or a "
        "DiffMotion (speech-driven gestures) checkpoint"
    )
    with pytest.raises(walkdiff.WalkdiffError, match="missing.ckpt: model checkpoint not found"):
        walkdiff.load(tmp_path / "missing.ckpt")
    model = walkdiff.load(styled)
    with pytest.raises(
        walkdiff.WalkdiffError, match="unknown style happy; valid: angry, childlike, depressed"
    ):
        model.sample("happy")
    with pytest.raises(walkdiff.WalkdiffError, match="weights > 0"):
        model.sample("angry:-1,old:2")
    with pytest.raises(walkdiff.WalkdiffError, match="unknown content dance; valid: walk"):
        model.sample("old", content="dance")
    with pytest.raises(
        walkdiff.WalkdiffError, match="^num must be at least 1, got 0"
    ):  # no flags from Python
        model.sample("old", num=0)
    with pytest.raises(walkdiff.WalkdiffError, match="^strength must be in \\(0, 1\\], got 1.5"):
        model.transfer(synthetic.walking(40), "old", strength=1.5)
    with pytest.raises(
        walkdiff.WalkdiffError, match="expected a Motion, a Take or the path of a BVH file, got int"
    ):
        model.transfer(42, "old")
    other = synthetic.skeleton()
    other.names[other.names.index("Head")] = "Skull"
    clip = synthetic.walking(40)
    with pytest.raises(walkdiff.WalkdiffError, match="another skeleton .* missing Head; extra Skull"):
        model.transfer(walkdiff.Motion(other, clip.rotations, clip.positions, clip.frame_time), "old")


def test_follow_walks_points_a_polyline_or_a_file_as_the_walk_command(walker, tmp_path, empty_folder):
    follower = walkdiff.load(walker)
    assert isinstance(follower, PathFollower) and "old" in follower.styles and follower.fps == 30.0
    points = [[0, 0], [0, 12], [12, 12]]
    take = follower.follow(points, style="old", speed=12.0, seed=1)
    assert take.num_frames == 61 and take.fps == pytest.approx(30.0)  # 24 m at 12 m/s, 30 fps, both ends
    assert take.skeleton.same_hierarchy(follower.skeleton)
    np.testing.assert_allclose(take.motion.root_positions[0, [0, 2]], [0, 0], atol=1e-4)
    assert not list(empty_folder.iterdir()), "nothing written unasked"
    for same in (np.array(points, dtype=float), Polyline.of(points)):
        np.testing.assert_array_equal(
            follower.follow(same, "old", speed=12.0, seed=1).positions, take.positions
        )
    path = tmp_path / "corner.json"
    path.write_text(json.dumps({"points": points, "speed": 12.0}))
    manifest = walk(walker, "old", str(path), str(tmp_path / "out"), seed=1, gif=False)
    from_file = follower.follow(path, "old", seed=1)
    assert from_file.to_bvh(tmp_path / "api.bvh").read_text() == Path(manifest["files"][0]).read_text()
    with pytest.raises(walkdiff.WalkdiffError, match=r"points\[1\] must be a pair of finite numbers"):
        follower.follow([[0, 0], [1, float("nan")]], "old")
    with pytest.raises(walkdiff.WalkdiffError, match="unknown style 'sleepy'; valid: angry, childlike"):
        follower.follow(points, "sleepy")
    with pytest.raises(walkdiff.WalkdiffError, match="no walking speed for a style; give speed"):
        follower.follow(points, "proud")  # no proud walks in the synthetic data


def test_gesture_of_a_wav_or_its_samples_is_the_gesture_commands_bvh(gestures, tmp_path, empty_folder):
    ckpt, takes = gestures
    model = walkdiff.load(ckpt)
    assert isinstance(model, GestureGenerator) and model.fps == 20.0
    clips = model.gesture(takes / "b.wav", seed=4, num=2, smooth=True)
    assert len(clips) == 2 and not list(empty_folder.iterdir()), "nothing written unasked"
    for clip in clips:
        assert clip.num_frames == 161 and clip.fps == pytest.approx(20.0)  # 8 s at 20 fps, both ends
        assert clip.skeleton.num_joints == 13 and clip.skeleton.same_hierarchy(model.skeleton)
    samples, rate = read_wav(takes / "b.wav")
    stereo = np.stack([samples, samples], axis=1)
    for given in (samples, stereo):
        again = model.gesture(given, seed=4, num=2, smooth=True, rate=rate)
        np.testing.assert_allclose(again[1].positions, clips[1].positions, atol=1e-5)
    report = gesture(str(ckpt), str(takes / "b.wav"), str(tmp_path / "out"), seed=4, smooth=True, num=2,
                     preview_seconds=1.0)  # fmt: skip
    for clip, written in zip(clips, report["files"][:2], strict=True):
        assert clip.to_bvh(tmp_path / Path(written).name).read_text() == Path(written).read_text()
    with pytest.raises(walkdiff.WalkdiffError, match="rate is for samples given as an array"):
        model.gesture(takes / "b.wav", rate=16000)
    with pytest.raises(walkdiff.WalkdiffError, match="need their rate in whole Hz > 0, got None"):
        model.gesture(samples)
    with pytest.raises(walkdiff.WalkdiffError, match="num must be a whole number >= 1, got 0"):
        model.gesture(samples, rate=rate, num=0)
    with pytest.warns(DeprecationWarning, match="samples= is deprecated; use num="):
        old = model.gesture(samples, rate=rate, samples=2, seed=4, smooth=True)
    np.testing.assert_allclose(old[1].positions, clips[1].positions, atol=1e-5)


def test_a_model_without_arms_cannot_be_retargeted_is_refused(styled, gestures, tmp_path, capsys):
    """A model whose skeleton has no arms (the synthetic one) cannot be put on a humanoid rig: the error
    names what is missing, and nothing is written. Streams refuse --to and say how to retarget after."""
    with pytest.raises(walkdiff.WalkdiffError, match=r"the source \(the clip's skeleton\) is not a humanoid "
                       r"rig: no arms \(left_upper_arm"):  # fmt: skip
        walkdiff.load(styled).sample("old", frames=30, to="smpl", **FAST)
    out = tmp_path / "none"
    argv = ["sample", "--ckpt", str(styled), "--style", "old", "--out", str(out), "--num", "1",
            "--frames", "30", "--sampler", "ddim", "--steps", "2", "--to", "smpl"]  # fmt: skip
    assert main(argv) == 1
    assert "no arms" in capsys.readouterr().err and not out.exists()
    ckpt, takes = gestures
    with pytest.raises(walkdiff.WalkdiffError, match="no arms"):
        walkdiff.load(ckpt).gesture(takes / "b.wav", to="mixamo")
    argv = ["gesture", "--ckpt", str(ckpt), "--audio", "-", "--out", str(out), "--stream", "--to", "smpl"]
    assert main(argv) == 1
    assert "--to does not work with --stream" in capsys.readouterr().err


# ---------------------------------------------------------------- the documentation's examples


def python_blocks() -> list:
    """Every ```python block of README.md and docs/*.md: (its file, its code at its own line numbers, so
    that a traceback points into the file), named by file and first line."""
    blocks = []
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        lines, start = doc.read_text().splitlines(), None
        for number, line in enumerate(lines, 1):
            if start is None and line.strip() == "```python":
                start = number
            elif start is not None and line.strip() == "```":
                code = "\n" * start + textwrap.dedent("\n".join(lines[start : number - 1]))
                name = str(doc.relative_to(ROOT))
                blocks.append(pytest.param(name, code, id=f"{name}:{start + 1}"))
                start = None
    return blocks


@pytest.fixture(scope="module")
def documented_files(xia_dir, xia_tiny, walker, gestures) -> dict[str, Path]:
    """What the examples name, by the name they use: the tiny generator of real Xia walks (so that it takes
    a real Xia clip), the tiny walker and gesture model, a Xia walk, speech."""
    return {
        "checkpoints/xia_cpu/best.ckpt": xia_tiny["generator"],
        "checkpoints/xia_style_codes/best.ckpt": xia_tiny["style_codes"],
        "checkpoints/walk_xia/last.ckpt": walker,
        "checkpoints/diffmotion_zeggs/last.ckpt": gestures[0],
        "my_walk.bvh": xia_dir / "neutral_01_000.bvh",
        "speech.wav": gestures[1] / "b.wav",
    }


@pytest.mark.parametrize(("doc", "code"), python_blocks())
def test_documented_python_runs_as_written(doc, code, documented_files, empty_folder, monkeypatch):
    """Run in a folder holding what it names; whatever it writes is what it asked a Take to write, and
    reads back."""
    for name, source in documented_files.items():
        (empty_folder / name).parent.mkdir(parents=True, exist_ok=True)
        (empty_folder / name).symlink_to(source)
    asked = {}
    for method in ("to_bvh", "to_glb"):
        write = getattr(walkdiff.Take, method)

        def record(take, path, overwrite=False, write=write):
            written = write(take, path, overwrite)
            asked[written.resolve()] = take
            return written

        monkeypatch.setattr(walkdiff.Take, method, record)
    exec(compile(code, doc, "exec"), {"__name__": "__main__"})
    written = {p.resolve() for p in empty_folder.rglob("*") if p.is_file() and not p.is_symlink()}
    assert written == set(asked)
    for path, take in asked.items():
        if path.suffix == ".bvh":
            back = walkdiff.read_bvh(path)
            assert back.num_frames == take.num_frames and back.skeleton.same_hierarchy(take.skeleton)
        else:
            assert len(pygltflib.GLTF2().load(str(path)).animations) == 1


def pickled_globals(ckpt: Path) -> set[str]:
    """The classes and functions a checkpoint's pickle would import when loaded."""
    import pickletools
    import zipfile

    with zipfile.ZipFile(ckpt) as archive:
        data = archive.read(next(n for n in archive.namelist() if n.endswith("data.pkl")))
    found, strings = set(), []
    for op, arg, _ in pickletools.genops(data):
        if op.name == "GLOBAL":
            found.add(arg.replace(" ", "."))
        elif op.name == "STACK_GLOBAL":
            found.add(".".join(strings[-2:]))
        if isinstance(arg, str):
            strings.append(arg)
    return found


def test_checkpoints_name_their_model_by_a_path_that_stays_importable(styled, walker, gestures):
    """Moving modules must not break checkpoints users already have: a checkpoint pickles no walkdiff
    object (only tensors and plain data), and the model class it records by name still imports."""
    import importlib

    from walkdiff.common.checkpoints import KINDS, checkpoint_class

    for ckpt in (styled, walker, gestures[0]):
        assert not {name for name in pickled_globals(ckpt) if name.startswith("walkdiff")}, ckpt
        recorded = checkpoint_class(ckpt)
        assert recorded in KINDS
    for class_path in KINDS:
        module, name = class_path.rsplit(".", 1)
        assert isinstance(getattr(importlib.import_module(module), name), type), class_path


def test_streams_from_python_make_what_the_whole_input_makes(walker, gestures):
    """`PathFollower.stream` and `GestureGenerator.stream`, fed piece by piece, hand over every frame once,
    in order, and end with what `follow` and `gesture` make of the whole input (the stream commands are
    written on them)."""
    follower = walkdiff.load(walker)
    points = [[0, 0], [0, 6], [3, 9], [6, 9]]
    whole = follower.follow(points, "old", speed=12.0, seed=1)
    live, lines = follower.stream("old", speed=12.0, seed=1), []
    for point in points:
        live.feed([point])
        live.run()
        lines += live.frames()
    live.close()
    live.run()
    lines += live.frames()
    assert [line["frame"] for line in lines] == list(range(whole.num_frames))
    np.testing.assert_array_equal(live.take().positions, whole.positions)
    np.testing.assert_allclose([line["root"] for line in lines], whole.positions[:, 0], atol=1e-3)
    with pytest.raises(walkdiff.WalkdiffError, match="a timeline .* is not for"):
        follower.stream("neutral@0,old@1", speed=12.0)

    ckpt, takes = gestures
    model = walkdiff.load(ckpt)
    samples, rate = read_wav(takes / "b.wav")
    clips = model.gesture(samples, rate=rate, num=2, seed=4, smooth=True)
    speech, made = model.stream(rate, num=2, seed=4, smooth=True), []
    for piece in np.array_split(samples, 7):
        speech.feed(piece)
        speech.run()
        made += speech.frames()
    speech.close()
    speech.run()
    made += speech.frames()
    assert speech.header()["streams"] == 2 and len(made) == 2 * clips[0].num_frames
    for k in range(2):
        assert [line["frame"] for line in made if line["stream"] == k] == list(range(clips[k].num_frames))
        np.testing.assert_allclose(speech.takes()[k].positions, clips[k].positions, atol=1e-4)
    with pytest.raises(walkdiff.WalkdiffError, match="--to does not work with a stream|to does not work"):
        model.stream(rate, to="mixamo")


def test_old_spellings_of_the_count_still_work_and_warn(capsys):
    from walkdiff.cli.main import build_parser

    args = build_parser().parse_args(
        ["gesture", "--ckpt", "g", "--audio", "a", "--out", "o", "--streams", "3"]
    )
    assert args.num == 3 and "--streams is deprecated; use --num" in capsys.readouterr().err
