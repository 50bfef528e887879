"""Few-step distillation: a student whose single DDIM steps go where the teacher's ODE goes in many.

DDIM over K respaced steps moves from a kept step t to the next one s with one first-order step of the
sampling ODE; at K = 10 that costs the trained model about 19% in FMD (README), and at K = 1 or 2 it gives
the blur of the posterior mean. Distillation (Salimans & Ho 2022, progressive distillation, here in one
stage since T = 100 is short; with the last step's target solved to the end, as in Luhman & Luhman 2021)
trains a copy of the network so that one DDIM step from t lands where the teacher lands after solving
the ODE from t to s finely, with DPM-Solver++(2M). DDIM's step (eta 0) is

    x_s = sqrt(abar_s) x0 + rho (x_t - sqrt(abar_t) x0),   rho = sqrt((1 - abar_s) / (1 - abar_t)),

so the estimate the student must give is x0* = (x_s - rho x_t) / (sqrt(abar_s) - rho sqrt(abar_t)),
which it learns in its own parameterisation (x0, eps or v). The last step goes to clean data (abar_s =
1, rho = 0): its target is the teacher's ODE solution itself, so a 1-step student maps noise to the
sample the teacher's ODE would give. The x_t are real training windows noised to t, the states sampling
passes through.

One network serves every distilled count: the student also takes the jump, how many trained steps a DDIM
step spans (MotionDenoiser's jump embedding, zero at the start), and gets it only when sampling with a
DDIM step count it was distilled for; several counts (1 and 2) share one student, told apart by their
jumps. Every other sampler (DDPM, DPM-Solver++, other DDIM counts, transfer, --fix-feet) needs the
teacher's plain denoiser, and the student checkpoint carries it, frozen: distillation moves the estimates
those samplers rely on. Holding a share of each batch to the teacher's output instead (as walkdiff did
until the 1- and 2-step students) kept the student's own DDPM near but not at the teacher's: FMD 230
against 150, and transfer recognised as the target style 57% of the time against 96% through the
carried teacher (README).

The student is saved as a checkpoint of the same model (with `distilled_steps` set, the teacher's
weights and a `distilled` record), so every command takes it.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from walkdiff.common.checkpoints import read_checkpoint
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_atomic
from walkdiff.common.progress import progress
from walkdiff.diffusion import (
    GaussianDiffusion,
    SamplerSteps,
    extract,
    log_snr_timesteps,
    respace,
    run_steps,
    step_coefficients,
)
from walkdiff.diffusion.samplers import ModelFn


def _first_steps(steps: SamplerSteps, n: int) -> SamplerSteps:
    return SamplerSteps(**{f.name: getattr(steps, f.name)[:n] for f in dataclasses.fields(steps)})


@dataclass(frozen=True)
class StudentStep:
    """One DDIM step of a student's schedule: from trained step t to trained step s, or to clean data
    (s = -1, the schedule's last step), and the teacher's solver path over the same span."""

    t: int
    s: int
    path: SamplerSteps

    @property
    def jump(self) -> int:  # what step_jumps gives the sampler at t
        return self.t - self.s


def student_steps(
    diffusion: GaussianDiffusion, step_counts: list[int], solver_steps: int | None = None
) -> list[StudentStep]:
    """Every DDIM step of the schedules of `step_counts` (respaced; a step shared by two schedules is
    listed for each), with the teacher's path: DPM-Solver++(2M) from t to the next kept step, stopping
    there, or from the last kept step all the way to clean data. The solver steps on the trained steps in
    between: every one (`solver_steps` None), or those of a `solver_steps`-step log-SNR grid over all of T,
    which makes a 1-step student's target cost `solver_steps` teacher passes instead of T."""
    total = diffusion.num_timesteps
    grid = set(range(total)) if solver_steps is None else set(log_snr_timesteps(diffusion, solver_steps))
    found = []
    for count in step_counts:
        timesteps = respace(total, count)
        for t, s in zip(timesteps, [*timesteps[1:], -1], strict=True):
            inner = sorted((g for g in grid if s < g < t), reverse=True)
            if s < 0:  # the solver's last step goes to clean data
                path = step_coefficients(diffusion, [t, *inner], 0.0, order=2)
            else:
                full = step_coefficients(diffusion, [t, *inner, s], 0.0, order=2)
                path = _first_steps(full, len(inner) + 1)
            found.append(StudentStep(t, s, path))
    return found


def ddim_targets(
    teacher: ModelFn,
    diffusion: GaussianDiffusion,
    x_t: torch.Tensor,
    index: torch.Tensor,
    steps: list[StudentStep],
) -> torch.Tensor:
    """The x0 estimates (B, ...) that make one DDIM step from x_t, steps[index] for each row, land on the
    teacher's solution at the step's end (for the last step, clean data: the estimate is the solution).
    teacher(x, t, rows) is the teacher on the batch rows `rows`."""
    abar = diffusion.alphas_cumprod64().tolist()
    targets = torch.empty_like(x_t)
    for k in index.unique().tolist():
        rows, step = index == k, steps[k]
        model_fn = lambda x, tt, rows=rows: teacher(x, tt, rows)  # noqa: E731
        x_s = run_steps(model_fn, diffusion, None, step.path, x_T=x_t[rows])
        a_t, a_s = abar[step.t], abar[step.s] if step.s >= 0 else 1.0
        rho = math.sqrt((1 - a_s) / (1 - a_t))
        targets[rows] = (x_s - rho * x_t[rows]) / (math.sqrt(a_s) - rho * math.sqrt(a_t))
    return targets


def student_targets(
    teacher,
    diffusion: GaussianDiffusion,
    batch: dict,
    steps: list[StudentStep],
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(x_t, t, jump, target) of one training batch: each window noised to the start t of a random student
    step, the step's jump, and the output that step needs (ddim_targets, in the network's
    parameterisation). teacher(x, t, style, content) is the teacher network."""
    x0 = batch["features"]
    index = torch.randint(0, len(steps), (x0.shape[0],))
    t = torch.tensor([step.t for step in steps])[index]
    jump = torch.tensor([step.jump for step in steps])[index]
    x_t = diffusion.q_sample(x0, t, torch.randn_like(x0))
    style, content = batch["style"], batch["content"]
    x0_target = ddim_targets(
        lambda x, tt, r: teacher(x, tt, style[r], content[r]), diffusion, x_t, index, steps
    )
    abar = extract(diffusion.alphas_cumprod, t, x0_target)
    eps_target = (x_t - abar.sqrt() * x0_target) / (1 - abar).sqrt()
    return x_t, t, jump, diffusion.training_target(x0_target, eps_target, t)


def distill_loss(out: torch.Tensor, target: torch.Tensor, lambda_accel: float = 0.0) -> torch.Tensor:
    """Squared error of the student's output (B, F, D), plus `lambda_accel` times that of its frame-to-frame
    acceleration (second differences over F). The plain error weighs every frequency alike, and what is
    left of it frame to frame shows as jitter (third differences): a few-step student's samples jittered
    10x more than the teacher's DDPM. For every parameterisation the x0 estimate is linear in the output
    at a given step, so the term is the x0 estimate's acceleration error up to a per-step scale."""
    error = out - target
    loss = error.pow(2).mean()
    if lambda_accel > 0:
        accel = error[:, 2:] - 2 * error[:, 1:-1] + error[:, :-2]
        loss = loss + lambda_accel * accel.pow(2).mean()
    return loss


def distill(
    ckpt: str,
    out: str,
    steps: list[int] | int = 10,
    iterations: int = 1000,
    minutes: float | None = None,
    lr: float = 3e-5,
    seed: int = 0,
    overwrite: bool = False,
    teacher_steps: int | None = None,
    lambda_accel: float = 0.0,
) -> dict:
    """Train a student of a StyledMotionDiffusion checkpoint for DDIM over each of `steps` (one count or
    several: one network, told apart by the jump) for `iterations` batches and save it to `out`.
    `teacher_steps`: the teacher's solver grid (student_steps; default every trained step). The work is
    the bound, so the same command and seed give the same student on a fast and a slow machine; `minutes`,
    when given, is only a safety net, and a student it stopped says so (on the console and in its
    `distilled` record). `lambda_accel`: the weight of the acceleration term (distill_loss). Returns the
    run's record."""
    from walkdiff.data.datamodule import MotionDataModule, data_settings
    from walkdiff.styled.generation import load_generator

    out_path = Path(out)
    if out_path.exists() and not overwrite:
        raise WalkdiffError("would overwrite an existing checkpoint; pass --overwrite", path=out_path)
    if iterations < 1:
        raise WalkdiffError(f"--iterations: expected a number of batches >= 1, got {iterations}")
    if minutes is not None and not (math.isfinite(minutes) and minutes > 0):
        raise WalkdiffError(f"--minutes: expected a positive number of minutes (or none), got {minutes}")
    if not (math.isfinite(lambda_accel) and lambda_accel >= 0):
        raise WalkdiffError(f"--lambda-accel must be a finite number >= 0, got {lambda_accel}")
    counts = sorted(set([steps] if isinstance(steps, int) else steps))
    model = load_generator(ckpt)
    if model.distilled_steps:
        raise WalkdiffError("already a distilled student; distil from the trained model", path=ckpt)
    diffusion = model.diffusion
    total = diffusion.num_timesteps
    if not counts or not all(1 <= k <= total for k in counts):
        raise WalkdiffError(f"--steps: expected DDIM step counts in [1, {total}], got {steps}")
    if teacher_steps is not None and not 1 <= teacher_steps <= total:
        raise WalkdiffError(f"--teacher-steps: expected a number in [1, {total}], got {teacher_steps}")
    plan = student_steps(diffusion, counts, teacher_steps)
    checkpoint = read_checkpoint(ckpt, "teacher", mmap=False)
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
    solver = f"DPM-Solver++ over {teacher_steps or total} steps"
    schedules = ", ".join(f"DDIM-{k}" for k in counts)
    print(f"distilling {ckpt} for {schedules} (teacher: {solver}): {iterations} batches{net}", flush=True)
    with progress(total=iterations, desc="distilling", unit="batch") as bar:
        for batch in _endless(datamodule):
            with torch.no_grad():
                x_t, t, jump, target = student_targets(teacher, diffusion, batch, plan)
            loss = distill_loss(student(x_t, t, batch["style"], batch["content"], jump), target, lambda_accel)
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
    settings = {
        "steps": counts,
        "teacher_steps": teacher_steps or total,
        "lambda_accel": lambda_accel,
    }
    return _save(checkpoint, teacher, student, out_path, ckpt, settings, done, iterations, elapsed, losses)


def _endless(datamodule):
    """Training batches, epoch after epoch (each epoch shuffled anew from the seeded generator)."""
    while True:
        yield from datamodule.train_dataloader()


def _save(
    checkpoint, teacher, student, out_path, teacher_ckpt, settings, batches, planned, elapsed, losses
) -> dict:
    state = checkpoint["state_dict"]
    # The student in both copies, so sampling and any further training agree.
    for name, value in student.state_dict().items():
        state[f"ema.module.{name}"] = value
        state[f"denoiser.{name}"] = value.clone()
    for name, value in teacher.state_dict().items():  # what the samplers it was not distilled for use
        state[f"teacher.{name}"] = value.clone()
    # The teacher's optimizer state does not belong to these weights.
    checkpoint["optimizer_states"], checkpoint["lr_schedulers"] = [], []
    checkpoint["hyper_parameters"]["distilled_steps"] = settings["steps"]  # builds the jump embedding
    record = {
        "teacher": str(teacher_ckpt),
        "sampler": "ddim",
        **settings,
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
