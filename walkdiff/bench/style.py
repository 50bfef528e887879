"""`walkdiff bench style`: style from example clips (issue 30), every row scored as `bench protocol` scores
its rows, each with the issue's bars as criteria, passed or failed on the values.

- Seen styles (`ckpt`, a model with a style encoder): every real test clip of the evaluator's data whose
  style the model holds a stored code for is an example clip, read as `StyledGenerator.examples` reads
  one; `per_example` windows from each clip's code, beside as many windows per style by label, and the
  label-only model (`labels_ckpt`) by label with the same counts.
- Unseen styles (`unseen_ckpt`, trained with `data.leave_out_styles`, read from its checkpoint): windows
  from example clips of the left-out styles, and the real test clips of its training styles restyled to
  them (strength 0.6) with the mean code of each style's examples; beside them the label-only model by
  label (the ceiling), the training style whose stored code is nearest and the unchanged sources (the
  baselines), and the real training windows of those styles (the floor). FMD and KID of this section
  are measured against the real test windows of the left-out styles only.

Every generated window is a clip of its own, as in `bench protocol`; every value has a 95% interval by
bootstrap over clips. Writes OUT/style.json and OUT/style.md.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from walkdiff.bench.protocol import (
    TRANSFER_METRICS,
    clips_of_raw,
    held_out_clips,
    metric_table,
    restyled_clips,
)
from walkdiff.bench.style_time import encoding_speed, transitions
from walkdiff.common.checkpoints import read_checkpoint
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import output_folder, write_json, write_text
from walkdiff.common.progress import progress, step_hook
from walkdiff.data.datamodule import data_settings
from walkdiff.diffusion.samplers import DEFAULT_STEPS
from walkdiff.evaluation.clips import ClipScorer
from walkdiff.evaluation.score import format_summary
from walkdiff.evaluation.scorer import WindowSet, window_set
from walkdiff.evaluation.transfer import real_targets, transfer_baselines, transfer_row
from walkdiff.metrics.bootstrap import Reference, interval, resample_weights
from walkdiff.metrics.protocol import PROPORTION
from walkdiff.models.style_examples import MATCH_CLIPS, mixed_code
from walkdiff.models.style_statistics import StyleStatistics
from walkdiff.motion.footfix import fix_feet_features
from walkdiff.styled.generation import Sampling
from walkdiff.styled.pipeline import StyledGenerator

SAMPLE_METRICS = ("style_acc", "content_acc", "fmd", "kid", "skate_ratio")
STRENGTH = 0.6  # of the unseen-style transfers
EXAMPLES = "from example clips"
CODE_ALONE = "from example clips, code alone (--match-clips 0)"
LABEL = "by label"
CEILING = "label-only model, by label (ceiling)"
NEAREST = "baseline: nearest training style"
FLOOR = "real train (floor)"


@dataclass
class Example:
    """A real test clip as a style example: its name, style, code and pose statistics."""

    name: str
    style: str
    code: torch.Tensor
    statistics: StyleStatistics


@dataclass
class Run:
    """What every row of one benchmark shares."""

    scorer: ClipScorer
    per_example: int
    sampling: Sampling
    seed: int
    bootstrap: int
    batch_size: int
    match_clips: float

    def matched(self, examples: list[Example]) -> StyleStatistics:
        """Each example's statistics, once per window sampled from it, matched at `match_clips`."""
        each = [replace(e.statistics, strength=torch.tensor(self.match_clips)) for e in examples]
        return StyleStatistics.stack([s for s in each for _ in range(self.per_example)])


def bench_style(
    out: str | Path,
    ckpt: str | Path,
    evaluator: str | Path,
    unseen_ckpt: str | Path | None = None,
    labels_ckpt: str | Path | None = None,
    per_example: int = 8,
    sampler: str = "ddim",
    steps: int | None = None,
    seed: int = 0,
    bootstrap: int = 200,
    batch_size: int = 64,
    timeline_clips: int = 32,
    match_clips: float = MATCH_CLIPS,
) -> dict:
    from walkdiff.styled.generation import load_generator

    started = time.perf_counter()
    out = output_folder(out)
    run = Run(
        ClipScorer(evaluator), per_example, Sampling(sampler, steps), seed, bootstrap, batch_size, match_clips
    )
    labels = None if labels_ckpt is None else load_generator(labels_ckpt)
    print("seen styles from example clips", flush=True)
    generator = StyledGenerator.load(ckpt)
    seen, versus = _seen(run, generator, labels)
    print("style over time, encoding speed", flush=True)
    timeline = transitions(run.scorer, generator, seen["styles"], run.sampling, seed, timeline_clips)
    encoding = encoding_speed(run.scorer, generator)
    unseen = None
    if unseen_ckpt is not None:
        print("unseen styles", flush=True)
        unseen = _unseen(run, unseen_ckpt, labels)
    sections = {"seen": seen, "seen_vs_labels": versus, "unseen": unseen}
    sections |= {"transitions": timeline, "encoding": encoding}
    passed = {
        f"{section}/{name}": criterion["pass"]
        for section, found in sections.items()
        if found is not None
        for name, criterion in found["criteria"].items()
    }
    result = {
        "benchmark": "style",
        "ckpt": str(ckpt),
        "unseen_ckpt": None if unseen_ckpt is None else str(unseen_ckpt),
        "labels_ckpt": None if labels_ckpt is None else str(labels_ckpt),
        "evaluator": str(evaluator),
        "contents": list(run.scorer.data.selection.names),
        "per_example": per_example,
        "match_clips": match_clips,
        "sampler": sampler,
        "steps": None if sampler == "ddpm" else steps or DEFAULT_STEPS,
        "bootstrap": bootstrap,
        "seed": seed,
        **sections,
        "passed": passed,
        "all_passed": all(passed.values()),
        "elapsed_s": round(time.perf_counter() - started, 1),
    }
    write_json(out / "style.json", result)
    write_text(out / "style.md", format_style(result))
    return result


# ---------------------------------------------------------------- seen styles


def _seen(run: Run, generator: StyledGenerator, labels) -> tuple[dict, dict | None]:
    """Sections 1 and 2: the code model from example clips and by label; the label-only model by label."""
    model = generator.model
    styles = _coded_styles(model)
    examples = _examples(run, generator, styles)
    targets = [e.style for e in examples for _ in range(run.per_example)]
    codes = torch.stack([e.code for e in examples]).repeat_interleave(run.per_example, 0)
    rows, per_style = {}, {}
    settings = {
        EXAMPLES: (codes, run.matched(examples)),
        CODE_ALONE: (codes, None),
        LABEL: (_ids(model, targets, "--ckpt"), None),
    }
    for name, (inputs, match) in settings.items():
        rows[name], per_style[name] = _sample_row(run, model, inputs, targets, run.scorer, name, match)
    example, label = rows[EXAMPLES], rows[LABEL]
    seen = {
        "styles": styles,
        "example_clips": _names(examples),
        "windows": len(targets),
        "rows": rows,
        "per_style_acc": per_style,
        "criteria": {
            "accuracy": _criterion(
                "target-style accuracy from example clips >= 0.95 x by label",
                example["style_acc"]["value"],
                0.95 * label["style_acc"]["value"],
            ),
            "fmd": _criterion(
                "FMD from example clips <= 1.1 x by label",
                example["fmd"]["value"],
                1.1 * label["fmd"]["value"],
                at_most=True,
            ),
        },
    }
    if labels is None:
        return seen, None
    name = "label-only model, by label"
    ids = _ids(labels, targets, "--labels-ckpt")
    row, accuracy = _sample_row(run, labels, ids, targets, run.scorer, name)
    versus = {
        "rows": {"style-code model, by label": label, name: row},
        "per_style_acc": {"style-code model, by label": per_style[LABEL], name: accuracy},
        "criteria": {
            "accuracy": _criterion(
                "style-code model's accuracy by label >= 0.9 x the label-only model's",
                label["style_acc"]["value"],
                0.9 * row["style_acc"]["value"],
            ),
            "fmd": _criterion(
                "style-code model's FMD by label <= 1.1 x the label-only model's",
                label["fmd"]["value"],
                1.1 * row["fmd"]["value"],
                at_most=True,
            ),
        },
    }
    return seen, versus


# ---------------------------------------------------------------- unseen styles


def _unseen(run: Run, path: str | Path, labels) -> dict:
    """Section 3: the left-out styles of a model trained without them, sampled and transferred to."""
    generator = StyledGenerator.load(path)
    model = generator.model
    left = left_out_styles(path)
    training = [s for s in _coded_styles(model) if s not in left]
    examples = _examples(run, generator, left)
    against = restricted(run.scorer, left)
    styles = list(model.spec["styles"])
    stored = model.ema.module.style.codes.cpu()[[styles.index(s) for s in training]]

    def nearest(code: torch.Tensor) -> str:  # codes are unit vectors: the largest dot product
        return training[int((stored @ code).argmax())]

    sampling = _unseen_sampling(run, model, labels, examples, against, nearest)
    means = {s: mixed_code([(e.code, 1.0) for e in examples if e.style == s]) for s in left}
    matches = {
        s: StyleStatistics.mixed([(e.statistics, 1.0) for e in examples if e.style == s], run.match_clips)
        for s in left
    }
    transfer = _unseen_transfer(run, model, labels, means, matches, against, nearest, training)
    row = sampling["rows"][EXAMPLES]
    floor = sampling["rows"][FLOOR]["fmd"]["value"]
    return {
        "ckpt": str(path),
        "left_out_styles": left,
        "training_styles": training,
        "example_clips": _names(examples),
        "sampling": sampling,
        "transfer": transfer,
        "criteria": {
            "target_style": _criterion(
                "target-style accuracy from example clips >= 0.70", row["style_acc"]["value"], 0.70
            ),
            "content_kept": _criterion(
                "content kept from example clips >= 0.95", row["content_acc"]["value"], 0.95
            ),
            "fmd": _criterion(
                "FMD from example clips <= 2 x the real floor of those styles",
                row["fmd"]["value"],
                2 * floor,
                at_most=True,
            ),
        },
    }


def left_out_styles(path: str | Path) -> list[str]:
    """The styles a checkpoint's run left out of training (`data.leave_out_styles`)."""
    checkpoint = read_checkpoint(path, "generator", mmap=False)
    left = list(data_settings(checkpoint).get("leave_out_styles") or [])
    if not left:
        raise WalkdiffError(
            "--unseen-ckpt: this model was trained on every style (no data.leave_out_styles), so no style "
            "is unseen; train one with styles left out (conf/xia_style_codes_unseen.yaml)",
            path=path,
        )
    return left


def _unseen_sampling(run: Run, model, labels, examples: list[Example], against: ClipScorer, nearest) -> dict:
    """Windows from each example's code, the ceiling and the nearest training style; the real floor."""
    targets = [e.style for e in examples for _ in range(run.per_example)]
    near = [nearest(e.code) for e in examples]
    codes = torch.stack([e.code for e in examples]).repeat_interleave(run.per_example, 0)
    settings = {EXAMPLES: (model, codes, run.matched(examples)), CODE_ALONE: (model, codes, None)}
    if labels is not None:
        settings[CEILING] = (labels, _ids(labels, targets, "--labels-ckpt"), None)
    nearest_ids = _ids(model, [n for n in near for _ in range(run.per_example)], "--unseen-ckpt")
    settings[NEAREST] = (model, nearest_ids, None)
    rows, per_style = {}, {}
    for name, (maker, inputs, match) in settings.items():
        rows[name], per_style[name] = _sample_row(run, maker, inputs, targets, against, name, match)
    rows[FLOOR], per_style[FLOOR] = _floor(run, against, sorted(set(targets)))
    return {
        "windows": len(targets),
        "nearest_training_style": {e.name: n for e, n in zip(examples, near, strict=True)},
        "rows": rows,
        "per_style_acc": per_style,
    }


def _unseen_transfer(run: Run, model, labels, means: dict[str, torch.Tensor],
                     matches: dict[str, StyleStatistics], against: ClipScorer, nearest,
                     training: list[str]) -> dict:  # fmt: skip
    """The real test clips of the training styles restyled to each left-out style (the mean code and
    statistics of its examples), beside the code alone, the ceiling and the baselines."""
    scorer = run.scorer
    sources, raws = held_out_clips(scorer, training)
    if not sources:
        raise WalkdiffError(
            f"the evaluator's test split has no clip of the training styles ({', '.join(training)}) at least "
            f"{scorer.window} frames long to restyle"
        )
    near = {style: nearest(code) for style, code in means.items()}
    settings = {f"{EXAMPLES} (mean code)": (model, means, matches), CODE_ALONE: (model, means, None)}
    if labels is not None:
        ids = _ids(labels, list(means), "--labels-ckpt")
        settings[CEILING] = (labels, dict(zip(means, ids, strict=True)), None)
    ids = _ids(model, list(near.values()), "--unseen-ckpt")
    settings[NEAREST] = (model, dict(zip(means, ids, strict=True)), None)
    rows, paired, targets = {}, [], []
    for name, (maker, to, match) in settings.items():
        to = {style: value.to(maker.device) for style, value in to.items()}
        outputs, paired, targets = restyled_clips(
            against, maker, sources, raws, STRENGTH, False, run.seed, to, run.sampling, match
        )
        rows[name] = transfer_row(against, outputs, paired, run.bootstrap, run.seed)
    real = real_targets(against, targets, paired)
    rows |= transfer_baselines(against, paired, targets, real, run.bootstrap, run.seed)
    return {
        "strength": STRENGTH,
        "sources": len(sources),
        "pairs": len(targets),
        "nearest_training_style": near,
        "rows": {name: row.summary for name, row in rows.items()},
        "per_style_acc": {
            name: _per_style(run, row.windows, row.windows.style_logits.argmax(-1) == row.windows.style)
            for name, row in rows.items()
        },
    }


def _floor(run: Run, against: ClipScorer, styles: list[str]) -> tuple[dict, dict]:
    """The real training windows of `styles`, scored against their test windows."""
    train = run.scorer.real_windows("train")
    ids = torch.tensor([run.scorer.styles.index(s) for s in styles])
    mine = torch.isin(train.style, ids)
    if not mine.any():
        raise WalkdiffError(f"the evaluator's training split has no window of {', '.join(styles)}")
    windows = _subset(train, mine)
    correct = against.recognition(windows)
    summary = against.statistics(windows, correct).bootstrap(run.bootstrap, run.seed)
    return summary, _per_style(run, windows, correct["style_acc"])


# ---------------------------------------------------------------- rows


def _coded_styles(model) -> list[str]:
    """The styles a model holds a stored code for (those it was trained on); refused for a label model."""
    model.style_code(None)  # a model without a style encoder is refused, saying so
    codes = model.ema.module.style.codes
    return [s for s, code in zip(model.spec["styles"], codes, strict=True) if code.any()]


def _examples(run: Run, generator: StyledGenerator, styles: list[str]) -> list[Example]:
    """Every real test clip of `styles` with at least one window of the model, with its code."""
    scorer, model = run.scorer, generator.model
    seconds = model.spec["window"] / model.spec["fps"]
    chosen = [
        (info, name)
        for info, name, features in scorer.data.split_features("test")
        if scorer.styles[info.style] in styles and (features.shape[0] - 2) / scorer.fps >= seconds
    ]
    missing = [s for s in styles if s not in {scorer.styles[info.style] for info, _ in chosen}]
    if missing:
        raise WalkdiffError(
            f"the evaluator's test split ({', '.join(scorer.data.selection.names)}) has no clip of "
            f"{', '.join(missing)} at least one model window long ({seconds:.2f} s) to take the style from"
        )
    out = []
    for info, name in progress(chosen, desc="example codes", unit="clip"):
        ((code, _),), ((statistics, _),), _ = generator.examples([info.path])
        out.append(Example(name, scorer.styles[info.style], code.cpu(), statistics))
    return out


def _sample_row(run: Run, model, inputs: torch.Tensor, targets: list[str], scorer: ClipScorer, name: str,
                match: StyleStatistics | None = None):  # fmt: skip
    """(metrics, per-style accuracy) of one window per style input (ids or codes), labelled with
    `targets`, moved to `match`'s statistics (one row per window) if given; contents cycle over the
    protocol's."""
    contents = list(model.spec["contents"])
    ids = [contents.index(n) for n in run.scorer.data.selection.names]
    content = torch.tensor(ids)[torch.arange(len(targets)) % len(ids)]
    generator = torch.Generator(device=model.device).manual_seed(run.seed)
    size, raws = run.batch_size, []
    with progress(desc=f"sampling: {name}", unit="step") as bar:
        hook = step_hook(bar, math.ceil(len(targets) / size))
        for i in range(0, len(targets), size):
            x = model.generate(
                inputs[i : i + size].to(model.device), content[i : i + size].to(model.device),
                sampler=run.sampling.sampler, steps=run.sampling.steps, generator=generator, progress=hook,
                match=None if match is None else match.rows(i, i + size),
            )  # fmt: skip
            raws.append(torch.from_numpy(_made(model, x, match)))
    clips = clips_of_raw(scorer, torch.cat(raws), targets, None, "sample")
    for clip, c in zip(clips, content, strict=True):
        clip.content = contents[int(c)]
    scored = scorer.windows(clips)
    correct = scorer.recognition(scored)
    summary = scorer.statistics(scored, correct).bootstrap(run.bootstrap, run.seed)
    return summary, _per_style(run, scored, correct["style_acc"])


def _made(model, x: torch.Tensor, match: StyleStatistics | None) -> np.ndarray:
    """Sampled windows in data units as `sample` writes them: grounded, and with matched statistics
    their feet pinned (`Request.pins_feet`)."""
    raw = model.to_raw(x, True)
    return (
        raw
        if match is None
        else fix_feet_features(raw, model.profile, model.spec["fps"], model.floor_heights)
    )


def _per_style(run: Run, windows: WindowSet, hits: torch.Tensor) -> dict[str, dict]:
    """Per target style: the share of its windows recognised as it, bootstrapped over its clips."""
    out = {}
    for style in windows.style.unique().tolist():
        mine = windows.style == style
        _, clip = windows.clip[mine].unique(return_inverse=True)
        count = torch.bincount(clip).double()
        right = torch.bincount(clip, weights=hits[mine].double())
        value = float(right.sum() / count.sum())
        weights = resample_weights(len(count), run.bootstrap, run.seed)
        draws = np.array([float(w @ right / (w @ count)) for w in weights], dtype=np.float64)
        low, high = interval(draws, value, PROPORTION)
        out[run.scorer.styles[style]] = {"value": value, "low": low, "high": high, "n": len(count)}
    return out


def restricted(scorer: ClipScorer, styles: list[str]) -> ClipScorer:
    """The scorer with FMD and KID measured against the real test windows of `styles` only."""

    def embed() -> WindowSet:  # as ClipScorer embeds its reference: the same cache
        return scorer.scorer.embed(window_set(scorer.data.split_features("test"), scorer.window))

    test = scorer.cached("test", {"stride": 1}, embed)
    mine = torch.isin(test.style, torch.tensor([scorer.styles.index(s) for s in styles]))
    if int(mine.sum()) < 2:
        raise WalkdiffError(f"the evaluator's test split has too few windows of {', '.join(styles)} for FMD")
    out = copy.copy(scorer)
    out.reference = Reference.of(test.features[mine])
    return out


def _subset(windows: WindowSet, mine: torch.Tensor) -> WindowSet:
    """The windows where `mine`, their clips numbered again from 0."""
    taken = windows.take(mine)
    return replace(taken, clip=taken.clip.unique(return_inverse=True)[1])


def _ids(model, styles: list[str], option: str) -> torch.Tensor:
    known = list(model.spec["styles"])
    missing = sorted(set(styles) - set(known))
    if missing:
        raise WalkdiffError(f"{option}: the model has no style {', '.join(missing)} ({', '.join(known)})")
    return torch.tensor([known.index(s) for s in styles])


def _names(examples: list[Example]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for e in examples:
        out.setdefault(e.style, []).append(e.name)
    return out


def _criterion(rule: str, value: float, bar: float, at_most: bool = False) -> dict:
    passed = value <= bar if at_most else value >= bar  # False where either is NaN
    return {"rule": rule, "value": value, "bar": bar, "pass": bool(passed)}


# ---------------------------------------------------------------- the report


def _per_style_table(rows: dict[str, dict]) -> list[str]:
    styles = list(dict.fromkeys(s for row in rows.values() for s in row))
    lines = ["| target style accuracy | " + " | ".join(styles) + " |", "|---|" + "---:|" * len(styles)]
    for name, row in rows.items():
        cells = [format_summary(row[s], 3) if s in row else "" for s in styles]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def _criteria(criteria: dict) -> list[str]:
    return [
        f"- {c['rule']}: {c['value']:.3f} against {c['bar']:.3f}: **{'pass' if c['pass'] else 'fail'}**"
        for c in criteria.values()
    ] + [""]


def format_style(result: dict) -> str:
    steps = f" {result['steps']}" if result["steps"] else ""
    seen = result["seen"]
    lines = [
        "# Style from example clips",
        "",
        f"- style-code model `{result['ckpt']}`, evaluator `{result['evaluator']}`, "
        f"{result['sampler']}{steps}, contents {', '.join(result['contents'])}",
        f"- {result['per_example']} windows per example clip (each window a clip); every value on the whole "
        f"set [95% interval by bootstrap over clips, {result['bootstrap']} resamples]",
        "",
        "## Seen styles",
        "",
        f"{sum(map(len, seen['example_clips'].values()))} real test clips of {', '.join(seen['styles'])} as "
        f"examples; {seen['windows']} windows per row.",
        "",
        *metric_table(seen["rows"], SAMPLE_METRICS),
        "",
        *_per_style_table(seen["per_style_acc"]),
        "",
        *_criteria(seen["criteria"]),
    ]
    versus = result["seen_vs_labels"]
    if versus is not None:
        lines += ["## Seen styles against the label-only model", "", f"`{result['labels_ckpt']}`", ""]
        lines += [
            *metric_table(versus["rows"], SAMPLE_METRICS),
            "",
            *_per_style_table(versus["per_style_acc"]),
            "",
        ]
        lines += _criteria(versus["criteria"])
    timeline, encoding = result["transitions"], result["encoding"]
    lines += [
        "## Style over time",
        "",
        f"{timeline['clips']} clips of three {timeline['segment_s']:g} s segments of consecutive styles, "
        f"ramped over {timeline['transition_s']:g} s: {timeline['transitions']} transitions, "
        f"{timeline['inside_windows']} evaluator windows inside segments. Control (the same clips with one "
        f"style in all three segments): {timeline['control_seams_within_p95']:.3f} of its ramps within.",
        "",
        *_criteria(timeline["criteria"]),
        "## Encoding an example clip",
        "",
        f"`{encoding['clip']}` ({encoding['seconds_of_motion']:g} s of motion), median of 20 runs on "
        f"{encoding['threads']} threads: {encoding['median_ms']:g} ms.",
        "",
        *_criteria(encoding["criteria"]),
    ]
    unseen = result["unseen"]
    if unseen is not None:
        sampling, transfer = unseen["sampling"], unseen["transfer"]
        lines += [
            f"## Unseen styles: {', '.join(unseen['left_out_styles'])}",
            "",
            f"`{unseen['ckpt']}`, trained on {', '.join(unseen['training_styles'])}. FMD and KID against the "
            "real test windows of the unseen styles only.",
            "",
            f"### Sampling ({sampling['windows']} windows per row)",
            "",
            *metric_table(sampling["rows"], SAMPLE_METRICS),
            "",
            *_per_style_table(sampling["per_style_acc"]),
            "",
            f"### Transfer ({transfer['sources']} real test clips of the training styles, each to every "
            f"unseen style at strength {transfer['strength']:g}: {transfer['pairs']} outputs per row)",
            "",
            *metric_table(transfer["rows"], TRANSFER_METRICS),
            "",
            *_per_style_table(transfer["per_style_acc"]),
            "",
            *_criteria(unseen["criteria"]),
        ]
    return "\n".join(lines)
