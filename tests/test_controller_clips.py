"""A steered walker that takes its posture and swing from example clips (issues 30 and 31): at the start,
switched live and ramped like a style, through the API, `walkdiff control` lines and `walkdiff play`.

The tiny walker (4 training steps, real Xia) is not a good walker; what is checked here is that the
clips' statistics reach every frame, ramp as commanded, fork with the walker and are recorded."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from test_controller import lines_in, script

from walkdiff.cli.main import main
from walkdiff.common.errors import WalkdiffError
from walkdiff.live.keys import KeyControl
from walkdiff.live.page import open_page
from walkdiff.models.style_examples import clip_statistics
from walkdiff.motion.representation import FeatureLayout
from walkdiff.walker.controller import controller
from walkdiff.walker.follow import load_walker

FAST = dict(sampler="ddim", steps=2, foot_lock=False)


@pytest.fixture(scope="module")
def walker_ckpt(xia_tiny):
    return xia_tiny["walker"]


@pytest.fixture(scope="module")
def clip(xia_dir):
    return str(xia_dir / "old_02_000.bvh")


def pose_distance(walker, target) -> float:
    """How far the mean pose of the walker's kept frames (after the first 20) is from the clips'."""
    model = walker.model
    frames = torch.from_numpy(np.stack([raw[0] for _, raw, _, _ in walker.kept[20:]]))
    pose = FeatureLayout(model.skeleton.num_joints).rotations
    return float((model.normalizer.normalize(frames).mean(0) - target.mean)[pose].norm())


def test_a_controller_takes_on_example_clips_from_the_start(walker_ckpt, clip):
    model = load_walker(walker_ckpt)
    target = clip_statistics(model, clip)
    plain = controller(model, "neutral", seed=3, **FAST)
    matched = controller(model, "neutral", seed=3, style_clips=clip, **FAST)
    for _ in range(50):
        plain.step(0, 1.0)
        matched.step(0, 1.0)
    assert pose_distance(matched, target) < 0.5 * pose_distance(plain, target)
    assert matched.commanded()["style_clips"] == [{"clip": clip, "weight": 1.0}]
    assert "style_clips" not in plain.commanded() and plain.guide is None  # no clips: nothing added


def test_clips_switched_live_ramp_in_and_out_and_fork(walker_ckpt, clip):
    model = load_walker(walker_ckpt)
    walker = controller(model, "neutral", seed=1, transition=0.1, **FAST)  # 3 frames at 30 fps
    walker.step()
    walker.command(style_clips=f"{clip}:2")
    strengths = []
    for _ in range(4):
        walker.step()
        strengths.append(float(walker.guide.target.strength[0]))
    assert strengths == pytest.approx([7 / 27, 20 / 27, 1, 1])  # smoothstep at 1/3 and 2/3
    assert walker.commanded()["style_clips"] == [{"clip": clip, "weight": 2.0}]
    target = clip_statistics(model, clip)
    torch.testing.assert_close(walker.guide.target.mean[0], target.mean)  # it ramps strength, not where to

    twin = walker.fork()
    walker.command(style_clips="")
    twin.command(style_clips="")
    strengths = []
    for _ in range(4):
        np.testing.assert_array_equal(walker.step(30, 1.0).rotations, twin.step(30, 1.0).rotations)
        strengths.append(float(walker.guide.target.strength[0]))
    assert strengths == pytest.approx([20 / 27, 7 / 27, 0, 0]) and "style_clips" not in walker.commanded()
    twin.step()  # the fork's running statistics are its own
    assert not torch.equal(twin.guide.mean, walker.guide.mean)


def test_control_lines_and_play_take_clips_and_record_them(walker_ckpt, clip, tmp_path, monkeypatch, capsys):
    lines_in(
        monkeypatch, [{"frames": 2}, {"style_clips": clip, "frames": 2}, {"style_clips": "", "frames": 1}]
    )
    out = tmp_path / "live"
    argv = ["control", "--ckpt", str(walker_ckpt), "--style", "old", "--steps", "2", "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    log = json.loads((out / "take.json").read_text())["commands"]
    clips = [entry["commands"][0].get("style_clips") for entry in log]
    record = [{"clip": clip, "weight": 1.0}]
    assert clips == [None, None, record, record, None]

    lines_in(monkeypatch, [{"frames": 1}, {"style_clips": str(tmp_path / "missing.bvh")}])
    assert main([*argv[:-1], str(tmp_path / "bad")]) == 1
    err = capsys.readouterr().err
    assert "-:2:" in err and "missing.bvh" in err, err

    played = tmp_path / "played"
    events = [{"t": 0, "direction": 0}, {"t": 0.2, "key": "c"}, {"t": 0.3}]  # C turns the clip off
    steps = script(tmp_path / "s.jsonl", events)
    argv = ["play", "--ckpt", str(walker_ckpt), "--steps", "2", "--style-clip", f"{clip}:0.5",
            "--match-clips", "0.7", "--script", steps, "--out", str(played)]  # fmt: skip
    assert main(argv) == 0
    manifest = json.loads((played / "take.json").read_text())
    assert manifest["style_clips"] == [{"clip": clip, "weight": 0.5}] and manifest["match_clips"] == 0.7
    assert manifest["commands"][0]["style_clips"] and "style_clips" not in manifest["commands"][-1]


def test_the_c_key_turns_the_start_clips_off_and_on_on_the_page(walker_ckpt, clip):
    keys = KeyControl(["neutral", "old"], lambda s: 1.0, "neutral", clips="a.bvh")
    keys.key("C")
    assert keys.state()["style_clips"] == ""
    keys.key("c", down=False)  # a release changes nothing
    keys.key("c")
    assert keys.state()["style_clips"] == "a.bvh"
    with pytest.raises(WalkdiffError, match="key c: no example clips to turn on: start with --style-clip"):
        KeyControl(["neutral"], lambda s: 1.0, "neutral").key("c")

    page = open_page(str(walker_ckpt), style="neutral", style_clips=clip, sampler="ddim", steps=2)
    assert json.loads(page.hello)["clips"] == [clip]
    page.step()
    assert page.walker.commanded()["style_clips"] == [{"clip": clip, "weight": 1.0}]
    page.receive('{"type": "key", "key": "c"}')
    page.step()
    assert "style_clips" not in page.walker.commanded()
    page.receive('{"type": "key", "key": "c"}')
    page.step()
    assert page.walker.commanded()["style_clips"] and set(page.walker.clip_cache) == {clip, ""}  # read once
