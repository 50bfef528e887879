"""DiffMotion: training steps, incremental batched generation, smoothing, gesture metrics and the commands."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import tiny
import torch
from PIL import Image

from walkdiff.cli.main import main
from walkdiff.common import memory
from walkdiff.common.errors import WalkdiffError
from walkdiff.data.speech import SpeechDataModule
from walkdiff.diffusion import SamplerChoice
from walkdiff.gestures.evaluate import (
    beat_consistency,
    beat_gain,
    diversity,
    l1_distance,
    mean_jerk,
    motion_beats,
    pck,
    shift_beats,
)
from walkdiff.gestures.generator import load_model
from walkdiff.models.diffmotion import ATEncoder, DiffMotion
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.filters import savgol


@pytest.fixture(autouse=True)
def plain_argv(monkeypatch):
    monkeypatch.setattr("sys.argv", ["walkdiff"])


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[Path, Path]:
    """A tiny model fitted for a few steps on two synthetic takes; (checkpoint, takes folder)."""
    return tiny.gestures(tmp_path_factory.mktemp("speech"))


def test_training_loss_falls_on_one_batch():
    torch.manual_seed(0)
    spec = dict(
        dataset="t", feature_dim=6, num_joints=2, window=20, fps=20.0, joints=("a", "b"), rotation="expmap",
        audio_dim=4, past=2, lookahead=3,
    )  # fmt: skip
    model = DiffMotion(spec, **tiny.GESTURES, dropout=0.0)
    t = torch.linspace(0, 6, 20)
    poses = torch.stack([torch.sin(t * (k + 1)) for k in range(6)], dim=-1).expand(8, 20, 6)
    batch = {"poses": poses, "audio": torch.randn(8, 25, 4)}
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    torch.manual_seed(1)
    first = model.loss(batch).item()
    for _ in range(150):
        opt.zero_grad()
        model.loss(batch).backward()
        opt.step()
    torch.manual_seed(1)
    assert model.loss(batch).item() < 0.8 * first  # eps-loss falls slowly: small-noise steps are hard


def test_checkpoint_keeps_skeleton_and_neutral_pose(trained):
    model = load_model(trained[0])
    assert model.skeleton.num_joints == 13 and model.neutral.rotations.shape == (13, 3, 3)
    assert tuple(model.spec["joints"]) == ("Spine", "Head")
    assert float(model.audio_normalizer.std.mean()) != 1.0  # the training audio statistics came along


def test_generation_is_incremental_batched_and_seeded(trained):
    model = load_model(trained[0])
    audio = torch.randn(30, 27)
    one = model.generate(audio, torch.Generator().manual_seed(3), streams=3)
    assert one.shape == (3, 30, 6) and torch.isfinite(one).all()
    assert not torch.allclose(one[0], one[1])  # streams differ
    again = model.generate(audio, torch.Generator().manual_seed(3), streams=3)
    torch.testing.assert_close(one, again)
    # Frame t depends only on audio up to t + lookahead: a shorter audio gives the same first frames.
    short = model.generate(audio[:20], torch.Generator().manual_seed(3), streams=3)
    torch.testing.assert_close(short[:, : 20 - 8], one[:, : 20 - 8])


SPEC = dict(
    dataset="t", feature_dim=6, num_joints=2, window=20, fps=20.0, joints=("a", "b"), rotation="expmap",
    audio_dim=4, past=2, lookahead=3,
)  # fmt: skip


def untrained_with_output(**options) -> DiffMotion:
    """A small untrained model whose eps network's output layer is not zero (as it is at initialisation),
    so that every layer of the network shows in the samples."""
    torch.manual_seed(0)
    model = DiffMotion(SPEC, **tiny.GESTURES | options).eval()
    torch.nn.init.normal_(model.eps_net.output.weight, std=0.5)
    torch.nn.init.normal_(model.eps_net.output.bias, std=0.5)
    return model


def test_lstm_step_is_nn_lstm_as_one_addmm_per_layer():
    torch.manual_seed(0)
    encoder = ATEncoder(pose_dim=6, window_dim=20, hidden=32, layers=2, audio_dim=8, dropout=0.1).eval()
    previous, audio = torch.randn(3, 5, 6), torch.randn(3, 5, 8)
    expected, (h_n, c_n) = encoder.lstm(torch.cat([previous, audio], dim=-1))
    state = None
    with torch.no_grad():
        for f in range(5):
            h, state = encoder(previous[:, f : f + 1], audio[:, f : f + 1], state)
            torch.testing.assert_close(h[:, 0], expected[:, f], atol=1e-6, rtol=1e-5)
    torch.testing.assert_close(state[0], h_n, atol=1e-6, rtol=1e-5)
    torch.testing.assert_close(state[1], c_n, atol=1e-6, rtol=1e-5)
    # A weight changed in place (an optimizer step) is seen by the next step: no stale copy is used.
    with torch.no_grad():
        encoder.lstm.weight_hh_l1.mul_(2)
        expected, _ = encoder.lstm(torch.cat([previous[:, :1], audio[:, :1]], dim=-1))
        h, _ = encoder(previous[:, :1], audio[:, :1])
    torch.testing.assert_close(h, expected, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize(
    "sampler", [SamplerChoice(), SamplerChoice("ddim", 4, 0.5), SamplerChoice("dpmpp", 4)]
)
def test_fused_eps_network_gives_the_modules_numbers(sampler):
    model = untrained_with_output()
    audio = torch.randn(12, 4)
    plain = model.generate(audio, torch.Generator().manual_seed(5), 3, sampler=sampler, fused=False)
    fused = model.generate(audio, torch.Generator().manual_seed(5), 3, sampler=sampler, fused=True)
    assert plain.abs().max() > 0.5 and not torch.allclose(plain[0], plain[1])  # streams differ
    assert (fused - plain).abs().max() < 1e-4 * plain.abs().max()
    again = model.generate(audio, torch.Generator().manual_seed(5), 3, sampler=sampler, fused=True)
    torch.testing.assert_close(again, fused, atol=0, rtol=0)  # same seed, same output


def test_few_step_sampling_calls_the_network_once_a_step():
    model = untrained_with_output(timesteps=20)
    calls = []
    model.eps_net.register_forward_hook(lambda *_: calls.append(1))
    audio = torch.randn(7, 4)
    for sampler, passes in ((SamplerChoice("ddim", 5), 5), (SamplerChoice("dpmpp", 3), 3), (None, 20)):
        calls.clear()
        poses = model.generate(audio, torch.Generator().manual_seed(1), 2, sampler=sampler, fused=False)
        assert poses.shape == (2, 7, 6) and torch.isfinite(poses).all()
        assert len(calls) == 7 * passes
    # DDIM over all N steps with eta = 1 is ancestral DDPM: the same draws give the same poses.
    ddpm = model.generate(audio, torch.Generator().manual_seed(2), 2)
    ddim = model.generate(audio, torch.Generator().manual_seed(2), 2, sampler=SamplerChoice("ddim", 20, 1.0))
    torch.testing.assert_close(ddim, ddpm)
    # ... and DDIM's deterministic eta = 0 over the same steps is not.
    ode = model.generate(audio, torch.Generator().manual_seed(2), 2, sampler=SamplerChoice("ddim", 20))
    assert (ode - ddpm).abs().max() > 1e-3


def test_sampler_options_a_sampler_does_not_use_are_refused():
    for options, words in (
        (("ddpm", 10, 0.0), "--steps applies to ddim and dpmpp"),
        (("dpmpp", 10, 0.5), "--eta applies to ddim only"),
        (("ddim", 0, 0.0), "--steps must be at least 1"),
        (("heun", None, 0.0), "--sampler"),
    ):
        with pytest.raises(WalkdiffError, match=words):
            SamplerChoice(*options)
    model = untrained_with_output()
    with pytest.raises(WalkdiffError, match="sampling steps must be in"):
        model.sampling_tables(SamplerChoice("ddim", 11))  # more steps than the 10 trained


def test_savgol_reduces_jerk_and_keeps_length():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 4, 80)
    clean = np.stack([np.sin(t), np.cos(2 * t), t], axis=-1)[:, None, :].repeat(2, axis=1)  # (F, J, 3)
    noisy = clean + rng.normal(0, 0.05, clean.shape)
    smooth = savgol(noisy)
    assert smooth.shape == noisy.shape
    assert mean_jerk(smooth, 20.0) < 0.2 * mean_jerk(noisy, 20.0)
    assert np.abs(smooth - clean).mean() < np.abs(noisy - clean).mean()
    assert savgol(noisy[:11]).shape == noisy[:11].shape  # shorter than the window
    np.testing.assert_array_equal(savgol(noisy[:4]), noisy[:4])  # too short to fit order 4
    with pytest.raises(WalkdiffError, match="odd"):
        savgol(noisy, window=30)


def test_metrics_on_known_inputs():
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(50, 4, 3))
    assert l1_distance(truth, truth) == 0.0 and pck(truth, truth, 0.1) == 1.0
    shifted = truth + np.array([1.0, -2.0, 0.5])
    assert l1_distance(shifted, truth) == pytest.approx(3.5)
    assert pck(shifted, truth, 2.0) == 0.0 and pck(shifted, truth, 3.0) == 1.0

    onsets = np.array([0.5, 1.5, 2.5])
    assert beat_consistency(onsets, onsets) == pytest.approx(1.0)
    assert beat_consistency(onsets + 0.1, onsets) == pytest.approx(np.exp(-0.5))
    assert beat_consistency(np.array([1.0]), onsets) < 0.01
    assert beat_consistency(np.array([]), onsets) == 0.0
    np.testing.assert_allclose(shift_beats(np.array([0.5, 2.5]), 2.0, 3.0), [1.5, 2.5])
    # Paired gain over samples: gains 0.1, 0.3 -> mean 0.2, sd 0.1414, CI 0.2 +- 1.96 * 0.1414 / sqrt(2).
    gain = beat_gain([{"bc": 0.6, "bc_shifted": 0.5}, {"bc": 0.7, "bc_shifted": 0.4}])
    assert gain["bc_gain"] == pytest.approx(0.2) and gain["bc_gain_positive_share"] == 1.0
    np.testing.assert_allclose(gain["bc_gain_ci95"], [0.2 - 0.196, 0.2 + 0.196], atol=1e-9)

    # A joint whose speed 1 - cos(pi (t - 0.025)) stops once inside the clip, at 2.025 s (between frames).
    fps, t = 20.0, np.arange(81) / 20.0
    x = t - np.sin(np.pi * (t - 0.025)) / np.pi
    positions = np.stack([x, 0 * x, 0 * x], axis=-1)[:, None]
    np.testing.assert_allclose(motion_beats(positions, fps), [2.025], atol=1e-9)

    same = np.repeat(truth[None], 3, axis=0)
    assert diversity(same, 10) > 0  # different clips of one sample still differ
    still = np.repeat(truth[:1][None], 3, axis=0).repeat(50, axis=1)
    assert diversity(still, 10) == 0.0
    with pytest.raises(WalkdiffError):
        diversity(truth[None, :5], 10)


def test_gesture_command_writes_bvh_on_the_full_skeleton(trained, tmp_path):
    ckpt, folder = trained
    out = tmp_path / "out"
    assert main(["gesture", "--ckpt", str(ckpt), "--audio", str(folder / "b.wav"), "--out", str(out),
                 "--smooth", "--num", "2", "--seed", "4"]) == 0  # fmt: skip
    bvhs = sorted(out.glob("b_*.bvh"))
    assert len(bvhs) == 2 and (out / "b.gif").stat().st_size > 0
    motion = read_bvh(bvhs[0])
    assert motion.skeleton.num_joints == 13 and motion.num_frames == 161 and motion.fps == pytest.approx(20)
    # A second run into the same folder refuses to replace the first's files, unless told to.
    again = ["gesture", "--ckpt", str(ckpt), "--audio", str(folder / "b.wav"), "--out", str(out),
             "--num", "2", "--seed", "4"]  # fmt: skip
    before = bvhs[0].read_text()
    assert main(again) == 1 and bvhs[0].read_text() == before
    assert main([*again, "--overwrite"]) == 0 and bvhs[0].read_text() != before  # not smoothed this time


def test_gesture_states_its_preview_and_refuses_audio_too_long_for_memory(
    trained, tmp_path, capsys, monkeypatch
):
    ckpt, folder = trained
    args = ["gesture", "--ckpt", str(ckpt), "--audio", str(folder / "b.wav"), "--out", str(tmp_path / "out")]
    assert main([*args, "--preview-seconds", "2", "--num", "2"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["preview"] == {
        "seconds": 2.0,
        "of_seconds": 8.05,
        "capped": True,
        "note": "first 2 s of 8.05 s",
    }
    with Image.open(tmp_path / "out" / "b.gif") as gif:
        assert gif.n_frames == 40  # 2 s at 20 fps, both streams side by side
    import av

    # The MP4 beside it plays the same 2 s with the speech that drove them.
    with av.open(str(tmp_path / "out" / "b.mp4")) as video:
        picture, speech = video.streams.video[0], video.streams.audio[0]
        assert sum(1 for _ in video.decode(video=0)) == 40
        assert float(speech.duration * speech.time_base) == pytest.approx(2.0, abs=0.07)
        assert float(picture.duration * picture.time_base) == pytest.approx(2.0)
    room = (memory.BASE_BYTES + 100 * memory.GESTURE_BYTES_PER_FRAME) / 1e9  # 100 frames of one stream
    monkeypatch.setenv("WALKDIFF_MEMORY_LIMIT_GB", str(room))
    assert main([*args[:-1], str(tmp_path / "refused")]) == 1
    err = capsys.readouterr().err
    assert "--audio: 161 frames would need about" in err and "(at most 100 frames)" in err  # 8.05 s
    assert not (tmp_path / "refused").exists()


def test_evaluate_gesture_plays_its_files_on_a_rig_it_can(trained, tmp_path, capsys):
    """--to on evaluate-gesture: its BVH previews go through the rig (this armless model is refused)."""
    argv = [
        "evaluate-gesture",
        "--ckpt",
        str(trained[0]),
        "--out",
        str(tmp_path),
        "--samples",
        "1",
        "--to",
        "smpl",
    ]
    assert main(argv) == 1 and "no arms" in capsys.readouterr().err


def test_evaluate_gesture_report(trained, tmp_path):
    ckpt, _ = trained
    assert main(["evaluate-gesture", "--ckpt", str(ckpt), "--out", str(tmp_path), "--samples", "2"]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert [row["take"] for row in report["takes"]] == ["a", "b"]
    row = report["takes"][0]
    assert row["frames"] == 40 and row["onsets"] > 0
    assert report["sampler"] == "ddpm-10" and report["retarget"] is None
    for name in ("generated", "smoothed"):
        assert row[name]["l1"] > 0 and 0 <= row[name]["pck"] <= 1 and row[name]["diversity"] > 0
        assert 0 <= row[name]["bc"] <= 1 and 0 <= row[name]["bc_shifted"] <= 1
        for key in ("l1", "pck", "bc", "jerk"):  # each mean within its interval over samples
            low, high = row[name][f"{key}_ci95"]
            assert low <= row[name][key] <= high, (name, key)
        assert 0 < row[name]["diversity_ci95"][0] <= row[name]["diversity_ci95"][1]
    assert row["smoothed"]["jerk"] < row["generated"]["jerk"]
    assert (tmp_path / "a" / "a.gif").is_file()

    # `walkdiff evaluate` knows a DiffMotion checkpoint and scores it the same way (--repeats samples).
    out = tmp_path / "via_evaluate"
    assert main(["evaluate", "--ckpt", str(ckpt), "--out", str(out), "--repeats", "2"]) == 0
    again = json.loads((out / "report.json").read_text())
    assert again["samples"] == 2 and again["takes"][0]["generated"] == row["generated"]

    # A few-step sampler: named in the report, and different samples.
    fast = tmp_path / "dpmpp"
    args = [
        "evaluate-gesture",
        "--ckpt",
        str(ckpt),
        "--out",
        str(fast),
        "--samples",
        "2",
        "--sampler",
        "dpmpp",
    ]
    assert main([*args, "--steps", "3"]) == 0
    few = json.loads((fast / "report.json").read_text())
    assert few["sampler"] == "dpmpp-3" and few["takes"][0]["generated"]["l1"] != row["generated"]["l1"]


def test_missing_checkpoint_is_a_clear_error(tmp_path, capsys):
    assert (
        main(["gesture", "--ckpt", str(tmp_path / "no.ckpt"), "--audio", "x.wav", "--out", str(tmp_path)])
        == 1
    )
    assert "checkpoint not found" in capsys.readouterr().err
    assert main(["evaluate", "--ckpt", str(tmp_path / "no.ckpt"), "--out", str(tmp_path)]) == 1
    assert "checkpoint not found" in capsys.readouterr().err


def test_config_trains_through_the_cli(trained, tmp_path, monkeypatch):
    """conf/diffmotion_zeggs.yaml as shipped (checkpoints, sample callback), on synthetic takes."""
    config = Path(__file__).parents[1] / "conf" / "diffmotion_zeggs.yaml"
    monkeypatch.chdir(tmp_path)  # the config's relative checkpoint folder lands here
    args = ["fit", "--config", str(config), "--data.dataset", str(trained[1]), "--data.window", "40",
            "--data.batch_size", "4", "--model.hidden", "32", "--model.timesteps", "10",
            "--trainer.max_epochs", "1", "--trainer.limit_train_batches", "2",
            "--trainer.logger", "false", "--trainer.enable_progress_bar", "false"]  # fmt: skip
    assert main(args) == 0
    model = load_model(tmp_path / "checkpoints" / "diffmotion_zeggs" / "last.ckpt")
    assert model.hparams.hidden == 32 and model.spec["window"] == 40


def test_sample_callback_writes_held_out_audio_clips(trained, tmp_path):
    from walkdiff.callbacks.samples import GestureSamples

    model = load_model(trained[0])
    dm = SpeechDataModule(str(trained[1]), window=40, past=5, lookahead=8)
    files = GestureSamples(seconds=1.0).write(model, dm, None, "samples/step_000001", folder=tmp_path)
    assert [f.name for f in files] == ["a.bvh", "a.gif", "a.mp4"]
    assert read_bvh(files[0]).num_frames == 20
