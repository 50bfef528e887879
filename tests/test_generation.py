"""Sampling of any length, style mixing, guidance, transfer and the `sample` / `transfer` commands.

A tiny generator (tests/tiny.py) is trained here for a few hundred batches on synthetic walks.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import synthetic
import tiny
import torch
from PIL import Image

from walkdiff.cli.main import main
from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion import GaussianDiffusion, log_snr_timesteps
from walkdiff.models.style_labels import parse_style
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.representation import features_to_positions
from walkdiff.styled.generation import (
    Sampling,
    generate_long,
    joint_speeds,
    load_generator,
    noised_steps,
    resolve_windows,
    restyle,
    seam_steps,
    seam_tails,
    seams_within_spread,
    window_plan,
    windowed,
)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("generation")
    synthetic.xia_like_folder(root, walk_clips=6, frames=240)
    return tiny.generator(root)


@pytest.fixture(scope="module")
def model(ckpt):
    return load_generator(ckpt)


@pytest.fixture(autouse=True)
def plain_argv(monkeypatch):
    monkeypatch.setattr("sys.argv", ["walkdiff"])


@pytest.mark.parametrize("frames", [1, 10, 24, 25, 40, 97, 300])
@pytest.mark.parametrize("overlap", [1, 8, 23])
def test_window_plan_covers_every_frame_once_with_the_overlap_known(frames, overlap):
    plan = window_plan(frames, 24, overlap)
    size = min(24, frames)
    done = 0
    for start, known in plan:
        assert start + known == done and 0 <= start and start + size <= frames
        assert known == 0 if start == 0 else known >= overlap
        done = start + size
    assert done == frames


def test_seam_criterion_passes_seamless_speeds_and_fails_jumps_and_halts():
    """Seams drawn like the inside steps pass; a speed-up or a halt of a quarter of the spread at every
    seam fails, however few seams there are."""
    speeds = torch.rand(64, 299, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 10 + 15
    seams = list(range(23, 299, 12)) + list(range(20, 299, 12))  # 48 of 299 steps
    below, above = seam_tails(speeds, seams)
    assert abs(below - 0.05) < 0.02 and abs(above - 0.05) < 0.02
    assert seams_within_spread(speeds, seams)
    for shift in (2.5, -2.5):
        shifted = speeds.clone()
        shifted[:, seams] += shift
        assert not seams_within_spread(shifted, seams), shift
    spike = speeds.clone()
    spike[:, seams[:1]] = 100.0
    assert seam_tails(spike, seams[:1])[1] == 1.0 and not seams_within_spread(spike, seams[:1])


def test_window_plan_rejects_bad_overlap():
    for overlap in (0, 24):
        with pytest.raises(WalkdiffError, match="overlap must be in"):
            window_plan(100, 24, overlap)


def test_windowed_holds_then_crossfades_the_shared_frames():
    calls = []

    def denoise(start, stop, inpaint):  # window k is all k, except where it is held
        calls.append(inpaint)
        out = torch.full((1, stop - start, 1), float(len(calls)))
        return out if inpaint is None else torch.where(inpaint[0] >= 1, inpaint[1], out)

    x = windowed(1, 40, 1, 24, 8, denoise, blend=4)[0, :, 0]  # windows at 0 and 16
    # Held frames always; fade frames for a falling share of the steps; new frames never.
    torch.testing.assert_close(
        calls[1][0][0, :, 0], torch.tensor([1.0] * 4 + [0.8, 0.6, 0.4, 0.2] + [0.0] * 16)
    )
    assert x[:20].tolist() == [1.0] * 20
    torch.testing.assert_close(x[20:24], torch.tensor([1.2, 1.4, 1.6, 1.8]))
    assert x[24:].tolist() == [2.0] * 16
    assert resolve_windows(24, None, None) == (12, 6)
    with pytest.raises(WalkdiffError, match="--blend must be in \\[0, 7\\]"):
        resolve_windows(24, 8, 8)


def test_parse_style_ids_mixes_and_errors(model):
    style, label = parse_style(model, "old")
    assert style.dtype == torch.long and style.ndim == 0 and label == "old"
    mix, label = parse_style(model, "angry:0.7, old:0.7")  # scaled to sum 1
    styles = list(model.spec["styles"])
    assert mix.sum().item() == pytest.approx(1.0) and label == "angry50+old50"
    assert mix[styles.index("angry")] == mix[styles.index("old")] == pytest.approx(0.5)

    with pytest.raises(WalkdiffError, match="unknown style happy; valid: angry, childlike"):
        parse_style(model, "happy:1,old:1")
    with pytest.raises(WalkdiffError, match="weights > 0"):
        parse_style(model, "angry:-1,old:2")


def test_long_motion_has_no_seams_and_a_continuous_root(model):
    # 64 clips: with 8 the share of 32 seam steps past the 5-95% band swings by +-4% between machines
    # whose floating point differs, across the 10% the criterion allows.
    frames, window, overlap = 88, 24, 8
    style = torch.tensor([0, 4] * 32)
    content = torch.zeros(64, dtype=torch.long)
    generator = torch.Generator().manual_seed(0)
    x = generate_long(model, style, content, frames, Sampling("ddim", 3), generator, overlap, blend=0)
    assert x.shape == (64, frames, model.spec["feature_dim"]) and torch.isfinite(x).all()
    seams = seam_steps(frames, window, overlap)  # steps from the last known frame of a window to a new one
    assert seams == [23, 39, 55, 71]
    assert seams_within_spread(joint_speeds(model, x), seams)
    # Cross-faded: the first 4 shared frames held, the next 4 faded; the seam is those 5 steps.
    faded = generate_long(model, style, content, frames, Sampling("ddim", 5), generator, overlap, blend=4)
    fade_seams = seam_steps(frames, window, overlap, blend=4)
    assert fade_seams[:5] == [19, 20, 21, 22, 23] and len(fade_seams) == 20
    assert seams_within_spread(joint_speeds(model, faded), fade_seams)
    # The check can fail: the new part of each window decoded on its own starts back at the origin.
    pieces = [model.to_raw(x[:, : seams[0] + 1])] + [
        model.to_raw(x[:, a + 1 : b + 1]) for a, b in zip(seams, seams[1:] + [frames - 1])
    ]
    skeleton = model.skeleton
    offsets = torch.from_numpy(skeleton.offsets)
    positions = torch.cat(
        [features_to_positions(torch.from_numpy(p).double(), offsets, skeleton.parents) for p in pieces],
        dim=1,
    )
    restarted = (positions[:, 1:] - positions[:, :-1]).norm(dim=-1).mean(-1) * 30.0
    assert not seams_within_spread(restarted, seams)


def test_guidance_and_style_mixing_sample(model):
    mix, _ = parse_style(model, "angry:0.7,old:0.3")
    content = torch.zeros(2, dtype=torch.long)
    out = {}
    for style in (mix.expand(2, -1), torch.tensor([0, 0])):
        for w in (1.0, 2.5):
            x = generate_long(
                model, style, content, 30, Sampling("ddim", 2, guidance=w), torch.Generator().manual_seed(1)
            )
            assert x.shape == (2, 30, model.spec["feature_dim"]) and torch.isfinite(x).all()
            out[style.is_floating_point(), w] = x
    assert not torch.allclose(out[True, 1.0], out[True, 2.5])  # guidance changes the sample
    assert not torch.allclose(out[True, 1.0], out[False, 1.0])  # so does mixing in another style


def test_noised_steps_start_at_strength():
    class Fake:
        diffusion = GaussianDiffusion(100, "linear", 1e-3, 0.2)

    t0, steps, eta = noised_steps(Fake, 0.6, Sampling())
    assert (t0, steps[0], steps[-1], len(steps), eta) == (59, 59, 0, 60, 1.0)
    t0, steps, eta = noised_steps(Fake, 0.6, Sampling("ddim", 10, eta=0.5))
    assert (t0, steps[0], steps[-1], len(steps), eta) == (59, 59, 9, 6, 0.5)  # trailing: 59, 49, ..., 9
    assert (Sampling().order, Sampling("ddim", 10).order, Sampling("dpmpp", 10).order) == (1, 1, 2)
    t0, steps, eta = noised_steps(Fake, 0.6, Sampling("dpmpp", 10))  # even in log-SNR below t0
    assert (t0, steps, eta) == (59, log_snr_timesteps(Fake.diffusion, 6, first=59), 0.0)
    with pytest.raises(WalkdiffError, match="--eta applies to ddim only"):
        Sampling("dpmpp", 10, eta=0.5)
    with pytest.raises(WalkdiffError, match="expected one of ddpm, ddim, dpmpp"):
        Sampling("euler")

    with pytest.raises(WalkdiffError, match="strength"):
        noised_steps(Fake, 0.0, Sampling())


def test_restyle_keeps_the_root_channels_and_moves_with_strength(model):
    clip = synthetic.walking(200, fps=120.0, seed=3)
    from walkdiff.motion.representation import encode
    from walkdiff.motion.resample import resample

    features = encode(resample(clip, 30.0), synthetic.xia_profile(clip))
    source = model.normalizer.normalize(torch.from_numpy(features))[None]
    source = source.expand(2, -1, -1)
    style, content = torch.tensor([0, 4]), torch.zeros(2, dtype=torch.long)
    changes = []
    for strength in (0.2, 0.9):
        out = restyle(
            model, source, style, content, strength, Sampling("ddim", 5), torch.Generator().manual_seed(0),
            keep_trajectory=True,
        )  # fmt: skip
        torch.testing.assert_close(out[..., [0, 1, 3]], source[..., [0, 1, 3]])
        changes.append((out - source).abs().mean().item())
    assert changes[0] < changes[1]


def test_sample_command_writes_bvh_gif_manifest_and_refuses_to_overwrite(ckpt, model, tmp_path, capsys):
    out = tmp_path / "samples"
    args = ["sample", "--ckpt", str(ckpt), "--style", "angry:0.7,old:0.3", "--num", "2", "--frames", "40",
            "--sampler", "ddim", "--steps", "2", "--seed", "5", "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "angry70+old30_walk_000.bvh", "angry70+old30_walk_000.gif", "angry70+old30_walk_000.mp4",
        "angry70+old30_walk_001.bvh", "angry70+old30_walk_001.gif", "angry70+old30_walk_001.mp4",
        "manifest.json",
    ]  # fmt: skip
    clip = read_bvh(out / "angry70+old30_walk_000.bvh")
    assert clip.num_frames == 40 and clip.fps == pytest.approx(30.0)
    assert clip.skeleton.same_hierarchy(model.skeleton)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["checkpoint"] == str(ckpt) and manifest["seed"] == 5
    assert manifest["settings"]["sampler"] == "ddim" and manifest["settings"]["steps"] == 2
    assert manifest["settings"]["distilled_jumps"] is False  # a trained model, not a student
    assert manifest["timing"]["generate_s"] > 0

    before = (out / "angry70+old30_walk_000.bvh").read_text()
    assert main(args) == 1
    assert "would overwrite" in capsys.readouterr().err
    assert main(args + ["--overwrite", "--seed", "6", "--fix-feet", "--no-gif"]) == 0
    assert (out / "angry70+old30_walk_000.bvh").read_text() != before
    assert main(args[:4] + ["happy"] + args[5:] + ["--overwrite"]) == 1
    assert "valid: angry, childlike, depressed, neutral, old" in capsys.readouterr().err


def test_transfer_command_resamples_keeps_the_path_and_refuses_other_skeletons(ckpt, model, tmp_path, capsys):
    clip = synthetic.walking(200, fps=120.0, seed=3)
    source = tmp_path / "mine.bvh"
    write_bvh(source, clip)
    out = tmp_path / "out"
    common = ["transfer", "--ckpt", str(ckpt), "--input", str(source), "--style", "old", "--out", str(out),
              "--sampler", "dpmpp", "--steps", "4"]  # fmt: skip
    assert main(common + ["--keep-trajectory"]) == 0
    result = read_bvh(out / "mine_to_old.bvh")
    assert result.num_frames == 50 and result.fps == pytest.approx(30.0)  # 200 frames at 120 fps
    report = json.loads((out / "mine_to_old.json").read_text())
    assert report["root_path_error"]["relative"] < 0.01
    assert (out / "mine_to_old.gif").is_file()
    assert main(common + ["--overwrite", "--strength", "1.0"]) == 0
    free = json.loads((out / "mine_to_old.json").read_text())
    assert free["root_path_error"]["relative"] > 10 * report["root_path_error"]["relative"]

    other = synthetic.skeleton()
    other.names[other.names.index("Head")] = "Skull"
    write_bvh(
        tmp_path / "alien.bvh", synthetic.Motion(other, clip.rotations, clip.positions, clip.frame_time)
    )
    assert main(common[:4] + [str(tmp_path / "alien.bvh")] + common[5:]) == 1
    err = capsys.readouterr().err
    assert "another skeleton" in err and "missing Head" in err and "extra Skull" in err
    assert np.isfinite(result.rotations).all()


def test_distill_writes_a_student_checkpoint_every_command_takes(ckpt, model, tmp_path, capsys):
    student_path = tmp_path / "student.ckpt"
    args = ["distill", "--ckpt", str(ckpt), "--out", str(student_path), "--steps", "2,1", "--iterations", "3"]
    assert main([*args, "--teacher-steps", "20"]) == 0
    printed = capsys.readouterr().out
    assert f"distilling {ckpt} for DDIM-1, DDIM-2 (teacher: DPM-Solver++ over 20 steps): 3 batches" in printed
    assert f"wrote {student_path}" in printed
    record = torch.load(student_path, map_location="cpu", weights_only=False)["distilled"]
    assert record["teacher"] == str(ckpt) and record["steps"] == [1, 2] and record["batches"] == 3
    assert record["teacher_steps"] == 20
    student = load_generator(student_path)
    assert student.distilled_steps == [1, 2]
    weights = dict(student.ema.module.named_parameters())
    moved = [not torch.equal(weights[name], p) for name, p in model.ema.module.named_parameters()]
    assert any(moved) and weights["jump_mlp.2.weight"].abs().sum() > 0

    # Deterministic DDIM over the distilled step count gives the network the jumps; nothing else does.
    seen = []
    forward = student.ema.module.forward
    student.ema.module.forward = lambda x, t, s, c, jump=None: seen.append(jump) or forward(x, t, s, c, jump)
    style, content = torch.tensor([0, 1]), torch.tensor([0, 0])
    student.generate(style, content, sampler="ddim", steps=1)
    student.generate(style, content, sampler="ddim", steps=2)
    assert [j.tolist() for j in seen] == [[100, 100], [50, 50], [50, 50]]  # 99 to data; 99 to 49 to data
    seen.clear()
    # Every other sampler is the teacher's: the student carries its network, as the teacher saved it.
    student.generate(style, content, sampler="ddim", steps=4)
    assert not seen
    taught = []
    teacher_forward = student.teacher.forward
    student.teacher.forward = lambda x, t, s, c, jump=None: taught.append(jump) or teacher_forward(x, t, s, c)
    student.generate(style, content, sampler="ddim", steps=4)
    student.generate(style, content, sampler="dpmpp", steps=2)
    student.generate(style, content, sampler="ddim", steps=2, eta=0.5)
    assert not seen and len(taught) == 8 and all(j is None for j in taught)
    del student.ema.module.forward, student.teacher.forward
    for name, p in model.ema.module.named_parameters():
        assert torch.equal(dict(student.teacher.named_parameters())[name], p)
    torch.manual_seed(3)
    by_student = student.generate(style, content, sampler="dpmpp", steps=3)
    torch.manual_seed(3)
    torch.testing.assert_close(by_student, model.generate(style, content, sampler="dpmpp", steps=3))
    torch.testing.assert_close(
        dict(student.ema.module.named_parameters())["input.weight"],
        dict(student.denoiser.named_parameters())["input.weight"],
    )
    out = tmp_path / "samples"
    assert main(["sample", "--ckpt", str(student_path), "--style", "old", "--num", "1", "--frames", "30",
                 "--sampler", "ddim", "--steps", "2", "--no-gif", "--out", str(out)]) == 0  # fmt: skip
    assert read_bvh(out / "old_walk_000.bvh").num_frames == 30
    assert json.loads((out / "manifest.json").read_text())["settings"]["distilled_jumps"] is True
    assert main(args) == 1
    assert "would overwrite" in capsys.readouterr().err
    assert main([*args[:-4], "--steps", "1,x", "--iterations", "3"]) == 1
    assert "--steps: expected whole numbers >= 1 separated by commas, got '1,x'" in capsys.readouterr().err
    again = ["distill", "--ckpt", str(student_path), "--out", str(tmp_path / "2.ckpt"), "--iterations", "1"]
    assert main(again) == 1
    assert "already a distilled student" in capsys.readouterr().err
    # A student saved without its teacher (as walkdiff's first students were) is refused by name.
    old = torch.load(student_path, map_location="cpu", weights_only=False)
    old["state_dict"] = {k: v for k, v in old["state_dict"].items() if not k.startswith("teacher.")}
    torch.save(old, tmp_path / "old.ckpt")
    assert main(["sample", "--ckpt", str(tmp_path / "old.ckpt"), "--style", "old", "--no-gif",
                 "--out", str(tmp_path / "old")]) == 1  # fmt: skip
    said = capsys.readouterr().err
    assert f"{tmp_path / 'old.ckpt'}: a student distilled before walkdiff kept the teacher's network" in said


def test_a_checkpoint_without_planted_heights_loads_but_refuses_grounding(ckpt, tmp_path):
    old = torch.load(ckpt, map_location="cpu", weights_only=False)
    del old["state_dict"]["planted_height"]  # as saved before walkdiff measured planted feet
    path = tmp_path / "old.ckpt"
    torch.save(old, path)
    model = load_generator(path)
    x = torch.zeros(1, 24, model.spec["feature_dim"])
    assert model.to_raw(x, grounded=False).shape == (1, 24, model.spec["feature_dim"])
    with pytest.raises(WalkdiffError, match="cannot be grounded: retrain it, or pass --no-ground"):
        model.to_raw(x)


def test_a_checkpoint_without_a_ground_tolerance_grounds_by_the_whole_shift(ckpt, tmp_path):
    """Saved before walkdiff measured how far real windows stand off: tolerance 0, as grounding was. A
    checkpoint's tolerance is what grounding leaves alone: a huge one grounds nothing."""
    saved = torch.load(ckpt, map_location="cpu", weights_only=False)
    assert "ground_tolerance" in saved["state_dict"]  # measured when training started
    dim = load_generator(ckpt).spec["feature_dim"]
    x = torch.randn(2, 24, dim, generator=torch.Generator().manual_seed(0))
    for tolerance, path in ((None, tmp_path / "old.ckpt"), (1e6, tmp_path / "huge.ckpt")):
        state = dict(saved["state_dict"], planted_height=torch.zeros(4))  # the tiny data plants no foot
        del state["ground_tolerance"]
        if tolerance is not None:
            state["ground_tolerance"] = torch.tensor(tolerance)
        torch.save({**saved, "state_dict": state}, path)
        model = load_generator(path)
        assert float(model.ground_tolerance) == (0.0 if tolerance is None else tolerance)
        same = np.array_equal(model.to_raw(x), model.to_raw(x, grounded=False))
        assert same == (tolerance is not None)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "empty file"),
        (b"not a checkpoint at all", "not a readable checkpoint"),
        ("truncated", "not a readable checkpoint"),
        ("evaluator", "this is a MotionEvaluator (style + content classifier) checkpoint; generator needs"),
    ],
)
def test_bad_checkpoints_are_named_with_what_is_wrong(ckpt, tmp_path, capsys, content, message):
    bad = tmp_path / "bad.ckpt"
    if content == "truncated":
        bad.write_bytes(ckpt.read_bytes()[:5000])
    elif content == "evaluator":
        checkpoint = torch.load(ckpt, map_location="cpu", weights_only=False)
        checkpoint["model_class"] = "walkdiff.models.evaluator.MotionEvaluator"
        torch.save(checkpoint, bad)
    else:
        bad.write_bytes(content)
    args = ["sample", "--ckpt", str(bad), "--style", "old", "--out", str(tmp_path / "out")]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"walkdiff: error: {bad}: ") and message in err and "Traceback" not in err


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--guidance", "nan"], "--guidance: expected a finite number in [0, 100], got 'nan'"),
        (["--sampler", "ddpm", "--steps", "5"], "--steps applies to ddim and dpmpp"),
        (["--sampler", "ddim", "--eta", "inf"], "--eta: expected a finite number in [0, 1], got 'inf'"),
        (["--eta", "0.5"], "--eta applies to ddim only (ddpm sets its own noise)"),
    ],
)
def test_sampling_options_a_sampler_cannot_honour_are_refused(ckpt, tmp_path, capsys, options, message):
    out = tmp_path / "out"
    assert main(["sample", "--ckpt", str(ckpt), "--style", "old", "--out", str(out), *options]) == 1
    assert message in capsys.readouterr().err
    assert not out.exists(), "nothing written"


def test_guidance_is_bounded_and_non_finite_motion_is_never_written(ckpt, model, tmp_path, capsys):
    """--guidance 1e30 made a BVH of NaN: the weight is bounded where it is given, and any clip with NaN
    or infinite values (here from a diverged network) is refused, naming what made it, before a file."""
    from walkdiff.cli import options
    from walkdiff.diffusion import MAX_GUIDANCE
    from walkdiff.styled.pipeline import StyledGenerator, check_finite

    assert options.MAX_GUIDANCE == MAX_GUIDANCE
    out = tmp_path / "out"
    args = ["sample", "--ckpt", str(ckpt), "--style", "old", "--num", "1", "--frames", "30", "--no-gif",
            "--sampler", "ddim", "--steps", "1"]  # fmt: skip
    assert main([*args, "--out", str(out), "--guidance", "1e30"]) == 1
    assert "--guidance: expected a finite number in [0, 100], got '1e30'" in capsys.readouterr().err
    generator = StyledGenerator(model)
    with pytest.raises(WalkdiffError, match=r"^guidance must be a number in \[0, 100\].*got 1e\+30"):
        generator.sample("old", frames=30, sampler="ddim", steps=1, guidance=1e30)

    diverged = torch.load(ckpt, map_location="cpu", weights_only=False)
    diverged["state_dict"]["ema.module.output.bias"][0] = float("nan")
    torch.save(diverged, tmp_path / "diverged.ckpt")
    clip = synthetic.walking(200, fps=120.0, seed=3)
    write_bvh(tmp_path / "mine.bvh", clip)
    for command in (
        ["sample", *args[1:2], str(tmp_path / "diverged.ckpt"), *args[3:]],
        ["transfer", "--ckpt", str(tmp_path / "diverged.ckpt"), "--style", "old", "--input",
         str(tmp_path / "mine.bvh"), "--sampler", "ddim", "--steps", "1"],
    ):  # fmt: skip
        assert main([*command, "--out", str(out)]) == 1
        err = capsys.readouterr().err
        assert "walkdiff: error: the model made non-finite motion (NaN or infinite values in clip 0" in err
        assert not out.exists(), "nothing written"
    nan = read_bvh(tmp_path / "mine.bvh")
    nan.positions[5, 0, 1] = float("nan")
    with pytest.raises(
        WalkdiffError, match="--guidance 50 made non-finite motion .* in 1 of 2 clips, the first clip 1"
    ):
        check_finite([clip, nan], Sampling(guidance=50))


def test_a_transfer_of_a_clip_shorter_than_a_window_says_so(ckpt, model, tmp_path, capsys):
    """A clip shorter than the model's window is restyled as one shorter window, which the model never
    trained on: a warning naming the file, its frames and the window; one pose is refused."""
    from walkdiff.styled.pipeline import StyledGenerator

    source = tmp_path / "short.bvh"
    write_bvh(source, synthetic.walking(40, fps=120.0, seed=3))  # 10 frames at the model's 30 fps
    out = tmp_path / "out"
    common = [
        "transfer",
        "--ckpt",
        str(ckpt),
        "--style",
        "old",
        "--sampler",
        "ddim",
        "--steps",
        "1",
        "--no-gif",
    ]
    assert main([*common, "--input", str(source), "--out", str(out)]) == 0
    said = (
        f"{source}: 10 frames at the model's 30 fps (0.33 s), shorter than its 24-frame window (0.80 s): "
        "restyled as one 10-frame window"
    )
    assert f"walkdiff: warning: {said}" in capsys.readouterr().err
    assert json.loads((out / "short_to_old.json").read_text())["warnings"][0].startswith(said)
    assert read_bvh(out / "short_to_old.bvh").num_frames == 10
    with pytest.warns(UserWarning, match="10 frames at the model's 30 fps"):
        StyledGenerator(model).transfer(source, "old", sampler="ddim", steps=1)

    write_bvh(tmp_path / "pose.bvh", synthetic.walking(4, fps=120.0, seed=3))  # 1 frame at 30 fps
    assert main([*common, "--input", str(tmp_path / "pose.bvh"), "--out", str(tmp_path / "pose")]) == 1
    err = capsys.readouterr().err
    assert f"{tmp_path / 'pose.bvh'}: 1 frame at the model's 30 fps: expected at least 2 frames" in err
    assert not (tmp_path / "pose").exists()


def test_outputs_in_the_way_and_missing_devices_are_named(ckpt, tmp_path, capsys):
    in_the_way = tmp_path / "a_file"
    in_the_way.write_text("not a folder")
    args = ["sample", "--ckpt", str(ckpt), "--style", "old", "--num", "1", "--frames", "30", "--no-gif"]
    assert main([*args, "--out", str(in_the_way)]) == 1
    assert "--out: a file of that name exists" in capsys.readouterr().err
    if not torch.cuda.is_available():
        assert main([*args, "--out", str(tmp_path / "out"), "--device", "cuda"]) == 1
        assert "--device cuda: this torch build sees no CUDA GPU" in capsys.readouterr().err


def test_a_long_sample_gets_a_capped_preview_that_the_manifest_and_console_state(ckpt, tmp_path, capsys):
    out = tmp_path / "long"
    args = ["sample", "--ckpt", str(ckpt), "--style", "angry", "--num", "1", "--frames", "120",
            "--sampler", "ddim", "--steps", "1", "--preview-seconds", "1", "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    assert read_bvh(out / "angry_walk_000.bvh").num_frames == 120  # the clip itself is whole
    with Image.open(out / "angry_walk_000.gif") as gif:
        assert gif.n_frames == 30  # 1 s of the 4 s at 30 fps
    preview = json.loads((out / "manifest.json").read_text())["preview"]
    assert preview == {"seconds": 1.0, "of_seconds": 4.0, "capped": True, "note": "first 1 s of 4 s"}
    assert "preview: first 1 s of 4 s" in capsys.readouterr().out
    assert main([*args, "--overwrite", "--preview-seconds", "nan"]) == 1
    assert "--preview-seconds: expected a finite number in (0, inf]" in capsys.readouterr().err


def test_sample_shows_progress_on_stderr_unless_turned_off(ckpt, tmp_path, capsys, monkeypatch):
    args = ["sample", "--ckpt", str(ckpt), "--style", "old", "--num", "1", "--frames", "40", "--no-gif",
            "--sampler", "ddim", "--steps", "3"]  # fmt: skip
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "sampling" in err and "0/9 [" in err  # 3 windows x 3 steps, with an ETA once started
    monkeypatch.setenv("WALKDIFF_PROGRESS", "0")
    assert main([*args, "--out", str(tmp_path / "b")]) == 0
    assert "sampling" not in capsys.readouterr().err


def test_frames_beyond_the_memory_estimate_are_refused_before_any_work(ckpt, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("WALKDIFF_MEMORY_LIMIT_GB", "1.5")
    out = tmp_path / "huge"
    args = ["sample", "--ckpt", str(ckpt), "--style", "old", "--num", "2", "--out", str(out)]
    assert main([*args, "--frames", "1000000"]) == 1
    err = capsys.readouterr().err
    assert "--frames: 1000000 frames x 2 clips would need about 16.70 GB" in err
    assert "above the limit of 1.50 GB (at most 50000 frames)" in err and "WALKDIFF_MEMORY_LIMIT_GB" in err
    assert not out.exists()
    assert main([*args, "--frames", "30", "--no-gif", "--sampler", "ddim", "--steps", "1"]) == 0
    monkeypatch.setenv("WALKDIFF_MEMORY_LIMIT_GB", "lots")
    assert main([*args, "--frames", "30", "--overwrite"]) == 1
    assert (
        "WALKDIFF_MEMORY_LIMIT_GB: expected a positive number of gigabytes, got 'lots'"
        in capsys.readouterr().err
    )


def test_memory_benchmark_records_peak_rss_per_frame_count(ckpt, tmp_path):
    from walkdiff.bench.memory import bench_memory

    result = bench_memory(str(tmp_path / "mem.json"), str(ckpt), frames=(60,))
    (row,) = json.loads((tmp_path / "mem.json").read_text())["sample"]
    assert row == result["sample"][0] and row["frames"] == 60
    assert 100 < row["peak_rss_mb"] < row["estimate_mb"]  # a Python with torch, under the estimate
    assert row["preview"] == "all 2 s" and row["gif_mb"] > 0


def test_a_sample_shorter_than_a_window_is_a_whole_windows_start_and_says_so(ckpt, model, tmp_path, capsys):
    """--frames below one window made a shorter window than the model ever trained on, silently: now one
    whole window is made and its first frames kept (the same frames as a window's sample from the same
    seed), and one line says so."""
    style, content = torch.tensor([4, 0]), torch.zeros(2, dtype=torch.long)
    whole, short = (
        generate_long(model, style, content, n, Sampling("ddim", 2), torch.Generator().manual_seed(3))
        for n in (24, 10)
    )
    assert short.shape[1] == 10
    torch.testing.assert_close(short, whole[:, :10])
    argv = ["sample", "--ckpt", str(ckpt), "--style", "old", "--num", "1", "--frames", "10", "--no-gif",
            "--sampler", "ddim", "--steps", "1", "--out", str(tmp_path / "short")]  # fmt: skip
    assert main(argv) == 0
    said = (
        "walkdiff: note: --frames 10 (0.33 s) is less than the model's 24-frame window (0.80 s): one whole "
        "window is made and its first 10 frames are kept"
    )
    assert said in capsys.readouterr().err.splitlines()
    assert read_bvh(next((tmp_path / "short").glob("*.bvh"))).num_frames == 10
    argv[argv.index("10")] = "24"
    assert main([*argv[:-1], str(tmp_path / "whole")]) == 0  # a whole window: nothing to say
    assert "note:" not in capsys.readouterr().err
