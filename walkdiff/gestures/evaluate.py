"""`walkdiff evaluate-gesture`: a trained DiffMotion scored on the held-out part of each take.

Metrics (all on world positions of the modelled joints, root and other joints in the neutral pose, so
generated and real motion are compared on the same footing):

- L1: mean over frames and joints of |x - x'| + |y - y'| + |z - z'| against the ground truth.
- PCK: the fraction of joints closer than `pck_threshold` metres (0.1 m; converted to the skeleton's units
  with its profile) to the truth.
- Beat consistency: motion beats B_m are the local minima of the mean joint speed, audio beats B_a the
  onsets; BC = 1/|B_m| sum_{b in B_m} exp(-min_{a in B_a} (b - a)^2 / (2 sigma^2)), sigma = 0.1 s.
- Diversity: samples of the same audio cut into clips of equal length; the mean L1 over all pairs of
  clips (DiffMotion's protocol).
- Jerk: mean norm of the third difference of positions times fps^3 (walkdiff.metrics.Jitter).
- Seconds per frame of generation.

Each metric of the generated samples comes with a 95% percentile-bootstrap interval over the samples
(`BOOTSTRAP` resamples), so samplers and settings can be told apart from the spread of the samples.
"""

from __future__ import annotations

import inspect
import itertools
import time
from pathlib import Path

import numpy as np
import torch
from scipy.signal import argrelmin

from walkdiff.common.checkpoints import read_checkpoint
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_json
from walkdiff.common.progress import progress
from walkdiff.data.speech import SpeechDataModule, onset_times, read_wav
from walkdiff.diffusion import SamplerChoice
from walkdiff.gestures.commands import write_clips
from walkdiff.gestures.generator import SMOOTH_ORDER, SMOOTH_WINDOW, joint_positions, load_model, synthesize
from walkdiff.metrics import Jitter
from walkdiff.motion.filters import savgol
from walkdiff.motion.target_rig import TargetRig

BEAT_SIGMA = 0.1  # seconds


SHIFT_SECONDS = 2.0  # the audio-blind baseline of beat consistency


BOOTSTRAP = 1000  # resamples of the samples behind each metric's interval


def l1_distance(pred: np.ndarray, truth: np.ndarray) -> float:
    """Mean over frames and joints of the L1 norm of the position error; (F, J, 3) each."""
    return float(np.abs(pred - truth).sum(axis=-1).mean())


def pck(pred: np.ndarray, truth: np.ndarray, threshold: float) -> float:
    """Fraction of (frame, joint) positions within `threshold` (Euclidean) of the truth."""
    return float((np.linalg.norm(pred - truth, axis=-1) < threshold).mean())


def motion_beats(positions: np.ndarray, fps: float) -> np.ndarray:
    """Times (s) of the local minima of the mean joint speed; positions (F, J, 3)."""
    speed = np.linalg.norm(np.diff(positions, axis=0), axis=-1).mean(axis=-1)
    return (argrelmin(speed)[0] + 0.5) / fps  # speed i lies between frames i and i + 1


def beat_consistency(beats: np.ndarray, onsets: np.ndarray, sigma: float = BEAT_SIGMA) -> float:
    """Mean over motion beats of exp(-d^2 / (2 sigma^2)), d the distance to the nearest audio onset."""
    if len(beats) == 0 or len(onsets) == 0:
        return 0.0
    distance = np.abs(np.asarray(beats)[:, None] - np.asarray(onsets)[None]).min(axis=1)
    return float(np.exp(-(distance**2) / (2 * sigma**2)).mean())


def shift_beats(beats: np.ndarray, seconds: float, duration: float) -> np.ndarray:
    """Beats of the motion rolled by `seconds` against its audio (circularly, so none are lost)."""
    return np.sort((np.asarray(beats) + seconds) % duration)


def diversity(samples: np.ndarray, clip_frames: int) -> float:
    """Mean L1 between all pairs of equal clips cut from the samples (S, F, J, 3) of one audio."""
    count = samples.shape[1] // clip_frames
    clips = samples[:, : count * clip_frames].reshape(-1, clip_frames, *samples.shape[2:])
    if len(clips) < 2:
        raise WalkdiffError(f"diversity needs at least two {clip_frames}-frame clips, got {len(clips)}")
    return float(
        np.mean([l1_distance(clips[i], clips[j]) for i, j in itertools.combinations(range(len(clips)), 2)])
    )


def mean_jerk(positions: np.ndarray, fps: float) -> float:
    """Mean jerk magnitude of (F, J, 3) or (S, F, J, 3) positions."""
    metric = Jitter(fps)
    metric.update(torch.from_numpy(positions.reshape(-1, *positions.shape[-3:])))
    return float(metric.compute())


def evaluate_gesture(
    ckpt: str,
    out: str,
    samples: int = 5,
    seed: int = 0,
    clip_seconds: float = 2.0,
    pck_threshold: float = 0.1,
    root: str | None = None,
    sampler: str = "ddpm",
    steps: int | None = None,
    eta: float = 0.0,
    to: str | None = None,
    to_map: str | None = None,
) -> dict:
    """`walkdiff evaluate-gesture`: every metric on the held-out part of each take, with 95% intervals
    over the samples, into report.json; the per-take BVH and previews played by `to` (+ `to_map`) when
    given (the metrics are on the model's skeleton)."""
    choice = SamplerChoice(sampler, steps, eta)
    rig = TargetRig.of(to, to_map)
    if samples < 1:
        raise WalkdiffError(f"--samples must be >= 1, got {samples}")
    if not 0 < pck_threshold < np.inf:
        raise WalkdiffError(f"--pck-threshold must be a positive distance in metres, got {pck_threshold}")
    model = load_model(ckpt)
    pck_units = pck_threshold / model.profile.metres_per_unit
    checkpoint = read_checkpoint(ckpt, "gesture model", mmap=False)
    settings = dict(checkpoint.get("datamodule_hyper_parameters") or {})
    settings |= {"root": root} if root is not None else {}
    accepted = inspect.signature(SpeechDataModule).parameters  # LightningCLI adds _class_path
    settings = {k: v for k, v in settings.items() if k in accepted}
    data = SpeechDataModule(**settings)
    fps = model.spec["fps"]
    out_dir = Path(out)
    rows = []
    for take in progress(data.load_takes(), desc="takes", unit="take"):
        begin, end = data.split_frames(take, "test")
        truth_features = data.poses(take)[begin:end]
        wav, rate = read_wav(take.wav)
        onsets = onset_times(wav[int(begin / fps * rate) : int(end / fps * rate)], rate)
        start = time.perf_counter()
        raw = synthesize(model, take.audio[begin:end], samples, seed, sampler=choice)
        elapsed = time.perf_counter() - start
        smooth = savgol(raw, SMOOTH_WINDOW, SMOOTH_ORDER, axis=1)
        truth = joint_positions(model, truth_features)
        duration, clip = (end - begin) / fps, round(clip_seconds * fps)
        row = {"take": take.name, "frames": end - begin, "seconds": duration, "onsets": len(onsets)}
        row["truth"] = _beat_row(truth, onsets, fps, duration) | {"jerk": mean_jerk(truth, fps)}
        resamples = np.random.default_rng(seed).integers(0, samples, (BOOTSTRAP, samples))
        for name, clips in (("generated", raw), ("smoothed", smooth)):
            positions = np.stack([joint_positions(model, c) for c in clips])
            beats = [_beat_row(p, onsets, fps, duration) for p in positions]
            per_sample = {
                "l1": [l1_distance(p, truth) for p in positions],
                "pck": [pck(p, truth, pck_units) for p in positions],
                "bc": [b["bc"] for b in beats],
                "bc_shifted": [b["bc_shifted"] for b in beats],
                "jerk": [mean_jerk(p, fps) for p in positions],
            }
            row[name] = {key: float(np.mean(values)) for key, values in per_sample.items()}
            row[name] |= beat_gain(beats)
            row[name]["diversity"] = None
            if samples * ((end - begin) // clip) >= 2:
                row[name]["diversity"] = diversity(positions, clip)
                row[name]["diversity_ci95"] = diversity_interval(positions, clip, resamples)
            for key, values in per_sample.items():
                row[name][f"{key}_ci95"] = mean_interval(np.asarray(values), resamples)
            row[name]["jerk_over_truth"] = row[name]["jerk"] / row["truth"]["jerk"]
        row["seconds_per_frame"] = elapsed / (end - begin)  # all `samples` streams generated together
        _, row["preview"] = write_clips(
            out_dir / take.name,
            take.name,
            model,
            [truth_features, smooth[0], raw[0]],
            ["truth", "smoothed", "generated"],
            rig=rig,
        )
        rows.append(row)
    report = {
        "checkpoint": str(ckpt),
        "sampler": choice.label(model.diffusion),
        "samples": samples,
        "bootstrap": BOOTSTRAP,
        "seed": seed,
        "retarget": None if rig is None else rig.record(),
        "pck_threshold_m": pck_threshold,
        "beat_sigma_s": BEAT_SIGMA,
        "shift_s": SHIFT_SECONDS,
        "clip_seconds": clip_seconds,
        "takes": rows,
    }
    write_json(out_dir / "report.json", report)
    return report


def mean_interval(values: np.ndarray, resamples: np.ndarray) -> list[float] | None:
    """95% percentile-bootstrap interval of the mean of per-sample `values` (S,); resamples (R, S) of
    sample indices. None for a single sample."""
    if len(values) < 2:
        return None
    return [float(q) for q in np.percentile(values[resamples].mean(axis=1), [2.5, 97.5])]


def diversity_interval(samples: np.ndarray, clip_frames: int, resamples: np.ndarray) -> list[float] | None:
    """95% percentile-bootstrap interval of `diversity` over the samples (S, F, J, 3): a resample counts
    each pair of clips as often as their samples were drawn together, never a clip against itself."""
    count = samples.shape[1] // clip_frames
    if len(samples) < 2 or count < 1:
        return None
    clips = samples[:, : count * clip_frames].reshape(-1, clip_frames, *samples.shape[2:])
    distance = np.zeros((len(clips), len(clips)))
    for i, j in itertools.combinations(range(len(clips)), 2):
        distance[i, j] = distance[j, i] = l1_distance(clips[i], clips[j])
    owner = np.repeat(np.arange(len(samples)), count)  # the sample of each clip
    values = []
    for draw in resamples:
        drawn = np.bincount(draw, minlength=len(samples))[owner].astype(float)
        weight = np.outer(drawn, drawn)
        np.fill_diagonal(weight, 0.0)
        if weight.sum() > 0:  # a draw of one sample cut into one clip has no pair
            values.append((weight * distance).sum() / weight.sum())
    return [float(q) for q in np.percentile(values, [2.5, 97.5])] if values else None


def _beat_row(positions: np.ndarray, onsets: np.ndarray, fps: float, duration: float) -> dict:
    beats = motion_beats(positions, fps)
    return {
        "bc": beat_consistency(beats, onsets),
        "bc_shifted": beat_consistency(shift_beats(beats, SHIFT_SECONDS, duration), onsets),
        "beats": len(beats),
    }


def beat_gain(beats: list[dict]) -> dict:
    """How much the timing with its own audio beats the 2-s shift, per sample (paired): mean and 95% CI."""
    gain = np.array([b["bc"] - b["bc_shifted"] for b in beats])
    half = 1.96 * gain.std(ddof=1) / np.sqrt(len(gain)) if len(gain) > 1 else float("nan")
    return {
        "bc_gain": float(gain.mean()),
        "bc_gain_ci95": [float(gain.mean() - half), float(gain.mean() + half)],
        "bc_gain_positive_share": float((gain > 0).mean()),
    }
