"""Editing motion (issue 45): in-betweening, keyframes and partial-body edits through masked sampling, in
the Python API and on the command line; the root projection, the window tiling and the in-betweening
measures on their own."""

from __future__ import annotations

import json

import numpy as np
import pytest
import synthetic
import tiny
import torch
from PIL import Image

import walkdiff
from walkdiff.bench.inbetween import gap_starts, interpolated, zero_velocity
from walkdiff.cli.main import main
from walkdiff.diffusion import GaussianDiffusion
from walkdiff.metrics.inbetween import l2p, l2q, npss
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.representation import FeatureLayout, root_trajectory
from walkdiff.styled.editing import RootKey, project_root, reconstruction_guided, tiled

FAST = dict(sampler="ddim", steps=4)
TOLERANCE = 1e-4  # body heights: kept parts come out as given


@pytest.fixture(scope="module")
def styled(tmp_path_factory):
    root = tmp_path_factory.mktemp("styled")
    synthetic.xia_like_folder(root, walk_clips=6, frames=240)
    return tiny.generator(root, epochs=5)


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """A walk cut in two BVH files with a gap between (at 120 fps: 4 file frames a model frame)."""
    folder = tmp_path_factory.mktemp("clips")
    walk = synthetic.walking(480, fps=120.0, seed=4)
    a, b = folder / "a.bvh", folder / "b.bvh"
    write_bvh(a, walk.slice(0, 160))
    write_bvh(b, walk.slice(320, 480))
    return a, b


def world(path_or_motion):
    motion = read_bvh(path_or_motion) if not hasattr(path_or_motion, "rotations") else path_or_motion
    return motion_world_positions(motion)


def test_inbetween_keeps_a_and_b_exactly_and_fills_the_gap(styled, clips):
    model = walkdiff.load(styled)
    a, b = clips
    height = model.model.profile.body_height
    result = model.inbetween(a, b, frames=20, style="old", seed=1, **FAST)
    take = result.take
    assert take.num_frames == 40 + 20 + 40 and result.extra["fill"] == (40, 60)
    made = take.positions
    # The inputs read at the model's 30 fps (every 4th frame of the 120 fps files), placed where they are.
    given_a, given_b = world(a)[::4], world(b)[::4]
    assert np.abs(made[:40] - given_a).max() < TOLERANCE * height
    assert np.abs(made[60:] - given_b).max() < TOLERANCE * height
    assert result.extra["kept_error"] < TOLERANCE
    fill = made[40:60]
    assert np.isfinite(fill).all() and np.abs(np.diff(fill, axis=0)).max() > 0  # it moves
    # No jump at the seams: the steps into and out of the fill are like the steps inside it.
    speed = np.linalg.norm(np.diff(made, axis=0), axis=-1).mean(-1)
    assert max(speed[39], speed[59]) < 3 * np.percentile(speed[40:59], 90)

    model.resample = 1  # RePaint's resampling: the same guarantees
    again = model.inbetween(a, b, frames=20, style="old", seed=1, **FAST)
    assert again.extra["kept_error"] < TOLERANCE and not np.allclose(again.positions[40:60], fill)
    model.resample = 0
    assert model.guide > 0  # fills are guided by default; unguided ones keep the same guarantees
    model.guide = 0.0
    plain = model.inbetween(a, b, frames=20, style="old", seed=1, **FAST)
    assert plain.extra["kept_error"] < TOLERANCE and not np.allclose(plain.positions[40:60], fill)
    model.guide = type(model).guide

    only = model.inbetween(a, b, frames=20, style="old", seed=1, fill_only=True, **FAST)
    assert only.num_frames == 20
    np.testing.assert_allclose(only.positions, fill, atol=1e-6 * height)

    # Eight fills by default, drawn together and the most typical kept; one alone keeps the same guarantees.
    one = model.inbetween(a, b, frames=20, style="old", seed=1, candidates=1, **FAST)
    assert result.settings["candidates"] == 8 and one.settings["candidates"] == 1
    assert one.extra["kept_error"] < TOLERANCE and not np.allclose(one.positions[40:60], fill)


def test_inbetween_defaults_to_eight_fills_in_twenty_dpm_solver_steps(styled, clips, tmp_path):
    model = walkdiff.load(styled)
    a, b = clips
    made = model.inbetween(a, b, frames=12, style="old", seed=2)
    settings = made.settings
    assert (settings["sampler"], settings["steps"], settings["candidates"]) == ("dpmpp", 20, 8)
    # A sampler that takes steps, named without them, takes the fill's 20; DDPM every trained step.
    assert model.inbetween(a, b, frames=12, sampler="ddim", candidates=1).settings["steps"] == 20
    spec = {"name": "dpmpp"}  # the spec as a dict (or a SamplerChoice) without steps: the same
    assert model.inbetween(a, b, frames=12, sampler=spec, candidates=1).settings["steps"] == 20
    ddpm = model.inbetween(a, b, frames=12, sampler="ddpm", candidates=1).settings
    assert (ddpm["sampler"], ddpm["steps"]) == ("ddpm", None)
    # The command's defaults are the API's.
    out = tmp_path / "default.bvh"
    args = ["--frames", "12", "--out", str(out), "--ckpt", str(styled), "--style", "old", "--seed", "2"]
    assert main(["inbetween", str(a), str(b), *args]) == 0
    assert made.to_bvh(tmp_path / "api.bvh").read_text() == out.read_text()
    assert json.loads(out.with_suffix(".json").read_text())["settings"] == settings


def test_a_gap_longer_than_a_window_and_placing_b(styled, clips):
    model = walkdiff.load(styled)
    a, b = clips
    height = model.model.profile.body_height
    long = model.inbetween(a, b, frames=70, style="angry", **FAST)  # the window is 24 frames
    assert long.num_frames == 150 and long.extra["kept_error"] < TOLERANCE
    np.testing.assert_allclose(long.positions[110:], world(b)[::4], atol=TOLERANCE * height)

    placed = model.inbetween(a, b, frames=70, style="angry", place=True, **FAST)
    moved = placed.positions[110:]
    given = world(b)[::4]
    assert np.abs(moved - given).max() > 1e-3 * height  # B went where the fill took it ...
    relative = lambda p: p - p[:1, :1]  # noqa: E731
    # ... turned about the vertical and moved on the ground, its own motion unchanged (heights as given).
    np.testing.assert_allclose(moved[..., 1], given[..., 1], atol=TOLERANCE * height)
    np.testing.assert_allclose(
        np.linalg.norm(relative(moved), axis=-1),
        np.linalg.norm(relative(given), axis=-1),
        atol=TOLERANCE * height,
    )


def test_bad_inbetweens_are_named(styled, clips, tmp_path):
    model = walkdiff.load(styled)
    a, b = clips
    with pytest.raises(walkdiff.WalkdiffError, match="^frames: the gap must be at least 1 frame, got 0"):
        model.inbetween(a, b, frames=0, style="old", **FAST)
    with pytest.raises(
        walkdiff.WalkdiffError, match=r"^candidates: expected a whole number of fills >= 1, got 0"
    ):
        model.inbetween(a, b, frames=10, style="old", candidates=0, **FAST)
    other = tmp_path / "other.bvh"
    motion = read_bvh(a)
    skeleton = motion.skeleton
    renamed = type(skeleton)(
        names=[n if n != "Head" else "Skull" for n in skeleton.names], parents=skeleton.parents,
        offsets=skeleton.offsets, channels=skeleton.channels, end_sites=skeleton.end_sites,
    )  # fmt: skip
    write_bvh(other, type(motion)(renamed, motion.rotations, motion.positions, motion.frame_time))
    with pytest.raises(walkdiff.WalkdiffError, match=r"other\.bvh.*another skeleton.*Head"):
        model.inbetween(a, other, frames=10, style="old", **FAST)


def test_keys_are_passed_through(styled, clips, tmp_path):
    model = walkdiff.load(styled)
    height = model.model.profile.body_height
    keys = [
        {"frame": 0, "root": [0.0, 0.0, 0.0], "heading": 0},
        {"frame": 30, "root": [20.0, 0.0, 40.0]},
        {"frame": 59, "root": [-10.0, 0.0, 80.0], "heading": 90},
    ]
    result = model.sample(keys=keys, frames=60, num=2, style="old", **FAST)
    for take in result:
        root = take.positions[:, 0]
        for key in keys:
            np.testing.assert_allclose(
                root[key["frame"], [0, 2]], np.array(key["root"])[[0, 2]], atol=1e-4 * height
            )
    assert result.extra["root_key_error"] < 1e-4

    # Key poses from a BVH with their frame numbers: those frames are the poses exactly.
    poses = read_bvh(clips[0]).slice(0, 160)
    keyed = tmp_path / "keys.bvh"
    write_bvh(
        keyed, type(poses)(poses.skeleton, poses.rotations[[0, 100]], poses.positions[[0, 100]], 1 / 30)
    )
    posed = model.sample(keys=f"{keyed}@5,50", frames=60, style="angry", **FAST).take
    given = world(keyed)
    assert np.abs(posed.positions[5] - given[0]).max() < TOLERANCE * height
    assert np.abs(posed.positions[50] - given[1]).max() < TOLERANCE * height

    with pytest.raises(walkdiff.WalkdiffError, match="key at frame 60 is outside the 60-frame clip"):
        model.sample(keys=[{"frame": 60, "heading": 0}], frames=60, style="old", **FAST)
    with pytest.raises(walkdiff.WalkdiffError, match="unknown field 'rot'"):
        model.sample(keys=[{"frame": 1, "rot": 0}], frames=60, style="old", **FAST)


def test_edits_keep_the_kept_joints_exactly(styled, clips):
    model = walkdiff.load(styled)
    clip = read_bvh(clips[0])
    height = model.model.profile.body_height
    legs = "LHipJoint,LeftUpLeg,LeftLeg,LeftFoot,LeftToeBase"
    result = model.edit(clip, keep=legs, style="angry", **FAST)
    source, made = model.source(clip), result.take.canonical()
    kept = [made.skeleton.index(n) for n in legs.split(",")]
    np.testing.assert_allclose(made.rotations[:, kept], source.rotations[:, kept], atol=1e-6)
    others = [j for j in range(made.skeleton.num_joints) if j not in kept]
    assert np.abs(made.rotations[:, others] - source.rotations[:, others]).max() > 1e-2  # made anew
    assert result.extra["kept_error"] < TOLERANCE

    rooted = model.edit(clip, keep="root", style="old", **FAST)
    np.testing.assert_allclose(rooted.take.positions[:, 0], world(clip)[::4, 0], atol=TOLERANCE * height)
    with pytest.raises(walkdiff.WalkdiffError, match="^keep: no joint 'Tail' in the model's skeleton"):
        model.edit(clip, keep="Hips,Tail", style="old", **FAST)


def test_edit_legs_and_upper_body_found_by_the_humanoid_map(xia_tiny, xia_dir):
    model = walkdiff.load(xia_tiny["generator"])
    clip = xia_dir / "old_01_000.bvh"
    names = model.skeleton.names
    for keep in ("legs", "upper-body"):
        result = model.edit(clip, keep=keep, style="neutral", **FAST)
        kept = set(result.settings["kept_joints"])
        assert ("LeftFoot" in kept) == (keep == "legs") and ("LeftHand" in kept) == (keep == "upper-body")
        assert len(kept) < len(names) and result.extra["kept_error"] < TOLERANCE


def test_commands_write_what_the_api_makes(styled, clips, tmp_path):
    a, b = clips
    out = tmp_path / "fill.bvh"
    args = ["--ckpt", str(styled), "--style", "old", "--sampler", "ddim", "--steps", "4", "--seed", "2"]
    assert main(["inbetween", str(a), str(b), "--frames", "12", "--out", str(out), *args]) == 0
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["fill_frames"] == [40, 52] and report["kept_error_body_heights"] < TOLERANCE
    # The previews show the input (A, A's last pose held over the gap, B) beside the result.
    assert out.with_suffix(".gif").stat().st_size > 0 and out.with_suffix(".mp4").stat().st_size > 0
    assert report["preview"]["of_seconds"] == round(92 / 30, 3)  # 40 + 12 + 40 frames at 30 fps
    with Image.open(out.with_suffix(".gif")) as gif:
        assert gif.size[0] == 2 * 320  # two panels
    api = walkdiff.load(styled).inbetween(a, b, frames=12, style="old", seed=2, **FAST)
    assert api.to_bvh(tmp_path / "api.bvh").read_text() == out.read_text()
    four = tmp_path / "four.bvh"
    assert (
        main(
            [
                "inbetween",
                str(a),
                str(b),
                "--frames",
                "12",
                "--out",
                str(four),
                "--candidates",
                "4",
                "--no-gif",
                *args,
            ]
        )
        == 0
    )
    api = walkdiff.load(styled).inbetween(a, b, frames=12, style="old", seed=2, candidates=4, **FAST)
    assert api.to_bvh(tmp_path / "api_four.bvh").read_text() == four.read_text() != out.read_text()
    assert (
        not four.with_suffix(".gif").exists()
        and json.loads(four.with_suffix(".json").read_text())["preview"] is None
    )
    held = api.extra["source"].motion  # the input as one take: A, the gap held at A's last pose, B
    assert held.num_frames == 92 and np.array_equal(
        held.rotations[40:52], held.rotations[39:40].repeat(12, 0)
    )
    assert (
        main(["inbetween", str(a), str(b), "--frames", "12", "--out", str(out), *args]) == 1
    )  # no overwrite

    keys = tmp_path / "keys.json"
    keys.write_text(json.dumps({"keys": [{"frame": 0, "heading": 0}, {"frame": 40, "heading": 45}]}))
    folder = tmp_path / "keyed"
    code = main(["sample", "--keys", str(keys), "--frames", "48", "--num", "1", "--out", str(folder),
                 "--no-gif", *args])  # fmt: skip
    assert code == 0 and json.loads((folder / "manifest.json").read_text())["keys"]["source"] == str(keys)

    edited = tmp_path / "edited.bvh"
    assert main(["edit", str(a), "--keep", "Hips", "--out", str(edited), *args]) == 0
    assert read_bvh(edited).num_frames == 40 and edited.with_suffix(".gif").exists()
    (tmp_path / "taken.gif").write_bytes(b"")  # a preview in the way is refused before any work, as the BVH
    taken = tmp_path / "taken.bvh"
    assert main(["edit", str(a), "--keep", "Hips", "--out", str(taken), *args]) == 1 and not taken.exists()


# ---------------------------------------------------------------- the machinery on its own


def test_root_projection_reaches_every_key_by_the_least_uniform_change():
    torch.manual_seed(0)
    layout = FeatureLayout(3)
    raw = torch.randn(2, 30, layout.dim, dtype=torch.float64) * 0.1
    keys = [RootKey(4, (1.0, -2.0), 0.3), RootKey(17, (5.0, 1.0), -1.0), RootKey(29, (0.0, 9.0), 2.0)]
    free = np.ones(30, bool)
    free[10:12] = False  # kept steps stay as they are
    out = project_root(raw, keys, free, free)
    assert torch.equal(out[:, 10:12], raw[:, 10:12])
    from walkdiff.styled.editing import placement_heading

    heading, root = root_trajectory(out, None, placement_heading(out, keys))
    offset = torch.tensor(keys[0].position, dtype=torch.float64) - root[:, 4, [0, 2]]
    for key in keys:
        np.testing.assert_allclose(
            (root[:, key.frame, [0, 2]] + offset).numpy(), np.tile(key.position, (2, 1)), atol=1e-9
        )
        turned = np.angle(np.exp(1j * (heading[:, key.frame].numpy() - key.heading)))  # modulo a turn
        np.testing.assert_allclose(turned, 0, atol=1e-9)


def test_tiled_windows_average_to_the_model_on_any_length():
    calls = []

    def model_fn_of(windows: int):
        calls.append(windows)
        return lambda x, t: x * 2 + t[:, None, None]

    for frames in (10, 24, 57):
        denoise = tiled(model_fn_of, frames, 24, 12)
        x = torch.randn(3, frames, 5)
        np.testing.assert_allclose(denoise(x, torch.full((3,), 7)).numpy(), (x * 2 + 7).numpy(), rtol=1e-6)
    assert calls == [1, 1, 4]  # 57 frames: windows at 0, 12, 24 and 33


def test_reconstruction_guidance_pulls_the_made_part_to_agree_with_the_known():
    diffusion = GaussianDiffusion(10, prediction="x0")
    # A toy network whose clean estimate of every frame is the mean over frames: the known frame's
    # estimate depends on the made ones, so agreeing with it means moving them.
    model_fn = lambda x, t: x.mean(1, keepdim=True).expand_as(x)  # noqa: E731
    mask = torch.zeros(2, 6, 3, dtype=torch.bool)
    mask[:, 0] = True
    known = torch.ones(2, 6, 3)
    x, t = torch.zeros(2, 6, 3), torch.full((2,), 4)
    plain = model_fn(x, t)
    guided = reconstruction_guided(model_fn, diffusion, mask, known, 1.0)(x, t)
    assert torch.equal(guided[:, 0], plain[:, 0])  # known channels' output as the network's
    assert (guided[:, 1:] > plain[:, 1:]).all()  # made ones moved toward what makes the known estimate 1
    stronger = reconstruction_guided(model_fn, diffusion, mask, known, 3.0)(x, t)
    assert (stronger[:, 1:] > guided[:, 1:]).all()


def test_inbetween_measures():
    rng = np.random.default_rng(0)
    real = rng.normal(size=(3, 12, 5, 3))
    assert np.allclose(l2p(real, real, 0, 1), 0)
    np.testing.assert_allclose(l2p(real + np.array([2.0, 0, 0]), real, 0, 2), np.sqrt(5))  # 5 joints off by 1
    q = rng.normal(size=(3, 12, 5, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    assert np.allclose(l2q(-q, q), 0) and l2q(np.roll(q, 1, axis=1), q).min() > 0
    signal = np.sin(np.linspace(0, 4 * np.pi, 30))[None, :, None] * np.ones((1, 1, 4))
    assert np.allclose(npss(signal, signal), 0)
    slow = np.sin(np.linspace(0, np.pi, 30))[None, :, None] * np.ones((1, 1, 4))
    assert npss(slow, signal)[0] > npss(signal * 2, signal)[0]  # scale keeps the spectrum's shape


def test_baselines_run_from_the_last_context_frame_to_the_keyframe():
    walk = synthetic.walking(120, fps=30.0, seed=1)
    lerp = interpolated(walk, 40, 9)
    assert lerp.num_frames == 9
    np.testing.assert_allclose(lerp.positions[4, 0], (walk.positions[39, 0] + walk.positions[49, 0]) / 2)
    held = zero_velocity(walk, 40, 9)
    assert np.allclose(held.rotations, walk.rotations[39]) and np.allclose(held.positions, walk.positions[39])
    assert gap_starts(60, 45, 10, 3) == [10, 12, 14] and gap_starts(50, 45, 10, 3) == []
    starts = gap_starts(100, 15, 10, 5)  # every offset of a clip, at most 5 frames apart
    assert starts[0] == 10 and starts[-1] == 84 and max(np.diff(starts)) <= 5 and len(starts) == 16


def test_the_most_typical_fill_is_the_one_in_the_middle_of_the_others(xia_dir):
    """Of fills that all hold A's context and B's keyframe, `most_typical` keeps the one nearest the rest:
    the real walk over the same walk running behind it through the gap, running ahead of it, and jittered
    (the real one lies between them), whatever order they come in (a real Xia walk, 10 + 45 + 1 frames at
    30 fps)."""
    from walkdiff.data.xia import PROFILE
    from walkdiff.motion.profile import SkeletonProfile
    from walkdiff.motion.representation import encode
    from walkdiff.styled.editing import Constraint, most_typical

    motion = read_bvh(xia_dir / "neutral_01_000.bvh")
    profile = SkeletonProfile.detect(motion, PROFILE)
    canonical = profile.to_canonical(motion)
    canonical = type(canonical)(
        canonical.skeleton, canonical.rotations[::4], canonical.positions[::4], canonical.frame_time * 4
    )
    raw = encode(canonical, profile)[:56].astype(np.float64)
    held = np.zeros(56, bool)
    held[:10] = held[55:] = True
    constraint = Constraint(raw, np.zeros(raw.shape, bool))
    u = np.linspace(0.0, 1.0, 46)[:-1]
    behind, ahead, jittered = raw.copy(), raw.copy(), raw.copy()
    behind[10:55] = raw[np.round(10 + 45 * u**1.5).astype(int)]
    ahead[10:55] = raw[np.round(10 + 45 * u ** (1 / 1.5)).astype(int)]
    jittered[10:55] += np.random.default_rng(0).normal(0.0, 0.02, raw[10:55].shape)
    fills = [raw, behind, ahead, jittered]
    for turn in range(4):
        order = fills[turn:] + fills[:turn]
        picked = most_typical(np.stack(order), constraint, held, canonical.skeleton, 30.0)
        assert order[picked] is raw


def test_bench_inbetween_fills_each_held_out_clip_with_its_own_content(tmp_path, monkeypatch):
    """A model of several contents is measured on every one: each held-out clip's gap is filled with the
    clip's own content label, and the report counts the windows of each."""
    from test_training import tiny_evaluator

    from walkdiff.bench.inbetween import HeldOut, bench_inbetween

    root = tmp_path / "data"
    synthetic.xia_like_folder(root, walk_clips=6, frames=240)  # walks and a run per style
    ckpt = tiny.generator(root, epochs=2, data_options={"contents": "all"})
    evaluator = tiny_evaluator(root, tmp_path / "evaluator.ckpt")
    asked = []
    request = HeldOut.request

    def recorded(self, style, content, sampler, steps):
        asked.append(content)
        return request(self, style, content, sampler, steps)

    monkeypatch.setattr(HeldOut, "request", recorded)
    result = bench_inbetween(
        ckpt, evaluator, tmp_path / "inbetween.json", gaps=(45,), sampler="ddim", steps=2, repeats=1,
        resamples=20,
    )  # fmt: skip
    gap = result["gaps"]["45"]
    assert set(gap["contents"]) == {"walk", "run"}, gap["contents"]
    assert sum(gap["contents"].values()) == gap["windows"]
    assert asked.count("run") >= gap["contents"]["run"] and "walk" in asked
