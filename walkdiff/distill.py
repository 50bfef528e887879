"""Few-step distillation: a student whose single DDIM steps go where the teacher's ODE goes in many.

DDIM over K respaced steps moves from a kept step t to the next one s with one first-order step of the
sampling ODE; at K = 10 that costs the trained model about 19% in FMD (README). Distillation (Salimans &
Ho 2022, progressive distillation, here in one stage since T = 100 is short) trains a copy of the network
so that one DDIM step from t lands where the teacher lands after solving the ODE from t to s finely,
with DPM-Solver++(2M) over every trained step in between. DDIM's step (eta 0) is

    x_s = sqrt(abar_s) x0 + rho (x_t - sqrt(abar_t) x0),   rho = sqrt((1 - abar_s) / (1 - abar_t)),

so the estimate the student must give is x0* = (x_s - rho x_t) / (sqrt(abar_s) - rho sqrt(abar_t)),
which it learns in its own parameterisation (x0, eps or v). The last step (to clean data) keeps the
teacher's estimate. The x_t are real training windows noised to t, the states sampling passes through.

The student is saved as a checkpoint of the same model, so every command takes it, with a `distilled`
record. It is made for `--sampler ddim --steps K`; other samplers run on it but it was not trained for
them.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from pathlib import Path

import torch

from walkdiff.diffusion import (
    GaussianDiffusion,
    SamplerSteps,
    extract,
    respace,
    run_steps,
    step_coefficients,
)
from walkdiff.diffusion.samplers import ModelFn
from walkdiff.errors import WalkdiffError
from walkdiff.files import write_atomic


def _first_steps(steps: SamplerSteps, n: int) -> SamplerSteps:
    return SamplerSteps(**{f.name: getattr(steps, f.name)[:n] for f in dataclasses.fields(steps)})


def teacher_paths(diffusion: GaussianDiffusion, timesteps: list[int]) -> list[SamplerSteps]:
    """For each step t_k -> t_k+1 of `timesteps` but the last: DPM-Solver++(2M) over every trained step
    from t_k down to t_k+1, stopping there (not going on to clean data)."""
    paths = []
    for t, s in zip(timesteps, timesteps[1:], strict=False):
        full = step_coefficients(diffusion, list(range(t, s - 1, -1)), 0.0, order=2)
        paths.append(_first_steps(full, t - s))
    return paths


def ddim_targets(
    teacher: ModelFn,
    diffusion: GaussianDiffusion,
    x_t: torch.Tensor,
    step: torch.Tensor,
    timesteps: list[int],
    paths: list[SamplerSteps],
) -> torch.Tensor:
    """The x0 estimates (B, ...) that make one DDIM step from x_t at timesteps[step] land on the teacher's
    solution at the next kept step. teacher(x, t, rows) is the teacher on the batch rows `rows`."""
    abar = diffusion.alphas_cumprod64().tolist()
    targets = torch.empty_like(x_t)
    for k in step.unique().tolist():
        rows = step == k
        t = timesteps[k]
        model_fn = lambda x, tt, rows=rows: teacher(x, tt, rows)  # noqa: E731
        if k == len(timesteps) - 1:  # the last step: DDIM returns the estimate itself
            x_last = x_t[rows]
            t_last = torch.full((len(x_last),), t, device=x_t.device)
            targets[rows] = diffusion.predict_x0(model_fn(x_last, t_last), x_last, t_last)
            continue
        x_s = run_steps(model_fn, diffusion, None, paths[k], x_T=x_t[rows])
        a_t, a_s = abar[t], abar[timesteps[k + 1]]
        rho = math.sqrt((1 - a_s) / (1 - a_t))
        targets[rows] = (x_s - rho * x_t[rows]) / (math.sqrt(a_s) - rho * math.sqrt(a_t))
    return targets


def distill(
    ckpt: str,
    out: str,
    steps: int = 10,
    minutes: float = 15.0,
    iterations: int | None = None,
    lr: float = 3e-5,
    seed: int = 0,
    overwrite: bool = False,
) -> dict:
    """Train a DDIM-`steps` student of a StyledMotionDiffusion checkpoint for `minutes` (or `iterations`
    batches, whichever ends first) and save it to `out`. Returns the run's record."""
    from walkdiff.data.datamodule import MotionDataModule
    from walkdiff.evaluation import data_settings
    from walkdiff.generation import load_generator

    out_path = Path(out)
    if out_path.exists() and not overwrite:
        raise WalkdiffError("would overwrite an existing checkpoint; pass --overwrite", path=out_path)
    if minutes <= 0 or (iterations is not None and iterations < 1):
        raise WalkdiffError(f"--minutes must be > 0 and --iterations >= 1, got {minutes} and {iterations}")
    model = load_generator(ckpt)
    diffusion = model.diffusion
    timesteps = respace(diffusion.num_timesteps, steps)
    paths = teacher_paths(diffusion, timesteps)
    checkpoint = torch.load(ckpt, map_location="cpu", weights_only=False)
    datamodule = MotionDataModule(**data_settings(checkpoint))
    datamodule.setup("fit")

    torch.manual_seed(seed)
    teacher = model.ema.module.eval().requires_grad_(False)
    # Dropout off: the student learns the teacher's deterministic map.
    student = copy.deepcopy(teacher).eval().requires_grad_(True)
    optimizer = torch.optim.Adam(student.parameters(), lr=lr)

    def teacher_on(batch: dict):
        return lambda x, t, rows: teacher(x, t, batch["style"][rows], batch["content"][rows])

    start, done, losses = time.perf_counter(), 0, []
    limit = f"{minutes:g} min" + (f" or {iterations} batches" if iterations else "")
    print(f"distilling {ckpt} for DDIM-{steps}: {limit}", flush=True)
    while True:
        for batch in datamodule.train_dataloader():
            x0 = batch["features"]
            step = torch.randint(0, steps, (x0.shape[0],))
            t = torch.tensor(timesteps)[step]
            noise = torch.randn_like(x0)
            x_t = diffusion.q_sample(x0, t, noise)
            with torch.no_grad():
                x0_target = ddim_targets(teacher_on(batch), diffusion, x_t, step, timesteps, paths)
                abar = extract(diffusion.alphas_cumprod, t, x0)
                eps_target = (x_t - abar.sqrt() * x0_target) / (1 - abar).sqrt()
                target = diffusion.training_target(x0_target, eps_target, t)
            loss = (student(x_t, t, batch["style"], batch["content"]) - target).pow(2).mean()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(student.parameters(), 1.0)
            optimizer.step()
            losses.append(loss.item())
            done += 1
            elapsed = time.perf_counter() - start
            if done % 25 == 0:
                recent = sum(losses[-25:]) / len(losses[-25:])
                print(f"  batch {done}, {elapsed / 60:.1f} min, loss {recent:.3g}", flush=True)
            if elapsed >= minutes * 60 or (iterations is not None and done >= iterations):
                return _save(checkpoint, student, out_path, ckpt, steps, done, elapsed, losses)


def _save(checkpoint, student, out_path, teacher_ckpt, steps, batches, elapsed, losses) -> dict:
    weights = student.state_dict()
    for name, value in weights.items():  # both copies, so sampling and any further training agree
        checkpoint["state_dict"][f"ema.module.{name}"] = value
        checkpoint["state_dict"][f"denoiser.{name}"] = value.clone()
    # The teacher's optimizer state does not belong to these weights.
    checkpoint["optimizer_states"], checkpoint["lr_schedulers"] = [], []
    record = {
        "teacher": str(teacher_ckpt),
        "sampler": "ddim",
        "steps": steps,
        "batches": batches,
        "minutes": round(elapsed / 60, 2),
        "final_loss": round(sum(losses[-25:]) / len(losses[-25:]), 6),
    }
    checkpoint["distilled"] = record
    write_atomic(out_path, lambda f: torch.save(checkpoint, f))
    print(f"wrote {out_path}: {record}")
    return record
