"""`walkdiff bench sample`: a generator's quality against sampling steps, its speed, seams, foot clean-up and
transfer."""

from __future__ import annotations

import statistics
from pathlib import Path

import torch

from walkdiff.bench.measure import interleaved_medians, machine, median_seconds, report
from walkdiff.bench.quality import QualityBench, with_feet_fixed, with_ratios
from walkdiff.common.files import write_atomic
from walkdiff.evaluation.scorer import drawn_labels


def _seam_speeds(model, x: torch.Tensor, overlap: int, blend: int) -> dict:
    """Joint speeds (units/s) at the window seams of long samples against the steps inside windows.

    A seam is every step from a window's last held frame through its cross-fade; `within_spread` is
    `generation.seams_within_spread` (at most 10% of seam steps beyond either end of the inside 5-95%
    band), the criterion the tests hold generation to.
    """
    from walkdiff.styled.generation import (
        joint_speeds,
        seam_steps,
        seam_tails,
        seams_within_spread,
        split_seams,
    )

    speed = joint_speeds(model, x)
    seams = seam_steps(x.shape[1], model.spec["window"], overlap, blend)
    inner, at_seams = split_seams(speed, seams)
    quantiles = inner.quantile(torch.tensor([0.05, 0.5, 0.95], dtype=torch.float64))
    below, above = seam_tails(speed, seams)
    return {
        "seam_mean": round(float(at_seams.mean()), 3),
        "seam_p95": round(float(at_seams.quantile(0.95)), 3),
        "seam_max": round(float(at_seams.max()), 3),
        "inside_mean": round(float(inner.mean()), 3),
        "inside_p05_p50_p95": [round(float(q), 3) for q in quantiles],
        "inside_max": round(float(inner.max()), 3),
        "seams_below_inside_p05": round(below, 4),
        "seams_above_inside_p95": round(above, 4),
        "within_spread": seams_within_spread(speed, seams),
    }


def _transfer_windows(model, dm, strength: float, keep_trajectory: bool, seed: int, ground: bool = True):
    """Every test clip restyled to every other style, cut into windows; plus the root path errors."""
    from walkdiff.evaluation.scorer import WindowSet
    from walkdiff.motion.representation import decode_root
    from walkdiff.styled.generation import Sampling, restyle

    window, styles = model.spec["window"], len(model.spec["styles"])
    walk = list(model.spec["contents"]).index("walk")
    generator = torch.Generator().manual_seed(seed)
    raws, targets, sources, errors = [], [], [], []
    for info, _, features in dm.split_features("test"):
        if features.shape[0] < window:
            continue
        target = torch.tensor([s for s in range(styles) if s != info.style])
        source = model.normalizer.normalize(torch.from_numpy(features))[None].expand(len(target), -1, -1)
        content = torch.full_like(target, walk)
        x = restyle(model, source, target, content, strength, Sampling(), generator, keep_trajectory)
        raw = torch.from_numpy(model.to_raw(x, ground))
        root_in, root_out = decode_root(torch.from_numpy(features)), decode_root(raw)
        walked = (root_in[1:, [0, 2]] - root_in[:-1, [0, 2]]).norm(dim=-1).sum()
        errors += ((root_out - root_in)[..., [0, 2]].norm(dim=-1).mean(-1) / walked).tolist()
        for start in range(0, raw.shape[1] - window + 1, 4):
            raws.append(raw[:, start : start + window])
            targets.append(target)
            sources.append(torch.full_like(target, info.style))
    raw = torch.cat(raws)
    windows = WindowSet(raw, torch.cat(targets), torch.full((len(raw),), walk), torch.full((len(raw),), -1))
    return windows, torch.cat(sources), errors


def _plot_quality(path: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.5))
    for ax, key, label in (
        (axes[0], "fmd", "FMD (lower is better)"),
        (axes[1], "style_acc", "style accuracy"),
    ):
        for sampler, label_ in (("ddim", "DDIM (eta 0)"), ("dpmpp", "DPM-Solver++(2M)")):
            line = [r for r in rows if r["sampler"] == sampler and r["eta"] == 0]
            ax.plot([r["steps"] for r in line], [r[key] for r in line], "o-", label=label_)
        noisy = [r for r in rows if r["sampler"] == "ddim" and r["eta"] > 0]
        for r, color in zip(noisy, ("C2", "C4", "C5", "C6"), strict=False):
            ax.plot([r["steps"]], [r[key]], "^", color=color, label=f"DDIM (eta {r['eta']})")
        for r in rows:
            if r["sampler"] == "ddpm":
                ax.plot([r["steps"]], [r[key]], "s", color="C3", label="DDPM")
                if key == "fmd":
                    ax.axhline(1.1 * r[key], color="C3", ls=":", lw=1, label="DDPM + 10%")
        ax.set_xscale("log")
        if key == "style_acc":
            ax.set_ylim(0, 1.05)
        ax.set_xlabel("denoising steps")
        ax.set_title(label)
        ax.legend(fontsize=7)
    fig.tight_layout()
    write_atomic(path, lambda f: fig.savefig(f, format="png", dpi=120))
    plt.close(fig)


def bench_sample(
    out: str,
    ckpt: str,
    evaluator: str,
    num: int = 400,
    seed: int = 0,
    ddim_steps: tuple[int, ...] = (50, 20, 10, 5),
    dpm_steps: tuple[int, ...] = (20, 10, 5),
    seeds: int = 3,
    batch_size: int = 32,
    repeats: int = 3,
    strength: float = 0.6,
    ground: bool = True,
) -> dict:
    """Quality against steps, speed, foot clean-up and transfer of a StyledMotionDiffusion checkpoint.

    Writes OUT/sample.json and OUT/sample.png. Quality: FMD and recognition against the real test
    windows (evaluation.py's scorer) of `num` windows with the labels of real ones, DDPM over all T
    steps, DDIM over each of `ddim_steps` and DPM-Solver++(2M) over each of `dpm_steps`, averaged over
    `seeds` seeds (the same seeds for every sampler), with each one's ratio to DDPM. A distilled
    student's DDIM step counts (`walkdiff distill`) join the DDIM rows, the speed (frames/s at each)
    and the seams.
    """
    from walkdiff.styled.generation import load_generator

    model = load_generator(ckpt)
    bench = QualityBench(model, ckpt, evaluator, num, seed, seeds, ground)
    reference = bench.reference
    quality, (ddpm, ddpm_scores) = _quality_rows(bench, model, ddim_steps, dpm_steps)
    real = bench.scored(
        reference.take(torch.randperm(len(reference), generator=torch.Generator().manual_seed(seed))[:num])
    )
    # Foot clean-up on the DDPM windows, scored the same way.
    fix_feet = {"before": ddpm_scores, "after": bench.scored(with_feet_fixed(model, ddpm))}

    torch.manual_seed(seed)
    style, content = drawn_labels(reference, batch_size, torch.Generator().manual_seed(seed))
    result = {
        "benchmark": "sample",
        "ckpt": ckpt,
        "evaluator": evaluator,
        "num": num,
        "seed": seed,
        "grounded": ground,
        "seeds": seeds,
        "quality": quality,
        "real_test": real,
        "fix_feet": fix_feet,
        "speed": _speed(model, style, content, repeats),
        "seams_300_frames": _seams(model, style, content, seed),
        "transfer": _transfer(bench, model, strength, seed, ground, real),
        "machine": machine(),
    }
    out_dir = Path(out)
    report(out_dir / "sample.json", result)
    _plot_quality(out_dir / "sample.png", quality)
    return result


def _quality_rows(bench: QualityBench, model, ddim_steps: tuple[int, ...], dpm_steps: tuple[int, ...]):
    """(a row per sampler and step count, with its ratios to DDPM; DDPM's first-seed windows and scores).

    DDPM over all T steps; DDIM at eta 0 over the step counts (and a distilled student's) and at 10 steps
    with some of DDPM's noise put back (eta > 0); DPM-Solver++(2M) over its steps.
    """
    configs = [("ddpm", model.diffusion.num_timesteps, 1.0)]
    ddim_counts = sorted({*ddim_steps, *model.distilled_steps}, reverse=True)
    configs += [("ddim", k, 0.0) for k in ddim_counts] + [("ddim", 10, eta) for eta in (0.5, 1.0)]
    configs += [("dpmpp", k, 0.0) for k in dpm_steps]
    quality, ddpm = [], None
    for config in configs:
        row, first_seed = bench.row(model, *config)
        ddpm = first_seed if ddpm is None else ddpm
        quality.append(with_ratios(row, quality[0] if quality else row))
    return quality, ddpm


LONG_FRAMES = 300  # the length of the long samples timed and whose seams are measured


def _speed(model, style: torch.Tensor, content: torch.Tensor, repeats: int) -> dict:
    """A batch of windows with DDIM-10 and DPM-Solver++-10, per-step cost against one network pass, long
    samples, a distilled student's step counts, and the latency of one stream."""
    from walkdiff.diffusion import respace
    from walkdiff.styled.generation import Sampling, generate_long

    batch_size, window, dim = len(style), model.spec["window"], model.spec["feature_dim"]
    distilled = model.distilled_steps

    def sample10(sampler: str):
        return lambda: model.generate(style, content, sampler=sampler, steps=10)

    sample10("ddim")()  # warm-up
    # The network as DDIM-10 calls it (a distilled student's with its jumps), at one of its steps.
    net = model.model_fn(style, content, jumps=model.jumps("ddim", 10, 0.0))
    x = torch.randn(batch_size, window, dim)
    t = torch.full((batch_size,), respace(model.diffusion.num_timesteps, 10)[5])

    def ten_forwards():
        with torch.no_grad():  # as generate runs the network
            for _ in range(10):
                net(x, t)

    def student(k: int):
        return lambda: model.generate(style, content, sampler="ddim", steps=k)

    for k in distilled:
        student(k)()  # warm-up
    medians = interleaved_medians(
        [sample10("ddim"), sample10("dpmpp"), ten_forwards, *(student(k) for k in distilled)], repeats
    )
    batch_s, dpm_s, ten_s = medians[:3]
    forward_s = ten_s / 10
    generate_long(model, style, content, LONG_FRAMES, Sampling("ddim", 10))  # warm-up
    long_s = median_seconds(
        lambda: generate_long(model, style, content, LONG_FRAMES, Sampling("ddim", 10)), 1
    )
    two_seconds = round(2 * model.spec["fps"])
    latency = {
        name: round(
            median_seconds(lambda s=s: generate_long(model, style[:1], content[:1], two_seconds, s), repeats),
            3,
        )
        for name, s in (
            ("ddim10_s", Sampling("ddim", 10)),
            ("dpmpp10_s", Sampling("dpmpp", 10)),
            ("ddpm_s", Sampling()),
        )
    }
    return {
        "batch": batch_size,
        "ddim10_window_frames_per_s": round(batch_size * window / batch_s, 1),
        "dpmpp10_window_frames_per_s": round(batch_size * window / dpm_s, 1),
        "ddim10_long_frames_per_s": round(batch_size * LONG_FRAMES / long_s, 1),
        **{
            f"student_ddim{k}_window_frames_per_s": round(batch_size * window / k_s, 1)
            for k, k_s in zip(distilled, medians[3:], strict=True)
        },
        "step_s": round(batch_s / 10, 5),
        "dpmpp_step_s": round(dpm_s / 10, 5),
        "forward_s": round(forward_s, 5),
        "step_over_forward": round(batch_s / 10 / forward_s, 3),
        "dpmpp_step_over_forward": round(dpm_s / 10 / forward_s, 3),
        f"batch1_latency_{two_seconds}_frames": latency,
    }


def _seams(model, style: torch.Tensor, content: torch.Tensor, seed: int) -> dict:
    """Seams of long samples: the default overlap held only (blend 0), a third of the window with its
    cross-fade, and the default; with each sampler and a distilled student's step counts."""
    from walkdiff.styled.generation import Sampling, generate_long, resolve_windows

    window, seams = model.spec["window"], {}
    for overlap, blend in ((None, 0), (max(1, window // 3), None), (None, None)):
        overlap, blend = resolve_windows(window, overlap, blend)
        samplings = (
            ("ddpm", Sampling()),
            ("ddim10", Sampling("ddim", 10)),
            ("dpmpp10", Sampling("dpmpp", 10)),
            *((f"student_ddim{k}", Sampling("ddim", k)) for k in model.distilled_steps),
        )
        for name, sampling in samplings:
            generator = torch.Generator().manual_seed(seed)
            x = generate_long(model, style, content, LONG_FRAMES, sampling, generator, overlap, blend)
            seams[f"{name}_overlap{overlap}_blend{blend}"] = _seam_speeds(model, x, overlap, blend)
    return seams


def _transfer(bench: QualityBench, model, strength: float, seed: int, ground: bool, real: dict) -> dict:
    """Every walking test clip to every other style, noised to `strength`, DDPM from there; with the
    source's root path free and kept."""
    transfer = {"strength": strength, "real_test_style_acc": real["style_acc"]}
    for keep in (False, True):
        windows, source_style, errors = _transfer_windows(
            model, bench.datamodule, strength, keep, seed, ground
        )
        values = bench.scored(windows)
        embedded = bench.scorer.embed(windows)
        transfer["keep_trajectory" if keep else "free"] = {
            "windows": len(windows),
            "target_style_acc": values["style_acc"],
            "target_over_real": round(values["style_acc"] / real["style_acc"], 3),
            "still_source_style": round(
                float((embedded.style_logits.argmax(-1) == source_style).float().mean()), 4
            ),
            "content_acc_walk": values["content_acc"],
            "root_path_error_relative_mean": statistics.mean(errors),
            "root_path_error_relative_max": max(errors),
            "fmd": values["fmd"],
        }
    return transfer
