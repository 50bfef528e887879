"""Generated windows scored against a generator's real test windows, as `bench sample` and `bench distill`
compare samplers and step counts."""

from __future__ import annotations

import statistics
import time
from dataclasses import replace

import torch

from walkdiff.common.checkpoints import read_checkpoint


class QualityBench:
    """FMD and recognition of generated windows against the real test windows of a generator's data
    (evaluation.py's scorer), each setting from `seeds` seeds (the same seeds for every setting): one
    seed's FMD moves by a few units, as much as some of the differences measured."""

    keys = ("fmd", "style_acc", "content_acc", "diversity", "skate_ratio", "slide_speed", "jitter")

    def __init__(self, model, ckpt: str, evaluator: str, num: int, seed: int, seeds: int, ground: bool):
        from walkdiff.data.datamodule import MotionDataModule, data_settings
        from walkdiff.evaluation.scorer import MotionScorer, load_evaluator, window_set

        checkpoint = read_checkpoint(ckpt, "generator")
        self.datamodule = MotionDataModule(**data_settings(checkpoint))
        spec = model.spec
        self.scorer = MotionScorer(load_evaluator(evaluator), model.skeleton, spec["fps"])
        self.reference = self.scorer.embed(window_set(self.datamodule.split_features("test"), spec["window"]))
        self.scorer.set_reference(self.reference)
        self.num, self.seed, self.seeds, self.ground = num, seed, seeds, ground

    def scored(self, windows) -> dict:
        values = self.scorer.score(self.scorer.embed(windows), seed=self.seed)
        return {k: round(values[k], 4) for k in self.keys}

    def row(self, model, sampler: str, steps: int, eta: float):
        """(the setting's mean scores over the seeds, the first seed's windows and their scores)."""
        from walkdiff.evaluation.scorer import drawn_labels, generate_windows

        runs, elapsed, first = [], 0.0, None
        for s in range(self.seed, self.seed + self.seeds):
            start = time.perf_counter()
            labels = drawn_labels(self.reference, self.num, torch.Generator().manual_seed(s))
            windows = generate_windows(
                model, labels, torch.Generator().manual_seed(s), self.num, self.ground,
                sampler=sampler, steps=steps, eta=eta,
            )  # fmt: skip
            elapsed += time.perf_counter() - start
            first = windows if first is None else first
            runs.append(self.scored(windows))
        row = {"sampler": sampler, "steps": steps, "eta": eta}
        row |= {k: round(statistics.mean(r[k] for r in runs), 4) for k in self.keys}
        row |= {"fmd_per_seed": [r["fmd"] for r in runs], "seconds_per_seed": round(elapsed / self.seeds, 2)}
        print(f"{sampler}-{steps} eta {eta}: {row}", flush=True)
        return row, (first, runs[0])


def with_feet_fixed(model, windows):
    """The windows with `--fix-feet` applied to their raw features."""
    from walkdiff.motion.footfix import fix_feet_features

    raw = fix_feet_features(windows.raw.numpy(), model.profile, model.spec["fps"], model.floor_heights)
    return replace(windows, raw=torch.from_numpy(raw))


def with_ratios(row: dict, reference: dict) -> dict:
    """The row with its FMD and style accuracy over the reference row's (None where that is 0: a model
    that never gives the asked style has no ratio to it)."""
    return row | {
        f"{key}_over_ddpm": round(row[key] / reference[key], 3) if reference[key] else None
        for key in ("fmd", "style_acc")
    }
