"""The evaluation protocol (Action2Motion / ACTOR / MDM, adapted to Xia) and `walkdiff evaluate`.

Every repeat draws `num` windows and scores them with a trained `MotionEvaluator`: FMD against the
features of the real reference split, style and content recognition accuracy, diversity, multimodality,
foot skating and jitter. Three rows are computed the same way, each as mean ± 1.96·σ/√repeats:

- generated: `num` clips from the generator, balanced over styles (and over its content selection);
- real <split>: `num` windows drawn with replacement from the reference split itself;
- real train vs <split>: `num` windows drawn from the training split, the floor a generator can reach.

FMD between two halves of the reference split (split by clip, balanced over styles) is reported too: with
Xia's few test clips it shows how much of an FMD value is estimation noise.

Real windows are cut at stride 1 by default: overlapping windows are correlated, but more of them give
better estimates of the feature mean and covariance than the training stride would.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torchmetrics.classification import MulticlassAccuracy

from walkdiff.common.checkpoints import expect_class, read_checkpoint
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_json, write_text
from walkdiff.common.progress import progress, step_hook
from walkdiff.data.datamodule import MotionDataModule, data_settings
from walkdiff.data.datasets import protocol_contents
from walkdiff.metrics import (
    Diversity,
    FootSkating,
    FrechetMotionDistance,
    Jitter,
    Multimodality,
    format_summary,
    summarize,
    summarize_runs,
)
from walkdiff.motion.representation import features_to_positions
from walkdiff.motion.skeleton import Skeleton

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


@dataclass
class WindowSet:
    """Motion windows with labels and, once embedded, their joint positions and the evaluator's outputs.

    A generator's windows come as raw features (`raw`), turned into positions by `MotionScorer.embed`;
    windows read from files (`walkdiff score`) come as positions directly.
    """

    raw: torch.Tensor | None  # (N, W, D) features in data units, or None
    style: torch.Tensor  # (N,) style ids (true or requested)
    content: torch.Tensor  # (N,) content group ids
    clip: torch.Tensor  # (N,) index of the source clip; -1 for generated windows
    positions: torch.Tensor | None = None  # (N, W, J, 3) world joint positions, canonical axes
    features: torch.Tensor | None = None  # (N, E) evaluator features
    style_logits: torch.Tensor | None = None
    content_logits: torch.Tensor | None = None

    def __len__(self) -> int:
        return self.style.shape[0]

    def take(self, index: torch.Tensor) -> WindowSet:
        def pick(x):
            return None if x is None else x[index]

        return WindowSet(*(pick(getattr(self, name)) for name in self.__dataclass_fields__))


def window_set(clips: list, window: int, stride: int = 1) -> WindowSet:
    """Every `window`-frame window of `(clip, name, features)` triples, as from `split_features`."""
    raws, styles, contents, sources = [], [], [], []
    for i, (info, _, features) in enumerate(clips):
        starts = range(0, features.shape[0] - window + 1, stride)
        raws += [features[s : s + window] for s in starts]
        styles += [info.style] * len(starts)
        contents += [info.content] * len(starts)
        sources += [i] * len(starts)
    if not raws:
        raise WalkdiffError(f"no clip of this split is at least {window} frames long; no window to evaluate")
    return WindowSet(
        torch.from_numpy(np.stack(raws)),
        torch.tensor(styles),
        torch.tensor(contents),
        torch.tensor(sources),
    )


class MotionScorer:
    """Scores sets of windows with an evaluator, against a fixed real reference set.

    `skeleton` is the skeleton of the raw feature windows it is given (a generator's); it must have the
    evaluator's joints.
    """

    def __init__(self, evaluator, skeleton: Skeleton, fps: float, batch_size: int = 512):
        self.evaluator = evaluator.eval()
        self.spec = evaluator.spec
        self.fps = fps
        self.batch_size = batch_size
        names = list(evaluator.body.names)
        if list(skeleton.names) != names:
            differ = sorted(set(skeleton.names) ^ set(names)) or ["the same joints in another order"]
            raise WalkdiffError(f"the motion's skeleton is not the evaluator's ({', '.join(differ[:8])})")
        contacts = evaluator.profile.contacts
        self.foot_joints = [names.index(name) for name in contacts.joints]
        self.speed_threshold = contacts.speed_threshold
        self.height_threshold = contacts.height_threshold
        self.floor: torch.Tensor | None = None  # per foot joint, from the real reference set
        self.offsets = torch.from_numpy(skeleton.offsets)
        self.parents = skeleton.parents
        self.fmd_real: FrechetMotionDistance | None = None

    def embed(self, windows: WindowSet) -> WindowSet:
        """The windows with positions (from `raw` when given) and the evaluator's outputs."""
        positions = windows.positions if windows.raw is None else self.positions(windows.raw)
        outputs = [
            self.evaluator.embed_and_classify(positions[i : i + self.batch_size])
            for i in range(0, len(windows), self.batch_size)
        ]
        features, style, content = (torch.cat([o[k] for o in outputs]).float().cpu() for k in range(3))
        return replace(
            windows, positions=positions, features=features, style_logits=style, content_logits=content
        )

    def set_reference(self, reference: WindowSet) -> None:
        """The real statistics every FMD of `score` is measured against, and the real floor height."""
        self.fmd_real = fmd_metric(reference.features)
        feet = reference.positions[..., self.foot_joints, 1]
        self.floor = torch.quantile(feet.flatten(0, 1).double(), 0.05, dim=0)

    def positions(self, raw: torch.Tensor) -> torch.Tensor:
        """(N, W, J, 3) float32 positions of raw windows, each starting at the origin (float64 FK in
        chunks: jitter multiplies position errors by fps^3)."""
        chunks = [
            features_to_positions(raw[i : i + self.batch_size].double(), self.offsets, self.parents).float()
            for i in range(0, raw.shape[0], self.batch_size)
        ]
        return torch.cat(chunks) if chunks else torch.zeros(0, raw.shape[1], len(self.parents), 3)

    def ground_contacts(self, positions: torch.Tensor) -> torch.Tensor:
        """A foot joint touches the ground when it is within the contact height of the real floor.

        Decided from the geometry, not from the predicted contact labels, so real and generated motion
        are judged alike (with labels, real data would have no skating by construction).
        """
        height = positions[..., self.foot_joints, 1].double() - self.floor
        return height < self.height_threshold

    def score(self, windows: WindowSet, seed: int = 0) -> dict[str, float]:
        """Every metric of one set of embedded windows (one repeat of the protocol)."""
        if self.fmd_real is None:
            raise RuntimeError("MotionScorer.set_reference must be called before score")
        self.fmd_real.reset()  # keeps the real statistics (reset_real_features=False)
        self.fmd_real.update(windows.features, real=False)
        values = {"fmd": self.fmd_real.compute()}

        for kind, labels, logits in (
            ("style", windows.style, windows.style_logits),
            ("content", windows.content, windows.content_logits),
        ):
            if len(self.spec[f"{kind}s"]) > 1:  # HumanAct12 has one style: nothing to recognise
                accuracy = MulticlassAccuracy(len(self.spec[f"{kind}s"]), average="micro")
                values[f"{kind}_acc"] = accuracy(logits, labels)

        diversity = Diversity(num_pairs=200, seed=seed)
        diversity.update(windows.features)
        values["diversity"] = diversity.compute()
        multimodality = Multimodality(num_pairs=20, seed=seed)
        # Per style; per action (content) for a dataset without styles, as in Action2Motion / ACTOR.
        styled = len(self.spec["styles"]) > 1
        multimodality.update(windows.features, windows.style if styled else windows.content)
        values["multimodality"] = multimodality.compute()

        positions = windows.positions.double()
        skating = FootSkating(self.foot_joints, self.fps, self.speed_threshold)
        skating.update(positions, self.ground_contacts(positions))
        values |= skating.compute()
        jitter = Jitter(self.fps)
        jitter.update(positions)
        values["jitter"] = jitter.compute()
        return {name: float(value) for name, value in values.items()}


def fmd_metric(real_features: torch.Tensor) -> FrechetMotionDistance:
    metric = FrechetMotionDistance(real_features.shape[1], reset_real_features=False)
    metric.update(real_features, real=True)
    return metric


def balanced_labels(num: int, styles: int, content_ids: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Style ids cycling over all styles, content ids cycling over `content_ids` per round of styles."""
    i = torch.arange(num)
    return i % styles, torch.tensor(content_ids)[(i // styles) % len(content_ids)]


def generate_windows(
    model,
    num: int,
    content_ids: list[int],
    generator: torch.Generator,
    batch_size: int,
    grounded: bool = True,
    desc: str = "generating windows",
    **sampling,
) -> WindowSet:
    """`num` raw windows from a generator (`generate`, `to_raw`), grounded unless told otherwise, with a
    progress bar `desc` over batches x denoising steps."""
    style, content = balanced_labels(num, len(model.spec["styles"]), content_ids)
    raws = []
    with progress(desc=desc, unit="step") as bar:
        hook = step_hook(bar, math.ceil(num / batch_size))
        for i in range(0, num, batch_size):
            x = model.generate(
                style[i : i + batch_size].to(model.device),
                content[i : i + batch_size].to(model.device),
                generator=generator,
                progress=hook,
                **sampling,
            )
            raws.append(torch.from_numpy(model.to_raw(x, grounded)))
    return WindowSet(torch.cat(raws), style, content, torch.full((num,), -1))


def halves_fmd(reference: WindowSet, generator: torch.Generator) -> float:
    """FMD between two halves of a real set, split by clip and balanced over styles."""
    first = []
    for style in reference.style.unique():
        clips = reference.clip[reference.style == style].unique()
        clips = clips[torch.randperm(len(clips), generator=generator)]
        first.append(clips[: len(clips) // 2])
    in_first = torch.isin(reference.clip, torch.cat(first))
    if in_first.sum() < 2 or (~in_first).sum() < 2:
        raise WalkdiffError("the reference split has too few clips to split into halves")
    metric = fmd_metric(reference.features[in_first])
    metric.update(reference.features[~in_first], real=False)
    return float(metric.compute())


# ---------------------------------------------------------------- checkpoints and data


EVALUATORS = ("walkdiff.models.evaluator.MotionEvaluator", "walkdiff.models.action_evaluator.ActionEvaluator")


def load_evaluator(path: str | Path, device: str | torch.device = "cpu"):
    import importlib

    # MotionEvaluator, or the HumanAct12 ActionEvaluator.
    class_path = expect_class(path, EVALUATORS, "--evaluator")
    module, name = class_path.rsplit(".", 1)
    evaluator_class = getattr(importlib.import_module(module), name)
    return evaluator_class.from_trained(path, "evaluator", device)


# ---------------------------------------------------------------- the command


def evaluate(
    evaluator: str | Path,
    out: str | Path,
    ckpt: str | Path | None = None,
    num: int = 1000,
    repeats: int = 20,
    seed: int = 0,
    real_only: bool = False,
    sampler: str = "ddpm",
    steps: int | None = None,
    guidance: float = 1.0,
    ground: bool = True,
    split: str = "test",
    contents: str | None = None,
    root: str | None = None,
    cache_dir: str | None = None,
    stride: int = 1,
    batch_size: int = 500,
    device: str = "auto",
    mlflow_experiment: str | None = None,
) -> dict:
    """Runs the protocol and writes `out/report.json` and `out/report.md`; returns the report."""
    started = time.perf_counter()
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
    model = None
    if real_only:
        # The evaluator's data holds every content; a dataset's protocol may score only some (Xia's:
        # walking), any other every content.
        default_contents = protocol_contents(scorer_model.spec["dataset"])
        settings = data_settings(
            read_checkpoint(evaluator, "evaluator", mmap=False), contents=contents or default_contents
        )
    else:
        from walkdiff.models.styled_ddpm import StyledMotionDiffusion

        settings = data_settings(read_checkpoint(ckpt, "generator", mmap=False), contents=contents)
        model = StyledMotionDiffusion.load_from_checkpoint(ckpt, map_location="cpu", weights_only=False)
        model = model.to(device).eval()
        for labels in ("styles", "contents"):
            if list(model.spec[labels]) != list(scorer_model.spec[labels]):
                raise WalkdiffError(
                    f"the generator's {labels} ({', '.join(model.spec[labels])}) differ from the "
                    f"evaluator's ({', '.join(scorer_model.spec[labels])})",
                    path=ckpt,
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

    scorer = MotionScorer(scorer_model, dm.skeleton, spec.fps, batch_size=batch_size)
    reference = scorer.embed(window_set(dm.split_features(split), spec.window, stride))
    train = scorer.embed(
        window_set(dm.split_features("train", mirrored=dm.hparams.mirror), spec.window, stride)
    )
    scorer.set_reference(reference)

    rows: dict[str, list[dict[str, float]]] = {}
    if model is not None:
        content_ids = [list(model.spec["contents"]).index(name) for name in dm.selection.names]
        generator = torch.Generator(device=model.device).manual_seed(seed)
        rows["generated"] = []
        for repeat in range(repeats):
            sampling = dict(sampler=sampler, steps=steps, guidance=guidance)
            windows = generate_windows(
                model, num, content_ids, generator, batch_size, grounded=False,
                desc=f"generating, repeat {repeat + 1} of {repeats}", **sampling,
            )  # fmt: skip
            if ground:
                # The same windows scored both ways: what grounding changes, and only that.
                rows.setdefault("generated, not grounded", []).append(
                    scorer.score(scorer.embed(windows), seed=seed + repeat)
                )
                windows = replace(windows, raw=torch.from_numpy(model.ground(windows.raw.numpy())))
            rows["generated"].append(scorer.score(scorer.embed(windows), seed=seed + repeat))

    draw = torch.Generator().manual_seed(seed)
    for name, pool in ((f"real {split}", reference), (f"real train vs {split}", train)):
        rows[name] = [
            scorer.score(pool.take(torch.randint(len(pool), (num,), generator=draw)), seed=seed + repeat)
            for repeat in progress(range(repeats), desc=name, unit="repeat")
        ]
    halves = [
        halves_fmd(reference, draw) for _ in progress(range(repeats), desc=f"{split} halves", unit="repeat")
    ]

    report = {
        "settings": {
            "ckpt": None if ckpt is None else str(ckpt),
            "evaluator": str(evaluator),
            "num": num,
            "repeats": repeats,
            "seed": seed,
            "real_only": real_only,
            "sampler": None if real_only else sampler,
            "steps": None if real_only else steps,
            "guidance": None if real_only else guidance,
            "grounded": None if real_only else ground,
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
        "rows": {name: summarize_runs(runs) for name, runs in rows.items()},
        f"fmd_{split}_halves": summarize(halves),
        "elapsed_s": round(time.perf_counter() - started, 1),
    }
    write_reports(report, Path(out))
    if mlflow_experiment:
        log_to_mlflow(report, Path(out), mlflow_experiment)
    return report


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
        f"- {s['num']} windows per repeat, {s['repeats']} repeats, seed {s['seed']}; "
        f"every value is mean ± 1.96·σ/√{s['repeats']}",
        "",
        "| | " + " | ".join(METRICS[m][0] for m in shown) + " |",
        "|---|" + "---:|" * len(shown),
    ]
    for name, summary in report["rows"].items():
        cells = [format_summary(summary[m], METRICS[m][1]) for m in shown]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
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
