"""The walker and the gesture model where games run (issue 44): `walkdiff export --format onnx`, its JSON
contract, and ONNX Runtime making the torch model's frames (`--runtime onnx`).

Parity is judged where an engine sees it: the joints' world positions over 300 frames, ONNX Runtime
against torch for the same seed (the noise drawn in the same order), at most 1e-4 of the body's height
apart. The tiny models are trained for a few steps only: enough to have real weights, normalisers and a
skeleton; nothing here says anything about motion quality.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import tiny
import torch

from walkdiff.cli.main import main
from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion import SamplerChoice
from walkdiff.export.runtime import OnnxFrames, frame_runtime
from walkdiff.gestures.generator import joint_positions, load_model
from walkdiff.models.path_walker import PathWalker
from walkdiff.walker.controller import controller
from walkdiff.walker.follow import load_walker

FRAMES = 300
FEW = SamplerChoice("ddim", 4, 1.0)  # the tiny models have 8 and 10 trained steps
TOLERANCE = 1e-4  # of the body's height


@pytest.fixture(autouse=True)
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def gesture_ckpt(tmp_path_factory):
    return tiny.gestures(tmp_path_factory.mktemp("onnx_gestures"))[0]


@pytest.fixture(scope="module")
def walker_ckpt(xia_dir, tmp_path_factory):
    root = tmp_path_factory.mktemp("onnx_walker")
    (root / "xia").mkdir()
    for style in ("neutral", "old"):  # the walks of conftest's xia_tiny, its walker alone
        for content in (1, 2, 3, 5, 6, 7):
            name = f"{style}_{content:02d}_000.bvh"
            (root / "xia" / name).symlink_to(xia_dir / name)
    return tiny.walker(root)[1]


def mlp_walker(ckpt) -> PathWalker:
    """The tiny walker's data, normalisers and skeleton with conf/walk_xia.yaml's kind of network (an MLP
    denoiser predicting x0, the control beside the state), small and at random weights, read-out included."""
    base = load_walker(ckpt)
    torch.manual_seed(1)
    model = PathWalker(
        base.spec, hidden=32, lstm_layers=2, control_hidden=16, denoiser="mlp", denoiser_hidden=48,
        denoiser_layers=2, prediction="x0", control_to_denoiser=True, timesteps=20,
    )  # fmt: skip
    torch.nn.init.normal_(model.eps_net.output.weight, std=0.05)
    for name in ("normalizer", "control_normalizer"):
        getattr(model, name).load_state_dict(getattr(base, name).state_dict())
    model.style_speed.copy_(base.style_speed)
    model.profile = base.profile
    return model.eval()


def height(positions: np.ndarray) -> float:
    return float(np.ptp(positions[..., 1]))


def walk(model, frames: int = FRAMES) -> np.ndarray:
    """World joint positions (F, 2 characters, J, 3) of two walkers told to turn, speed up and stop."""
    walker = controller(model, "old", seed=3, sampler="ddim", steps=4, characters=2)
    out = []
    for frame in range(frames):
        if frame == 60:
            walker.command(direction=90.0)
        if frame == 150:
            walker.command(speed=1.6, character=1)
        if frame == 240:
            walker.command(speed=0.0, character=0)
        out.append(np.stack([p.positions for p in walker.advance()]))
    return np.stack(out)


@pytest.mark.parametrize("network", ["timegrad", "mlp"])
def test_walker_frames_match_torch(walker_ckpt, network):
    model = load_walker(walker_ckpt) if network == "timegrad" else mlp_walker(walker_ckpt)
    torch_positions = walk(model)
    onnx_positions = walk(OnnxFrames(model, FEW))
    moved = np.linalg.norm(torch_positions[-1, :, 0] - torch_positions[0, :, 0], axis=-1)
    assert (moved > 0.5).all(), "the walkers did not walk: nothing to compare"
    error = np.abs(onnx_positions - torch_positions).max()
    print(f"walker ({network}): largest difference {error:.3g}, body height {height(torch_positions):.3g}")
    assert error <= TOLERANCE * height(torch_positions), (error, height(torch_positions))


def test_gesture_frames_match_torch(gesture_ckpt):
    model = load_model(gesture_ckpt)
    normal = model.audio_normalizer
    audio = normal.mean + normal.std * torch.randn(
        FRAMES, model.spec["audio_dim"], generator=torch.Generator().manual_seed(0)
    )
    streams = 2
    made = []
    for runner in (model, OnnxFrames(model, FEW)):
        poses = runner.generate(audio, torch.Generator().manual_seed(5), streams, sampler=FEW)
        made.append(np.stack([joint_positions(model, p) for p in poses.numpy()]))
    assert np.abs(made[0][:, 1:] - made[0][:, :-1]).max() > 1e-3, (
        "the gestures do not move: nothing to compare"
    )
    error = np.abs(made[1] - made[0]).max()
    print(f"gestures: largest difference {error:.3g}, body height {height(made[0]):.3g}")
    assert error <= TOLERANCE * height(made[0]), (error, height(made[0]))


def test_a_walk_along_a_path_matches_torch(walker_ckpt):
    from walkdiff.motion.path import Polyline

    model = load_walker(walker_ckpt)
    path = Polyline.of([[0.0, 0.0], [0.0, 60.0], [60.0, 120.0]])
    style, speed = torch.tensor([1, 0]), torch.full((2,), 40.0)
    walks = [
        runner.generate(path, style, speed, 120, torch.Generator().manual_seed(1), sampler=FEW)[0]
        for runner in (model, OnnxFrames(model, FEW))
    ]
    assert np.abs(walks[1] - walks[0]).max() <= 1e-4 * np.abs(walks[0]).max()
    with pytest.raises(WalkdiffError, match="sample_frame makes frames with torch"):
        OnnxFrames(model, FEW).sample_frame(None, None, None)


def test_export_writes_graph_and_contract(gesture_ckpt, walker_ckpt, tmp_path):
    import onnxruntime

    for ckpt, kind in ((gesture_ckpt, "gesture"), (walker_ckpt, "walker")):
        out = tmp_path / kind
        assert (
            main(["export", "--format", "onnx", "--ckpt", str(ckpt), "--out", str(out), "--steps", "4"]) == 0
        )
        terms = json.loads((out / f"{kind}.json").read_text())
        assert terms["kind"] == kind and terms["onnx"] == f"{kind}.onnx"
        assert terms["sampler"]["label"] == "ddim-4-eta1" and len(terms["sampler"]["timesteps"]) == 4
        session = onnxruntime.InferenceSession(str(out / terms["onnx"]), providers=["CPUExecutionProvider"])
        declared = {i["name"]: i["shape"] for i in terms["inputs"]}
        assert {i.name for i in session.get_inputs()} == set(declared)
        for given in session.get_inputs():  # every axis fixed but the batch, as the contract says
            fixed = [d if isinstance(d, int) else "batch" for d in given.shape]
            assert fixed == declared[given.name], given.name
        assert [o.name for o in session.get_outputs()] == [o["name"] for o in terms["outputs"]]
        skeleton = terms["skeleton"]
        assert len(skeleton["names"]) == len(skeleton["parents"]) == len(skeleton["offsets"])
        assert (
            main(["export", "--format", "onnx", "--ckpt", str(ckpt), "--out", str(out)]) == 1
        )  # not unasked
    assert main(["export", "--ckpt", str(gesture_ckpt), "--out", str(tmp_path / "s"), "--steps", "4"]) == 1


def test_runtime_refuses_what_it_cannot_run(walker_ckpt, xia_dir):
    walker_clip = xia_dir / "old_01_000.bvh"
    model = load_walker(walker_ckpt)
    with pytest.raises(WalkdiffError, match="--runtime"):
        frame_runtime(model, "tensorrt")
    frames = OnnxFrames(model, FEW)
    with pytest.raises(WalkdiffError, match="made for ddim-4-eta1, not ddim-2"):
        frames.start_streams(1, SamplerChoice("ddim", 2, 1.0))
    with pytest.raises(WalkdiffError, match="need --runtime torch"):
        controller(frames, "old", sampler="ddim", steps=4).command(style_clips=str(walker_clip))


def test_export_refuses_what_it_cannot_export(gesture_ckpt, tmp_path, capsys):
    out, missing = tmp_path / "out", tmp_path / "missing.ckpt"
    assert main(["export", "--format", "onnx", "--ckpt", str(missing), "--out", str(out)]) == 1
    assert "missing.ckpt" in capsys.readouterr().err
    # A page steers a walker: a gesture model is refused (without onnxruntime-web: `make web` is asked for).
    assert main(["export", "--format", "web", "--ckpt", str(gesture_ckpt), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "needs a path walker" in err or "make web" in err
    assert not out.exists() or not any(out.iterdir())


def test_streams_out_of_step_match_torch(gesture_ckpt):
    """Streams fed at different paces advance a few rows at a time (`advance(rows=...)`): the same
    frames on both runtimes."""
    from walkdiff.gestures.stream import GestureBatch, GestureStream

    model = load_model(gesture_ckpt)
    rate = model.spec["sample_rate"]
    audio = np.random.default_rng(0).normal(0, 0.1, 3 * rate).astype(np.float32)
    made = []
    for runner in (model, OnnxFrames(model, FEW)):
        batch = GestureBatch(runner, 7, FEW)
        streams = [GestureStream(runner, rate, batch=batch) for _ in range(3)]
        for start in range(0, len(audio), rate // 4):
            for k, stream in enumerate(streams):  # stream k is fed k + 1 pieces a round, then catches up
                stream.feed(audio[start * (k + 1) // 3 : (start + rate // 4) * (k + 1) // 3])
            batch.run()
        made.append([np.stack(s.made) for s in streams])
    for torch_poses, onnx_poses in zip(*made, strict=True):
        assert len(torch_poses) == len(onnx_poses) > 5
        assert np.abs(torch_poses - onnx_poses).max() <= 1e-3 * np.abs(torch_poses).max()


def test_benches_run_on_onnx_runtime(gesture_ckpt, walker_ckpt, tmp_path):
    out = tmp_path / "gesture.json"
    assert main(["bench", "gesture", "--runtime", "onnx", "--ckpt", str(gesture_ckpt), "--out", str(out),
                 "--frames", "2", "--repeats", "1", "--steps", "4", "--streams", "2,3"]) == 0  # fmt: skip
    result = json.loads(out.read_text())
    assert result["runtime"] == "onnx" and result["sampler"] == "ddim-4-eta1"
    assert result["ms_per_frame_1_stream"] > 0 and result["ms_per_frame_graph_alone"] > 0
    assert set(result["frames_per_second_batched"]) == {"2", "3"}
    out = tmp_path / "stream.json"
    assert main(["bench", "stream", "--runtime", "onnx", "--out", str(out), "--ckpt", str(gesture_ckpt),
                 "--walker", str(walker_ckpt), "--seconds", "1", "--frames", "1", "--most", "2", "--threads",
                 "1", "--sampler", "ddim", "--steps", "4", "--eta", "1"]) == 0  # fmt: skip
    result = json.loads(out.read_text())
    assert result["runtime"] == "onnx" and result["walk"]["frames_measured"] > 0
    assert 0 <= result["gesture"]["realtime_streams"] <= 2 and 0 <= result["walk"]["realtime_streams"] <= 2


def test_the_contract_alone_makes_the_same_frames(gesture_ckpt, walker_ckpt, tmp_path):
    """docs/onnx_loop.py, which knows only the JSON and ONNX Runtime, walks and gestures as walkdiff does
    for the same noise: the joints' world positions within 1e-4 of the body's height."""
    import ast
    import math
    import subprocess
    import sys
    from pathlib import Path

    from walkdiff.gestures.generator import to_motion
    from walkdiff.motion.kinematics import motion_world_positions
    from walkdiff.motion.representation import features_to_positions

    script = Path(__file__).resolve().parent.parent / "docs" / "onnx_loop.py"
    tree = ast.parse(script.read_text())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert imported <= {"__future__", "argparse", "json", "math", "pathlib", "numpy", "onnxruntime"}

    def loop(ckpt, kind: str, noise: np.ndarray, *args: str) -> np.ndarray:
        folder = tmp_path / kind
        assert (
            main(["export", "--format", "onnx", "--ckpt", str(ckpt), "--out", str(folder), "--steps", "4"])
            == 0
        )
        np.save(tmp_path / f"{kind}_noise.npy", noise)
        out = tmp_path / f"{kind}.npz"
        subprocess.run(
            [sys.executable, "-I", str(script), str(folder / f"{kind}.json"), "--noise",
             str(tmp_path / f"{kind}_noise.npy"), "--out", str(out), *args],
            check=True, capture_output=True,
        )  # fmt: skip
        return np.load(out)["positions"]

    def noise_of(model, seed: int) -> np.ndarray:  # what torch draws from the seed, frame by frame
        generator, frames = torch.Generator().manual_seed(seed), OnnxFrames(model, FEW)
        return np.stack([frames.noise(1, generator) for _ in range(FRAMES)])

    walker = load_walker(walker_ckpt)
    steered = controller(walker, "old", seed=2, sampler="ddim", steps=4, turn_rate=math.inf,
                         heading_assist=0.0, foot_lock=False)  # fmt: skip
    for _ in range(FRAMES):
        steered.advance()
    raw = torch.from_numpy(np.stack([r[0] for _, r, _, _ in steered.kept]))
    skeleton = walker.skeleton
    expected = features_to_positions(raw, torch.from_numpy(skeleton.offsets), skeleton.parents).numpy()
    made = loop(walker_ckpt, "walker", noise_of(walker, 2), "--frames", str(FRAMES), "--style", "old")
    assert np.linalg.norm(expected[-1, 0] - expected[0, 0]) > 0.5 / walker.profile.metres_per_unit
    assert np.abs(made - expected).max() <= TOLERANCE * height(expected)

    model = load_model(gesture_ckpt)
    normal = model.audio_normalizer
    audio = normal.mean + normal.std * torch.randn(FRAMES, model.spec["audio_dim"])
    np.save(tmp_path / "audio.npy", audio.numpy())
    features = model.generate(audio, torch.Generator().manual_seed(4), 1, sampler=FEW)[0]
    expected = motion_world_positions(to_motion(model, features.numpy()))
    made = loop(gesture_ckpt, "gesture", noise_of(model, 4), "--audio", str(tmp_path / "audio.npy"))
    assert np.abs(made - expected).max() <= TOLERANCE * height(expected)


def page_noise(seed: int):
    """The static page's noise (mulberry32 uniforms, Box-Muller), drawn in Python."""
    import math

    mask, state = 0xFFFFFFFF, seed & 0xFFFFFFFF

    def uniform() -> float:
        nonlocal state
        state = (state + 0x6D2B79F5) & mask
        t = state
        t = ((t ^ (t >> 15)) * (t | 1)) & mask
        t = (t ^ (t + (((t ^ (t >> 7)) * (t | 61)) & mask))) & mask
        return ((t ^ (t >> 14)) & mask) / 4294967296

    return lambda: math.sqrt(-2 * math.log(1 - uniform())) * math.cos(2 * math.pi * uniform())


def test_the_page_walks_in_the_browser_as_python_does(walker_ckpt, tmp_path):
    """`walkdiff export --format web`: the page loads in headless Chromium, walks, takes a held key as a
    turn, and its frames are ONNX Runtime's in Python for the same seed and keys (positions within 1e-3 of
    the body's height)."""
    import functools
    import http.server
    import importlib.util
    import math
    import threading
    import time
    from pathlib import Path

    import onnxruntime

    from walkdiff.export.static_page import ort_web_folder
    from walkdiff.preview.browser import Browser, find_chromium

    required = os.environ.get("WALKDIFF_REQUIRE_BROWSER") == "1"  # CI: make install fetched both
    if find_chromium() is None and not required:
        pytest.skip("no chromium on PATH")
    try:
        ort_web_folder()
    except WalkdiffError as error:
        if required:
            raise
        pytest.skip(str(error))
    out = tmp_path / "page"
    assert (
        main(["export", "--format", "web", "--ckpt", str(walker_ckpt), "--out", str(out), "--steps", "4"])
        == 0
    )
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(out))
    handler.log_message = lambda *args: None
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    segments = [(30, None), (30, "keyDown"), (30, "keyUp")]
    try:
        with Browser(f"http://127.0.0.1:{server.server_port}/index.html?manual&seed=3") as browser:
            browser.wait_for(
                "window.walkdiffStatic && (walkdiffStatic.ready || walkdiffStatic.error)", timeout=60
            )
            ready_s = time.monotonic() - browser.launched
            assert browser.evaluate("walkdiffStatic.error") is None
            done = 0
            for frames, event in segments:
                if event is not None:  # a real key event, as a person's key press reaches the page
                    browser.send("Input.dispatchKeyEvent", type=event, key="ArrowLeft", code="ArrowLeft",
                                 windowsVirtualKeyCode=37)  # fmt: skip
                done += frames
                browser.evaluate(
                    f"(async () => {{ for (let i = 0; i < {frames}; i++) await walkdiffStatic.step(); }})()"
                )
                browser.wait_for(f"walkdiffStatic.recorded.length >= {done}", timeout=60, every=0.02)
            recorded = browser.evaluate(
                "walkdiffStatic.recorded.map(f => [f.pose, f.positions, f.direction])"
            )
            browser.evaluate("walkdiffStatic.bench(60).then(v => walkdiffStatic.speed = v)")
            speed = browser.wait_for("walkdiffStatic.speed", timeout=60)
    finally:
        server.shutdown()
        server.server_close()
    print(f"page ready {ready_s:.2f} s after the browser's launch; {speed:.0f} frames/s in the browser")

    spec = importlib.util.spec_from_file_location(
        "onnx_loop", Path(__file__).parent.parent / "docs" / "onnx_loop.py"
    )
    loop = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(loop)
    terms = json.loads((out / "walker.json").read_text())
    session = onnxruntime.InferenceSession(str(out / "walker.onnx"), providers=["CPUExecutionProvider"])
    shapes = {i["name"]: [1 if d == "batch" else d for d in i["shape"]] for i in terms["inputs"]}
    state = {n: np.zeros(shapes[n], np.float32) for n in ("previous", "h", "c")}
    control, fps = terms["control"], terms["fps"]
    styles = list(control["style_speed"])
    weights = np.eye(len(styles), dtype=np.float32)[:1]
    times, draw = np.asarray(control["ahead_frames"]) / fps, page_noise(3)
    rot = slice(*terms["features"]["layout"]["rotations"])
    x = z = heading = direction = 0.0
    expected, held = [], False
    for frames, event in segments:
        held = {None: held, "keyDown": True, "keyUp": False}[event]
        for _ in range(frames):
            direction += math.radians(90) / fps if held else 0.0
            delta = (direction - heading + math.pi) % (2 * math.pi) - math.pi
            delta = min(max(delta, -math.pi / 2), math.pi / 2)
            pace = control["style_speed"][styles[0]] * times
            points = np.stack([pace * math.sin(delta), pace * math.cos(delta)], -1).reshape(1, -1)
            noise = np.array([draw() for _ in range(int(np.prod(shapes["noise"])))], np.float32)
            feeds = {
                "control": points.astype(np.float32),
                "style": weights,
                "noise": noise.reshape(shapes["noise"]),
            }
            pose, state["previous"], state["h"], state["c"] = session.run(None, feeds | state)
            raw = pose[0].astype(np.float64)
            rotations = loop.sixd_to_matrix(raw[rot].reshape(-1, 6))
            rotations[0] = loop.yaw(heading) @ rotations[0]
            positions = loop.forward_kinematics(rotations, np.array([x, raw[2], z]), terms["skeleton"])
            expected.append((positions, direction))
            x, z = (
                x + raw[0] * math.cos(heading) + raw[1] * math.sin(heading),
                z - raw[0] * math.sin(heading) + raw[1] * math.cos(heading),
            )
            heading += raw[3]
    page = np.array([p for _, p, _ in recorded])
    python = np.stack([p for p, _ in expected])
    assert len(page) == len(python) == 90
    assert np.linalg.norm(page[-1, 0] - page[0, 0]) * terms["skeleton"]["metres_per_unit"] > 0.5  # it walks
    assert recorded[29][2] == 0 and recorded[-1][2] == pytest.approx(math.radians(90), abs=1e-6)  # the key
    assert [d for _, _, d in recorded] == pytest.approx([d for _, d in expected], abs=1e-9)
    assert np.abs(page - python).max() <= 1e-3 * height(python)
    assert speed > 0


def test_bench_play_runs_on_onnx_runtime(walker_ckpt, xia_dir, tmp_path):
    """`bench play --runtime onnx`: every section measured with ONNX Runtime's frames (the example clips'
    walks on torch, their guide being torch's)."""
    import math

    from test_evaluator import tiny_datamodule, tiny_trainer

    from walkdiff.models.evaluator import MotionEvaluator

    root = tmp_path / "evaluator"
    (root / "xia").mkdir(parents=True)
    for style in ("neutral", "old"):
        for content in (1, 2, 3, 5, 6, 7):
            name = f"{style}_{content:02d}_000.bvh"
            (root / "xia" / name).symlink_to(xia_dir / name)
    torch.manual_seed(0)
    dm = tiny_datamodule(root, root / "cache", contents="walk")
    trainer = tiny_trainer(max_epochs=1, limit_val_batches=1)
    trainer.fit(MotionEvaluator(dm.spec, hidden=16, embed_dim=8, blocks=1), dm)
    trainer.save_checkpoint(root / "evaluator.ckpt")
    out = tmp_path / "play.json"
    assert main(["bench", "play", "--runtime", "onnx", "--ckpt", str(walker_ckpt), "--evaluator",
                 str(root / "evaluator.ckpt"), "--out", str(out), "--seeds", "1", "--switch-seeds", "1",
                 "--hold", "2", "--steps", "2", "--characters", "1,2", "--frames", "3"]) == 0  # fmt: skip
    result = json.loads(out.read_text())
    assert result["runtime"] == "onnx" and result["sampler"] == "ddim-2-eta1"
    assert set(result["generation"]["by_characters"]) == {"1", "2"}
    assert result["generation"]["frames_per_s_one_character"] > 0 and result["latency"]["median_ms"] > 0
    assert result["example_clips"]["ms_per_frame"] > 0
    assert all(math.isfinite(x) for x in numbers(result))


def numbers(tree) -> list:
    if isinstance(tree, dict):
        return [x for v in tree.values() for x in numbers(v)]
    if isinstance(tree, list):
        return [x for v in tree for x in numbers(v)]
    return [tree] if isinstance(tree, float | int) and not isinstance(tree, bool) else []


# ---------------------------------------------------------------- --runtime onnx on the live commands


def world_positions(bvh) -> np.ndarray:
    from walkdiff.motion.bvh import read_bvh
    from walkdiff.motion.kinematics import motion_world_positions

    return motion_world_positions(read_bvh(bvh))


def live_runs(monkeypatch, capsys, tmp_path, name: str, argv: list[str], stdin: bytes | None, bvh: str):
    """`argv` run with --runtime torch, then onnx (stdin fed each time): each run's BVH `bvh` (under its
    --out) as world joint positions, and its last printed line."""
    import io

    made, last = {}, {}
    capsys.readouterr()
    for runtime in ("torch", "onnx"):
        out = tmp_path / f"{name}_{runtime}"
        if stdin is not None:
            monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(stdin)))
        assert main([*argv, "--out", str(out), "--runtime", runtime]) == 0
        printed = capsys.readouterr().out.strip()
        last[runtime] = json.loads(printed.splitlines()[-1] if stdin is not None else printed)
        made[runtime] = world_positions(out / bvh)
    return made, last


def assert_same_frames(made: dict, what: str) -> None:
    torch_positions, onnx_positions = made["torch"], made["onnx"]
    assert torch_positions.shape == onnx_positions.shape and len(torch_positions) > 10, what
    assert np.abs(np.diff(torch_positions, axis=0)).max() > 1e-3 * height(torch_positions), (
        f"{what}: nothing moves, nothing to compare"
    )
    error = np.abs(onnx_positions - torch_positions).max()
    print(f"{what}: largest difference {error:.3g}, body height {height(torch_positions):.3g}")
    assert error <= TOLERANCE * height(torch_positions), (what, error)


def test_control_and_play_run_on_onnx_runtime(walker_ckpt, tmp_path, monkeypatch, capsys):
    """`control` (JSON lines in) and `play --script` write the same take with --runtime onnx as with
    torch for the same seed: joint positions within 1e-4 of the body's height."""
    lines = [{"direction": [1, 0], "speed": 1.0, "frames": 40}, {"style": "neutral", "frames": 30},
             {"speed": 0.4, "direction": [0, 1], "frames": 30}]  # fmt: skip
    stdin = "".join(json.dumps(line) + "\n" for line in lines).encode()
    argv = ["control", "--ckpt", str(walker_ckpt), "--style", "old", "--seed", "1", "--steps", "4"]
    made, last = live_runs(monkeypatch, capsys, tmp_path, "control", argv, stdin, "take.bvh")
    assert last["onnx"]["frames"] == 100
    assert json.loads((tmp_path / "control_onnx" / "take.json").read_text())["runtime"] == "onnx"
    assert_same_frames(made, "control")

    script = tmp_path / "script.jsonl"
    events = [{"t": 0, "key": "ArrowUp"}, {"t": 0.5, "key": "ArrowLeft", "down": True},
              {"t": 1.5, "key": "ArrowLeft", "down": False}, {"t": 2, "style": "neutral"},
              {"t": 3.5}]  # fmt: skip
    script.write_text("".join(json.dumps(e) + "\n" for e in events))
    argv = ["play", "--ckpt", str(walker_ckpt), "--script", str(script), "--seed", "2", "--steps", "4"]
    made, last = live_runs(monkeypatch, capsys, tmp_path, "play", argv, None, "take.bvh")
    assert last["onnx"]["runtime"] == "onnx" and last["torch"]["runtime"] == "torch"
    assert_same_frames(made, "play --script")


def test_streams_run_on_onnx_runtime(walker_ckpt, gesture_ckpt, tmp_path, monkeypatch, capsys):
    """`walk --stream` and `gesture --stream` write the same BVH with --runtime onnx as with torch for the
    same seed; a graph exported beforehand (--onnx DIR) makes the same frames as one exported at the
    start."""
    points = [[0.0, 0.0], [0.0, 0.6], [0.4, 1.2], [1.1, 1.6], [1.8, 1.7]]  # metres
    stdin = "".join(json.dumps({"x": x, "z": z}) + "\n" for x, z in points).encode()
    argv = ["walk", "--stream", "--ckpt", str(walker_ckpt), "--style", "old", "--speed", "0.7", "--seed", "2",
            "--path", "-", "--sampler", "ddim", "--steps", "4", "--eta", "1"]  # fmt: skip
    made, last = live_runs(monkeypatch, capsys, tmp_path, "walk", argv, stdin, "old_stdin.bvh")
    assert last["onnx"]["runtime"] == "onnx" and last["onnx"]["done"]
    assert_same_frames(made, "walk --stream")

    model = load_model(gesture_ckpt)
    samples = np.random.default_rng(3).normal(0, 0.2, 2 * model.spec["sample_rate"])
    pcm = (np.clip(samples, -1, 1 - 1 / 32768) * 32768).astype("<i2").tobytes()
    few = ["--sampler", "ddim", "--steps", "4", "--eta", "1"]
    argv = ["gesture", "--stream", "--ckpt", str(gesture_ckpt), "--audio", "-", "--seed", "4", *few]
    made, last = live_runs(monkeypatch, capsys, tmp_path, "gesture", argv, pcm, "stdin.bvh")
    assert last["onnx"]["runtime"] == "onnx"
    assert_same_frames(made, "gesture --stream")

    graph = tmp_path / "graph"
    assert main(["export", "--format", "onnx", "--ckpt", str(gesture_ckpt), "--out", str(graph), *few]) == 0
    import io

    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(pcm)))
    out = tmp_path / "gesture_exported"
    assert main([*argv, "--out", str(out), "--runtime", "onnx", "--onnx", str(graph)]) == 0
    np.testing.assert_array_equal(world_positions(out / "stdin.bvh"), made["onnx"])


def test_the_live_commands_refuse_what_onnx_runtime_cannot_do(
    walker_ckpt, gesture_ckpt, xia_dir, tmp_path, monkeypatch, capsys
):
    import io

    graph = tmp_path / "graph"
    assert (
        main(["export", "--format", "onnx", "--ckpt", str(walker_ckpt), "--out", str(graph), "--steps", "4"])
        == 0
    )
    capsys.readouterr()
    control = ["control", "--ckpt", str(walker_ckpt), "--style", "old", "--steps", "4"]
    clip = str(xia_dir / "old_01_000.bvh")

    def refused(argv: list[str], expected: str) -> None:
        monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(b'{"frames": 2}\n')))
        assert main(argv) == 1, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and expected in err[0], err

    mismatch = "walker.onnx was exported for the sampler ddim-4-eta1, this run asks for ddim-2-eta1"
    refused([*control, "--runtime", "onnx", "--onnx", str(graph), "--steps", "2"], mismatch)
    refused([*control, "--onnx", str(graph)], "add --runtime onnx")
    refused([*control, "--runtime", "onnx", "--onnx", str(tmp_path)], "no walker.onnx here")
    refused([*control, "--runtime", "onnx", "--style-clip", clip], "example clips (--style-clip")
    refused(["play", "--ckpt", str(walker_ckpt), "--runtime", "onnx", "--style-clip", clip, "--script",
             str(tmp_path / "s.jsonl"), "--out", str(tmp_path / "p"), "--steps", "4"],
            "need --runtime torch")  # fmt: skip
    refused(["walk", "--stream", "--ckpt", str(walker_ckpt), "--style", "old", "--path", "-", "--out",
             str(tmp_path / "w"), "--runtime", "onnx", "--style-clip", clip],
            "need --runtime torch")  # fmt: skip
    refused(["walk", "--ckpt", str(walker_ckpt), "--style", "old", "--path", "p.json", "--out",
             str(tmp_path / "w"), "--runtime", "onnx"], "--runtime needs --stream")  # fmt: skip
    refused(["gesture", "--stream", "--ckpt", str(gesture_ckpt), "--audio", "-", "--out", str(tmp_path / "g"),
             "--runtime", "onnx", "--onnx", str(graph)], "no gesture.onnx here")  # fmt: skip
    terms = json.loads((graph / "walker.json").read_text())
    terms["normalizers"]["pose"]["mean"][0] += 1.0  # the graph of another model
    (graph / "walker.json").write_text(json.dumps(terms))
    refused(
        [*control, "--runtime", "onnx", "--onnx", str(graph), "--steps", "4"], "exported from another model"
    )
    assert not (tmp_path / "w").exists() and not (tmp_path / "g").exists()


def test_play_static_writes_the_page_folder(walker_ckpt, tmp_path, monkeypatch, capsys):
    """`play --static OUT`: the page, its graph and contract, and onnxruntime-web's files (here a stand-in
    folder: the page itself runs in the browser test above); an existing page refused unless
    --overwrite, the served walker's options refused."""
    from walkdiff.export.static_page import ORT_WEB_FILES

    ort = tmp_path / "ort-web"
    ort.mkdir()
    for name in ORT_WEB_FILES:
        (ort / name).write_bytes(name.encode())
    monkeypatch.setenv("WALKDIFF_ORT_WEB", str(ort))
    out = tmp_path / "page"
    argv = ["play", "--static", str(out), "--ckpt", str(walker_ckpt), "--steps", "4"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["sampler"] == "ddim-4-eta1" and summary["static"] == str(out)
    assert "<script" in (out / "index.html").read_text()
    assert [(out / "ort" / n).read_bytes() for n in ORT_WEB_FILES] == [n.encode() for n in ORT_WEB_FILES]
    terms = json.loads((out / "walker.json").read_text())
    assert terms["kind"] == "walker" and terms["sampler"]["label"] == "ddim-4-eta1"
    session_inputs = {i.name for i in __import__("onnxruntime").InferenceSession(
        str(out / "walker.onnx"), providers=["CPUExecutionProvider"]).get_inputs()}  # fmt: skip
    assert session_inputs == {i["name"] for i in terms["inputs"]}
    before = (out / "walker.onnx").stat().st_mtime_ns
    assert main(argv) == 1
    assert "would overwrite" in capsys.readouterr().err
    assert (out / "walker.onnx").stat().st_mtime_ns == before
    assert main([*argv, "--overwrite"]) == 0
    capsys.readouterr()
    refusals = [(["--style", "old"], "--style"), (["--script", "s.jsonl"], "--script"),
                (["--no-foot-lock"], "--no-foot-lock"), (["--runtime", "onnx"], "--runtime")]  # fmt: skip
    for extra, flag in refusals:
        assert main([*argv, "--overwrite", *extra]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{flag} is not for play --static" in err[0], err


def test_the_parser_names_the_runtimes_the_runtime_knows():
    from walkdiff.cli import options
    from walkdiff.export import runtime

    assert options.RUNTIMES == runtime.RUNTIMES
