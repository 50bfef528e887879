"""The evaluation protocol (Action2Motion / ACTOR / MDM, adapted to Xia) and `walkdiff evaluate`.

Every repeat draws `num` windows and scores them with a trained `MotionEvaluator`: FMD against the
features of the real reference split, style and content recognition accuracy, diversity, multimodality,
foot skating and jitter. Three rows are computed the same way, each as mean ± 1.96·σ/√repeats:

- generated: `num` clips from the generator, asked for the labels of `num` reference windows drawn at
  random with replacement;
- real <split>: `num` reference windows with those labels;
- real train vs <split>: `num` windows of the training split with those labels, the floor a generator
  can reach (each real window drawn among its split's windows of its style and content).

So every row holds each label as often as the reference split does.

FMD between two halves of the reference split (split by clip, balanced over styles) is reported too: with
Xia's few test clips it shows how much of an FMD value is estimation noise.

Real windows are cut at stride 1 by default: overlapping windows are correlated, but more of them give
better estimates of the feature mean and covariance than the training stride would.
"""

from __future__ import annotations

import logging
import math
import statistics
import time
from dataclasses import replace
from pathlib import Path

import torch

from walkdiff.common.checkpoints import read_checkpoint
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_json, write_text
from walkdiff.common.progress import progress, say
from walkdiff.data.datamodule import MotionDataModule, data_settings
from walkdiff.data.datasets import protocol_contents
from walkdiff.evaluation.plan import Plan, protocol
from walkdiff.evaluation.scorer import (
    MotionScorer,
    WindowSet,
    drawn_labels,
    generate_windows,
    halves_fmd,
    load_evaluator,
    matching_windows,
    window_set,
)
from walkdiff.metrics import format_summary, summarize, summarize_runs
from walkdiff.metrics.protocol import NON_NEGATIVE
from walkdiff.motion.footfix import fix_feet_features

log = logging.getLogger(__name__)

# name in the report -> (table header, decimals)
METRICS = {
    "fmd": ("FMD ↓", 3),
    "style_acc": ("Style acc. ↑", 3),
    "content_acc": ("Content acc. ↑", 3),
    "diversity": ("Diversity →", 3),
    "multimodality": ("Multimodality →", 3),
    "skate_ratio": ("Skate ratio ↓", 3),
    "slide_speed": ("Slide speed ↓", 3),
    "jitter": ("Jitter ↓", 1),
}


def evaluate(
    evaluator: str | Path,
    out: str | Path,
    ckpt: str | Path | None = None,
    num: int | None = None,
    repeats: int | None = None,
    seed: int = 0,
    real_only: bool = False,
    sampler: str | None = None,
    steps: int | None = None,
    guidance: float = 1.0,
    ground: bool = True,
    fix_feet: bool = False,
    split: str = "test",
    contents: str | None = None,
    root: str | None = None,
    cache_dir: str | None = None,
    stride: int = 1,
    batch_size: int = 500,
    device: str = "auto",
    mlflow_experiment: str | None = None,
    quick: bool = False,
) -> dict:
    """Runs the protocol (`quick`: the quick one; `num`, `repeats`, `sampler` and `steps` given replace
    its own) and writes `out/report.json` and `out/report.md`; returns the report. Its plan, and once the
    first batch is timed its cost, are said on stderr first."""
    started = time.perf_counter()
    run = protocol(quick, num, repeats, sampler, steps)
    num, repeats, sampler, steps = run.num, run.repeats, run.sampler, run.steps
    if num < 2 or repeats < 1 or stride < 1 or batch_size < 1:
        raise WalkdiffError(
            f"evaluate needs --num >= 2, --repeats >= 1, --stride >= 1 and --batch-size >= 1, "
            f"got {num}, {repeats}, {stride}, {batch_size}"
        )
    if split not in ("test", "val"):
        raise WalkdiffError(f"--split: expected test or val, got {split!r}")
    if not real_only and ckpt is None:
        raise WalkdiffError("--ckpt (the generator) is required unless --real-only is given")
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    torch.manual_seed(seed)

    scorer_model = load_evaluator(evaluator, device)
    model, settings = _generator_and_data(
        evaluator, None if real_only else ckpt, scorer_model, contents, device
    )
    settings |= {k: v for k, v in {"root": root, "cache_dir": cache_dir}.items() if v is not None}
    dm = MotionDataModule(**settings)
    spec = dm.spec
    if spec.feature_dim != scorer_model.spec["feature_dim"] or spec.fps != scorer_model.spec["fps"]:
        raise WalkdiffError(
            f"the evaluator was trained on {scorer_model.spec['feature_dim']} features at "
            f"{scorer_model.spec['fps']} fps, the data has {spec.feature_dim} at {spec.fps} fps",
            path=evaluator,
        )

    _check_num(num, scorer_model.spec, dm.selection.names)
    plan = None if model is None else Plan(run, quick, model.diffusion, batch_size)
    say(plan.describe() if plan else f"walkdiff: evaluate: real rows only: {repeats} repeats x {num} windows")

    scorer = MotionScorer(scorer_model, dm.skeleton, spec.fps, batch_size=batch_size)
    reference = scorer.embed(window_set(dm.split_features(split), spec.window, stride))
    train = scorer.embed(
        window_set(dm.split_features("train", mirrored=dm.hparams.mirror), spec.window, stride)
    )
    scorer.set_reference(reference)

    rows = _Rows(scorer, seed)
    # Every row holds the same labels each repeat: those of `num` reference windows drawn at random.
    draw = torch.Generator().manual_seed(seed)
    labels = [drawn_labels(reference, num, draw) for _ in range(repeats)]
    if model is not None:
        sampling = dict(sampler=sampler, steps=steps, guidance=guidance)
        finishes = _finishes(model, ground, fix_feet)
        _generated_rows(rows, model, labels, seed, batch_size, finishes, sampling, plan.timed)
    _real_rows(rows, {f"real {split}": reference, f"real train vs {split}": train}, labels, draw)
    halves = [
        halves_fmd(reference, draw) for _ in progress(range(repeats), desc=f"{split} halves", unit="repeat")
    ]

    report = {
        "settings": {
            "ckpt": None if ckpt is None else str(ckpt),
            "evaluator": str(evaluator),
            "protocol": "quick" if quick else "full",
            "num": num,
            "repeats": repeats,
            "seed": seed,
            "real_only": real_only,
            "sampler": None if real_only else sampler,
            "steps": None if real_only else steps,
            "guidance": None if real_only else guidance,
            "grounded": None if real_only else ground,
            "fix_feet": None if real_only else fix_feet,
            "split": split,
            "stride": stride,
            "device": str(device),
        },
        "data": {
            "dataset": spec.dataset,
            "contents": list(dm.selection.names),
            "window": spec.window,
            "fps": spec.fps,
            "windows": {split: len(reference), "train": len(train)},
            "clips": {split: len(reference.clip.unique()), "train": len(train.clip.unique())},
        },
        "rows": {name: summarize_runs(runs) for name, runs in rows.pooled.items()},
        "per_content": rows.per_content_summary(spec.contents),
        f"fmd_{split}_halves": summarize(halves, NON_NEGATIVE),
        "elapsed_s": round(time.perf_counter() - started, 1),
        "estimated_generation_s": None if plan is None else round(plan.estimate_s, 3),
    }
    write_reports(report, Path(out))
    if mlflow_experiment:
        log_to_mlflow(report, Path(out), mlflow_experiment)
    return report


def _check_num(num: int, spec: dict, contents: list[str]) -> None:
    """Before anything is generated: multimodality pairs windows of one style (of one content without
    styles), so --num must be able to give every one of them 2 windows (a label rarer than that in the
    reference split may still have fewer, and is then left out of the mean, in every row alike)."""
    styled = len(spec["styles"]) > 1
    kind, classes = ("style", len(spec["styles"])) if styled else ("content group", len(contents))
    if num < 2 * classes:
        raise WalkdiffError(
            f"--num {num} is too small: multimodality pairs windows of one {kind}, and {num} windows give "
            f"some of the {classes} {kind}s fewer than 2; the smallest --num that works is {2 * classes}"
        )


def _generator_and_data(evaluator, ckpt, scorer_model, contents: str | None, device):
    """The generator of `ckpt` and the data settings it was trained on; without `ckpt` (real rows only),
    None and the evaluator's data settings, restricted to the dataset's protocol contents."""
    if ckpt is None:
        # The evaluator's data holds every content; a dataset's protocol may score only some (Xia's:
        # walking), any other every content.
        default_contents = protocol_contents(scorer_model.spec["dataset"])
        settings = data_settings(
            read_checkpoint(evaluator, "evaluator", mmap=False), contents=contents or default_contents
        )
        return None, settings
    from walkdiff.models.styled_ddpm import StyledMotionDiffusion

    settings = data_settings(read_checkpoint(ckpt, "generator", mmap=False), contents=contents)
    model = StyledMotionDiffusion.from_trained(ckpt, "generator", device)
    for labels in ("styles", "contents"):
        if list(model.spec[labels]) != list(scorer_model.spec[labels]):
            raise WalkdiffError(
                f"the generator's {labels} ({', '.join(model.spec[labels])}) differ from the "
                f"evaluator's ({', '.join(scorer_model.spec[labels])})",
                path=ckpt,
            )
    return model, settings


class _Rows:
    """Each row's scores per repeat: pooled (`MotionScorer.score`) and per content label
    (`MotionScorer.per_content`, on the same windows)."""

    def __init__(self, scorer: MotionScorer, seed: int):
        self.scorer, self.seed = scorer, seed
        self.pooled: dict[str, list[dict[str, float]]] = {}
        self.labels: dict[str, list[dict[int, dict[str, float]]]] = {}

    def add(self, row: str, windows, repeat: int, labels: bool = True) -> None:
        """Scores one repeat's windows (embedded here when they are not yet)."""
        if windows.features is None:
            windows = self.scorer.embed(windows)
        self.pooled.setdefault(row, []).append(self.scorer.score(windows, seed=self.seed + repeat))
        if labels:
            self.labels.setdefault(row, []).append(self.scorer.per_content(windows, seed=self.seed + repeat))

    def per_content_summary(self, names: list[str]) -> dict[str, dict[str, dict]]:
        """{content label: {row: {figure: summary over repeats}}}; a figure that is NaN in some repeat
        (no foot contact seen) is summarised over the repeats that have it."""
        summary: dict[str, dict[str, dict]] = {}
        for row, repeats in self.labels.items():
            # A rare label may be missing from some repeats' draws of real windows.
            for content in sorted({c for r in repeats for c in r}):
                figures = {}
                for figure in ("turn_deg_s", "multimodality", "skate_ratio"):
                    values = [r[content][figure] for r in repeats if content in r]
                    values = [v for v in values if math.isfinite(v)]
                    if values:
                        figures[figure] = summarize(values)
                figures["windows"] = round(
                    statistics.fmean(r[content]["windows"] for r in repeats if content in r)
                )
                summary.setdefault(names[content], {})[row] = figures
        return summary


def _generated_rows(
    rows: _Rows, model, labels: list[tuple], seed: int, batch_size: int, finishes: dict[str, tuple],
    sampling: dict, timed=None,
) -> None:  # fmt: skip
    """Scores of one set of generated windows per repeat, asked for that repeat's `labels`, once per row
    of `finishes` (row name -> (what is done to the sampled raw windows, whether the row gets per-label
    figures)): the same windows in every row, so that rows differ by what their finish changes and only
    that. `timed`: told the seconds of each batch of the first repeat."""
    generator = torch.Generator(device=model.device).manual_seed(seed)
    for repeat, asked in enumerate(labels):
        windows = generate_windows(
            model, asked, generator, batch_size, grounded=False,
            desc=f"generating, repeat {repeat + 1} of {len(labels)}", timed=timed if repeat == 0 else None,
            **sampling,
        )  # fmt: skip
        for row, (finish, per_label) in finishes.items():
            windows_finished = replace(windows, raw=torch.from_numpy(finish(windows.raw.numpy())))
            rows.add(row, windows_finished, repeat, per_label)


def _real_rows(rows: _Rows, pools: dict[str, WindowSet], labels: list[tuple], draw: torch.Generator) -> None:
    """Per repeat, each pool's windows with that repeat's labels, each drawn among the pool's windows of
    its style and content; a pair a pool lacks is said."""
    unmatched = 0
    for name, pool in pools.items():
        for repeat in progress(range(len(labels)), desc=name, unit="repeat"):
            windows, missing = matching_windows(pool, labels[repeat], draw)
            rows.add(name, windows, repeat)
            unmatched += missing
    if unmatched:
        say(
            f"walkdiff: evaluate: {unmatched} real windows have a style and content pair their split "
            f"lacks: drawn among its windows of that content instead"
        )


def _finishes(model, ground: bool, fix_feet: bool) -> dict[str, tuple]:
    """The generated rows: grounded (as `generate` gives them; with `ground`) and as sampled beside,
    and with `fix_feet` the grounded windows with their feet pinned too (as `generate --fix-feet`)."""

    def as_sampled(raw):
        return raw

    finished = model.ground if ground else as_sampled
    out = {"generated": (finished, True)}
    if ground:
        out["generated, not grounded"] = (as_sampled, False)
    if fix_feet:
        fps = model.spec["fps"]
        out["generated, feet fixed"] = (
            lambda raw: fix_feet_features(finished(raw), model.profile, fps, model.floor_heights),
            True,
        )
    return out


def format_report(report: dict) -> str:
    s, d = report["settings"], report["data"]
    split = s["split"]
    shown = [m for m in METRICS if m in next(iter(report["rows"].values()))]  # no style acc. without styles
    lines = ["# walkdiff evaluation", ""]
    if s["ckpt"]:
        sampling = f"sampler {s['sampler']}, steps {s['steps'] or 'all'}, guidance {s['guidance']}"
        lines.append(f"- generator: `{s['ckpt']}` ({sampling})")
    lines += [
        f"- evaluator: `{s['evaluator']}`",
        f"- data: {d['dataset']}, contents {', '.join(d['contents'])}, {d['window']}-frame windows at "
        f"{d['fps']:g} fps; {split}: {d['windows'][split]} windows from {d['clips'][split]} clips, "
        f"train: {d['windows']['train']} windows from {d['clips']['train']} clips (stride {s['stride']})",
        f"- {s['protocol']} protocol: {s['num']} windows per repeat, {s['repeats']} repeats, "
        f"seed {s['seed']}; "
        f"every value is mean ± 1.96·σ/√{s['repeats']}, or mean [low, high] where that interval is cut "
        "to the metric's range (an accuracy stays in [0, 1])",
        "",
        "| | " + " | ".join(METRICS[m][0] for m in shown) + " |",
        "|---|" + "---:|" * len(shown),
    ]
    for name, summary in report["rows"].items():
        cells = [format_summary(summary[m], METRICS[m][1]) for m in shown]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", *format_per_content(report["per_content"])]
    halves = report[f"fmd_{split}_halves"]
    lines += [
        "",
        f"FMD({split} half A, {split} half B), halves split by clip: {format_summary(halves, 3)}",
        "",
        f"FMD is measured against the features of the whole real {split} split. → : closer to the real "
        "rows is better. Skating: over the steps where a foot joint is within the contact height of the "
        "real floor, the share sliding faster than the contact speed threshold, and the mean slide speed "
        "(units/s); jitter: mean jerk (units/s³).",
        "",
    ]
    return "\n".join(lines)


PER_CONTENT = {
    "turn_deg_s": ("Turn °/s (+ left)", 1),
    "multimodality": ("Multimodality →", 3),
    "skate_ratio": ("Skate ratio ↓", 3),
}


def format_per_content(per_content: dict) -> list[str]:
    """Per content label, each row beside the others: the figures pooled rows average away."""
    lines = [
        "Per content label (multimodality: pairs of one style inside the label):",
        "",
        "| label | row | windows | " + " | ".join(h for h, _ in PER_CONTENT.values()) + " |",
        "|---|---|---:|" + "---:|" * len(PER_CONTENT),
    ]
    for label, rows in per_content.items():
        for row, figures in rows.items():
            cells = [
                format_summary(figures[f], d) if f in figures else "–" for f, (_, d) in PER_CONTENT.items()
            ]
            lines.append(f"| {label} | {row} | {figures['windows']} | " + " | ".join(cells) + " |")
    return lines


def write_reports(report: dict, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "report.json", report)
    write_text(out / "report.md", format_report(report))


def log_to_mlflow(report: dict, out: Path, experiment: str) -> None:
    """Metrics (means and CI half-widths), settings and both report files into a new MLflow run."""
    import mlflow
    from mlflow.entities import Metric, Param

    from walkdiff.common.tracking import DEFAULT_ARTIFACT_ROOT, check_tracking_uri, tracking_uri

    uri = tracking_uri()
    check_tracking_uri(uri)
    client = mlflow.MlflowClient(tracking_uri=uri)
    found = client.get_experiment_by_name(experiment)
    if found is None:
        artifacts = Path(DEFAULT_ARTIFACT_ROOT).resolve()
        experiment_id = client.create_experiment(experiment, artifact_location=artifacts.as_uri())
    else:
        experiment_id = found.experiment_id
    run_id = client.create_run(experiment_id, run_name="evaluate").info.run_id
    split = report["settings"]["split"]
    summaries = {
        f"{row.replace(' ', '_')}/{m}": s for row, ms in report["rows"].items() for m, s in ms.items()
    }
    summaries[f"fmd_{split}_halves"] = report[f"fmd_{split}_halves"]
    now = int(time.time() * 1000)
    metrics = [
        Metric(key + suffix, summary[field], now, 0)
        for key, summary in summaries.items()
        for suffix, field in (("", "mean"), ("_ci95", "ci95"))
        if math.isfinite(summary[field])  # NaN: no contact step was seen
    ]
    params = [Param(key, str(value)) for key, value in report["settings"].items()]
    client.log_batch(run_id, metrics=metrics, params=params)
    for name in ("report.json", "report.md"):
        client.log_artifact(run_id, str(out / name), "evaluation")
    client.set_terminated(run_id)
    log.info(f"evaluation logged to MLflow run {run_id} of experiment {experiment!r} at {uri}")
