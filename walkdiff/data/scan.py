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
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_text
from walkdiff.common.progress import progress
from walkdiff.data.clips import ContentSelection
from walkdiff.data.folder import NO_CONTENT, NO_STYLE, SPLITS, FolderSource
from walkdiff.motion.profile import SkeletonProfile

TRAINING_FPS = 30  # the suggested rate for data at 30 fps or more
WINDOW_SECONDS = 0.8  # the suggested window, at most the 10th percentile clip length
MIN_WINDOW = 8
STRIDES_PER_WINDOW = 6
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
) -> str:
    """The report on `folder` (text to print); with `out`, also writes the two training configs.

    `labels`, `pattern`, `default_style`, `default_content`, `profile`, `val_fraction` and
    `test_fraction` are the folder dataset's options (`walkdiff.data.folder`); `fps` replaces the
    suggested training frame rate; `name` (default: the folder's name) names the configs, checkpoints
    and experiments; existing configs are kept unless `overwrite`.
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
    name = config_name(name if name is not None else folder.name)
    out = None if out is None else Path(out).expanduser()
    paths = () if out is None else (out / f"evaluator_{name}.yaml", out / f"{name}.yaml")
    existing = [p for p in paths if p.exists()]
    if existing and not overwrite:
        raise WalkdiffError("config exists: pass overwrite (--overwrite) to replace it", path=existing[0])
    if fps is not None and not (isinstance(fps, int | float) and math.isfinite(fps) and fps > 0):
        raise WalkdiffError(f"fps: expected a positive frame rate, got {fps!r}")

    found = _read_clips(source, clips)
    suggested = _suggest(found, fps)
    lines = _report(folder, source, clips, found, suggested)
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
        "batch_size": 64,
        "num_workers": 0,
    }
    summary = (
        f"# {len(clips)} clips, {found.durations.sum() / 60:.1f} min, {len(source.styles)} style(s), "
        f"{len(source.groups)} content group(s); root {found.profile.root}."
    )
    texts = (
        _evaluator_config(name, folder, summary, data),
        _generator_config(name, folder, summary, data, source.groups[0]),
    )
    for path, text in zip(paths, texts):
        write_text(path, text)
    lines.append(f"Wrote {paths[0]} and {paths[1]}. Train the evaluator of the metrics, then the generator:")
    lines += [f"  walkdiff fit --config {p}" for p in paths]
    return "\n".join(lines)


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
    frames, frame_times = [], []
    bar = progress(clips, desc="reading BVH", unit="file", show=len(clips) > PROGRESS_ABOVE)
    for clip in bar:
        motion = source.load(clip)
        if skeleton_profile is None:
            skeleton_profile = SkeletonProfile.detect(motion, source.profile, clip.path)
        skeleton_profile.check(motion.skeleton, clip.path)
        frames.append(motion.num_frames)
        frame_times.append(motion.frame_time)
    assert skeleton_profile is not None
    frames_arr, frame_times_arr = np.asarray(frames), np.asarray(frame_times)
    return _Found(skeleton_profile, frames_arr, 1.0 / frame_times_arr, frames_arr * frame_times_arr)


def _suggest(found: _Found, fps: float | None) -> _Suggested:
    """The training frame rate (`fps` when given), window and stride that fit the clips' lengths."""
    training_fps = _number(fps) if fps is not None else _suggest_fps(float(found.rates.min()))
    training_frames = np.floor((found.frames - 1) * training_fps / found.rates + 1e-6).astype(int) + 1
    window = min(round(WINDOW_SECONDS * training_fps), int(np.percentile(training_frames, 10)))
    window = max(window, MIN_WINDOW)
    window -= window % 2
    stride = max(1, window // STRIDES_PER_WINDOW)
    return _Suggested(training_fps, training_frames, window, stride)


# ---------------------------------------------------------------- report helpers


def _report(folder: Path, source: FolderSource, clips, found: _Found, suggested: _Suggested) -> list[str]:
    """The report's lines: the skeleton profile, notes, frame rates, lengths, labels, splits, suggestion."""
    profile, durations = found.profile, found.durations
    splits = source.split_clips(clips, ContentSelection(tuple(source.groups)))
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
    if empty:
        notes.append(
            f"no {' and no '.join(empty)} clips, which training needs: {source.empty_split_advice(empty)}"
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


def _trainer(directory: str, max_epochs: int, max_time: str, validate_every: int | None = None) -> str:
    """The trainer section both configs share (CPU, 32-bit), up to the logger."""
    every = f"  check_val_every_n_epoch: {validate_every}\n" if validate_every else ""
    return f"""\
seed_everything: 0
trainer:
  accelerator: cpu
  devices: 1
  precision: 32-true
  max_epochs: {max_epochs}            # the bound: the same model on a fast or a busy machine
  max_time: "{max_time}"        # only a safety net (says so and tags the run when it fires)
{every}  log_every_n_steps: 20
  num_sanity_val_steps: 0
  default_root_dir: {_yaml(directory)}
"""


def _last_checkpoint(directory: str) -> str:
    """The checkpoint without a monitor: last.ckpt (a link into the run's folder), every epoch."""
    return f"""\
    - class_path: walkdiff.callbacks.checkpoints.RunCheckpoint
      init_args:
        dirpath: {_yaml(directory)}
        filename: last
        save_top_k: 1
        save_on_train_epoch_end: true  # also when a run ends before its first validation
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


def _evaluator_config(name: str, folder: Path, summary: str, data: dict) -> str:
    directory = f"checkpoints/evaluator_{name}"
    return (
        f"""\
# The motion evaluator of the metrics (style + content classifier) on {_comment(folder)}, mirrored copies
# included when the skeleton has left/right pairs. Written by `walkdiff data scan`; sized for CPU.
{summary}
# Train it first: walkdiff fit --config <this file>
"""
        + _trainer(directory, 40, "00:01:00:00")
        + _logger(name, f"evaluator_{name}")
        + f"""\
  callbacks:
    - class_path: walkdiff.callbacks.checkpoints.RunCheckpoint
      init_args:
        dirpath: {_yaml(directory)}
        filename: best
        monitor: style_acc/val
        mode: max
        save_top_k: 1
    # The latest epoch as last.ckpt: the generator's metrics use it.
"""
        + _last_checkpoint(directory)
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


def _generator_config(name: str, folder: Path, summary: str, data: dict, content: str) -> str:
    directory = f"checkpoints/{name}"
    return (
        f"""\
# Styled motion GAN-DDPM on {_comment(folder)}. Written by `walkdiff data scan`; sized for CPU
# (modelled on conf/xia_cpu.yaml). Every key can be overridden on the command line.
{summary}
# Train the evaluator first (walkdiff fit --config evaluator_{name}.yaml, beside this file): the
# metrics callback reads its last checkpoint.
"""
        + _trainer(directory, 40, "00:04:00:00", validate_every=5)
        + _logger(name, name)
        + f"""\
  callbacks:
    # FMD, style accuracy, diversity and foot skating of generated samples; placed before the
    # checkpoints that monitor its numbers.
    - class_path: walkdiff.callbacks.metrics.MotionMetrics
      init_args:
        evaluator_ckpt: {_yaml(f"checkpoints/evaluator_{name}/last.ckpt")}
        every_n_epochs: 5
        num_samples: 128
        sampler: ddpm
    - class_path: walkdiff.callbacks.checkpoints.RunCheckpoint
      init_args:
        dirpath: {_yaml(directory)}
        filename: "best-{{epoch:04d}}"
        monitor: metrics/fmd
        mode: min
        save_top_k: 1
"""
        + _last_checkpoint(directory)
        + f"""\
    - class_path: walkdiff.callbacks.samples.SampleClips
      init_args:
        every_n_epochs: 10
        content: {_yaml(content)}
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
    lambda_contact: 1.0
    lambda_root: 0.023
    lambda_adv: 0.05
    lambda_velocity: 0.5
    lambda_foot: 1.0
    lambda_foot_height: 2.0
    lambda_position: 1.0
    adv_warmup_batches: 250
    cond_drop: 0.1
    lr: 1.0e-3
    lr_discriminator: 4.0e-4
    lr_warmup_batches: 100
    grad_clip: 1.0
    ema_decay: 0.995
"""
        + _data_section(data)
    )
