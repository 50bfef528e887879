"""`walkdiff bench inbetween` and `walkdiff bench edit`: the edits measured on held-out clips.

In-betweening follows Harvey et al. 2020: in each held-out test clip of the generator's data (its data
module's test split), a gap of N frames is cut after `context` frames of past context, at every offset
the clip allows (at most `stride` frames apart, as Harvey et al. cut LaFAN1's test takes into windows at
several offsets), and filled from those and the one frame after the gap (the target keyframe); the fill
is compared with the real frames by L2P, L2Q and NPSS (metrics/inbetween.py), beside the paper's two
baselines: linear interpolation (the root lerped, every joint's rotation slerped, from the last context
frame to the keyframe) and zero velocity (the last context frame held). Positions for L2P are taken
relative to the last context frame (its root on the ground and its heading) and standardised per
coordinate by the real gap frames' statistics. The same fills put back into their clips are scored by a
trained evaluator: the style it recognises in the window over the gap, and foot skating over the gap's
steps, each beside the real clip's. Intervals are 95% bootstrap intervals over clips
(metrics/bootstrap.py `resample_weights`), never over windows (one clip's windows share frames); a method
beats another where the interval of the paired difference lies wholly on one side of 0. Each gap reports
its windows, fills and clips, and in how many clips the fill is better on average.

`bench edit` regenerates each test clip's legs or upper body in another style and reports the kept
joints' largest error (body heights) and how often the evaluator recognises the asked style in the edited
clip's windows, beside how often it recognises real test windows' own styles.
"""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from walkdiff.bench.measure import machine, report
from walkdiff.common.checkpoints import read_checkpoint
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.progress import progress
from walkdiff.metrics.bootstrap import resample_weights
from walkdiff.metrics.inbetween import l2p, l2q, npss
from walkdiff.metrics.physics import skating_sums
from walkdiff.motion.kinematics import forward_kinematics
from walkdiff.motion.representation import decode, root_heading, yaw_matrix
from walkdiff.motion.rotations import matrix_to_quaternion
from walkdiff.motion.skeleton import Motion
from walkdiff.styled.edits import CANDIDATES, FILL_SAMPLER, fill_steps
from walkdiff.styled.pipeline import StyledGenerator

GAPS = (5, 15, 30, 45)
CONTEXT = 10  # frames of past context, as Harvey et al.
METHODS = ("model", "interpolation", "zero_velocity")


class HeldClip(NamedTuple):
    """A held-out clip: its labels (the model's names) and its canonical motion."""

    style: str
    content: str
    name: str
    motion: Motion


class HeldOut:
    """A generator with its held-out test clips (canonical, decoded from the data module's features) and
    an evaluator scoring windows of them. Each clip is filled or edited with its own content label: a
    model of several contents is measured on every one of them, not as if all were its first."""

    def __init__(self, ckpt: str | Path, evaluator: str | Path, splits: tuple[str, ...] = ("test",)):
        from walkdiff.data.datamodule import MotionDataModule, data_settings
        from walkdiff.evaluation.scorer import MotionScorer, load_evaluator, window_set

        self.generator = StyledGenerator.load(ckpt)
        model = self.generator.model
        self.skeleton, self.profile, self.fps = model.skeleton, model.profile, self.generator.fps
        data = MotionDataModule(**data_settings(read_checkpoint(ckpt, "generator")))
        unknown = [s for s in splits if s not in ("test", "val")]
        if unknown or not splits:
            raise WalkdiffError(
                f"--split: expected test, val or test,val (held-out clips), got {','.join(splits)}"
            )
        test = [clip for split in splits for clip in data.split_features(split)]
        styles, contents = list(model.spec["styles"]), list(model.spec["contents"])
        dt = 1.0 / self.fps
        self.clips = [
            HeldClip(styles[info.style], contents[info.content], name, decode(features, self.skeleton, dt))
            for info, name, features in test
        ]
        self.scorer = MotionScorer(load_evaluator(evaluator), self.skeleton, self.fps)
        self.window = int(self.scorer.spec["window"])
        self.scorer.set_reference(self.scorer.embed(window_set(test, self.window, stride=4)))
        self.eval_styles = list(self.scorer.spec["styles"])
        self.requests: dict = {}

    def request(self, style: str, content: str, sampler: str, steps: int | None):
        if (style, content) not in self.requests:
            self.requests[style, content] = self.generator.request(
                style, content=content, sampler=sampler, steps=steps
            )
        return self.requests[style, content]

    def recognised(self, windows: list[np.ndarray], styles: list[str]) -> np.ndarray:
        """(N,) whether the evaluator recognises each style in world position windows (W, J, 3)."""
        from walkdiff.evaluation.scorer import WindowSet

        root = 0
        cut = np.stack([w - w[:1, root : root + 1] * np.array([1.0, 0.0, 1.0]) for w in windows])
        ids = torch.tensor([self.eval_styles.index(s) for s in styles])
        embedded = self.scorer.embed(
            WindowSet(None, ids, torch.zeros_like(ids), torch.zeros_like(ids), torch.from_numpy(cut).float())
        )
        return (embedded.style_logits.argmax(-1) == ids).numpy()

    def skating(self, positions: np.ndarray) -> tuple[float, float]:
        """(contact steps, skating steps) of world positions (F, J, 3), contacts judged by geometry."""
        s = self.scorer
        p = torch.from_numpy(positions).float()[None]
        contact, skating, _ = skating_sums(
            p, s.ground_contacts(p), s.foot_joints, self.fps, s.speed_threshold
        )
        return float(contact[0]), float(skating[0])


# ---------------------------------------------------------------- the baselines


def interpolated(real: Motion, start: int, gap: int) -> Motion:
    """The gap's frames by linear interpolation from frame start - 1 to frame start + gap: the root's
    position lerped, every joint's rotation (the root's too) slerped."""
    import roma

    first, last = real.rotations[start - 1], real.rotations[start + gap]
    q0 = roma.rotmat_to_unitquat(torch.from_numpy(first))
    q1 = roma.rotmat_to_unitquat(torch.from_numpy(last))
    steps = torch.arange(1, gap + 1, dtype=torch.float64) / (gap + 1)
    rotations = roma.unitquat_to_rotmat(roma.unitquat_slerp(q0, q1, steps)).numpy()
    positions = np.repeat(real.positions[start - 1][None], gap, axis=0)
    a, b = real.positions[start - 1, 0], real.positions[start + gap, 0]
    positions[:, 0] = a + steps.numpy()[:, None] * (b - a)
    return Motion(real.skeleton, rotations, positions, real.frame_time)


def zero_velocity(real: Motion, start: int, gap: int) -> Motion:
    """The gap's frames as the last context frame held."""
    frame = real.slice(start - 1, start)
    return Motion(
        real.skeleton,
        np.repeat(frame.rotations, gap, axis=0),
        np.repeat(frame.positions, gap, axis=0),
        real.frame_time,
    )


def spliced(real: Motion, start: int, fill: Motion) -> Motion:
    """The real clip with its frames from `start` replaced by `fill`'s."""
    rotations, positions = real.rotations.copy(), real.positions.copy()
    rotations[start : start + fill.num_frames] = fill.rotations
    positions[start : start + fill.num_frames] = fill.positions
    return Motion(real.skeleton, rotations, positions, real.frame_time)


def gap_starts(frames: int, gap: int, context: int, stride: int) -> list[int]:
    """Gap starts that leave `context` frames before and one after, from the first possible to the last,
    evenly spread at most `stride` frames apart (windows at several offsets of one clip, as Harvey et al.
    take LaFAN1's test windows; they share frames, so intervals resample clips, not windows)."""
    last = frames - gap - 1
    if last < context:
        return []
    count = -(-(last - context) // stride) + 1
    return sorted({round(x) for x in np.linspace(context, last, count)})


# ---------------------------------------------------------------- measuring


def world(motion: Motion, profile) -> tuple[np.ndarray, np.ndarray]:
    """World positions (F, J, 3) and rotations as quaternions (F, J, 4) of a canonical clip."""
    positions, rotations = forward_kinematics(
        torch.from_numpy(motion.rotations), torch.from_numpy(motion.positions), motion.skeleton.parents, True
    )
    return positions.numpy(), matrix_to_quaternion(rotations).numpy()


def aligned(positions: np.ndarray, anchor: Motion, profile) -> np.ndarray:
    """Positions (F, J, 3) in the frame of `anchor`'s first frame: its root on the ground at the origin,
    facing +Z."""
    heading = root_heading(torch.from_numpy(anchor.rotations[0, 0]), profile.forward)
    turn = yaw_matrix(-heading).numpy()
    ground = anchor.positions[0, 0] * np.array([1.0, 0.0, 1.0])
    return (positions - ground) @ turn.T


def continuous(quaternions: np.ndarray) -> np.ndarray:
    """Quaternions (F, J, 4) with signs flipped frame to frame so that no frame jumps hemisphere."""
    out = quaternions.copy()
    for f in range(1, len(out)):
        flip = (out[f] * out[f - 1]).sum(-1) < 0
        out[f, flip] *= -1
    return out


def bootstrap(values: np.ndarray, clips: np.ndarray, resamples: int, seed: int) -> dict:
    """Mean of per-case `values` and its 95% interval over clips (cases resampled with their clip)."""
    ids = np.unique(clips, return_inverse=True)[1]
    sums = np.bincount(ids, weights=values)
    counts = np.bincount(ids).astype(np.float64)
    means = [
        float(w.numpy() @ sums / (w.numpy() @ counts)) for w in resample_weights(len(sums), resamples, seed)
    ]
    low, high = np.percentile(means, [2.5, 97.5])
    return {"mean": round(float(values.mean()), 4), "interval": [round(float(low), 4), round(float(high), 4)]}


def ratio_interval(made: np.ndarray, real: np.ndarray, clips: np.ndarray, resamples: int, seed: int) -> dict:
    """The ratio of two shares over cases, with its 95% interval over clips: `made` and `real` are
    per-case (count, total) pairs (N, 2) (skating steps of contact steps, windows recognised of windows),
    or per-case values (N,) whose totals are the number of cases."""
    ids = np.unique(clips, return_inverse=True)[1]

    def sums(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.asarray(x, np.float64)
        x = np.stack([x, np.ones_like(x)], -1) if x.ndim == 1 else x
        return np.bincount(ids, weights=x[:, 0]), np.bincount(ids, weights=x[:, 1])

    (a, na), (b, nb) = sums(made), sums(real)

    def ratio(w: np.ndarray) -> float:
        top, bottom = (w @ a) / max(w @ na, 1e-12), (w @ b) / max(w @ nb, 1e-12)
        return top / bottom if bottom > 0 else float("nan")

    ratios = [ratio(w.numpy()) for w in resample_weights(len(a), resamples, seed)]
    low, high = np.nanpercentile(ratios, [2.5, 97.5]) if np.isfinite(ratios).any() else (np.nan, np.nan)
    return {
        "ratio": round(ratio(np.ones(len(a))), 4),
        "interval": [round(float(low), 4), round(float(high), 4)],
    }


def bench_inbetween(
    ckpt: str | Path,
    evaluator: str | Path,
    out: str | Path,
    gaps: tuple[int, ...] = GAPS,
    context: int = CONTEXT,
    stride: int = 5,
    seed: int = 0,
    sampler: str = FILL_SAMPLER,
    steps: int | None = None,
    resamples: int = 1000,
    repeats: int = 5,
    fix_feet: bool = True,
    splits: tuple[str, ...] = ("test",),
    resample: int = 0,
    samples: int = 1,
    guide: float | None = None,
    candidates: int = CANDIDATES,
) -> dict:
    """Every gap's table (see the module docstring), the timing of a 45-frame fill, written to `out`.
    `stride`: frames between the gap starts cut in one clip; `samples`: fills per gap (seeds), each scored
    on its own; `resample`: RePaint resampling of the fills (editing.masked_sample; 0, the API's);
    `guide`: their reconstruction guidance (None: the API's); `candidates`: fills drawn for each, the
    most typical kept (the API's default); `steps`: none, the fill's own (recorded as run)."""
    steps = fill_steps(sampler, steps)
    held = HeldOut(ckpt, evaluator, splits)
    held.generator.resample = resample
    if guide is not None:
        held.generator.guide = guide
    result = {
        "splits": list(splits),
        "resample": resample, "guide": held.generator.guide,
        "checkpoint": str(ckpt), "evaluator": str(evaluator), "context": context, "stride": stride,
        "samples": samples, "candidates": candidates,
        "sampler": sampler, "steps": steps, "seed": seed, "fix_feet": fix_feet, "test_clips": len(held.clips),
        "gaps": {},
    }  # fmt: skip
    for gap in gaps:
        result["gaps"][str(gap)] = _gap(
            held, gap, context, stride, seed, sampler, steps, resamples, fix_feet, samples, candidates
        )
    result["timing"] = _timing(held, context, sampler, steps, repeats, seed, candidates)
    result["machine"] = machine()
    report(out, result)
    return result


def _gap(
    held: HeldOut, gap, context, stride, seed, sampler, steps, resamples, fix_feet=True, samples=1,
    candidates=CANDIDATES,
):  # fmt: skip
    profile, generator = held.profile, held.generator
    windows = [
        (i, s)
        for i, clip in enumerate(held.clips)
        for s in gap_starts(clip.motion.num_frames, gap, context, stride)
    ]
    # Each window filled `samples` times (seeds clip + 1000 k), each fill scored as a case of its own.
    cases = [(i, s, seed + i + 1000 * k) for k in range(samples) for i, s in windows]
    if not cases:
        raise WalkdiffError(f"no test clip has {context} + {gap} + 1 frames: no gap of {gap} frames to fill")
    measures = {
        m: {"positions": [], "quaternions": [], "window": [], "skating": []} for m in (*METHODS, "real")
    }
    styles, clips = [], []
    for i, s, drawn in progress(cases, desc=f"gap {gap}", unit="fill"):
        style, content, _, real = held.clips[i]
        a = profile.to_file(real.slice(s - context, s))
        b = profile.to_file(real.slice(s + gap, s + gap + 1))
        request = held.request(style, content, sampler, steps)
        made = generator.fill(
            request, a, b, gap, drawn, fill_only=True, fix_feet=fix_feet, candidates=candidates
        )
        made = made.take.canonical()
        fills = {
            "model": made, "interpolation": interpolated(real, s, gap),
            "zero_velocity": zero_velocity(real, s, gap), "real": real.slice(s, s + gap),
        }  # fmt: skip
        anchor = real.slice(s - 1, s)
        start = min(max(0, s + gap // 2 - held.window // 2), real.num_frames - held.window)
        for method, fill in fills.items():
            clip = spliced(real, s, fill)
            positions, quaternions = world(clip, profile)
            record = measures[method]
            record["positions"].append(aligned(positions[s : s + gap], anchor, profile))
            record["quaternions"].append(quaternions[s : s + gap])
            record["window"].append(positions[start : start + held.window])
            record["skating"].append(held.skating(positions[s - 1 : s + gap + 1]))
        styles.append(style)
        clips.append(i)
    clips = np.asarray(clips)
    real_p = np.stack(measures["real"]["positions"])
    mean, std = real_p.mean((0, 1)), np.maximum(real_p.std((0, 1)), 1e-6 * profile.body_height)
    real_q = np.stack([continuous(q) for q in measures["real"]["quaternions"]])
    real_style = held.recognised(measures["real"]["window"], styles)
    real_skate = np.array(measures["real"]["skating"])
    rows, values = {}, {}
    for method in METHODS:
        record = measures[method]
        made_q = np.stack(record["quaternions"])
        made_q = np.where((made_q * real_q).sum(-1, keepdims=True) < 0, -made_q, made_q)
        values[method] = {
            "l2p": l2p(np.stack(record["positions"]), real_p, mean, std),
            "l2q": l2q(made_q, real_q),
            "npss": npss(made_q.reshape(*made_q.shape[:2], -1), real_q.reshape(*real_q.shape[:2], -1)),
        }
        skate = np.array(record["skating"])
        style_ok = held.recognised(record["window"], styles).astype(float)
        rows[method] = {
            **{k: bootstrap(v, clips, resamples, seed) for k, v in values[method].items()},
            "style_acc": bootstrap(style_ok, clips, resamples, seed),
            "style_vs_real": ratio_interval(style_ok, real_style.astype(float), clips, resamples, seed),
            "skate_ratio": round(float(skate[:, 1].sum() / max(skate[:, 0].sum(), 1)), 4),
            "skating_vs_real": ratio_interval(skate[:, ::-1], real_skate[:, ::-1], clips, resamples, seed),
        }  # fmt: skip
    beats = {
        key: bootstrap(values["model"][key] - values["interpolation"][key], clips, resamples, seed)
        for key in ("l2p", "l2q", "npss")
    }
    ids = np.unique(clips, return_inverse=True)[1]
    better = {  # clips whose mean paired difference is below 0 (the model better there)
        key: int((np.bincount(ids, values["model"][key] - values["interpolation"][key]) < 0).sum())
        for key in ("l2p", "l2q", "npss")
    }
    return {
        "windows": len(windows),
        "cases": len(cases),
        "clips": len(set(clips.tolist())),
        "contents": dict(Counter(held.clips[i].content for i, _ in windows)),  # windows of each label
        "real": {
            "style_acc": bootstrap(real_style.astype(float), clips, resamples, seed),
            "skate_ratio": round(float(real_skate[:, 1].sum() / max(real_skate[:, 0].sum(), 1)), 4),
        },
        **rows,
        "model_minus_interpolation": beats,
        "model_beats_interpolation": {k: v["interval"][1] < 0 for k, v in beats.items()},
        "clips_model_better": better,
    }


def _timing(
    held: HeldOut, context, sampler, steps, repeats: int, seed: int, candidates: int, gap: int = 45
) -> dict:
    """Median seconds of a `gap`-frame fill (the API call, model loaded) on this machine's threads."""
    style, content, _, real = max(held.clips, key=lambda c: c.motion.num_frames)
    if real.num_frames < context + 2:
        return {}
    a = held.profile.to_file(real.slice(real.num_frames - context - 1, real.num_frames - 1))
    b = held.profile.to_file(real.slice(real.num_frames - 1, real.num_frames))
    request = held.request(style, content, sampler, steps)
    spent = []
    for _ in range(repeats):
        started = time.perf_counter()
        held.generator.fill(request, a, b, gap, seed, fill_only=True, candidates=candidates)
        spent.append(time.perf_counter() - started)
    return {
        "gap": gap, "candidates": candidates, "median_s": round(float(np.median(spent)), 3),
        "threads": torch.get_num_threads(),
    }  # fmt: skip


# ---------------------------------------------------------------- edits


def bench_edit(
    ckpt: str | Path,
    evaluator: str | Path,
    out: str | Path,
    keeps: tuple[str, ...] = ("legs", "upper-body"),
    seed: int = 0,
    sampler: str = "ddpm",
    steps: int | None = None,
    resamples: int = 1000,
    splits: tuple[str, ...] = ("test",),
) -> dict:
    """Per kept part: the kept joints' largest error, and the asked style's recognition in the edited
    clips (each test clip edited into the next style of the model's list) beside real windows' own."""
    held = HeldOut(ckpt, evaluator, splits)
    styles = list(held.generator.styles)
    clips = [(i, c) for i, c in enumerate(held.clips) if c.motion.num_frames >= held.window]
    stride = max(1, held.window // 2)

    def windows(motion: Motion) -> list[np.ndarray]:
        positions = world(motion, held.profile)[0]
        return [positions[s : s + held.window] for s in range(0, motion.num_frames - held.window + 1, stride)]

    real_w, real_s, real_c = [], [], []
    for i, (style, _, _, real) in clips:
        found = windows(real)
        real_w += found
        real_s += [style] * len(found)
        real_c += [i] * len(found)
    real_ok = held.recognised(real_w, real_s).astype(float)
    result = {
        "checkpoint": str(ckpt), "evaluator": str(evaluator), "sampler": sampler, "steps": steps,
        "seed": seed, "test_clips": len(clips),
        "real_style_acc": bootstrap(real_ok, np.asarray(real_c), resamples, seed),
        "keeps": {},
    }  # fmt: skip
    for keep in keeps:
        made_w, made_s, made_c, errors, source_ok = [], [], [], [], []
        for i, (style, content, _, real) in progress(clips, desc=f"edit {keep}", unit="clip"):
            target = styles[(styles.index(style) + 1) % len(styles)]
            request = held.request(target, content, sampler, steps)
            edited = held.generator.edited(request, held.profile.to_file(real), keep, seed + i)
            errors.append(edited.extra["kept_error"])
            found = windows(edited.take.canonical())
            made_w += found
            made_s += [target] * len(found)
            made_c += [i] * len(found)
            source_ok += held.recognised(windows(real), [target] * len(found)).tolist()
        ok = held.recognised(made_w, made_s).astype(float)
        made_c = np.asarray(made_c)
        result["keeps"][keep] = {
            "kept_error_body_heights": float(max(errors)),
            "style_acc": bootstrap(ok, made_c, resamples, seed),
            "style_vs_real": ratio_interval(ok, np.full(len(ok), real_ok.mean()), made_c, resamples, seed),
            "source_as_asked_style": bootstrap(np.asarray(source_ok, float), made_c, resamples, seed),
        }  # fmt: skip
    result["machine"] = machine()
    report(out, result)
    return result


def format_differences(result: dict) -> list[str]:
    """The model minus interpolation per gap as Markdown rows (docs/editing.md): mean [95% interval over
    clips], with the windows and clips it rests on and the clips where the model is better on average."""
    lines = [
        "| gap | windows (clips) | L2P | NPSS | L2Q | clips better (L2P / NPSS) |",
        "|---|---|---|---|---|---|",
    ]
    for gap, row in result["gaps"].items():
        d, better = row["model_minus_interpolation"], row["clips_model_better"]
        cells = [_signed(d[m], 3 if m != "npss" else 4) for m in ("l2p", "npss", "l2q")]
        count = f"{row['windows']} ({row['clips']})" + (
            f" x {row['cases'] // row['windows']}" if row["cases"] > row["windows"] else ""
        )
        lines.append(
            f"| {gap} | {count} | "
            + " | ".join(cells)
            + f" | {better['l2p']} / {better['npss']} of {row['clips']} |"
        )
    return lines


def _signed(value: dict, digits: int) -> str:
    low, high = value["interval"]
    return f"{value['mean']:+.{digits}f} [{low:+.{digits}f}, {high:+.{digits}f}]"


def format_inbetween(result: dict) -> list[str]:
    """The in-betweening table as Markdown rows (docs/editing.md)."""
    lines = [
        "| gap | fills (clips) | method | L2P | L2Q | NPSS | style vs real | skating vs real |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for gap, row in result["gaps"].items():
        for method in METHODS:
            r = row[method]
            cells = [_cell(r[m], "mean", 3) for m in ("l2p", "l2q", "npss")]
            cells += [_cell(r[m], "ratio", 2) for m in ("style_vs_real", "skating_vs_real")]
            lines.append(
                f"| {gap} | {row['cases']} ({row['clips']}) | {method} | " + " | ".join(cells) + " |"
            )
    return lines


def _cell(value: dict, key: str, digits: int) -> str:
    low, high = value["interval"]
    return f"{value[key]:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"
