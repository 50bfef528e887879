"""Walking along a path: path files and geometry, the walker's controls, training and `walkdiff walk`."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import synthetic
import tiny
import torch
from PIL import Image

from walkdiff.cli.main import main
from walkdiff.common.errors import WalkdiffError
from walkdiff.data.xia import list_clips, load
from walkdiff.models.path_walker import PathWalker, advance_root, local_offsets
from walkdiff.models.pose_mlp import PoseMLP
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.path import Polyline, read_path
from walkdiff.motion.representation import FeatureLayout, encode, root_trajectory, yaw_matrix
from walkdiff.motion.resample import resample
from walkdiff.walker.follow import load_walker, path_error


@pytest.fixture(autouse=True)
def plain_argv(monkeypatch):
    monkeypatch.setattr("sys.argv", ["walkdiff"])


# ---------------------------------------------------------------- geometry


def test_polyline_arc_length_points_and_projection():
    path = Polyline.of([[0, 0], [0, 10], [0, 10], [5, 10]])  # an L; the repeated point is dropped
    assert path.length == 15 and len(path.points) == 3
    np.testing.assert_allclose(path.at(np.array([0, 4, 12, 99])), [[0, 0], [0, 4], [2, 10], [5, 10]])
    np.testing.assert_allclose(path.direction(12.0), [1, 0])
    s, d = path.project(np.array([[1.0, 3.0], [3.0, 12.0], [-2.0, -1.0]]))
    np.testing.assert_allclose(s, [3, 13, 0])
    np.testing.assert_allclose(d, [1, 2, math.sqrt(5)])
    # Searching near an arc length keeps to that stretch of a path that comes back on itself.
    loop = Polyline.of([[0, 0], [0, 10], [1, 10], [1, 0]])
    s, _ = loop.project(np.array([[0.5, 5.0]]), near=np.array([16.0]), reach=3.0)
    assert s[0] == pytest.approx(16.0)


def test_path_error_of_a_walk_beside_the_path():
    path = Polyline.of([[0, 0], [0, 100]])
    walked = np.stack([np.full(51, 2.0), np.linspace(0, 100, 51)], axis=-1)
    error = path_error(path, walked)
    assert error["mean_distance"] == pytest.approx(2.0)
    assert error["error_percent"] == pytest.approx(2.0)
    assert error["path_covered_percent"] == pytest.approx(100.0)


@pytest.mark.parametrize(
    "text, expected",
    [
        ("{", "not valid JSON"),
        ('{"pts": [[0, 0], [1, 1]]}', "expected an object with 'points'"),
        ("[[0, 0]]", "at least 2"),
        ('[[0, 0], [1, "a"]]', "points[1] must be a pair of finite numbers"),
        ("[[0, 0], [0, 0]]", "no length"),
        ('{"points": [[0, 0], [0, 5]], "speed": -3}', "'speed' must be a positive number"),
        ("[[0, 0], [1e200, 0]]", "the path's length overflows: expected coordinates in metres"),
    ],
)
def test_bad_path_files_name_the_file_and_the_field(tmp_path, text, expected):
    file = tmp_path / "path.json"
    file.write_text(text)
    with pytest.raises(WalkdiffError) as error:
        read_path(file)
    assert expected in str(error.value) and str(file) in str(error.value)


def test_shipped_example_paths_read():
    folder = Path(__file__).parents[1] / "conf" / "paths"
    s_curve, speed = read_path(folder / "s_curve.json")
    # In metres: Xia's 160-unit S and 40-unit circle (CMU units are 0.0564 m), 20 units/s.
    assert s_curve.length > 9.0 and speed is None
    circle, speed = read_path(folder / "circle.json")
    assert circle.length == pytest.approx(2 * math.pi * 40 * 0.0564444, rel=1e-3)
    assert speed == pytest.approx(20 * 0.0564444, rel=1e-3)


def test_local_offsets_invert_the_heading_rotation():
    generator = torch.Generator().manual_seed(0)
    heading = torch.rand(5, generator=generator) * 6 - 3
    origin = torch.randn(5, 2, generator=generator)
    local = torch.randn(5, 4, 2, generator=generator)
    world = (
        yaw_matrix(heading)[:, None]
        @ torch.stack([local[..., 0], 0 * local[..., 0], local[..., 1]], -1)[..., None]
    )
    targets = world[..., [0, 2], 0] + origin[:, None]
    torch.testing.assert_close(local_offsets(targets, origin, heading), local.flatten(-2))


def test_advance_root_integrates_like_decoding():
    layout = FeatureLayout(3)
    raw = np.random.default_rng(0).normal(size=(2, 30, layout.dim))
    heading, root = root_trajectory(torch.from_numpy(raw), None, 0.4)
    position, angle = np.zeros((2, 2)), np.full(2, 0.4)
    for f in range(29):
        position, angle = advance_root(position, angle, raw[:, f], layout)
    np.testing.assert_allclose(position, root[:, -1, [0, 2]].numpy(), atol=1e-9)
    np.testing.assert_allclose(angle, heading[:, -1].numpy(), atol=1e-9)


# ---------------------------------------------------------------- the walker


def test_controls_of_real_walking_point_ahead(xia_dir):
    """On real Xia walks the control's first point is the walker itself and the others lie ahead."""
    spec = dict(
        dataset="xia", feature_dim=194, num_joints=31, window=24, fps=30.0, styles=("a",), contents=("w",)
    )
    model = PathWalker(spec, **tiny.WALKER)
    clips = [c for c in list_clips(xia_dir) if c.content == 0][:6]
    for clip in clips:
        motion = load(clip)
        raw = (
            torch.from_numpy(encode(resample(motion, 30.0), synthetic.xia_profile(motion)))
            .unsqueeze(0)
            .double()
        )
        control = model.controls_of(raw)[0].unflatten(-1, (-1, 2))  # (F, K, 2)
        assert torch.all(control[:, 0] == 0)
        ahead = control[:-1, -1]  # the farthest point, 0.5 s ahead
        assert (ahead[:, 1] > 2 * ahead[:, 0].abs()).double().mean() > 0.9, clip.name
        spacing = control[:, 1:].sub(control[:, :-1]).norm(dim=-1).mean()
        assert 0.5 < spacing.item() * 30 / 3 < 80, "3-frame spacing gives a walking speed in units/s"


@pytest.fixture(scope="module")
def synthetic_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("walk")
    synthetic.xia_like_folder(root, walk_clips=8, frames=240)
    return root


@pytest.fixture(scope="module")
def trained(synthetic_root) -> Path:
    """A tiny walker fitted for a few steps on synthetic Xia-like walks; its checkpoint."""
    model, ckpt = tiny.walker(synthetic_root)
    speeds = model.style_speed.numpy()  # the synthetic walks go at 12 units/s; styles without data: 0
    np.testing.assert_allclose(speeds[[0, 4]], 12.0, rtol=0.05)
    assert np.all(np.delete(speeds, [0, 4]) == 0)
    return ckpt


def test_walk_command_writes_bvh_gif_plot_and_error(trained, tmp_path):
    path = tmp_path / "corner.json"
    path.write_text(json.dumps({"points": [[0, 0], [0, 12], [12, 12]], "speed": 12.0}))
    out = tmp_path / "out"
    args = ["walk", "--ckpt", str(trained), "--style", "old", "--path", str(path), "--out", str(out)]
    assert main(args) == 0
    manifest = json.loads((out / "old_corner.json").read_text())
    assert manifest["frames"] == 61  # 24 m at 12 m/s, 30 fps, both ends
    motion = read_bvh(out / "old_corner.bvh")
    assert motion.num_frames == 61
    np.testing.assert_allclose(motion.root_positions[0, [0, 2]], [0, 0], atol=1e-4)
    assert (out / "old_corner.gif").stat().st_size > 0 and (out / "old_corner_path.png").stat().st_size > 0
    assert math.isfinite(manifest["path_error_m"]["error_percent"])
    assert main(args) == 1, "an existing output is not overwritten"


def test_walk_refuses_an_unknown_style(trained, tmp_path, capsys):
    path = tmp_path / "p.json"
    path.write_text("[[0, 0], [0, 10]]")
    args = ["walk", "--ckpt", str(trained), "--style", "sleepy", "--path", str(path), "--out", str(tmp_path)]
    assert main(args) == 1
    assert "valid: angry, childlike" in capsys.readouterr().err


def test_generation_is_seeded_and_batched(trained):
    model = load_walker(trained)
    path = Polyline.of([[0, 0], [0, 20]])
    speed = torch.tensor([12.0, 12.0])
    one = model.generate(path, torch.tensor([0, 4]), speed, 10, torch.Generator().manual_seed(3))[0]
    two = model.generate(path, torch.tensor([0, 4]), speed, 10, torch.Generator().manual_seed(3))[0]
    np.testing.assert_array_equal(one, two)
    assert one.shape == (2, 10, model.spec["feature_dim"]) and not np.allclose(one[0], one[1])


def test_config_trains_through_the_cli(synthetic_root, tmp_path, monkeypatch):
    """conf/walk_xia.yaml as shipped, shrunk, on the synthetic walks."""
    config = Path(__file__).parents[1] / "conf" / "walk_xia.yaml"
    monkeypatch.chdir(tmp_path)  # the config's relative checkpoint folder lands here
    args = ["fit", "--config", str(config), "--data.root", str(synthetic_root),
            "--data.cache_dir", str(synthetic_root / "cache"), "--data.preprocess_workers", "1",
            "--data.batch_size", "4", "--model.hidden", "32", "--model.timesteps", "8",
            "--trainer.max_epochs", "1", "--trainer.limit_train_batches", "2",
            "--trainer.limit_val_batches", "1",
            "--trainer.logger", "false", "--trainer.enable_progress_bar", "false"]  # fmt: skip
    assert main(args) == 0
    model = load_walker(tmp_path / "checkpoints" / "walk_xia" / "last.ckpt")
    assert model.hparams.hidden == 32 and model.ahead == [0, 3, 6, 9, 12, 15]
    assert model.style_speed[0] > 0 and model.control_normalizer.mean.abs().sum() > 0  # fitted
    # The shipped walker reads whole poses with its MLP (no fused twin) and trains with the body terms.
    assert isinstance(model.eps_net, PoseMLP) and model.hparams.lambda_foot > 0
    # ... with each frame's control and style beside the LSTM's state (not only through its memory).
    assert model.hparams.control_to_denoiser
    assert model.eps_net.cond.in_features == model.hparams.hidden + model.hparams.control_hidden
    path = Polyline.of([[0, 0], [0, 20]])
    raw, _ = model.generate(
        path, torch.tensor([0]), torch.tensor([12.0]), 3, torch.Generator().manual_seed(0)
    )
    assert raw.shape == (1, 3, model.spec["feature_dim"]) and np.isfinite(raw).all()
    with pytest.raises(WalkdiffError, match="model.denoiser must be timegrad or mlp"):
        PathWalker(model.spec, denoiser="unet")
    with pytest.raises(WalkdiffError, match="control_to_denoiser needs model.denoiser mlp"):
        PathWalker(model.spec, control_to_denoiser=True)


def test_a_path_too_long_for_memory_is_refused_before_walking(trained, tmp_path, capsys):
    path = tmp_path / "far.json"
    path.write_text(json.dumps({"points": [[0, 0], [0, 1e6]], "speed": 12.0}))  # 23 h of walking
    out = tmp_path / "new" / "out"
    args = ["walk", "--ckpt", str(trained), "--style", "old", "--path", str(path), "--out", str(out)]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert re.search(
        r"--path: 250000\d frames would need about 15.70 GB of memory, above the limit of 4.00 GB",
        err,
    )
    assert "walking" not in err
    assert not (tmp_path / "new").exists(), "a refused walk leaves no folder behind, not even an empty one"


def test_a_long_walk_gets_a_capped_preview(trained, tmp_path):
    path = tmp_path / "line.json"
    path.write_text(json.dumps({"points": [[0, 0], [0, 36]], "speed": 12.0}))  # 3 s
    out = tmp_path / "out"
    args = ["walk", "--ckpt", str(trained), "--style", "old", "--path", str(path), "--out", str(out)]
    assert main([*args, "--preview-seconds", "1"]) == 0
    manifest = json.loads((out / "old_line.json").read_text())
    assert manifest["preview"] == {
        "seconds": 1.0, "of_seconds": 3.033, "capped": True, "note": "first 1 s of 3.033 s"
    }  # fmt: skip
    with Image.open(out / "old_line.gif") as gif:
        assert gif.n_frames == 30


def test_walker_training_preview_draws_the_path(trained, tmp_path):
    """conf/walk_xia.yaml's callback: the first style walks a fixed path; the still (with the path on the
    ground), the plot (in metres), BVH, GIF and MP4 come out."""
    from walkdiff.callbacks.samples import WalkSamples
    from walkdiff.preview.scene import PATH

    model = load_walker(trained)
    points = [[0.0, 0.0], [0.4, 0.0], [0.8, 0.2]]  # metres: ~16 units of the synthetic skeleton
    files = WalkSamples(points=points).write(model, None, "", folder=tmp_path)
    assert [f.name for f in files] == [
        "angry_walk.bvh",
        "angry_walk.gif",
        "angry_walk.mp4",
        "walk.png",
        "walk_path.png",
    ]
    with Image.open(tmp_path / "walk.png") as still:
        pixels = np.asarray(still.convert("RGB"))
    assert pixels.shape[1] <= 1000 and (pixels == PATH).all(axis=-1).sum() > 100
    with Image.open(tmp_path / "walk_path.png") as plot:
        assert plot.size[0] >= 800
    with Image.open(tmp_path / "angry_walk.gif") as gif:
        gif.seek(gif.n_frames // 2)
        assert (np.asarray(gif.convert("RGB")) == PATH).all(axis=-1).sum() > 20
    with pytest.raises(WalkdiffError, match="unknown style 'tired'"):
        WalkSamples(style="tired").write(model, None, "", folder=tmp_path)


def test_walker_body_terms_put_each_predicted_frame_between_the_real_ones(xia_dir):
    """The walker's body terms (teacher forcing: a predicted frame between the real frames around it)
    are zero for the real motion, and measure a root lifted or a planted foot dragged in the skeleton's
    contact units."""
    clip = next(c for c in list_clips(xia_dir) if c.content == 0)
    motion = load(clip)
    profile = synthetic.xia_profile(motion)
    raw = torch.from_numpy(encode(resample(motion, 30.0), profile))[None, :60].float()
    spec = dict(dataset="xia", feature_dim=raw.shape[-1], num_joints=31, window=24, fps=30.0,
                styles=("a",), contents=("w",))  # fmt: skip
    model = PathWalker(spec, **tiny.WALKER)
    model.profile = profile
    weight = torch.ones(1, raw.shape[1] - 2)
    real = model.body_losses(raw, raw, weight)
    assert real["velocity"].item() == pytest.approx(0, abs=1e-9)
    assert real["foot_height"].item() == pytest.approx(0, abs=1e-9)
    assert real["foot"].item() < 0.1  # real planted feet hardly move
    lifted = raw.clone()
    lifted[..., model.layout.root_height] += profile.contacts.height_threshold
    assert model.body_losses(raw, lifted, weight)["foot_height"].item() == pytest.approx(1, rel=1e-4)
    # A root step twice as long drags the planted feet of the frame after it.
    striding = raw.clone()
    striding[..., model.layout.root_vel] *= 2
    dragged = model.body_losses(raw, striding, weight)
    assert dragged["foot"].item() > 10 * real["foot"].item() + 0.1
    assert dragged["velocity"].item() > 0.1
