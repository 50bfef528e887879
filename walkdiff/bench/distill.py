"""`walkdiff bench distill`: a distilled student's few-step samples against its teacher's."""

from __future__ import annotations

import torch

from walkdiff.bench.measure import machine, report
from walkdiff.bench.quality import QualityBench, with_feet_fixed, with_ratios
from walkdiff.common.checkpoints import read_checkpoint
from walkdiff.common.errors import WalkdiffError


def bench_distill(
    out: str,
    teacher: str,
    student: str,
    evaluator: str,
    num: int = 256,
    seed: int = 0,
    seeds: int = 3,
    ground: bool = True,
) -> dict:
    """A distilled student's DDIM samples against its teacher's DDPM-100, DDIM and DPM-Solver++.

    Writes OUT (JSON): the teacher's DDPM over all T steps (the reference of `fmd_over_ddpm`), DDIM and
    DPM-Solver++(2M) at each of the student's step counts; the student's DDIM at each of its counts (its
    other samplers are the teacher's, which it carries). Each the mean over `seeds` seeds (the same for
    all), scored on the teacher's real test windows. `bench sample` on the student adds its speed, seams
    and transfer.
    """
    from walkdiff.styled.generation import load_generator

    teacher_model, student_model = load_generator(teacher), load_generator(student)
    record = read_checkpoint(student, "student").get("distilled")
    if record is None:
        raise WalkdiffError("not a distilled checkpoint (made by `walkdiff distill`)", path=student)
    carried, given = student_model.teacher.state_dict(), teacher_model.ema.module.state_dict()
    if carried.keys() != given.keys() or any(not torch.equal(carried[k], v) for k, v in given.items()):
        raise WalkdiffError(
            f"--teacher {teacher}: the student was distilled from another teacher ({record['teacher']}), "
            "whose network it carries; pass that checkpoint",
            path=student,
        )
    counts = student_model.distilled_steps
    bench = QualityBench(teacher_model, teacher, evaluator, num, seed, seeds, ground)
    ddpm_steps = teacher_model.diffusion.num_timesteps
    settings = [("teacher", teacher_model, "ddpm", ddpm_steps)]
    settings += [("teacher", teacher_model, sampler, k) for k in counts for sampler in ("ddim", "dpmpp")]
    settings += [("student", student_model, "ddim", k) for k in counts]
    rows = []
    for who, model, sampler, k in settings:
        row, first_seed = bench.row(model, sampler, k, 1.0 if sampler == "ddpm" else 0.0)
        rows.append(with_ratios({"model": who} | row, rows[0] if rows else row))
        if (who, sampler, k) == ("student", "ddim", counts[0]):
            student_windows, student_scores = first_seed
    # --fix-feet on the samples the student is for (first seed), as `bench sample` does on DDPM's.
    fix_feet = {
        "before": student_scores,
        "after": bench.scored(with_feet_fixed(student_model, student_windows)),
    }
    result = {
        "benchmark": "distill",
        "teacher": teacher,
        "student": student,
        "distilled": record,
        "evaluator": evaluator,
        "num": num,
        "seed": seed,
        "seeds": seeds,
        "grounded": ground,
        "quality": rows,
        "student_ddim_fix_feet": fix_feet,
        "machine": machine(),
    }
    report(out, result)
    return result
