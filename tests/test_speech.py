"""Speech takes: BVH + WAV pairing, alignment, the pose features, the data module and the real ZEGGS take."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import roma
import soundfile
import synthetic
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.data.speech import (
    NeutralPose,
    SpeechDataModule,
    decode_poses,
    default_joints,
    encode_poses,
    list_takes,
    load_take,
    log_mel,
    read_wav,
)
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.profile import SkeletonProfile

RATE = 16_000


def write_wav(path: Path, seconds: float, seed: int = 0, clicks_per_second: float = 3.0) -> np.ndarray:
    """Noise bursts at random times over a quiet hum; returns the burst times (s)."""
    rng = np.random.default_rng(seed)
    n = int(round(seconds * RATE))
    t = np.arange(n) / RATE
    samples = 0.01 * np.sin(2 * np.pi * 150 * t)
    onsets = np.sort(rng.uniform(0.2, max(seconds - 0.3, 0.3), int(seconds * clicks_per_second)))
    for onset in onsets:
        start = int(onset * RATE)
        burst = rng.normal(0, 0.5, min(1600, n - start)) * np.exp(-np.arange(min(1600, n - start)) / 400)
        samples[start : start + len(burst)] += burst
    soundfile.write(path, samples.astype(np.float32), RATE, subtype="PCM_16")
    return onsets


def write_take(folder: Path, stem: str, seconds: float, audio_seconds: float | None = None, seed: int = 0):
    """`stem.bvh` at 30 fps lasting `seconds` (first to last frame) and `stem.wav` of `audio_seconds`."""
    folder.mkdir(parents=True, exist_ok=True)
    synthetic.write_bvh(
        folder / f"{stem}.bvh", synthetic.walking(int(round(seconds * 30)) + 1, fps=30.0, seed=seed)
    )
    return write_wav(folder / f"{stem}.wav", seconds if audio_seconds is None else audio_seconds, seed)


def _load_take(folder, stem, **options):
    bvh = folder / f"{stem}.bvh"
    return load_take(bvh, folder / f"{stem}.wav", SkeletonProfile.detect(read_bvh(bvh)), **options)


def test_take_is_aligned_frame_for_frame(tmp_path):
    write_take(tmp_path, "a", 6.0)
    take = _load_take(tmp_path, "a", fps=20.0)
    assert take.motion.fps == pytest.approx(20.0)
    assert take.motion.num_frames == 121  # 0 .. 6 s at 20 fps
    assert take.audio.shape == (121, 27)
    assert np.isfinite(take.audio).all()


def test_mel_frame_k_is_centred_on_motion_frame_k():
    # A burst at 2.0 s must peak in mel frame 40 at 20 fps.
    samples = np.zeros(4 * RATE, dtype=np.float32)
    samples[2 * RATE - 200 : 2 * RATE + 200] = np.random.default_rng(0).normal(0, 0.5, 400)
    mel = log_mel(samples, RATE, 20.0)
    assert mel.shape == (81, 27)
    assert int(np.argmax(mel.sum(axis=1))) == 40


def test_mel_resamples_rates_that_do_not_divide_into_frames():
    samples = np.random.default_rng(0).normal(0, 0.1, 22_050 * 2).astype(np.float32)
    assert log_mel(samples, 22_050, 20.0).shape == (41, 27)


def test_length_mismatch_names_both_files(tmp_path):
    write_take(tmp_path, "short", 6.0, audio_seconds=5.0)
    with pytest.raises(WalkdiffError) as error:
        _load_take(tmp_path, "short")
    message = str(error.value)
    assert "short.bvh" in message and "short.wav" in message
    assert "121 frames" in message and "101" in message


def test_one_frame_of_mismatch_is_trimmed(tmp_path):
    write_take(tmp_path, "a", 6.0, audio_seconds=6.0 - 0.05)
    take = _load_take(tmp_path, "a")
    assert take.motion.num_frames == len(take.audio) == 120


def test_unpaired_files_are_named(tmp_path):
    write_take(tmp_path, "a", 2.0)
    (tmp_path / "b.wav").write_bytes((tmp_path / "a.wav").read_bytes())
    with pytest.raises(WalkdiffError, match="b.wav"):
        list_takes(tmp_path)


@pytest.mark.parametrize("rotation", ["expmap", "6d"])
def test_poses_round_trip_and_expmaps_stay_continuous(rotation):
    motion = synthetic.walking(60, fps=20.0)
    # Spin the spine about Y through pi and beyond: a plain rotation vector would jump there.
    angle = np.linspace(2.5, 3.8, 60)
    motion.rotations[:, 11] = roma.rotvec_to_rotmat(torch.tensor(angle[:, None] * [0.0, 1.0, 0.0])).numpy()
    joints = [11, 12]
    features = encode_poses(motion, joints, rotation)
    assert features.shape == (60, 2 * (3 if rotation == "expmap" else 6))
    assert np.abs(np.diff(features, axis=0)).max() < 0.1
    neutral = NeutralPose.of([motion])
    back = decode_poses(features, motion.skeleton, joints, rotation, neutral, motion.frame_time)
    np.testing.assert_allclose(back.rotations[:, joints], motion.rotations[:, joints], atol=1e-5)
    # Everything else is the neutral pose: fixed root, mean rotations.
    np.testing.assert_allclose(back.root_positions, np.repeat(neutral.root[None], 60, 0))
    np.testing.assert_allclose(back.rotations[:, 2], np.repeat(neutral.rotations[None, 2], 60, 0))
    assert np.isfinite(motion_world_positions(back)).all()


def test_default_joints_of_a_gesture_skeleton():
    sk = synthetic.skeleton()
    assert default_joints(sk) == ["Spine", "Head"]


def test_datamodule_sequences(tmp_path):
    write_take(tmp_path / "takes", "a", 10.0, seed=1)
    write_take(tmp_path / "takes", "b", 8.0, seed=2)
    dm = SpeechDataModule(str(tmp_path / "takes"), window=40, stride=10, past=5, lookahead=8, batch_size=4)
    spec = dm.spec
    assert spec.joints == ("Spine", "Head") and spec.feature_dim == 6 and spec.audio_dim == 27
    dm.setup("fit")
    take = dm.load_takes()[0]
    assert dm.split_frames(take, "train") == (0, 161) and dm.split_frames(take, "test") == (161, 201)
    batch = next(iter(dm.train_dataloader()))
    assert batch["poses"].shape == (4, 40, 6)
    assert batch["audio"].shape == (4, 5 + 40 + 8, 27)
    # Training sequences stay inside the first 80% of each take; the test part has its own.
    takes = dm.load_takes()
    for split in ("train", "test"):
        for part, start in dm.datasets[split].index:
            begin, end = dm.split_frames(takes[part], split)
            assert begin <= start and start + 40 <= end
    # Normalised over the training frames: roughly zero mean, unit std there.
    train = np.concatenate([dm.datasets["train"][i]["poses"] for i in range(len(dm.datasets["train"]))])
    assert np.abs(train.mean(axis=0)).max() < 0.5


def test_zeggs_take_loads_and_aligns(zeggs_dir):
    dm = SpeechDataModule(str(zeggs_dir.resolve()), window=120)
    take = dm.load_takes()[0]
    assert take.motion.num_frames == len(take.audio) == 1377  # 68.8 s at 20 fps
    assert dm.spec.joints == (
        "Spine", "Spine1", "Spine2", "Spine3", "Neck", "Neck1", "Head",
        "RightShoulder", "RightArm", "RightForeArm", "RightHand",
        "LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand",
    )  # fmt: skip
    assert dm.split_frames(take, "train") == (0, 1102)
    poses = dm.poses(take)
    assert poses.shape == (1377, 45)
    # The hands turn through pi in this take: where a rotation changes little from one frame to the next
    # (< 0.2 rad), its exponential map must not jump (a plain rotation vector jumps by ~2 pi there).
    rotations = torch.tensor(take.motion.rotations[:, dm.joint_indices])
    small = roma.rotmat_geodesic_distance(rotations[1:], rotations[:-1]).numpy() < 0.2
    jumps = np.linalg.norm(np.diff(poses.reshape(-1, 15, 3), axis=0), axis=-1)
    assert jumps[small].max() < 0.5
    # Speech is louder than the pauses: the log-mel energy spans a wide range.
    energy = take.audio.mean(axis=1)
    assert energy.max() - energy.min() > 5


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_wav_with_non_finite_samples_is_refused_with_where(tmp_path, bad):
    samples = np.zeros((16000, 2), dtype=np.float32)
    samples[8000, 1] = bad
    path = tmp_path / "speech.wav"
    soundfile.write(path, samples, 16000, subtype="FLOAT")
    with pytest.raises(WalkdiffError) as error:
        read_wav(path)
    assert (
        str(path) in str(error.value) and "0.500 s" in str(error.value) and "not finite" in str(error.value)
    )
