"""Live control of a walker (issue 31): the controller and its control, keys, `walkdiff control` (JSON
lines), `walkdiff play --script` and `walkdiff bench play`.

The tiny walker (4 training steps) hardly listens to its control, so where a test asks whether the walker
goes where it is told, the tiny walker's network is replaced by an ideal follower (`ideal`): it steps
towards the control's first point ahead and turns towards its last, as a trained walker roughly does.
That checks everything the controller adds (the control it builds, the root it integrates, the commands
it keeps); the rest runs the tiny walker as it is. Nothing here says anything about motion quality.
"""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest
import torch
from test_evaluator import tiny_datamodule, tiny_trainer

import walkdiff
from walkdiff.cli.main import main
from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion import SamplerChoice
from walkdiff.live.keys import KeyControl
from walkdiff.models.evaluator import MotionEvaluator
from walkdiff.motion.bvh import read_bvh
from walkdiff.walker.controller import WalkController, command_control, controller
from walkdiff.walker.follow import load_walker

FAST = dict(sampler="ddim", steps=2)
TWO = SamplerChoice("ddim", 2, 1.0)


@pytest.fixture(autouse=True)
def one_thread(monkeypatch):
    monkeypatch.setattr("sys.argv", ["walkdiff"])
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def ckpt(xia_tiny):
    return xia_tiny["walker"]


@pytest.fixture
def ideal(ckpt):
    """The tiny walker with an ideal follower for a network: each frame it steps to the control's point one
    spacing ahead (divided by the frames to it) and turns a fifth of the way towards its last point."""
    model = load_walker(ckpt)
    mean = model.normalizer.mean.double()
    layout, spacing = model.layout, model.ahead[1]

    def encode_control(control, style):
        return control

    def advance(streams, control, generator, rows=None):
        points = control.double().reshape(len(control), -1, 2)
        raw = mean.repeat(len(control), 1)
        raw[:, layout.root_vel] = points[:, 1] / spacing
        raw[:, layout.heading_vel.start] = 0.2 * torch.atan2(points[:, -1, 0], points[:, -1, 1])
        return model.normalizer.normalize(raw.float())

    model.encode_control, model.advance = encode_control, advance
    return model


def walked(walker: WalkController, frames: int) -> np.ndarray:
    """Root (x, z) in metres before each of the next `frames` frames."""
    roots = []
    for _ in range(frames):
        roots.append(walker.position[0] * walker.unit)
        walker.advance()
    return np.array(roots)


# ---------------------------------------------------------------- the control


def test_the_control_runs_along_the_command_and_bends_into_turns():
    times = np.arange(0, 16, 3) / 30
    controls = command_control(
        np.zeros(4), np.radians([0, 90, 180, 90.0]), np.array([10, 10, 10, 0.0]), times, math.pi
    )
    straight, left, behind, halt = controls.reshape(4, -1, 2)
    np.testing.assert_allclose(straight, np.stack([np.zeros(6), 10 * times], -1), atol=1e-12)
    np.testing.assert_allclose(halt, 0)
    # A left turn starts straight ahead and bends left (+x) at 180 degrees/s: a quarter circle by 0.5 s.
    assert np.all(np.diff(left[:, 0]) > 0) and left[1, 0] < 0.2 * left[1, 1]
    np.testing.assert_allclose(left[-1], 10 / math.pi * np.array([1.0, 1.0]), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(np.diff(left, axis=0), axis=1).sum(), 5, rtol=0.01)
    # Straight behind turns left too, aimed at as a quarter turn: the points never lie behind the walker,
    # however fast the control bends (at 720 degrees/s, the default, a 90 degree turn is done in 1/8 s).
    np.testing.assert_allclose(behind, left, atol=1e-12)
    fast = command_control(np.zeros(3), np.radians([90, 180, -135.0]), np.full(3, 10.0), times, 4 * math.pi)
    quarter, around, back_right = fast.reshape(3, -1, 2)
    np.testing.assert_allclose(around, quarter, atol=1e-12)
    np.testing.assert_allclose(back_right, quarter * [-1, 1], atol=1e-12)
    assert np.all(fast.reshape(3, -1, 2)[..., 1] >= 0), "no point behind the walker"
    direct = command_control(np.zeros(1), np.radians([90.0]), np.array([10.0]), times, math.inf)
    np.testing.assert_allclose(direct.reshape(-1, 2), np.stack([10 * times, np.zeros(6)], -1), atol=1e-12)
    # The control is in the walker's frame: a walker facing +x told to go +x walks straight on.
    np.testing.assert_allclose(
        command_control(np.radians([90.0]), np.radians([90.0]), np.array([10.0]), times, math.pi),
        command_control(np.zeros(1), np.zeros(1), np.array([10.0]), times, math.pi),
        atol=1e-12,
    )


def test_an_ideal_follower_walks_along_turns_towards_and_stops_where_told(ideal):
    walker = WalkController(ideal, "old", speed=1.2, sampler=TWO)
    roots = walked_after(walker, dict(direction=(1, 1)), 90)
    travel = roots[-1] - roots[30]
    assert math.degrees(math.atan2(travel[0], travel[1])) == pytest.approx(45, abs=5)
    assert np.linalg.norm(travel) == pytest.approx(1.2 * 2, rel=0.15)

    walker = WalkController(ideal, "old", speed=1.2, sampler=TWO)
    walked_after(walker, dict(direction=0), 30)
    headings = []
    walker.command(direction=90)  # to +x: a left turn
    for _ in range(30):
        headings.append(walker.step().heading)
    assert np.all(np.diff(headings[:10]) > 0) and headings[-1] == pytest.approx(90, abs=10)

    walker.command(speed=0)
    stopped = walked(walker, 40)
    assert np.linalg.norm(stopped[-1] - stopped[10]) < 0.01
    walker.command(speed=1.0)  # and it walks again, the way it was told last
    again = walked(walker, 40)
    assert np.linalg.norm(again[-1] - again[10]) == pytest.approx(1.0, rel=0.15)


def test_the_heading_assist_turns_the_root_at_most_its_rate_and_never_when_standing(ideal):
    """A walker that never turns on its own is turned towards the command by the assist alone: at most
    `heading_assist` degrees a second, closing the error with time constant ASSIST_TIME, not at all with
    the assist off or while standing; the assist is counted."""
    from walkdiff.walker.controller import ASSIST_TIME

    layout, advance = ideal.layout, ideal.advance

    def straight_on(streams, control, generator, rows=None):  # the ideal follower without its own turn
        raw = ideal.normalizer.denormalize(advance(streams, control, generator, rows))
        raw[:, layout.heading_vel] = 0
        return ideal.normalizer.normalize(raw)

    ideal.advance = straight_on
    turned = {}
    for rate in (0.0, 30.0, 90.0):
        walker = WalkController(ideal, "old", speed=1.2, sampler=TWO, heading_assist=rate)
        walker.command(direction=90)
        headings = []
        for _ in range(30):
            walker.step()
            headings.append(math.degrees(walker.heading[0]))  # after the frame's turn
        turned[rate] = headings
        assert walker.assisted[0] == pytest.approx(math.radians(headings[-1]), rel=1e-9)
    assert turned[0.0] == [0.0] * 30
    np.testing.assert_allclose(np.diff([0.0, *turned[30.0]]), 1.0, atol=1e-9)  # 30 degrees/s at 30 fps
    steps = np.diff([0.0, *turned[90.0]])
    assert np.all(steps <= 3.0 + 1e-9) and steps[0] == pytest.approx(3.0)
    # Once within reach, the error closes by 1 / (ASSIST_TIME * fps) of itself a frame.
    error = 90 - np.array(turned[90.0])
    assert error[-1] == pytest.approx(error[-2] * (1 - 1 / (ASSIST_TIME * 30)), rel=1e-6)
    standing = WalkController(ideal, "old", speed=0.0, sampler=TWO, heading_assist=90.0)
    standing.command(direction=90)
    assert [standing.step().heading for _ in range(10)] == [0.0] * 10
    with pytest.raises(WalkdiffError, match="heading_assist"):
        WalkController(ideal, "old", sampler=TWO, heading_assist=-1.0)


def walked_after(walker: WalkController, command: dict, frames: int) -> np.ndarray:
    walker.command(**command)
    return walked(walker, frames)


# ---------------------------------------------------------------- the tiny walker as it is


def test_the_command_lines_turn_as_the_api_does():
    from walkdiff.cli.main import build_parser
    from walkdiff.walker.controller import HEADING_ASSIST, TRANSITION, TURN_RATE

    for command in (["control"], ["play"], ["bench", "play", "--evaluator", "e.ckpt", "--out", "o.json"]):
        args = build_parser().parse_args([*command, "--ckpt", "x.ckpt"])
        assert args.turn_rate == TURN_RATE and args.heading_assist == HEADING_ASSIST and args.foot_lock
        assert args.transition == TRANSITION
        assert not build_parser().parse_args([*command, "--ckpt", "x.ckpt", "--no-foot-lock"]).foot_lock


def test_the_api_steps_poses_and_takes(ckpt, tmp_path):
    follower = walkdiff.load(ckpt)
    walker = follower.controller(style="old", **FAST)
    assert walker.sampler.label(follower.model.diffusion) == "ddim-2-eta1"
    poses = [walker.step((0, 1), 1.1) for _ in range(20)] + [walker.step(90, 0.8, "neutral")]
    pose = poses[-1]
    joints = follower.skeleton.num_joints
    assert [p.frame for p in poses] == list(range(21)) and pose.character == 0
    assert pose.positions.shape == (joints, 3) and pose.rotations.shape == (joints, 4)
    assert np.linalg.norm(pose.rotations, axis=-1) == pytest.approx(1, abs=1e-6)
    assert 1.0 < np.ptp(poses[0].positions[:, 1]) < 2.2, "a body about 1-2 m tall, Y up, in metres"
    assert -180 < pose.heading <= 180 and walker.commanded() == {
        "direction": 90.0,
        "speed": 0.8,
        "style": "neutral",
    }
    take = walker.take()
    assert isinstance(take, walkdiff.Take) and take.num_frames == 21
    profile = follower.model.profile
    metres = take.positions @ profile.turn.T * take.metres_per_unit  # the poses' joints and units
    np.testing.assert_allclose(metres, [p.positions for p in poses], atol=1e-6)
    np.testing.assert_allclose(take.motion.positions[:, 0], [p.translation for p in poses], atol=1e-6)
    assert read_bvh(take.to_bvh(tmp_path / "t.bvh")).num_frames == 21
    walker.step(style="angry:0.5,old:0.5", speed=1.0)  # a style without a known speed, at a given speed
    own = follower.controller(style="old", **FAST)  # at the style's own speed, which angry has not
    with pytest.raises(WalkdiffError, match="style angry: the checkpoint has no walking speed"):
        own.step(style="angry")  # the tiny walker knows only neutral's and old's speeds
    assert own.commanded()["style"] == "old" and own.frame == 0, "a refused command changes nothing"
    with pytest.raises(WalkdiffError, match=r"direction: expected a non-zero \[x, z\]"):
        walker.step((0, 0))


def test_characters_are_batched_and_independent_of_each_others_commands(ckpt):
    model = load_walker(ckpt)

    def run(last_direction):
        walker = controller(
            model, "old", 1.0, seed=3, characters=3, **FAST, positions=[[0, 0], [2, 0], [4, 0]]
        )
        frames = []
        for _ in range(8):
            walker.command(direction=(0, 1), character=0)
            walker.command(direction=(1, 0), speed=0.5, style="neutral", character=1)
            walker.command(direction=last_direction, character=2)
            frames.append(walker.step())
        return walker, frames

    walker, a = run(0)
    _, b = run(180)
    assert len(a[0]) == 3 and [p.character for p in a[0]] == [0, 1, 2]
    for f in range(8):
        for k in (0, 1):  # the same seed and batch: untouched by character 2's commands
            np.testing.assert_array_equal(a[f][k].positions, b[f][k].positions)
        assert not np.allclose(a[f][2].rotations, b[f][2].rotations) or f == 0
    assert a[0][1].root[0] == pytest.approx(2, abs=0.1), "characters start where placed (metres)"
    assert walker.commanded(1) == {"direction": 90.0, "speed": 0.5, "style": "neutral"}
    assert [walker.take(k).num_frames for k in range(3)] == [8] * 3


def test_style_ramps_fork_and_recording(ckpt):
    model = load_walker(ckpt)
    walker = controller(model, "old", seed=1, transition=0.1, **FAST)  # 3 frames at 30 fps
    old, neutral = (model.spec["styles"].index(s) for s in ("old", "neutral"))
    walker.step()
    walker.command(style="neutral")
    shares = []
    for _ in range(4):
        walker.step()
        shares.append(float(walker.weights[0, neutral]))
    assert shares == pytest.approx([7 / 27, 20 / 27, 1, 1]) and float(walker.weights[0, old]) == 0  # eased
    assert walker.commanded()["speed"] == pytest.approx(walker.speed_of("neutral"), abs=1e-4)  # its own

    twin = walker.fork()
    for _ in range(5):
        np.testing.assert_array_equal(walker.step(30, 1.0).rotations, twin.step(30, 1.0).rotations)
    walker.record = False
    walker.step()
    walker.record = True
    walker.step()
    assert walker.recorded == [*range(10), 11] and walker.take().num_frames == 11


# ---------------------------------------------------------------- keys


def test_keys_steer_speed_style_and_recording():
    keys = KeyControl(
        ["angry", "neutral", "old"], lambda s: {"neutral": 1.2, "old": 0.9}.get(s, 0), "neutral"
    )
    keys.key("ArrowLeft", True)
    keys.tick(0.5)
    keys.key("ArrowLeft", False)
    keys.tick(1.0)
    assert keys.direction == pytest.approx(45)
    keys.key("D")
    keys.tick(1.0)
    assert keys.direction == pytest.approx(-45)
    keys.key("ArrowUp")
    keys.key("w")
    assert keys.speed == pytest.approx(1.6)
    for _ in range(20):
        keys.key("s")
    assert keys.speed == 0
    keys.key("3")
    keys.key("r")
    assert keys.state() == {
        "direction": -45.0,
        "speed": 0.0,
        "style": "old",
        "style_clips": None,
        "recording": False,
    }
    with pytest.raises(WalkdiffError, match="key 'q': expected ArrowLeft"):
        keys.key("q")
    with pytest.raises(WalkdiffError, match="key 9: the model has 3 styles"):
        keys.key("9")


# ---------------------------------------------------------------- walkdiff control


def lines_in(monkeypatch, lines: list) -> None:
    text = "".join((line if isinstance(line, str) else json.dumps(line)) + "\n" for line in lines)
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(text.encode())))


def test_control_json_lines_round_trip(ckpt, tmp_path, monkeypatch, capsys):
    commands = [{"direction": [1, 0], "speed": 1.0}, {"frames": 3}, "", {"style": "neutral", "frames": 2},
                {"record": False}, {"speed": 0, "frames": 0}, {"frames": 1}]  # fmt: skip
    lines_in(monkeypatch, commands)
    out = tmp_path / "live"
    argv = ["control", "--ckpt", str(ckpt), "--style", "old", "--steps", "2", "--out", str(out)]
    assert main(argv) == 0
    printed = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    header, frames, summary = printed[0], printed[1:-1], printed[-1]
    assert header["fps"] == 30 and header["styles"][4] == "old" and len(header["joints"]) == 31
    assert [f["frame"] for f in frames] == list(range(8)) and summary["done"]
    assert summary["frames"] == 8 and summary["recorded_frames"] == 6
    assert {"root", "heading", "positions", "rotations", "latency_ms", "time"} <= set(frames[0])
    bvh = read_bvh(out / "take.bvh")
    assert bvh.num_frames == 6 and (out / "take.glb").is_file()
    np.testing.assert_allclose([f["root"] for f in frames[:6]], bvh.positions[:, 0], atol=1e-3)
    log = json.loads((out / "take.json").read_text())["commands"]
    assert [entry["commands"][0]["style"] for entry in log] == ["old"] * 4 + ["neutral"] * 4
    assert log[6]["recording"] is False and log[7]["commands"][0]["speed"] == 0

    lines_in(monkeypatch, commands[:1])
    assert main(argv) == 1
    assert "would overwrite" in capsys.readouterr().err


@pytest.mark.parametrize(
    "bad, expected",
    [
        ({"speed": "fast"}, "-:3: speed: expected metres per second (a number >= 0), got 'fast'"),
        ({"sped": 1}, "-:3: unknown field 'sped'; expected direction, speed, style"),
        ({"direction": [0, 0]}, "-:3: direction: expected a non-zero [x, z]"),
        ({"style": "happy"}, "-:3: unknown style happy; valid: angry"),
        ({"frames": -1}, "-:3: frames: expected a whole number from 0 to"),
        ("[1, 2]", "-:3: expected a JSON object"),
    ],
)
def test_a_bad_control_line_names_its_line_and_field_and_keeps_the_frames(
    ckpt, tmp_path, monkeypatch, capsys, bad, expected
):
    lines_in(monkeypatch, [{"direction": 90}, {"frames": 1}, bad, {"frames": 5}])
    out = tmp_path / "o"
    assert main(["control", "--ckpt", str(ckpt), "--style", "old", "--steps", "2", "--out", str(out)]) == 1
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and expected in err[0] and "the 2 frames made before it are in" in err[0], err
    last = json.loads(captured.out.splitlines()[-1])
    assert last["done"] is False and last["frames"] == 2
    assert read_bvh(out / "take.bvh").num_frames == 2


# ---------------------------------------------------------------- walkdiff play --script


def script(path, events: list) -> str:
    path.write_text("".join((e if isinstance(e, str) else json.dumps(e)) + "\n" for e in events))
    return str(path)


def test_play_a_script_writes_the_take_and_refuses_to_overwrite(ckpt, tmp_path, capsys):
    events = [{"t": 0, "key": "ArrowLeft", "down": True}, {"t": 0.3, "key": "ArrowLeft", "down": False},
              {"t": 0.4, "key": "ArrowUp"}, {"t": 0.5, "direction": [0, 1], "speed": 0.8, "style": "neutral"},
              {"t": 0.6, "key": "r"}, {"t": 0.8, "key": "r"}, {"t": 1.0}]  # fmt: skip
    path = script(tmp_path / "s.jsonl", events)
    out = tmp_path / "take"
    argv = [
        "play",
        "--ckpt",
        str(ckpt),
        "--script",
        path,
        "--out",
        str(out),
        "--style",
        "old",
        "--steps",
        "2",
    ]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    manifest = json.loads((out / "take.json").read_text())
    # A script that presses r starts with recording off: on over 0.6-0.8 s.
    assert summary["frames"] == 30 and manifest["recorded_frames"] == 6
    assert sorted(p.name for p in out.iterdir()) == ["take.bvh", "take.glb", "take.json"]
    assert read_bvh(out / "take.bvh").num_frames == 6
    log = manifest["commands"]
    assert log[0]["direction"] == 0 and log[5]["direction"] == pytest.approx(15)  # 90 degrees/s, held
    assert log[9]["direction"] == pytest.approx(27) and log[12]["speed"] == pytest.approx(
        0.89 + 0.2, abs=0.02
    )
    assert log[15] | {"frame": 0, "time": 0} == {
        "frame": 0, "time": 0, "recording": False, "direction": 0.0, "speed": 0.8, "style": "neutral"
    }  # fmt: skip
    assert [e["recording"] for e in log[16:26]] == [False] * 2 + [True] * 6 + [False] * 2
    before = (out / "take.bvh").read_bytes()
    assert main(argv) == 1
    assert "would overwrite" in capsys.readouterr().err and (out / "take.bvh").read_bytes() == before
    assert main([*argv, "--overwrite", "--fps", "60"]) == 0
    assert read_bvh(out / "take.bvh").frame_time == pytest.approx(1 / 60)


@pytest.mark.parametrize(
    "line, expected",
    [
        ({"t": 0.5, "key": "q"}, "s.jsonl:3: key 'q': expected ArrowLeft"),
        ({"t": 0.1, "speed": 1}, "s.jsonl:3: t: 0.1 is before the line above's 0.2"),
        ({"t": 0.5, "speed": -1}, "s.jsonl:3: speed: expected metres per second (a number >= 0), got -1"),
        ({"t": 0.5, "key": "w", "speed": 1}, "s.jsonl:3: a line is a key event or a command, not both"),
        ({"t": 0.5, "style": "angry"}, "s.jsonl:3: style angry: the checkpoint has no walking speed"),
        ({"t": 0.5, "kee": "w"}, "s.jsonl:3: unknown field 'kee'"),
        ("{t: 1}", "s.jsonl:3: expected a JSON object"),
    ],
)
def test_a_bad_script_line_is_named_before_any_work(ckpt, tmp_path, capsys, line, expected):
    path = script(tmp_path / "s.jsonl", [{"t": 0, "direction": 10}, {"t": 0.2}, line, {"t": 1.0}])
    out = tmp_path / "o"
    argv = [
        "play",
        "--ckpt",
        str(ckpt),
        "--script",
        path,
        "--out",
        str(out),
        "--style",
        "old",
        "--steps",
        "2",
    ]
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expected in err[0], err
    assert not out.exists()


# ---------------------------------------------------------------- walkdiff bench play


@pytest.fixture(scope="module")
def evaluator(xia_tiny, xia_dir, tmp_path_factory):
    """A one-epoch evaluator of the tiny walker's twelve real Xia walks."""
    root = tmp_path_factory.mktemp("play_evaluator")
    (root / "xia").mkdir()
    for style in ("neutral", "old"):
        for content in (1, 2, 3, 5, 6, 7):
            name = f"{style}_{content:02d}_000.bvh"
            (root / "xia" / name).symlink_to(xia_dir / name)
    torch.manual_seed(0)
    dm = tiny_datamodule(root, root / "cache", contents="walk")
    trainer = tiny_trainer(max_epochs=1, limit_val_batches=1)
    trainer.fit(MotionEvaluator(dm.spec, hidden=16, embed_dim=8, blocks=1), dm)
    trainer.save_checkpoint(root / "evaluator.ckpt")
    return root / "evaluator.ckpt"


def numbers(tree) -> list:
    if isinstance(tree, dict):
        return [x for v in tree.values() for x in numbers(v)]
    if isinstance(tree, list):
        return [x for v in tree for x in numbers(v)]
    return [tree] if isinstance(tree, float | int) and not isinstance(tree, bool) else []


def test_bench_play_writes_every_section_with_finite_numbers(ckpt, evaluator, tmp_path, capsys):
    out = tmp_path / "play.json"
    argv = ["bench", "play", "--ckpt", str(ckpt), "--evaluator", str(evaluator), "--out", str(out), "--seeds",
            "1", "--switch-seeds", "1", "--hold", "2", "--steps", "2", "--characters", "1,2",
            "--frames", "3"]  # fmt: skip
    assert main(argv) == 0
    result = json.loads(out.read_text())
    printed = capsys.readouterr().out
    assert "bench play: turn_90_left, seed 0" in printed and "bench play: style, skating and seams" in printed
    for section in ("latency", "generation", "following", "style", "skating", "seams", "page", "targets"):
        assert section in result, section
    assert "machine" in result and "page_open_s" in result["page"] and result["page"].get("bones_drawn", 1)
    if "skipped" not in result["page"]:  # Chromium here (CI installs it): the page timed over three launches
        assert len(result["page"]["launches_s"]) == 3
    assert all(math.isfinite(x) for x in numbers(result))
    assert result["styles"] == ["neutral", "old"] and result["seams"]["switches"] == 2  # 2 a tour, 1 seed
    low, high = result["seams"]["share_interval_95"]
    assert low <= result["seams"]["share_above_p95"] <= high and high - low > 0.3  # 2 switches say little
    assert result["seams"]["switched_at_once"]["switches"] == 2
    assert result["seams"]["over_ramp"]["frames"] == 15 and result["seams"]["over_ramp"]["inside_p95"] > 0
    clipped = result["example_clips"]  # one real test clip per style of the tiny evaluator steers a walker
    assert set(clipped["clips"]) == set(clipped["per_style"]) and len(clipped["clips"]) >= 2
    assert 0 <= clipped["accuracy"] <= 1 and 0 <= clipped["label_alone_accuracy"] <= 1
    assert clipped["ms_per_frame"] > 0 and clipped["label_alone_ms_per_frame"] > 0
    assert {"turn", "speed", "stop"} == set(result["latency"]["by_kind"])
    assert len(result["latency"]["commands"]) == 9 and result["latency"]["median_ms"] > 0
    assert set(result["following"]["heading_error_deg"]) == {"straight", "turn_45", "turn_90", "turn_180"}
    assert set(result["generation"]["by_characters"]) == {"1", "2"}
    assert result["style"]["windows"] > 0 and result["skating"]["generated"] >= 0
    real_feet = result["skating"]["feet_on_ground_speed"]["real_test"]
    assert 0 <= real_feet["feet"] < real_feet["root"], "real feet on the ground stand while the body moves"
    for name, verdict in result["targets"].items():
        assert set(verdict) == {"value", "target", "pass"} and verdict["pass"] in (True, False, None), name
    assert main(argv) == 1
    assert "would overwrite" in capsys.readouterr().err


def test_the_foot_lock_holds_a_planted_foot_fades_it_after_lift_off_and_lets_go_when_far(ckpt):
    """A foot the walker's contacts plant stays where it touched down while the body walks on (two-bone
    IK reaches it exactly), its offset fades out over BLEND frames once it is off the ground, the other
    leg is left alone, and an anchor the body has walked too far from is dragged along."""
    from walkdiff.motion.profile_detection import CONTACT_HEIGHT
    from walkdiff.motion.representation import features_to_positions
    from walkdiff.walker.foot_lock import BLEND, MAX_OFFSET, FootLock

    model = load_walker(ckpt)
    skeleton, spec, layout = model.skeleton, model.profile.contacts, model.layout
    offsets = torch.from_numpy(skeleton.offsets).double()
    heel = skeleton.index(spec.joints[0])
    leg = spec.height_threshold / CONTACT_HEIGHT
    lock = FootLock(model, 1)
    pose = model.normalizer.mean.double().numpy()[None].copy()
    pose[:, layout.contacts] = [1.0, 1.0, 0.0, 0.0]  # the left foot planted, the right in the air

    def heel_at(raw, position):
        world = features_to_positions(torch.from_numpy(raw), offsets, skeleton.parents, position, 0.3)
        return world[0, heel, [0, 2]].numpy()

    places, raws = [], []
    for frame in range(5):
        position = np.array([0.0, 0.03 * leg * frame])  # the body walks on, the foot would slide with it
        raw = pose.copy()
        lock.apply(raw, position[None], np.array([0.3]))
        places.append(heel_at(raw, position))
        raws.append(raw)
    np.testing.assert_allclose(places, np.repeat(places[:1], 5, axis=0), atol=1e-6 * leg)
    others = [j for j in range(skeleton.num_joints) if j not in (heel, skeleton.parents[heel],
             skeleton.parents[skeleton.parents[heel]])]  # fmt: skip
    channels = np.concatenate([np.arange(6) + layout.rotations.start + 6 * j for j in others])
    np.testing.assert_array_equal(raws[-1][:, channels], pose[:, channels])  # only the left leg moved
    assert not np.array_equal(raws[-1], pose)
    np.testing.assert_array_equal(raws[0], pose)  # no offset on landing
    # The contacts off but the foot still on the ground: it stays where it is.
    low = pose.copy()
    low[:, layout.contacts] = 0.0
    lock.apply(low, position[None], np.array([0.3]))
    np.testing.assert_allclose(heel_at(low, position), places[0], atol=1e-6 * leg)
    # Lift-off (the contacts off and the foot a contact height up): the offset falls by equal steps to
    # nothing over BLEND frames.
    lifted = pose.copy()
    lifted[:, layout.contacts] = 0.0
    lifted[:, layout.root_height] += 1.5 * spec.height_threshold
    position = np.array([0.0, 0.03 * leg * 4])
    free = heel_at(lifted, position)
    gaps = []
    for _ in range(BLEND + 1):
        raw = lifted.copy()
        lock.apply(raw, position[None], np.array([0.3]))
        gaps.append(np.linalg.norm(heel_at(raw, position) - free))
    first = np.linalg.norm(places[-1] - free)
    np.testing.assert_allclose(gaps, first * (1 - np.arange(1, BLEND + 2) / (BLEND + 1)), atol=1e-6 * leg)
    # Planted again, and the body jumps further than MAX_OFFSET leg lengths: the anchor is dragged along,
    # the foot held that far behind where the walker puts it.
    lock.apply(pose.copy(), position[None], np.array([0.3]))
    far = position + [0.0, 1.5 * MAX_OFFSET * leg]
    raw = pose.copy()
    lock.apply(raw, far[None], np.array([0.3]))
    dragged = np.linalg.norm(heel_at(raw, far) - heel_at(pose, far))
    assert dragged == pytest.approx(MAX_OFFSET * leg, rel=1e-6)


def test_the_foot_lock_lifts_a_free_foot_that_skims_the_floor_and_lets_it_down_gently(ckpt):
    """Feet that have landed, then move along the ground faster than a planted foot may without the
    walker's contacts: each is raised until its lower joint is a contact height above where it landed;
    standing still again, the lift falls by LIFT_FADE a frame."""
    from walkdiff.motion.representation import features_to_positions
    from walkdiff.walker.foot_lock import LIFT_FADE, FootLock

    model = load_walker(ckpt)
    skeleton, spec, layout = model.skeleton, model.profile.contacts, model.layout
    offsets = torch.from_numpy(skeleton.offsets).double()
    joints = [skeleton.index(name) for name in spec.joints]
    lock = FootLock(model, 1)
    pose = model.normalizer.mean.double().numpy()[None].copy()

    def heights(raw, position):
        world = features_to_positions(torch.from_numpy(raw), offsets, skeleton.parents, position, 0.0)
        return world[0, joints, 1].numpy()

    def step(contacts, position, up=0.0):
        raw = pose.copy()
        raw[:, layout.contacts] = contacts
        raw[:, layout.root_height] += up
        lock.apply(raw, position[None], np.array([0.0]))
        return raw

    origin = np.zeros(2)
    landed = heights(step([1.0] * 4, origin), origin)  # both feet land where the pose puts them
    step([0.0] * 4, origin, up=1.5 * spec.height_threshold)  # and lift off: free again
    fast = 2 * spec.speed_threshold / model.spec["fps"]  # twice a planted foot's speed, a frame
    position = origin.copy()
    for _ in range(3):
        position = position + [0.0, fast]
        raw = step([0.0] * 4, position)
    raised = heights(raw, position)
    for side in (slice(0, 2), slice(2, 4)):  # each foot's lower joint a contact height above its landing
        gaps = raised[side] - landed[side]
        assert gaps.min() == pytest.approx(spec.height_threshold, rel=1e-4)
    lift = raised - heights(pose, position)
    raw = step([0.0] * 4, position)  # standing still: no longer skimming
    np.testing.assert_allclose(heights(raw, position) - heights(pose, position), LIFT_FADE * lift, atol=1e-4)


def test_ctrl_c_on_control_writes_the_take_recorded(ckpt, tmp_path, monkeypatch, capsys):
    """Ctrl-C while `control` waits for the next line: the recorded frames are written as a complete take
    (BVH, glb, manifest), one line says where, exit 130 (it was: 'interrupted', nothing written)."""
    from test_streaming import ctrl_c_after, interrupted_output

    commands = [{"direction": [1, 0], "speed": 1.0}, {"frames": 4}]
    monkeypatch.setattr("sys.stdin", ctrl_c_after("".join(json.dumps(c) + "\n" for c in commands).encode()))
    out = tmp_path / "live"
    assert main(["control", "--ckpt", str(ckpt), "--style", "old", "--steps", "2", "--out", str(out)]) == 130
    frames, summary, err = interrupted_output(capsys)
    assert len(frames) == 5 and summary["interrupted"] and summary["frames"] == 5
    assert err == [f"walkdiff: interrupted; the 5 frames made so far are in {', '.join(summary['files'])}"]
    assert read_bvh(out / "take.bvh").num_frames == 5 and (out / "take.glb").is_file()
    assert json.loads((out / "take.json").read_text())["error"] == "interrupted"
