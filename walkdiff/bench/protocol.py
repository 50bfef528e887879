"""`walkdiff bench protocol`: walkdiff's rows of the evaluation protocol, scored as `walkdiff score` scores
any method, beside the baselines every method is compared with.

- Sampling: `samples` windows with the labels of real test windows from the generator (DDPM over all
  steps and DDIM-10) and from a distilled student (DDIM at each step count it was made for, when
  given), each window a clip; the real training split as the floor a generator can reach.
- Transfer: every real test clip of the protocol's contents restyled to every other style, at each
  strength, with and without `--keep-trajectory`; the unchanged sources and real clips of the target
  styles scored the same way. A setting is a style transfer when it beats both baselines
  (`transfer.transfer_verdict`: "inconclusive" where the clips are too few to tell).

Writes OUT/protocol.json and OUT/protocol.md (the README's table).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import torch

from walkdiff.common.files import output_folder, write_json, write_text
from walkdiff.common.progress import progress
from walkdiff.evaluation.clips import Clip, ClipScorer
from walkdiff.evaluation.score import METRICS, format_summary
from walkdiff.evaluation.scorer import drawn_labels, generate_windows
from walkdiff.evaluation.transfer import (
    MIN_SOURCES_PER_STYLE,
    real_targets,
    sources_per_style,
    transfer_baselines,
    transfer_row,
    transfer_verdict,
)
from walkdiff.motion.footfix import fix_feet_features

SAMPLE_METRICS = ("style_acc", "fmd", "kid", "diversity", "skate_ratio", "jitter")
TRANSFER_METRICS = ("target_style_acc", "content_kept", "content_distance", "fmd", "kid", "skate_ratio")


def clips_of_raw(scorer: ClipScorer, raw: torch.Tensor, styles: list[str], content: str | None, name: str):
    """Raw feature windows (B, F, D) as Clips of world positions, what the scorer scores, named
    `name`/index and labelled with `styles` (one each) and `content`."""
    positions = scorer.scorer.positions(raw).numpy()
    return [
        Clip(f"{name}/{i}", p, style, content)
        for i, (p, style) in enumerate(zip(positions, styles, strict=True))
    ]


def _sample_row(scorer: ClipScorer, model, samples: int, seed: int, batch: int, bootstrap: int, **sampling):
    contents = list(model.spec["contents"])
    labels = drawn_labels(scorer.reference_windows, samples, torch.Generator().manual_seed(seed))
    generator = torch.Generator(device=model.device).manual_seed(seed)
    windows = generate_windows(model, labels, generator, batch, **sampling)
    styles = [model.spec["styles"][int(s)] for s in windows.style]
    clips = clips_of_raw(scorer, windows.raw, styles, None, "sample")
    for clip, c in zip(clips, windows.content, strict=True):
        clip.content = contents[int(c)]
    scored = scorer.windows(clips)
    return scorer.statistics(scored, scorer.recognition(scored)).bootstrap(bootstrap, seed)


def held_out_clips(scorer: ClipScorer, styles=None) -> tuple[list[Clip], list[torch.Tensor]]:
    """The real test clips at least a window long (of `styles` only, where given), as Clips of positions
    (what is scored) and as raw features (what restyle takes), in the same order."""
    test = [
        (info, features)
        for info, _, features in scorer.data.split_features("test")
        if features.shape[0] >= scorer.window and (styles is None or scorer.styles[info.style] in styles)
    ]
    sources = [
        Clip(f"test/{i}", scorer.scorer.positions(torch.from_numpy(f)[None])[0].numpy(),
             scorer.styles[info.style], scorer.data.source.groups[info.content])
        for i, (info, f) in enumerate(test)
    ]  # fmt: skip
    return sources, [torch.from_numpy(f) for _, f in test]


def restyled_clips(scorer: ClipScorer, model, sources: list[Clip], raws: list[torch.Tensor], strength: float,
               keep: bool, seed: int, to: dict[str, torch.Tensor] | None = None,
               sampling=None, match: dict | None = None,
               ) -> tuple[list[Clip], list[Clip], list[str]]:  # fmt: skip
    """Every source restyled to every other style: (outputs, their sources, target styles). `to` (target
    style -> the model's style input, an id or a code) restyles to those styles instead; `sampling`
    (default DDPM) is how; `match` (target style -> StyleStatistics): the statistics each is moved to."""
    from walkdiff.models.style_statistics import StyleStatistics
    from walkdiff.styled.generation import Sampling, restyle

    styles = list(model.spec["styles"])
    contents = list(model.spec["contents"])
    to = to or {s: torch.tensor(i) for i, s in enumerate(styles)}
    generator = torch.Generator().manual_seed(seed)
    outputs, paired, targets = [], [], []
    pairs = list(zip(sources, raws, strict=True))
    for source, raw in progress(pairs, desc=f"transfer {strength}", unit="clip"):
        names = [s for s in to if s != source.style]
        target = torch.stack([to[s] for s in names])
        x0 = model.normalizer.normalize(raw)[None].expand(len(names), -1, -1)
        content = torch.full((len(names),), contents.index(source.content))
        how = sampling or Sampling()
        if match is not None:
            how = replace(how, match=StyleStatistics.stack([match[s] for s in names]))
        x = restyle(model, x0, target, content, strength, how, generator, keep)
        restyled = model.to_raw(x, True)
        if match is not None:  # as `transfer` makes them: feet pinned where statistics are matched
            restyled = fix_feet_features(restyled, model.profile, model.spec["fps"], model.floor_heights)
        restyled = torch.from_numpy(restyled)
        outputs += clips_of_raw(scorer, restyled, names, None, f"{source.name}->")
        paired += [source] * len(target)
        targets += names
    return outputs, paired, targets


def bench_protocol(
    out: str | Path,
    ckpt: str | Path,
    evaluator: str | Path,
    student: str | Path | None = None,
    strengths: tuple[float, ...] = (0.4, 0.6, 0.8),
    samples: int = 256,
    bootstrap: int = 200,
    seed: int = 0,
    batch_size: int = 64,
) -> dict:
    from walkdiff.styled.generation import load_generator

    started = time.perf_counter()
    out = output_folder(out)
    scorer = ClipScorer(evaluator)
    model = load_generator(ckpt)
    rows: dict[str, dict] = {}
    print("sampling rows", flush=True)
    rows["walkdiff, DDPM 100"] = _sample_row(scorer, model, samples, seed, batch_size, bootstrap)
    rows["walkdiff, DDIM 10"] = _sample_row(
        scorer, model, samples, seed, batch_size, bootstrap, sampler="ddim", steps=10
    )
    if student is not None:
        distilled = load_generator(student)
        for k in distilled.distilled_steps or [10]:
            rows[f"distilled student, DDIM {k}"] = _sample_row(
                scorer, distilled, samples, seed, batch_size, bootstrap, sampler="ddim", steps=k
            )
    train = scorer.real_windows("train")
    rows["real train (floor)"] = scorer.statistics(train, scorer.recognition(train)).bootstrap(
        bootstrap, seed
    )

    sources, raws = held_out_clips(scorer)  # transfer's sources
    transfer: dict[str, dict] = {}
    paired, targets = None, None
    for strength in strengths:
        for keep in (False, True):
            outputs, paired, targets = restyled_clips(scorer, model, sources, raws, strength, keep, seed)
            name = f"transfer {strength:g}" + (", keep trajectory" if keep else "")
            transfer[name] = transfer_row(scorer, outputs, paired, bootstrap, seed)
    real = real_targets(scorer, targets, paired)
    stand_ins = [
        {"source": s.name, "style": t, "real": r.name, "real_content": r.content}
        for s, t, r in zip(paired, targets, real, strict=True)
    ]
    baselines = transfer_baselines(scorer, paired, targets, real, bootstrap, seed)
    per_style = sources_per_style(targets, [s.name for s in paired])
    verdicts = {
        name: transfer_verdict({"output": row} | baselines, per_style, bootstrap, seed)
        for name, row in transfer.items()
    }
    transfer = {name: row.summary for name, row in (transfer | baselines).items()}

    result = {
        "benchmark": "protocol",
        "ckpt": str(ckpt),
        "student": None if student is None else str(student),
        "evaluator": str(evaluator),
        "samples": samples,
        "bootstrap": bootstrap,
        "seed": seed,
        "transfer_pairs": len(targets),
        "sources": len(sources),
        "sampling": rows,
        "transfer": transfer,
        "verdicts": verdicts,
        "baseline_real_clips": stand_ins,
        "elapsed_s": round(time.perf_counter() - started, 1),
    }
    write_json(out / "protocol.json", result)
    write_text(out / "protocol.md", format_protocol(result))
    return result


def metric_table(rows: dict[str, dict], metrics: tuple[str, ...], verdicts: dict | None = None) -> list[str]:
    head = "| | " + " | ".join(METRICS[m][0] for m in metrics) + (" | style transfer |" if verdicts else " |")
    lines = [head, "|---|" + "---:|" * len(metrics) + ("---|" if verdicts else "")]
    for name, row in rows.items():
        cells = [format_summary(row[m], METRICS[m][1]) if m in row else "" for m in metrics]
        verdict = ""
        if verdicts is not None:
            shown = {"yes": "**yes**", "no": "no", "inconclusive": "inconclusive"}
            verdict = " | " + (shown[verdicts[name]["verdict"]] if name in verdicts else "")
        lines.append(f"| {name} | " + " | ".join(cells) + verdict + " |")
    return lines


def format_protocol(result: dict) -> str:
    lines = [
        "# walkdiff on the evaluation protocol",
        "",
        f"- generator `{result['ckpt']}`, evaluator `{result['evaluator']}`"
        + (f", student `{result['student']}`" if result["student"] else ""),
        f"- sampling: {result['samples']} windows per row; transfer: {result['sources']} real test clips, "
        f"each to every other style ({result['transfer_pairs']} outputs per row)",
        f"- every value on the whole set [95% interval by bootstrap over clips, {result['bootstrap']} "
        "resamples]",
        "",
        "## Sampling",
        "",
        *metric_table(result["sampling"], SAMPLE_METRICS),
        "",
        "## Style transfer",
        "",
        *metric_table(result["transfer"], TRANSFER_METRICS, result["verdicts"]),
        "",
        "A style transfer must recognise the target style at least 80% as often as real clips of that "
        "style do and more often than the unchanged source, keep the source's content in 95% of windows, "
        "and stay nearer the source than real clips of the target style. A verdict needs at least "
        f"{MIN_SOURCES_PER_STYLE} source clips per target style and the 95% interval of every check's margin "
        "on one side of its bar; else it is inconclusive. The real clip that stood in for each source and "
        "target style: `baseline_real_clips` in protocol.json.",
        "",
    ]
    return "\n".join(lines)
