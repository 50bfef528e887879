"""`walkdiff data scan DIR`: what a folder of BVH files holds, and training configs that fit it.

Reads every clip (`walkdiff.data.folder.FolderSource`), checks that all share one skeleton, finds the
skeleton profile from the first clip and reports the labels, lengths, frame rates and splits. From the
lengths it suggests the training frame rate, window and stride; with `out` it writes two configs that
`walkdiff fit --config` runs as they are: the evaluator of the metrics, then the generator.
"""

from __future__ import annotations

import json
import math
import re
import textwrap
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_text
from walkdiff.common.progress import progress
from walkdiff.data import laterality
from walkdiff.data.budget import (
    BATCH_SIZE,
    DISCRIMINATOR_WINDOWS,
    EVALUATOR_STEPS,
    GENERATOR_BATCH_SIZE,
    Budget,
    generator_budget,
    root_travel,
)
from walkdiff.data.clips import ContentSelection
from walkdiff.data.folder import NO_CONTENT, NO_STYLE, SPLITS, FolderSource
from walkdiff.motion.profile import SkeletonProfile

TRAINING_FPS = 30  # the suggested rate for data at 30 fps or more
WINDOW_SECONDS = 0.8  # the suggested window, at most the 10th percentile clip length
MIN_WINDOW = 8
STRIDES_PER_WINDOW = 6
# Validations in batches (the budgets themselves: walkdiff/data/budget.py). Windows beyond MAX_WINDOWS
# would be seen less than about 4 times in a budget: the stride grows instead (up to half a window).
GENERATOR_VALIDATE, EVALUATOR_VALIDATE = 225, 200
MAX_WINDOWS = 30_000
VAL_BATCHES = 32  # validation batches at most: a larger folder validates no longer
PERCENTILES = (5, 25, 50, 75, 95)
PROGRESS_ABOVE = 20  # files: a progress bar on stderr beyond this
_TABLE_LIMIT = 24  # rows / columns of the style x content table
_PLAIN = re.compile(r"[A-Za-z_/][A-Za-z0-9_./-]*")  # strings written without quotes
_YAML_WORDS = {"true", "false", "yes", "no", "on", "off", "y", "n", "null"}


def scan(
    folder: str | Path,
    labels: str | None = None,
    pattern: str | None = None,
    default_style: str | None = None,
    default_content: str | None = None,
    out: str | Path | None = None,
    fps: float | None = None,
    name: str | None = None,
    overwrite: bool = False,
    profile: dict | None = None,
    val_fraction: float | None = None,
    test_fraction: float | None = None,
    mirror_labels: dict | None = None,
) -> str:
    """The report on `folder` (text to print); with `out`, also writes the two training configs.

    `labels`, `pattern`, `default_style`, `default_content`, `profile`, `val_fraction` and
    `test_fraction` are the folder dataset's options (`walkdiff.data.folder`), `mirror_labels` the data
    module's ({label: partner}, `walkdiff.data.laterality`); `fps` replaces the suggested training frame
    rate; `name` (default: the folder's name) names the configs, checkpoints and experiments; existing
    configs are kept unless `overwrite`. A folder without val clips gets configs that do not validate.
    """
    folder = Path(folder).expanduser().resolve()
    if not folder.is_dir():
        raise WalkdiffError("folder of BVH files not found", path=folder)
    options = {
        "labels": labels, "pattern": pattern, "default_style": default_style,
        "default_content": default_content, "val_fraction": val_fraction, "test_fraction": test_fraction,
    }  # fmt: skip
    options = {k: v for k, v in options.items() if v is not None}
    source = FolderSource(folder, profile=dict(profile or {}), **options)
    clips = source.list_clips()
    splits = source.split_clips(clips, ContentSelection(tuple(source.groups)))
    name = config_name(name if name is not None else folder.name)
    paths = () if out is None else config_paths(folder, out, name)
    existing = [p for p in paths if p.exists()]
    if existing and not overwrite:
        raise WalkdiffError("config exists: pass overwrite (--overwrite) to replace it", path=existing[0])
    if fps is not None and not (isinstance(fps, int | float) and math.isfinite(fps) and fps > 0):
        raise WalkdiffError(f"fps: expected a positive frame rate, got {fps!r}")

    found = _read_clips(source, clips)
    suggested = _suggest(found, fps)
    mirrors = bool(found.profile.mirror_pairs)  # mirror true is written: the labels of mirrored copies
    swaps = laterality.mirror_labels(source.styles, source.groups, mirror_labels) if mirrors else None
    budget = generator_budget(source.groups, [c.content for c in clips], found.travel)
    lines = _report(folder, source, clips, splits, found, suggested, swaps, budget)
    if out is None:
        lines.append("To write the two training configs, scan again with an output folder (--out DIR).")
        return "\n".join(lines)

    data = {
        "dataset": "folder",
        "root": str(folder),
        **{k: options[k] for k in ("labels", "pattern", "default_style", "default_content") if k in options},
        **{k: options[k] for k in ("val_fraction", "test_fraction") if k in options},
        **({"profile": dict(source.profile)} if source.profile else {}),
        "contents": "all",
        "fps": suggested.fps,
        "window": suggested.window,
        "stride": suggested.stride,
        "mirror": bool(found.profile.mirror_pairs),
        **({"mirror_labels": dict(mirror_labels)} if mirror_labels and found.profile.mirror_pairs else {}),
        "batch_size": BATCH_SIZE,
        "num_workers": 0,
    }
    summary = (
        f"# {len(clips)} clips, {found.durations.sum() / 60:.1f} min, {len(source.styles)} style(s), "
        f"{len(source.groups)} content group(s); root {found.profile.root}."
    )
    validate = bool(splits["val"])
    texts = (
        _evaluator_config(name, folder, summary, data, validate),
        _generator_config(name, folder, summary, data | _balance(source), source.groups[0], budget, validate),
    )
    for path, text in zip(paths, texts):
        write_text(path, text)
    lines.append(f"Wrote {paths[0]} and {paths[1]}. Train the evaluator of the metrics, then the generator:")
    lines += [f"  walkdiff fit --config {p}" for p in paths]
    return "\n".join(lines)


def config_paths(folder: str | Path, out: str | Path, name: str | None = None) -> tuple[Path, Path]:
    """The evaluator's and the generator's config files `scan` writes into `out`."""
    name = config_name(name if name is not None else Path(folder).expanduser().resolve().name)
    out = Path(out).expanduser()
    return out / f"evaluator_{name}.yaml", out / f"{name}.yaml"


def config_name(text: str) -> str:
    """`text` as a config/checkpoint name: lower case, [a-z0-9_] only."""
    return re.sub(r"[^a-z0-9_]+", "_", text.lower()).strip("_") or "folder"


# ---------------------------------------------------------------- reading and suggesting


@dataclass(frozen=True)
class _Found:
    """What reading every clip found: the skeleton profile (from the first clip) and each clip's length."""

    profile: SkeletonProfile
    frames: np.ndarray  # per clip
    rates: np.ndarray  # frames per second, per clip
    durations: np.ndarray  # seconds, per clip
    travel: np.ndarray  # body heights per second the root moves along the ground, per clip


@dataclass(frozen=True)
class _Suggested:
    """The training settings suggested for the clips."""

    fps: int | float
    frames: np.ndarray  # each clip's frames at `fps`
    window: int
    stride: int


def _read_clips(source: FolderSource, clips) -> _Found:
    """Every clip read and checked to be on the first clip's skeleton."""
    skeleton_profile: SkeletonProfile | None = None
    frames, frame_times, travel = [], [], []
    bar = progress(clips, desc="reading BVH", unit="file", show=len(clips) > PROGRESS_ABOVE)
    for clip in bar:
        motion = source.load(clip)
        if skeleton_profile is None:
            skeleton_profile = SkeletonProfile.detect(motion, source.profile, clip.path)
        skeleton_profile.check(motion.skeleton, clip.path)
        frames.append(motion.num_frames)
        frame_times.append(motion.frame_time)
        travel.append(root_travel(skeleton_profile, motion))
    assert skeleton_profile is not None
    frames_arr, frame_times_arr = np.asarray(frames), np.asarray(frame_times)
    return _Found(
        skeleton_profile, frames_arr, 1.0 / frame_times_arr, frames_arr * frame_times_arr, np.asarray(travel)
    )


def _suggest(found: _Found, fps: float | None) -> _Suggested:
    """The training frame rate (`fps` when given), window and stride that fit the clips' lengths."""
    training_fps = _number(fps) if fps is not None else _suggest_fps(float(found.rates.min()))
    training_frames = np.floor((found.frames - 1) * training_fps / found.rates + 1e-6).astype(int) + 1
    window = min(round(WINDOW_SECONDS * training_fps), int(np.percentile(training_frames, 10)))
    window = max(window, MIN_WINDOW)
    window -= window % 2
    stride = max(1, window // STRIDES_PER_WINDOW)
    # Mirrored copies double the windows; the stride grows with the data so the budget still sees each.
    frames = 2 * int(training_frames[training_frames >= window].sum())
    stride = min(max(stride, math.ceil(frames / MAX_WINDOWS)), max(1, window // 2))
    return _Suggested(training_fps, training_frames, window, stride)


# ---------------------------------------------------------------- report helpers


def training_windows(
    clips, splits: dict, suggested: _Suggested, swaps: laterality.MirrorLabels | None
) -> Counter:
    """Training windows per (style, content) index pair at the suggested window and stride, mirrored
    copies counted under their own labels (a mirrored left turn is a right turn's window)."""
    frames = {clip.name: n for clip, n in zip(clips, suggested.frames)}
    cells: Counter = Counter()
    for clip in splits["train"]:
        n = max(0, (int(frames[clip.name]) - suggested.window) // suggested.stride + 1)
        copies = [clip] if swaps is None else [clip, swaps.mirrored(clip)]
        for copy in copies:
            if copy is not None and n:
                cells[copy.style, copy.content] += n
    return cells


def _balance(source: FolderSource) -> dict:
    """The generator draws every content label alike where there are several: on the turns folder of
    docs/training.md (walk 83% of the windows) that took skating from 1.48x real to 1.39x."""
    return {"balance": "content"} if len(source.groups) > 1 else {}


def _window_lines(source: FolderSource, cells: Counter) -> list[str]:
    """How the training windows split over content labels: the share each gets of an unbalanced epoch."""
    if len(source.groups) < 2 or not cells:
        return []
    by_content = Counter()
    for (_, content), n in cells.items():
        by_content[content] += n
    total = sum(by_content.values())
    shares = ", ".join(f"{g} {by_content[i] / total:.0%}" for i, g in enumerate(source.groups))
    return [
        f"Training windows per content (mirrored copies under their own labels): {shares}; the generator's "
        "config draws every content label alike (data.balance: content)"
    ]


def _report(
    folder: Path,
    source: FolderSource,
    clips,
    splits: dict,
    found: _Found,
    suggested: _Suggested,
    swaps: laterality.MirrorLabels | None,
    budget: Budget,
) -> list[str]:
    """The report's lines: the skeleton profile, notes, frame rates, lengths, labels, mirrored labels,
    splits, suggestion."""
    profile, durations = found.profile, found.durations
    seconds = {c.name: float(d) for c, d in zip(clips, durations)}
    joints = profile.skeleton.num_joints
    lines = [f"Folder: {folder} ({len(clips)} BVH files, one skeleton of {joints} joints)"]
    lines.append(f"Skeleton profile (found from {clips[0].name}; overrides: {source.profile or 'none'}):")
    lines += ["  " + line for line in profile.describe()]

    notes = list(profile.notes)
    rate_counts = Counter(round(float(r), 2) for r in found.rates)
    if len(rate_counts) > 1:
        notes.append(f"{len(rate_counts)} frame rates: every clip is resampled to {suggested.fps:g} fps")
    short = int((suggested.frames < suggested.window).sum())
    if short:
        notes.append(
            f"{short} clips are shorter than the window ({suggested.window} frames) and are not trained on"
        )
    empty = [split for split in SPLITS if not splits[split]]
    needed = [split for split in empty if split != "val"]
    if needed:
        notes.append(
            f"no {' and no '.join(needed)} clips, which training needs: {source.empty_split_advice(needed)}"
        )
    if "val" in empty:
        notes.append(
            "no val clips: the written configs do not validate (trainer.limit_val_batches 0): no checkpoint "
            "chosen on validation, and no metrics or previews while the generator trains (they follow "
            "validations; measure last.ckpt with `walkdiff evaluate`). To validate: "
            + source.empty_split_advice(["val"])
        )
    unpaired = [f"{s.kind} {s.label}" for s in swaps.unpaired] if swaps is not None else []
    if unpaired:
        notes.append(
            f"{len(unpaired)} label(s) name a side but have no partner ({', '.join(unpaired)}): their "
            "mirrored copies are left out of training (see 'Mirrored copies' below)"
        )
    lines.append("Notes:" if notes else "Notes: none")
    lines += [f"  - {note}" for note in notes]

    lines.append(
        "Frame rates: "
        + ", ".join(f"{rate:g} fps: {n} file{'s' * (n != 1)}" for rate, n in sorted(rate_counts.items()))
    )
    total = float(durations.sum())
    lines.append(
        f"Duration: {total:.1f} s in total ({total / 60:.1f} min); clips of {found.frames.min()} to "
        f"{found.frames.max()} frames ({durations.min():.2f} to {durations.max():.2f} s)"
    )
    lines += _label_lines(source, clips)
    if swaps is not None:
        lines += _mirror_lines(swaps)
    lines += _window_lines(source, training_windows(clips, splits, suggested, swaps))

    fps, window, stride = suggested.fps, suggested.window, suggested.stride
    lines.append(f"Clip length at {fps:g} fps (p{' / p'.join(str(p) for p in PERCENTILES)}):")
    lines.append("  frames:  " + " / ".join(f"{v:.0f}" for v in np.percentile(suggested.frames, PERCENTILES)))
    lines.append("  seconds: " + " / ".join(f"{v:.2f}" for v in np.percentile(durations, PERCENTILES)))
    lines.append(
        "Splits (clips, seconds): "
        + ", ".join(f"{s} {len(splits[s])} ({sum(seconds[c.name] for c in splits[s]):.1f} s)" for s in SPLITS)
    )
    lines.append(
        f"Suggested: fps {fps:g}, window {window} ({window / fps:.2f} s), stride {stride}, "
        f"mirror {'true' if profile.mirror_pairs else 'false'}"
    )
    lines.append(
        f"Budget: the evaluator {EVALUATOR_STEPS:,} batches of {BATCH_SIZE} windows, the generator "
        f"{budget.steps:,} batches of {GENERATOR_BATCH_SIZE} ({budget.why}), whatever the folder's size "
        f"(the stride grows past {MAX_WINDOWS:,} windows instead)"
    )
    return lines


def _number(value: float) -> int | float:
    value = float(value)
    return int(value) if value.is_integer() else value


def _suggest_fps(lowest_rate: float) -> int | float:
    """30 fps for data at 30 fps or more (29.97 counts), else the data's own (lowest) rate."""
    if lowest_rate >= TRAINING_FPS * 0.998:
        return TRAINING_FPS
    return _number(round(lowest_rate, 2))


def _label_lines(source: FolderSource, clips) -> list[str]:
    styles, groups = source.styles, source.groups
    has_styles = styles != (NO_STYLE,) or source.default_style is not None
    has_contents = groups != (NO_CONTENT,) or source.default_content is not None
    lines = [f"Labels (from {source.labelled_by}):"]
    by_style = Counter(c.style for c in clips)
    by_content = Counter(c.content for c in clips)
    if has_styles:
        counts = ", ".join(f"{s} {by_style[i]}" for i, s in enumerate(styles))
        lines.append(f"  style ({len(styles)}): {counts}")
    else:
        lines.append(f"  style: none (one style, {NO_STYLE!r})")
    if has_contents:
        counts = ", ".join(f"{g} {by_content[i]}" for i, g in enumerate(groups))
        lines.append(f"  content ({len(groups)}): {counts}")
    else:
        lines.append(f"  content: none (one content group, {NO_CONTENT!r})")
    if has_styles and has_contents:
        if len(styles) > _TABLE_LIMIT or len(groups) > _TABLE_LIMIT:
            lines.append(f"  style x content: {len(styles)} x {len(groups)} (too large to show)")
            return lines
        pairs = Counter((c.style, c.content) for c in clips)
        first = max(len(s) for s in styles) + 2
        widths = [max(len(g), 3) + 2 for g in groups]
        lines.append("  style x content:")
        lines.append("  " + " " * first + "".join(g.rjust(w) for g, w in zip(groups, widths)))
        for i, s in enumerate(styles):
            counts = "".join(str(pairs[i, j]).rjust(w) for j, w in enumerate(widths))
            lines.append("  " + s.ljust(first) + counts)
    return lines


def _mirror_lines(swaps: laterality.MirrorLabels) -> list[str]:
    """What the mirrored training copies (mirror true) are labelled: the lateral labels."""
    if not swaps.swaps:
        return [
            "Mirrored copies keep their labels: no style or content label names a side (left/right, l/r, "
            "lturn/rturn, cw/ccw, ...)"
        ]
    lines = ["Mirrored copies swap the labels that name a side (a mirrored left turn turns right):"]
    lines += [f"  {line}" for line in swaps.describe()]
    return lines


# ---------------------------------------------------------------- configs


def _yaml(value) -> str:
    """A YAML scalar (or JSON flow collection) that OmegaConf reads back as `value`."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str) and _PLAIN.fullmatch(value) and value.lower() not in _YAML_WORDS:
        return value
    if isinstance(value, str):
        return json.dumps(value.replace("${", "\\${"), ensure_ascii=False)  # no OmegaConf interpolation
    return json.dumps(value, ensure_ascii=False)


def _comment(path: Path) -> str:
    return " ".join(str(path).splitlines())


def _data_section(data: dict) -> str:
    body = "".join(f"    {key}: {_yaml(value)}\n" for key, value in data.items())
    return f"data:\n  class_path: walkdiff.data.datamodule.MotionDataModule\n  init_args:\n{body}"


def _trainer(directory: str, max_steps: int, validate_every: int, max_time: str) -> str:
    """The trainer section both configs share (CPU, 32-bit), up to the logger."""
    return f"""\
seed_everything: 0
trainer:
  accelerator: cpu
  devices: 1
  precision: 32-true
  max_steps: {max_steps}              # the bound, in batches: the same model on a fast or a busy machine
  max_time: "{max_time}"        # only a safety net (says so and tags the run when it fires)
  val_check_interval: {validate_every}        # batches between validations, across epochs
  check_val_every_n_epoch: null
  limit_val_batches: {VAL_BATCHES}
  log_every_n_steps: 20
  num_sanity_val_steps: 0
  default_root_dir: {_yaml(directory)}   # the checkpoints and their links (last.ckpt, best.ckpt)
"""


def _last_checkpoint() -> str:
    """The checkpoint without a monitor: last.ckpt (a link into the run's folder), after every validation
    and when training ends (`RunCheckpoint.on_train_end`)."""
    return """\
    - class_path: walkdiff.callbacks.checkpoints.RunCheckpoint
      init_args:
        filename: last
        save_top_k: 1
"""


def _logger(name: str, run: str) -> str:
    """MLflow, its best and last checkpoints logged by walkdiff's RunTracking (hence no log_model)."""
    return f"""\
  logger:
    class_path: lightning.pytorch.loggers.MLFlowLogger
    init_args:
      experiment_name: {_yaml(f"walkdiff-{name}")}
      run_name: {_yaml(run)}
      tracking_uri: sqlite:///mlruns/mlflow.db
      artifact_location: mlruns/artifacts
"""


def _without_validation(trainer: str) -> str:
    """The trainer section of a folder without val clips: no validation loop, hence nothing that
    follows one (`MotionDataModule` accepts an empty val split when trainer.limit_val_batches is 0)."""
    validation = re.compile(r"  (val_check_interval|check_val_every_n_epoch|limit_val_batches):")
    lines = trainer.splitlines(keepends=True)
    first = [i for i, line in enumerate(lines) if validation.match(line)]
    at = first[0] if first else lines.index("trainer:\n") + 1
    kept = [line for line in lines if not validation.match(line)]
    kept.insert(at, "  limit_val_batches: 0          # the folder has no val clips: no validation\n")
    return "".join(kept)


def _evaluator_config(name: str, folder: Path, summary: str, data: dict, validate: bool = True) -> str:
    directory = f"checkpoints/evaluator_{name}"
    trainer = _trainer(directory, EVALUATOR_STEPS, EVALUATOR_VALIDATE, "00:01:00:00")
    best = """\
    - class_path: walkdiff.callbacks.checkpoints.RunCheckpoint
      init_args:
        filename: best
        monitor: style_acc/val
        mode: max
        save_top_k: 1
"""
    return (
        f"""\
# The motion evaluator of the metrics (style + content classifier) on {_comment(folder)}, mirrored copies
# included when the skeleton has left/right pairs. Written by `walkdiff data scan`; sized for CPU.
{summary}
# Train it first: walkdiff fit --config <this file>
"""
        + (trainer if validate else _without_validation(trainer))
        + _logger(name, f"evaluator_{name}")
        + "  callbacks:\n"
        + (best if validate else "    # No val clips: no best checkpoint by validation accuracy.\n")
        + "    # The latest as last.ckpt: the generator's metrics use it.\n"
        + _last_checkpoint()
        + """\
model:
  class_path: walkdiff.models.evaluator.MotionEvaluator
  init_args:
    hidden: 128
    embed_dim: 128
    blocks: 3
    kernel: 5
    dropout: 0.2
    input_noise: 0.1
    content_weight: 1.0
    lr: 1.0e-3
    weight_decay: 1.0e-2
"""
        + _data_section(data)
    )


def _generator_config(
    name: str, folder: Path, summary: str, data: dict, content: str, budget: Budget, validate: bool = True
) -> str:
    directory = f"checkpoints/{name}"
    trainer = _trainer(directory, budget.steps, GENERATOR_VALIDATE, "00:04:00:00")
    measured = f"""\
    # FMD, style accuracy, diversity and foot skating of generated samples; placed before the
    # checkpoints that monitor its numbers.
    - class_path: walkdiff.callbacks.metrics.MotionMetrics
      init_args:
        evaluator_ckpt: {_yaml(f"checkpoints/evaluator_{name}/last.ckpt")}
        every_n_steps: {GENERATOR_VALIDATE}
        num_samples: 128
        sampler: ddpm
    - class_path: walkdiff.callbacks.checkpoints.RunCheckpoint
      init_args:
        filename: "best-{{step:06d}}"
        monitor: metrics/fmd
        mode: min
        save_top_k: 1
"""
    previews = f"""\
    - class_path: walkdiff.callbacks.samples.SampleClips
      init_args:
        every_n_steps: {2 * GENERATOR_VALIDATE}
        content: {_yaml(content)}
"""
    if validate:
        first = f"""\
# Train the evaluator first (walkdiff fit --config evaluator_{name}.yaml, beside this file): the
# metrics callback reads its last checkpoint.
"""
    else:
        first = f"""\
# The folder has no val clips, so nothing validates: the metrics and previews (which follow validations)
# and the best checkpoint they choose are left out; last.ckpt is the model. Score it after training with
# walkdiff evaluate --evaluator checkpoints/evaluator_{name}/last.ckpt.
"""
    return (
        f"""\
# Styled motion GAN-DDPM on {_comment(folder)}. Written by `walkdiff data scan`; sized for CPU
# (modelled on conf/xia_cpu.yaml). Every key can be overridden on the command line.
{summary}
{textwrap.fill(f"{budget.steps:,} batches: {budget.why}.", 100, initial_indent="# ", subsequent_indent="# ")}
"""
        + first
        + (trainer if validate else _without_validation(trainer))
        + _logger(name, name)
        + "  callbacks:\n"
        + (measured if validate else "")
        + _last_checkpoint()
        + (previews if validate else "")
        + f"""\
model:
  class_path: walkdiff.models.styled_ddpm.StyledMotionDiffusion
  init_args:
    d_model: 256
    layers: 4
    heads: 4
    dropout: 0.0
    timesteps: 100
    schedule: linear
    beta_start: 1.0e-3
    beta_end: 0.2
    prediction: x0
    conditioning: adaln   # labels in every layer: with the low-foot term, turns 0.93x real, not 0.70x
    min_snr_gamma: 5.0   # FMD 1.65x the floor, not 2.20x (walkdiff bench ablate: docs/training.md)
    lambda_contact: 1.0
    lambda_root: 0.023
    lambda_adv: 0.05
    lambda_velocity: 0.5
    lambda_foot: 1.0
    lambda_foot_height: 8.0   # skating 1.48x real, not 1.56x; x16 was worse (walkdiff bench ablate)
    lambda_low_foot: 4.0   # skating as sampled 1.59x real, not 2.77x (actions), 0.16x, not 1.25x (turns)
    lambda_position: 1.0
    adv_warmup_batches: 250
    discriminator_windows: {DISCRIMINATOR_WINDOWS}   # of {GENERATOR_BATCH_SIZE}: D's cost fixed at any batch
    cond_drop: 0.1
    lr: 1.0e-3
    lr_discriminator: 4.0e-4
    lr_warmup_batches: 100
    grad_clip: 1.0
    ema_decay: 0.995
"""
        + _data_section(data | {"batch_size": GENERATOR_BATCH_SIZE})
    )
