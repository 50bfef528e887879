"""Streaming: the frame-by-frame API, incremental audio features, gesture and walking streams, commands."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
import soundfile
import synthetic
import torch
from test_speech import RATE, write_take

from walkdiff.cli.main import main
from walkdiff.common.errors import WalkdiffError
from walkdiff.data.datamodule import MotionDataModule
from walkdiff.data.speech import LOG_FLOOR, LogMelBatch, LogMelStream, SpeechDataModule, log_mel, read_wav
from walkdiff.gestures.generator import load_model, synthesize
from walkdiff.gestures.stream import GestureBatch, GestureStream
from walkdiff.models.diffmotion import DiffMotion
from walkdiff.models.path_walker import PathWalker
from walkdiff.models.style_examples import clip_statistics
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.path import Polyline, frames_for
from walkdiff.walker.follow import load_walker
from walkdiff.walker.stream import WalkBatch, WalkStream

SPEECH = dict(hidden=32, lstm_layers=2, audio_hidden=16, channels=8, residual_layers=4, timesteps=4)
WALKER = dict(hidden=32, lstm_layers=2, control_hidden=16, channels=8, residual_layers=2, timesteps=8)


@pytest.fixture(autouse=True)
def plain_argv(monkeypatch):
    monkeypatch.setattr("sys.argv", ["walkdiff"])


@pytest.fixture(autouse=True)
def one_thread():
    """Tiny models frame by frame: one torch thread is as fast as two, and far faster on a busy machine."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def speech_ckpt(tmp_path_factory) -> tuple[Path, Path]:
    """A tiny DiffMotion fitted for two steps on a synthetic take; (checkpoint, takes folder)."""
    folder = tmp_path_factory.mktemp("speech") / "takes"
    write_take(folder, "a", 6.0, seed=1)
    torch.manual_seed(0)
    dm = SpeechDataModule(str(folder), window=20, stride=10, past=5, lookahead=8, batch_size=4)
    model = DiffMotion(dm.spec, **SPEECH)
    trainer = synthetic.quiet_trainer(max_steps=2)
    trainer.fit(model, dm)
    ckpt = folder.parent / "tiny.ckpt"
    trainer.save_checkpoint(ckpt)
    return ckpt, folder


@pytest.fixture(scope="module")
def walker_ckpt(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("walk")
    synthetic.xia_like_folder(root, walk_clips=8, frames=240)
    dm = MotionDataModule(
        root=str(root), cache_dir=str(root / "cache"), window=24, stride=8, batch_size=4, preprocess_workers=1
    )
    torch.manual_seed(0)
    model = PathWalker(dm.spec, **WALKER)
    trainer = synthetic.quiet_trainer(max_steps=2)
    trainer.fit(model, dm)
    ckpt = root / "walker.ckpt"
    trainer.save_checkpoint(ckpt)
    return ckpt


def random_chunks(samples: np.ndarray, rng: np.random.Generator, most: int) -> list[np.ndarray]:
    """`samples` cut at random sizes from 1 sample to `most`, log-uniformly (many small, some large)."""
    chunks, at = [], 0
    while at < len(samples):
        size = int(np.exp(rng.uniform(0, np.log(most + 1))))
        chunks.append(samples[at : at + size])
        at += size
    return chunks


# ---------------------------------------------------------------- the frame loop


def test_offline_generation_is_a_loop_over_the_stream_api():
    """generate() through start_streams/advance makes what the loop it replaced made, bit for bit."""
    torch.manual_seed(0)
    spec = dict(
        dataset="t", feature_dim=6, num_joints=2, window=20, fps=20.0, joints=("a", "b"), rotation="expmap",
        audio_dim=4, past=2, lookahead=3,
    )  # fmt: skip
    model = DiffMotion(spec, **SPEECH).eval()
    for p in model.parameters():  # random weights that reach the output (it starts at zero)
        p.data.normal_(0, 0.3)
    audio = torch.randn(2, 25, 4)
    got = model.generate(audio, torch.Generator().manual_seed(3), streams=2)

    # The loop as it was written before the stream API: one LSTM step and one sample per frame.
    generator = torch.Generator().manual_seed(3)
    with torch.inference_mode():
        normal = model.audio_normalizer.normalize(audio).repeat_interleave(2, dim=0)
        padded = torch.cat([normal[:, :1].expand(-1, 2, -1), normal, normal[:, -1:].expand(-1, 3, -1)], 1)
        emb = model.encoder.audio(model.control_windows(padded))
        tables, previous, state, poses = model.sampling_tables(), torch.zeros(4, 1, 6), None, []
        for f in range(25):
            h, state = model.encoder(previous, emb[:, f : f + 1], state)
            x = model.sample_frame(h[:, 0], tables, generator)
            poses.append(x)
            previous = x.unsqueeze(1)
        expected = model.normalizer.denormalize(torch.stack(poses, 1))
    torch.testing.assert_close(got, expected, rtol=0, atol=0)

    # Advancing some rows only leaves the others' state alone and matches advancing them on their own.
    with torch.inference_mode():
        streams = model.start_streams(3)
        control = torch.randn(3, 16)
        model.advance(streams, control, torch.Generator().manual_seed(1))
        before = streams.previous[1].clone(), streams.state[0][:, 1].clone()
        rows = torch.tensor([0, 2])
        x = model.advance(streams, control[rows], torch.Generator().manual_seed(2), rows)
        assert torch.equal(streams.previous[1], before[0]) and torch.equal(streams.state[0][:, 1], before[1])
        assert torch.equal(streams.previous[rows, 0], x)


# ---------------------------------------------------------------- audio features


@pytest.mark.parametrize("most", [1, 50, 20_000, 3 * RATE])
def test_log_mel_stream_equals_the_offline_features(most):
    """Chunks from 1 sample to seconds give log_mel's frames, each as soon as its window has arrived."""
    rng = np.random.default_rng(most)
    samples = (rng.normal(0, 0.1, int(0.7 * RATE)) * np.sin(np.arange(int(0.7 * RATE)) / 900)).astype(
        np.float32
    )
    offline = log_mel(samples, RATE, 20.0)
    stream, parts, received = LogMelStream(RATE, 20.0), [], 0
    for chunk in random_chunks(samples, rng, most):
        part = stream.push(chunk)
        received += len(chunk)
        parts.append(part)
        # frame k is out exactly when the samples before (k + 1) hops are in (its window's last one)
        assert stream.frames == min(received // 800, 1 + len(samples) // 800)
    parts.append(stream.finish())
    streamed = np.concatenate(parts)
    assert streamed.shape == offline.shape == (15, 27)
    np.testing.assert_allclose(streamed, offline, atol=5e-5, rtol=0)


def test_log_mel_stream_refuses_a_rate_without_whole_samples_per_frame():
    with pytest.raises(WalkdiffError, match="22050 Hz is not a whole number of samples per frame at 20 fps"):
        LogMelStream(22050, 20.0)


def pushes_one_by_one(samples: np.ndarray, pushes: list[np.ndarray], mel: LogMelBatch) -> np.ndarray:
    """The frames of `samples` pushed in `pushes`, each push's frames computed on their own (one FFT and
    one mel product per push, the samples not yet arrived zero) with `mel`'s window and filters: what a
    lone stream computed before streams were featurised together."""
    hop, half, done, received, out = mel.hop, mel.n_fft // 2, 0, 0, []
    for push in [*pushes, None]:
        received += 0 if push is None else len(push)
        end = done
        while (push is None and end < 1 + received // hop) or (
            push is not None and mel.needed(end) <= received
        ):
            end += 1
        known = np.concatenate(
            [np.zeros(half, np.float32), samples[:received], np.zeros(2 * half, np.float32)]
        )
        if end > done:
            columns = np.stack([known[k * hop : k * hop + 2 * half] for k in range(done, end)], axis=1)
            power = np.abs(np.fft.rfft(mel.window[:, None] * columns, axis=0)) ** 2.0
            out.append(np.log(mel.mel_basis @ power + LOG_FLOOR).T)
        done = end
    return np.concatenate(out)


def test_streams_featurised_together_get_the_floats_each_gets_alone():
    """Five streams' audio, pushed in turn in chunks of 1 sample to a second and computed together at
    random moments (one FFT for all their new frames): each frame is, bit for bit, the one its stream
    computes alone, so the frames made do not depend on which streams share a batch."""
    rng = np.random.default_rng(0)
    mel = LogMelBatch(RATE, 20.0)
    length = int(1.3 * RATE)
    takes = [rng.normal(0, 0.1, length) * np.sin(np.arange(length) / (300 + 200 * k)) for k in range(5)]
    takes = [t.astype(np.float32) for t in takes]
    rows = [mel.add() for _ in takes]
    pushes = [random_chunks(t, rng, most) for t, most in zip(takes, [1, 700, 800, 5000, RATE])]
    turns = [row for row in rows for _ in pushes[row]]
    rng.shuffle(turns)
    left = [iter(p) for p in pushes]
    made: list[dict] = [{} for _ in rows]

    def compute():
        for row, frame, values in zip(*mel.compute()):
            assert frame not in made[row]
            made[row][frame] = values

    for row in turns:
        mel.push(row, next(left[row]))
        if rng.random() < 0.2:
            compute()
    for row in rows:
        mel.finish(row)
    compute()
    for row, take in zip(rows, takes):
        together = np.stack([made[row][f] for f in range(len(made[row]))])
        alone = pushes_one_by_one(take, pushes[row], mel)
        assert together.shape == alone.shape == (1 + length // 800, 27)
        assert np.array_equal(together.view(np.uint32), alone.view(np.uint32))


# ---------------------------------------------------------------- gesture streams


def test_streamed_zeggs_equals_the_whole_file(zeggs_dir, speech_ckpt):
    """The real ZEGGS take pushed in random chunk sizes: the features and, with the same seed, the poses
    `walkdiff gesture` makes of the whole file (its `synthesize`; the commands are compared below)."""
    ckpt, _ = speech_ckpt
    wav = next(zeggs_dir.glob("*.wav"))
    samples, rate = read_wav(wav)
    model = load_model(ckpt)
    offline_mel = log_mel(samples, rate, model.spec["fps"])
    offline = synthesize(model, offline_mel, 1, seed=7)[0]

    stream = GestureStream(model, rate, seed=7)
    poses = []
    for chunk in random_chunks(samples, np.random.default_rng(0), 2 * rate):
        poses.append(stream.push(chunk))
    poses.append(stream.finish())
    streamed = np.concatenate(poses)
    assert streamed.shape == offline.shape == (len(offline_mel), model.spec["feature_dim"])
    np.testing.assert_allclose(streamed, offline, atol=1e-4, rtol=0)
    # and the features it used were the offline ones
    mel = LogMelStream(rate, model.spec["fps"])
    mels = [mel.push(c) for c in random_chunks(samples, np.random.default_rng(1), rate)] + [mel.finish()]
    np.testing.assert_allclose(np.concatenate(mels), offline_mel, atol=5e-5, rtol=0)


def test_a_pose_waits_only_for_its_lookahead(speech_ckpt):
    model = load_model(speech_ckpt[0])
    rng = np.random.default_rng(0)
    samples = rng.normal(0, 0.1, 2 * RATE).astype(np.float32)
    stream, hop, ahead = GestureStream(model, seed=0), RATE // 20, model.spec["lookahead"]
    made = 0
    for at in range(0, len(samples), 160):  # 10 ms chunks
        made += len(stream.push(samples[at : at + 160]))
        # pose t needs mel frame t + lookahead, which needs the samples before (t + lookahead + 1) hops
        assert made == max(0, (at + 160) // hop - ahead)
    assert made + len(stream.finish()) == 1 + len(samples) // hop
    assert stream.waited[0] == pytest.approx((ahead + 1) * hop / RATE)
    assert stream.waited[-1] == pytest.approx(len(samples) / RATE)


def test_streams_batched_one_forward_per_frame(speech_ckpt, monkeypatch):
    model = load_model(speech_ckpt[0])
    rng = np.random.default_rng(0)
    takes = rng.normal(0, 0.1, (2, 3 * RATE)).astype(np.float32)
    mels = np.stack([log_mel(t, RATE, 20.0) for t in takes])
    offline = model.generate(torch.from_numpy(mels), torch.Generator().manual_seed(5), streams=2).numpy()

    calls = []
    advance = model.advance
    monkeypatch.setattr(model, "advance", lambda *a, **k: calls.append(len(a[1])) or advance(*a, **k))
    batch = GestureBatch(model, seed=5)
    streams = [GestureStream(model, batch=batch) for _ in range(4)]  # 2 takes x 2 samples, in lockstep
    out = [[] for _ in streams]
    for at in range(0, takes.shape[1], 700):
        for k, stream in enumerate(streams):
            stream.feed(takes[k // 2, at : at + 700])
        batch.run()
        for o, stream in zip(out, streams):
            o.append(stream.take())
    for stream in streams:
        stream.close()
    batch.run()
    for o, stream in zip(out, streams):
        o.append(stream.take())
    assert calls == [4] * mels.shape[1], "one forward per frame for all four streams"
    for k, o in enumerate(out):  # the offline batch of the same takes and seed (rows take b, sample k)
        np.testing.assert_allclose(np.concatenate(o), offline[k], atol=1e-4, rtol=0)

    # Streams at different points: each frame is one forward for the streams that have one ready.
    calls.clear()
    batch = GestureBatch(model, seed=5)
    ahead, behind = GestureStream(model, batch=batch), GestureStream(model, batch=batch)
    ahead.feed(takes[0, : 2 * RATE])
    behind.feed(takes[1, :RATE])
    batch.run()
    frames_ahead, frames_behind = len(ahead.take()), len(behind.take())
    assert frames_ahead == 40 - 8 and frames_behind == 20 - 8
    assert calls == [2] * frames_behind + [1] * (frames_ahead - frames_behind)
    # A stream joining a running batch starts from the beginning (zero state, mean pose), alone.
    late = GestureStream(model, batch=batch)
    late.feed(takes[1, :RATE])
    calls.clear()
    batch.run()
    assert calls == [1] * 12 and len(late.take()) == 12 and len(ahead.take()) == len(behind.take()) == 0


def test_a_batch_of_streams_at_two_rates_for_longer_than_its_buffers(speech_ckpt):
    """Streams at 16 and 48 kHz in one batch, fed 20 ms at a time for 15 s (their sample and feature
    buffers made room for many times over), advance in lockstep and make the poses the offline batch
    makes of the same audio and seed."""
    model = load_model(speech_ckpt[0])
    rng = np.random.default_rng(3)
    rates, seconds = (RATE, 3 * RATE), 15
    takes = [
        (rng.normal(0, 0.1, seconds * r) * np.sin(np.arange(seconds * r) / r * 7)).astype(np.float32)
        for r in rates
    ]
    mels = np.stack([log_mel(t, r, 20.0) for t, r in zip(takes, rates)])
    offline = model.generate(torch.from_numpy(mels), torch.Generator().manual_seed(2), streams=1).numpy()
    batch = GestureBatch(model, seed=2)
    streams = [GestureStream(model, r, batch=batch) for r in rates]
    widths = []
    for at in range(0, seconds * 50):
        for stream, take, r in zip(streams, takes, rates):
            stream.feed(take[at * r // 50 : (at + 1) * r // 50])
        batch.run()
        if at in (50, seconds * 50 - 1):  # after a second, and at the end
            widths.append([batch.history.shape[1], *(s.features.buffer.shape[1] for s in streams)])
    for stream in streams:
        stream.close()
    batch.run()
    for k, stream in enumerate(streams):
        streamed = stream.take()
        assert streamed.shape == offline[k].shape == (1 + seconds * 20, model.spec["feature_dim"])
        np.testing.assert_allclose(streamed, offline[k], atol=1e-4, rtol=0)
    assert widths[0] == widths[1], "the buffers made room by dropping what no window needs, not by growing"


# ---------------------------------------------------------------- walking streams


def test_a_path_given_point_by_point_walks_as_the_whole_path(walker_ckpt):
    model = load_walker(walker_ckpt)
    u = np.linspace(0, 1, 60)
    points = np.stack([15 * np.sin(3 * u), 50 * u], axis=-1)
    path = Polyline.of(points)
    frames = frames_for(path, 12.0, model.spec["fps"])
    whole, start = model.generate(
        path, torch.tensor([1]), torch.tensor([12.0]), frames, torch.Generator().manual_seed(4)
    )

    stream, parts, counts = WalkStream(model, 1, 12.0, seed=4), [], []
    for point in points:
        parts.append(stream.push(point[None]))
        counts.append(len(parts[-1]))
    parts.append(stream.finish())
    walked = np.concatenate(parts)
    np.testing.assert_array_equal(walked, whole[0])
    assert sum(counts) > frames // 2, "frames come while the path is still growing"
    np.testing.assert_array_equal(stream.start[0], start[0])

    # Two walkers in one batch, each on its own path, one forward per frame.
    batch = WalkBatch(model, seed=4)
    a, b = WalkStream(model, 1, 12.0, batch=batch), WalkStream(model, 3, 12.0, batch=batch)
    a.feed(points)
    b.feed(points[:30] * [-1, 1])
    a.close()
    b.close()
    batch.run()
    assert len(a.take()) == frames and len(b.take()) == frames_for(Polyline.of(points[:30]), 12.0, 30.0)


def walk_and_stream(common: list[str], points: list, tmp_path, monkeypatch, capsys):
    """`walk` of a path file and `walk --stream` of the same points on stdin: both BVHs (as "a/old_p.bvh"
    and "b/old_stdin.bvh" name them for --style old) and the stream's JSON lines."""
    tmp_path.mkdir(exist_ok=True)
    (tmp_path / "p.json").write_text(json.dumps(points))
    argv = ["walk", *common, "--path", str(tmp_path / "p.json"), "--out", str(tmp_path / "a"), "--no-gif"]
    assert main(argv) == 0
    capsys.readouterr()
    lines = "".join(json.dumps({"x": x, "z": z}) + "\n" for x, z in points)
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(lines.encode())))
    assert main(["walk", "--stream", *common, "--path", "-", "--out", str(tmp_path / "b")]) == 0
    out = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    return read_bvh(tmp_path / "a" / "old_p.bvh"), read_bvh(tmp_path / "b" / "old_stdin.bvh"), out


def test_walk_stream_command_from_stdin_equals_walk(walker_ckpt, tmp_path, monkeypatch, capsys):
    points = [[0.0, 0.0], [0.0, 0.4], [0.3, 0.9], [0.9, 1.2], [1.5, 1.3]]  # metres
    common = ["--ckpt", str(walker_ckpt), "--style", "old", "--speed", "0.7", "--seed", "2"]
    a, b, out = walk_and_stream(common, points, tmp_path, monkeypatch, capsys)
    np.testing.assert_array_equal(a.rotations, b.rotations)
    np.testing.assert_array_equal(a.positions, b.positions)
    header, frames, summary = out[0], out[1:-1], out[-1]
    assert header["joints"] == a.skeleton.names and summary["done"] and summary["frames"] == a.num_frames
    assert [f["frame"] for f in frames] == list(range(a.num_frames))
    np.testing.assert_allclose([f["root"] for f in frames], a.positions[:, 0], atol=1e-3)


def test_walk_stream_with_an_example_clip_equals_walk_with_it(walker_ckpt, tmp_path, monkeypatch, capsys):
    """--style-clip on a stream moves its frames as walk moves the whole path's: the same frames."""
    clip = str(sorted(walker_ckpt.parent.rglob("*.bvh"))[-1])
    points = [[0.0, 0.0], [0.0, 0.5], [0.4, 1.0], [1.0, 1.2]]
    common = ["--ckpt", str(walker_ckpt), "--style", "old", "--speed", "0.7", "--seed", "3"]
    clips = ["--style-clip", f"{clip}:2", "--match-clips", "0.8"]
    a, b, out = walk_and_stream([*common, *clips], points, tmp_path / "clip", monkeypatch, capsys)
    assert out[-1]["style_clips"] == [{"clip": clip, "weight": 2.0}]
    np.testing.assert_array_equal(a.rotations, b.rotations)
    plain, _, _ = walk_and_stream(common, points, tmp_path / "plain", monkeypatch, capsys)
    assert not np.array_equal(plain.rotations, a.rotations)  # the clip did act

    model = load_walker(walker_ckpt)
    matched = WalkStream(model, 0, 12.0, match=clip_statistics(model, clip))
    with pytest.raises(WalkdiffError, match="matches example clips holds one stream"):
        WalkStream(model, 0, 12.0, batch=matched.batch)


# ---------------------------------------------------------------- the gesture command


def pcm(samples: np.ndarray) -> bytes:
    return (np.clip(samples, -1, 1 - 1 / 32768) * 32768).astype("<i2").tobytes()


def test_gesture_stream_from_stdin(speech_ckpt, tmp_path, monkeypatch, capsys):
    ckpt, _ = speech_ckpt
    samples = np.random.default_rng(3).normal(0, 0.2, int(1.5 * RATE)).astype(np.float32)
    data = pcm(samples)
    soundfile.write(tmp_path / "same.wav", np.frombuffer(data, "<i2"), RATE, subtype="PCM_16")
    assert main(["gesture", "--ckpt", str(ckpt), "--audio", str(tmp_path / "same.wav"), "--out",
                 str(tmp_path / "offline"), "--num", "2", "--preview-seconds", "1"]) == 0  # fmt: skip
    capsys.readouterr()
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(data)))
    assert main(["gesture", "--stream", "--ckpt", str(ckpt), "--audio", "-", "--out", str(tmp_path / "live"),
                 "--num", "2"]) == 0  # fmt: skip
    out = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    header, frames, summary = out[0], out[1:-1], out[-1]
    assert header["rate"] == RATE and header["joints"] == ["Spine", "Head"]
    assert header["lookahead_s"] == pytest.approx(9 * 800 / RATE)
    assert summary["frames"] == 31 and len(frames) == 2 * 31
    assert sorted((f["stream"], f["frame"]) for f in frames) == [(k, t) for k in range(2) for t in range(31)]
    for f in frames:
        assert f["audio_time"] <= f["time"] + header["lookahead_s"] + 1e-9
        assert np.linalg.norm(f["rotations"], axis=-1) == pytest.approx(1, abs=1e-4)
    # --seconds stops reading there: half a second of the audio is 1 + 8000 // 800 frames.
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(data)))
    assert main(["gesture", "--stream", "--ckpt", str(ckpt), "--audio", "-", "--out", str(tmp_path / "half"),
                 "--seconds", "0.5"]) == 0  # fmt: skip
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["frames"] == 11
    # Following the WAV file (complete here: it stops growing) gives the same.
    wav = str(tmp_path / "same.wav")
    assert main(["gesture", "--stream", "--idle", "0.05", "--ckpt", str(ckpt), "--audio", wav,
                 "--out", str(tmp_path / "file"), "--num", "2"]) == 0  # fmt: skip
    for k in range(2):  # the same two samples as the offline command's --num 2
        a = read_bvh(tmp_path / "offline" / f"same_seed0_{k}.bvh")
        for live in (tmp_path / "live" / f"stdin_seed0_{k}.bvh", tmp_path / "file" / f"same_seed0_{k}.bvh"):
            np.testing.assert_allclose(a.rotations, read_bvh(live).rotations, atol=1e-4)


@pytest.mark.parametrize(
    "audio, args, expected",
    [
        (b"\x01\x02\x03", ["--audio", "-"], "--audio -: 3 bytes, an odd number: expected s16le samples"),
        (None, ["--audio", "f44.wav"], "f44.wav: 44100 Hz; the model was trained on 16000 Hz audio"),
        (None, ["--audio", "u8.wav"], "u8.wav: a WAV of format 1 with 8-bit samples; expected 16-bit PCM"),
        (None, ["--audio", "text.wav"], "text.wav: not a WAV file"),
        (None, ["--audio", "missing.wav"], "missing.wav: file not found"),
        (b"", ["--audio", "-"], "no audio arrived"),
        (
            b"\x00\x00",
            ["--audio", "-", "--rate", "22050"],
            "22050 Hz is not a whole number of samples per frame",
        ),
    ],
)
def test_gesture_stream_bad_input_is_one_line(
    speech_ckpt, tmp_path, monkeypatch, capsys, audio, args, expected
):
    monkeypatch.chdir(tmp_path)
    soundfile.write("f44.wav", np.zeros(4410, np.float32), 44100, subtype="PCM_16")
    soundfile.write("u8.wav", np.zeros(1600, np.float32), RATE, subtype="PCM_U8")
    Path("text.wav").write_text("not audio at all")
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(audio or b"")))
    assert (
        main(["gesture", "--stream", "--idle", "0.05", "--ckpt", str(speech_ckpt[0]), "--out", "o", *args])
        == 1
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expected in err[0], err
    assert not list(Path("o").glob("*.bvh")) if Path("o").exists() else True


def test_walk_stream_bad_line_names_it(walker_ckpt, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(b'{"x": 0, "z": 0}\n\n{"x": 1, "y": 2}\n')))
    args = ["walk", "--stream", "--ckpt", str(walker_ckpt), "--style", "old", "--speed", "1", "--path", "-"]
    assert main([*args, "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("walkdiff: error: -:3: expected a JSON object") and '"y": 2' in err
    assert not list(tmp_path.glob("*.bvh"))


def test_a_streamed_point_too_far_for_memory_is_refused_by_its_line(
    walker_ckpt, tmp_path, monkeypatch, capsys
):
    """A streamed path is capped as `walk --path FILE` caps a path file, at the point that asks too much
    (one at 1e30 m was walked towards without end, at full CPU, with nothing said)."""
    stream = WalkStream(load_walker(walker_ckpt), 1, 12.0)
    with pytest.raises(WalkdiffError, match=r"the path up to this point: \d+ frames would need about"):
        stream.feed([[0, 0], [0, 5], [0, 1e30], [0, 6]])
    assert len(stream.points) == 2 and stream.path.length == 5  # the points before it are kept
    with pytest.raises(WalkdiffError, match=r"expected a path point of finite numbers, got \[nan, 0.0\]"):
        stream.feed([[float("nan"), 0]])

    lines = b'{"x": 0, "z": 0}\n{"x": 0, "z": 0.2}\n{"x": 0, "z": 1e30}\n'
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(lines)))
    args = ["walk", "--stream", "--ckpt", str(walker_ckpt), "--style", "old", "--speed", "1", "--path", "-"]
    assert main([*args, "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("walkdiff: error: -:3: the path up to this point: "), err
    assert "above the limit of 4.00 GB" in err[0]
    assert not (tmp_path / "out").exists()


def test_a_walk_stream_gone_bad_midway_keeps_the_frames_made(walker_ckpt, tmp_path, monkeypatch, capsys):
    """A bad line after some frames: the BVH of those frames is written, the last JSON line and the
    error say so, and the points before the bad line in the same read still walk."""
    lines = "".join(json.dumps({"x": 0.0, "z": 0.1 * k}) + "\n" for k in range(31))  # 3 m
    lines += '{"x": 0, "z": "far"}\n'
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(lines.encode())))
    out = tmp_path / "out"
    args = ["walk", "--stream", "--ckpt", str(walker_ckpt), "--style", "old", "--speed", "0.7", "--path", "-"]
    assert main([*args, "--out", str(out)]) == 1
    captured = capsys.readouterr()
    printed = [json.loads(line) for line in captured.out.splitlines()]
    frames, summary, bvh = printed[1:-1], printed[-1], out / "old_stdin.bvh"
    bad = """-:32: expected a JSON object {"x": metres, "z": metres}, got '{"x": 0, "z": "far"}'"""
    assert len(frames) > 30
    assert summary == {"done": False, "frames": len(frames), "error": bad, "files": [str(bvh)]}
    err = captured.err.strip().splitlines()
    assert err == [f"walkdiff: error: {bad}; the {len(frames)} frames made before it are in {bvh}"]
    motion = read_bvh(bvh)
    assert motion.num_frames == len(frames)
    np.testing.assert_allclose([f["root"] for f in frames], motion.positions[:, 0], atol=1e-3)


def test_a_gesture_stream_gone_bad_midway_keeps_the_frames_made(speech_ckpt, tmp_path, capsys):
    """A float WAV with a NaN sample a second in: the poses made from the audio before it are written."""
    samples = np.random.default_rng(3).normal(0, 0.2, int(1.5 * RATE)).astype(np.float32)
    samples[RATE] = np.nan
    wav, out = tmp_path / "talk.wav", tmp_path / "out"
    soundfile.write(wav, samples, RATE, subtype="FLOAT")
    args = ["gesture", "--stream", "--idle", "0.05", "--ckpt", str(speech_ckpt[0]), "--audio", str(wav)]
    assert main([*args, "--out", str(out)]) == 1
    captured = capsys.readouterr()
    printed = [json.loads(line) for line in captured.out.splitlines()]
    frames, summary = printed[1:-1], printed[-1]
    bad = f"{wav}: a sample that is not a finite number at 1.000 s; expected audio in [-1, 1]"
    assert len(frames) == 20 - 8  # the mel frames of the first second, less the look-ahead
    assert summary == {"done": False, "frames": 12, "error": bad, "files": [str(out / "talk.bvh")]}
    err = captured.err.strip().splitlines()
    assert err == [f"walkdiff: error: {bad}; the 12 frames made before it are in {out / 'talk.bvh'}"]
    assert read_bvh(out / "talk.bvh").num_frames == 12


def test_bench_stream_reports_latency_and_streams(speech_ckpt, walker_ckpt, tmp_path, capsys):
    out = tmp_path / "stream.json"
    assert main(["bench", "stream", "--out", str(out), "--ckpt", str(speech_ckpt[0]), "--walker",
                 str(walker_ckpt), "--seconds", "1", "--frames", "1", "--most", "2",
                 "--threads", "1"]) == 0  # fmt: skip
    result = json.loads(out.read_text())
    gesture, walk = result["gesture"], result["walk"]
    assert gesture["lookahead_ms"] == pytest.approx(450.0) and gesture["target_audio_to_pose_ms"] == 500.0
    for figure in (gesture["latency_chunk_to_pose"], gesture["latency_audio_to_pose"]):
        assert 0 < figure["median_ms"] <= figure["p95_ms"]
    # a pose comes after its own moment by at least the look-ahead it waits for
    assert gesture["latency_audio_to_pose"]["median_ms"] >= 450.0
    assert (
        0 <= gesture["realtime_streams"] <= 2
        and "1" in gesture["by_threads"]["1"]["seconds_per_frame_by_streams"]
    )
    assert walk["frames_measured"] > 0 and walk["latency_point_to_pose"]["median_ms"] > 0
    assert 0 <= walk["realtime_streams"] <= 2


def test_gesture_stream_follows_a_wav_while_it_is_written(speech_ckpt, tmp_path, capsys):
    """A writer appends to the WAV (placeholder sizes in its header, as recorders leave them) while the
    command reads it: the BVH is the whole file's."""
    import threading
    import time

    ckpt, _ = speech_ckpt
    samples = np.random.default_rng(5).normal(0, 0.2, RATE).astype(np.float32)
    data = pcm(samples)
    soundfile.write(tmp_path / "whole.wav", np.frombuffer(data, "<i2"), RATE, subtype="PCM_16")
    header = (tmp_path / "whole.wav").read_bytes()[:44]
    header = header[:4] + b"\xff\xff\xff\xff" + header[8:40] + b"\xff\xff\xff\xff"  # sizes unknown yet
    growing = tmp_path / "live.wav"
    growing.write_bytes(header)

    def write():
        with growing.open("ab") as f:
            for at in range(0, len(data), 1600):  # 50 ms of audio every 10 ms
                f.write(data[at : at + 1600])
                f.flush()
                time.sleep(0.01)

    writer = threading.Thread(target=write)
    writer.start()
    assert main(["gesture", "--stream", "--idle", "0.5", "--ckpt", str(ckpt), "--audio", str(growing),
                 "--out", str(tmp_path / "live")]) == 0  # fmt: skip
    writer.join()
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert lines[-1]["frames"] == 21 and lines[-1]["seconds"] == pytest.approx(1.0)
    assert main(["gesture", "--ckpt", str(ckpt), "--audio", str(tmp_path / "whole.wav"), "--out",
                 str(tmp_path / "whole"), "--preview-seconds", "1"]) == 0  # fmt: skip
    live, whole = read_bvh(tmp_path / "live" / "live.bvh"), read_bvh(tmp_path / "whole" / "whole.bvh")
    np.testing.assert_allclose(live.rotations, whole.rotations, atol=1e-4)


# ---------------------------------------------------------------- Ctrl-C on a stream


class CtrlC(io.RawIOBase):
    """Standard input that gives `data`, then raises KeyboardInterrupt where it would block: what Ctrl-C
    does to a command waiting for more input on a terminal or a pipe."""

    def __init__(self, data: bytes):
        self.data = data

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        if not self.data:
            raise KeyboardInterrupt
        n = min(len(buffer), len(self.data))
        buffer[:n], self.data = self.data[:n], self.data[n:]
        return n


def ctrl_c_after(data: bytes) -> io.TextIOWrapper:
    return io.TextIOWrapper(io.BufferedReader(CtrlC(data)))


def interrupted_output(capsys) -> tuple[list[dict], dict, list[str]]:
    """(frame lines, last line, stderr lines) of a stream stopped by Ctrl-C."""
    captured = capsys.readouterr()
    printed = [json.loads(line) for line in captured.out.splitlines()]
    return printed[1:-1], printed[-1], captured.err.strip().splitlines()


def test_ctrl_c_on_a_walk_stream_writes_the_frames_made(walker_ckpt, tmp_path, monkeypatch, capsys):
    """Ctrl-C while the walker waits for more path: the BVH holds every frame sent, the last JSON line and
    one stderr line say so, and the exit status is 130 (it was: 'interrupted', nothing written)."""
    lines = "".join(json.dumps({"x": 0.0, "z": 0.1 * k}) + "\n" for k in range(31))  # 3 m
    monkeypatch.setattr("sys.stdin", ctrl_c_after(lines.encode()))
    out = tmp_path / "out"
    args = ["walk", "--stream", "--ckpt", str(walker_ckpt), "--style", "old", "--speed", "0.7", "--path", "-"]
    assert main([*args, "--out", str(out)]) == 130
    frames, summary, err = interrupted_output(capsys)
    bvh = out / "old_stdin.bvh"
    assert len(frames) > 30
    assert summary == {"done": False, "frames": len(frames), "interrupted": True, "files": [str(bvh)]}
    assert err == [f"walkdiff: interrupted; the {len(frames)} frames made so far are in {bvh}"]
    motion = read_bvh(bvh)
    assert motion.num_frames == len(frames)
    np.testing.assert_allclose([f["root"] for f in frames], motion.positions[:, 0], atol=1e-3)


def test_ctrl_c_on_a_gesture_stream_writes_the_frames_made(speech_ckpt, tmp_path, monkeypatch, capsys):
    samples = np.random.default_rng(3).normal(0, 0.2, RATE).astype(np.float32)
    monkeypatch.setattr("sys.stdin", ctrl_c_after(pcm(samples)))
    out = tmp_path / "out"
    args = ["gesture", "--stream", "--ckpt", str(speech_ckpt[0]), "--audio", "-", "--num", "2"]
    assert main([*args, "--out", str(out)]) == 130
    frames, summary, err = interrupted_output(capsys)
    files = [out / "stdin_seed0_0.bvh", out / "stdin_seed0_1.bvh"]
    made = len(frames) // 2
    assert made == 20 - 8  # the mel frames of the second heard, less the look-ahead: no padded end
    assert summary == {"done": False, "frames": made, "interrupted": True, "files": [str(f) for f in files]}
    assert err == [f"walkdiff: interrupted; the {made} frames made so far are in {files[0]}, {files[1]}"]
    assert [read_bvh(f).num_frames for f in files] == [made, made]


def test_ctrl_c_before_any_frame_writes_nothing(walker_ckpt, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("sys.stdin", ctrl_c_after(b'{"x": 0, "z": 0}\n'))
    args = ["walk", "--stream", "--ckpt", str(walker_ckpt), "--style", "old", "--speed", "1", "--path", "-"]
    assert main([*args, "--out", str(tmp_path / "out")]) == 130
    _, summary, err = interrupted_output(capsys)
    assert summary == {"done": False, "frames": 0, "interrupted": True, "files": []}
    assert err == ["walkdiff: interrupted; 0 frames made, nothing written"]
    assert not (tmp_path / "out").exists()


def test_sigint_on_a_walk_stream_process_exits_130_with_its_bvh(walker_ckpt, tmp_path):
    """The real signal on a real process waiting on a pipe: what Ctrl-C in a terminal sends."""
    import os
    import signal
    import subprocess
    import sys

    out = tmp_path / "out"
    command = [sys.executable, "-m", "walkdiff.cli.main", "--threads", "1", "walk", "--stream",
               "--ckpt", str(walker_ckpt), "--style", "old", "--speed", "0.7", "--path", "-",
               "--out", str(out)]  # fmt: skip
    env = {**os.environ, "WALKDIFF_PROGRESS": "0"}
    # A shell's background job (`make test &`, nohup) inherits SIGINT ignored, and Python leaves it
    # ignored; a terminal's foreground process has it at its default, as here.
    process = subprocess.Popen(
        command, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    try:
        for k in range(31):
            process.stdin.write(json.dumps({"x": 0.0, "z": 0.1 * k}) + "\n")
        process.stdin.flush()
        header = process.stdout.readline()
        assert header.startswith('{"fps"'), process.stderr.read()
        assert json.loads(process.stdout.readline())["frame"] == 0  # walking: now waiting for more path
        process.send_signal(signal.SIGINT)
        rest, err = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == 130, err
    summary = json.loads(rest.splitlines()[-1])
    assert summary["interrupted"] and summary["frames"] > 0
    assert err.strip().splitlines() == [
        f"walkdiff: interrupted; the {summary['frames']} frames made so far are in {out / 'old_stdin.bvh'}"
    ]
    assert read_bvh(out / "old_stdin.bvh").num_frames == summary["frames"]
