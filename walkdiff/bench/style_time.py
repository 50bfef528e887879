"""`walkdiff bench style`, its time rows: style timelines (transitions) and how fast a clip is encoded.

- Transitions: `clips` long clips, each a timeline of three `segment`-second segments of consecutive
  training styles (clip i: styles i, i+1, i+2), ramped over `transition` seconds. The evaluator's windows
  that lie fully inside a segment, clear of its ramps, are labelled with that segment's style: the share
  recognised is the bar (>= 90%). Seams: the frame-to-frame change of the mean joint speed, averaged
  over a transition's ramp, against the 95th percentile of that average over the stretches of the same
  length inside the clips' segments that lie where the ramp lies in the grid of window joins: a
  transition passes within it (a ramp that looks like the rest does 95% of the time; the control of
  clips that never change style says how often). The bar: >= 90% of transitions pass.
- Encoding: the median time of `StyledGenerator.examples` on a real test clip in memory (features,
  windows, encoder; the file's reading left out), over `repeats` runs, on the threads torch uses here.
"""

from __future__ import annotations

import statistics
import time

import numpy as np
import torch

from walkdiff.bench.protocol import clips_of_raw
from walkdiff.evaluation.clips import ClipScorer
from walkdiff.models.style_labels import parse_timeline
from walkdiff.motion.bvh import read_bvh
from walkdiff.styled.generation import Sampling, generate_long, joint_speeds, resolve_windows
from walkdiff.styled.pipeline import StyledGenerator

SEGMENT_SECONDS = 4.0
TRANSITION_SECONDS = 1.0


def transitions(
    scorer: ClipScorer, generator: StyledGenerator, styles: list[str], sampling: Sampling, seed: int,
    clips: int = 32, segment: float = SEGMENT_SECONDS, transition: float = TRANSITION_SECONDS,
) -> dict:  # fmt: skip
    """The transitions row: inside-segment recognition and seams at the ramps (see the module), beside the
    same measures of clips whose three segments share one style (a control: how often a ramp that is
    no transition passes)."""
    recognised, seams = _timelines(scorer, generator, styles, sampling, seed, clips, segment, transition)
    _, control = _timelines(scorer, generator, styles[:1], sampling, seed, clips, segment, transition)
    passed = float(np.mean(seams))
    return {
        "clips": clips,
        "segment_s": segment,
        "transition_s": transition,
        "inside_windows": recognised["windows"],
        "inside_style_acc": recognised["accuracy"],
        "transitions": len(seams),
        "seams_within_p95": passed,
        "control_seams_within_p95": float(np.mean(control)),
        "criteria": {
            "inside": _bar("windows inside segments recognised as theirs >= 0.90", recognised["accuracy"]),
            "seams": _bar("transitions whose ramp stays within the inside p95 >= 0.90", passed),
        },
    }


def _timelines(scorer, generator, styles, sampling, seed, clips, segment, transition) -> tuple[dict, list]:
    """Clips of three segments of consecutive `styles`: inside-segment recognition, seams per ramp."""
    model, fps = generator.model, generator.fps
    keys = [[styles[(i + k) % len(styles)] for k in range(3)] for i in range(clips)]
    timelines = [
        parse_timeline(model, ",".join(f"{s}@{k * segment:g}" for k, s in enumerate(names)), transition)
        for names in keys
    ]
    frames = round(3 * segment * fps)
    content = model.label_ids([scorer.data.selection.names[0]], "content")
    generator_ = torch.Generator(device=model.device).manual_seed(seed)

    def style_at(start: int, stop: int) -> torch.Tensor:
        middle = (start + stop - 1) / 2 / fps
        return torch.stack([t.at(middle) for t in timelines]).to(model.device)

    x = generate_long(
        model, style_at(0, 1), content.expand(clips), frames, sampling, generator_, style_at=style_at
    )
    recognised = _inside_recognition(scorer, model, x, keys, segment, transition)
    window = model.spec["window"]
    hop = window - resolve_windows(window, None, None)[0]
    return recognised, _ramp_seams(joint_speeds(model, x).numpy(), fps, segment, transition, hop)


def _inside_recognition(scorer: ClipScorer, model, x: torch.Tensor, keys, segment: float, transition: float):
    raw = torch.from_numpy(model.to_raw(x, True))
    clips = clips_of_raw(scorer, raw, [k[0] for k in keys], None, "timeline")
    window, fps = scorer.window, scorer.fps
    starts, labels = [], []
    for names in keys:
        mine, styles = [], []
        for k, style in enumerate(names):
            first = k * segment + (transition / 2 if k else 0.0)
            last = (k + 1) * segment - (transition / 2 if k < 2 else 0.0)
            for s in range(int(np.ceil(first * fps)), int(last * fps) - window + 1, scorer.stride):
                mine.append(s)
                styles.append(scorer.styles.index(style))
        starts.append(mine)
        labels += styles
    scored = scorer.windows(clips, starts)
    hits = scored.style_logits.argmax(-1) == torch.tensor(labels)
    return {"windows": len(labels), "accuracy": float(hits.double().mean())}


def _ramp_seams(speeds: np.ndarray, fps: float, segment: float, transition: float, hop: int) -> list[bool]:
    """Per transition of each clip: the mean change of joint speed over its ramp within the 95th
    percentile of the same mean over every stretch as long inside the clips' segments that starts at the
    same place in the window grid (`hop` frames: windows are joined every hop frames, and a stretch holds
    more joins or fewer by where it starts). The percentile is of every clip's stretches together: a
    clip has a score of them, too few for its own 95th percentile. A ramp like the rest passes 95% of
    the time."""
    change = np.abs(np.diff(speeds, axis=1))  # (B, steps): step t is frames t -> t + 2
    steps = np.arange(change.shape[1]) + 1.0
    half = transition / 2
    ramps = [(steps >= (k * segment - half) * fps) & (steps <= (k * segment + half) * fps) for k in (1, 2)]
    inside = ~(ramps[0] | ramps[1])
    length = int(ramps[0].sum())
    means = np.stack([np.convolve(clip, np.ones(length) / length, mode="valid") for clip in change])
    clear = np.convolve(inside, np.ones(length), mode="valid") == length  # stretches wholly inside
    starts = np.arange(means.shape[1])
    out = np.zeros((len(change), len(ramps)), dtype=bool)
    for k, ramp in enumerate(ramps):
        first = int(np.argmax(ramp))
        bound = np.percentile(means[:, clear & (starts % hop == first % hop)], 95)
        out[:, k] = means[:, first] <= bound
    return out.ravel().tolist()


def encoding_speed(scorer: ClipScorer, generator: StyledGenerator, repeats: int = 20) -> dict:
    """Median seconds to encode the longest real test clip in memory (features, windows and encoder)."""
    info, _, _ = max(scorer.data.split_features("test"), key=lambda clip: clip[2].shape[0])
    clip = read_bvh(info.path)
    generator.examples([clip])  # warm up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        generator.examples([clip])
        times.append(time.perf_counter() - start)
    median = statistics.median(times)
    return {
        "clip": info.path.name,
        "seconds_of_motion": round(clip.num_frames / clip.fps, 2),
        "median_ms": round(1000 * median, 2),
        "threads": torch.get_num_threads(),
        "criteria": {
            "speed": {
                "rule": "encoding a clip <= 20 ms",
                "value": median * 1000,
                "bar": 20.0,
                "pass": median <= 0.020,
            }
        },  # fmt: skip
    }


def _bar(rule: str, value: float) -> dict:
    return {"rule": rule, "value": value, "bar": 0.9, "pass": value >= 0.9}
