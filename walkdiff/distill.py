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

One network serves both samplers: the student also takes the jump, how many trained steps a DDIM step
spans (MotionDenoiser's jump embedding, zero at the start), and gets it only when sampling with the DDIM
step count it was distilled for. A share of every batch (`preserve`) is drawn at any trained step with no
jump and the teacher's own output as target, which keeps the plain denoiser that DDPM, DPM-Solver++,
other DDIM step counts, transfer and --fix-feet use close to the teacher's. Without the jump and this
share the student's DDPM drifted (FMD 59 against the teacher's 68, README): distillation then moved the
same estimates DDPM relies on.

The student is saved as a checkpoint of the same model (with `distilled_steps` set and a `distilled`
record), so every command takes it.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import sys
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
    step_jumps,
)
from walkdiff.diffusion.samplers import ModelFn
from walkdiff.errors import WalkdiffError
from walkdiff.files import write_atomic
from walkdiff.progress import progress


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


def student_targets(
    teacher,
    diffusion: GaussianDiffusion,
    batch: dict,
    timesteps: list[int],
    paths: list[SamplerSteps],
    preserve: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(x_t, t, jump, target) of one training batch.

    Most rows: the window noised to a random kept step t_k, the jump t_k - t_k+1 of DDIM's step from
    there, and the output that step needs (ddim_targets, in the network's parameterisation). A `preserve`
    share of the rows: a random trained step, no jump (0) and the teacher's own output, which keeps the
    plain denoiser, the one DDPM and the other samplers use, the teacher's. teacher(x, t, style,
    content) is the teacher network."""
    x0 = batch["features"]
    step = torch.randint(0, len(timesteps), (x0.shape[0],))
    t = torch.tensor(timesteps)[step]
    jump = step_jumps(diffusion.num_timesteps, timesteps)[t]
    held = torch.rand(x0.shape[0]) < preserve
    t[held] = torch.randint(0, diffusion.num_timesteps, (int(held.sum()),))
    jump[held] = 0
    x_t = diffusion.q_sample(x0, t, torch.randn_like(x0))
    style, content = batch["style"], batch["content"]
    target = torch.empty_like(x0)
    if held.any():
        target[held] = teacher(x_t[held], t[held], style[held], content[held])
    rows = ~held
    if rows.any():
        s, c = style[rows], content[rows]
        x0_target = ddim_targets(
            lambda x, tt, r: teacher(x, tt, s[r], c[r]), diffusion, x_t[rows], step[rows], timesteps, paths
        )
        abar = extract(diffusion.alphas_cumprod, t[rows], x0_target)
        eps_target = (x_t[rows] - abar.sqrt() * x0_target) / (1 - abar).sqrt()
        target[rows] = diffusion.training_target(x0_target, eps_target, t[rows])
    return x_t, t, jump, target


def distill(
    ckpt: str,
    out: str,
    steps: int = 10,
    iterations: int = 1000,
    minutes: float | None = None,
    lr: float = 3e-5,
    seed: int = 0,
    overwrite: bool = False,
    preserve: float = 0.25,
) -> dict:
    """Train a DDIM-`steps` student of a StyledMotionDiffusion checkpoint for `iterations` batches and save
    it to `out`. The work is the bound, so the same command and seed give the same student on a fast and a
    slow machine; `minutes`, when given, is only a safety net, and a student it stopped says so (on the
    console and in its `distilled` record). `preserve`: the share of each batch held, without a jump, to
    the teacher's own output. Returns the run's record."""
    from walkdiff.data.datamodule import MotionDataModule
    from walkdiff.evaluation import data_settings
    from walkdiff.generation import load_generator

    out_path = Path(out)
    if out_path.exists() and not overwrite:
        raise WalkdiffError("would overwrite an existing checkpoint; pass --overwrite", path=out_path)
    if iterations < 1:
        raise WalkdiffError(f"--iterations: expected a number of batches >= 1, got {iterations}")
    if minutes is not None and not (math.isfinite(minutes) and minutes > 0):
        raise WalkdiffError(f"--minutes: expected a positive number of minutes (or none), got {minutes}")
    if not 0 <= preserve < 1:
        raise WalkdiffError(f"--preserve must be in [0, 1), got {preserve}")
    model = load_generator(ckpt)
    if model.hparams.get("distilled_steps", 0):
        raise WalkdiffError("already a distilled student; distil from the trained model", path=ckpt)
    diffusion = model.diffusion
    timesteps = respace(diffusion.num_timesteps, steps)
    paths = teacher_paths(diffusion, timesteps)
    checkpoint = torch.load(ckpt, map_location="cpu", weights_only=False)
    datamodule = MotionDataModule(**data_settings(checkpoint))
    datamodule.setup("fit")

    torch.manual_seed(seed)
    teacher = model.ema.module.eval().requires_grad_(False)
    # Dropout off: the student learns the teacher's deterministic map.
    student = copy.deepcopy(teacher)
    student.add_jump_conditioning()
    student.eval().requires_grad_(True)
    optimizer = torch.optim.Adam(student.parameters(), lr=lr)

    start, done, losses = time.perf_counter(), 0, []
    net = f" (safety net: {minutes:g} min)" if minutes is not None else ""
    print(f"distilling {ckpt} for DDIM-{steps}: {iterations} batches{net}", flush=True)
    with progress(total=iterations, desc="distilling", unit="batch") as bar:
        for batch in _endless(datamodule):
            with torch.no_grad():
                x_t, t, jump, target = student_targets(teacher, diffusion, batch, timesteps, paths, preserve)
            loss = (student(x_t, t, batch["style"], batch["content"], jump) - target).pow(2).mean()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(student.parameters(), 1.0)
            optimizer.step()
            losses.append(loss.item())
            done += 1
            bar.update(1)
            bar.set_postfix(loss=f"{sum(losses[-25:]) / len(losses[-25:]):.3g}", refresh=False)
            elapsed = time.perf_counter() - start
            if done >= iterations or (minutes is not None and elapsed >= minutes * 60):
                break
    if done < iterations:
        print(
            f"walkdiff: --minutes {minutes:g} stopped distillation after {done} of {iterations} batches: "
            "on a slower or busier machine the same command trains fewer; without --minutes it trains all",
            file=sys.stderr,
        )
    return _save(checkpoint, student, out_path, ckpt, steps, preserve, done, iterations, elapsed, losses)


def _endless(datamodule):
    """Training batches, epoch after epoch (each epoch shuffled anew from the seeded generator)."""
    while True:
        yield from datamodule.train_dataloader()


def _save(
    checkpoint, student, out_path, teacher_ckpt, steps, preserve, batches, planned, elapsed, losses
) -> dict:
    weights = student.state_dict()
    for name, value in weights.items():  # both copies, so sampling and any further training agree
        checkpoint["state_dict"][f"ema.module.{name}"] = value
        checkpoint["state_dict"][f"denoiser.{name}"] = value.clone()
    # The teacher's optimizer state does not belong to these weights.
    checkpoint["optimizer_states"], checkpoint["lr_schedulers"] = [], []
    checkpoint["hyper_parameters"]["distilled_steps"] = steps  # builds the jump embedding on loading
    record = {
        "teacher": str(teacher_ckpt),
        "sampler": "ddim",
        "steps": steps,
        "preserve": preserve,
        "batches": batches,
        "planned_batches": planned,
        "stopped_by_minutes": batches < planned,  # then the student depends on the machine's speed
        "minutes": round(elapsed / 60, 2),
        "final_loss": round(sum(losses[-25:]) / len(losses[-25:]), 6),
    }
    checkpoint["distilled"] = record
    write_atomic(out_path, lambda f: torch.save(checkpoint, f))
    print(f"wrote {out_path}: {record}")
    return record
