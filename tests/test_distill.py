"""The distillation targets: what one DDIM step must predict to land where the teacher's ODE lands."""

from __future__ import annotations

import pytest
import torch

from walkdiff.diffusion import (
    PREDICTIONS,
    GaussianDiffusion,
    ddim_sample,
    extract,
    respace,
    run_steps,
    step_coefficients,
    step_jumps,
)
from walkdiff.styled.distill import ddim_targets, student_steps


def _diffusion(prediction: str) -> GaussianDiffusion:
    return GaussianDiffusion(100, "linear", 1e-3, 0.2, prediction=prediction)


@pytest.mark.parametrize("prediction", PREDICTIONS)
@pytest.mark.parametrize("counts", [[10], [1, 2]])
def test_an_exact_teacher_asks_the_student_for_the_data_itself(prediction, counts):
    """For data that is always x0 the teacher's ODE is exact and one DDIM step with x0 lands on it."""
    diffusion = _diffusion(prediction)
    steps = student_steps(diffusion, counts)
    x0 = torch.randn(len(steps), 6, 3, generator=torch.Generator().manual_seed(0))
    index = torch.arange(len(steps))  # every student step, the last ones (to clean data) included

    def teacher(x_t, t, rows):
        eps = (x_t - extract(diffusion.sqrt_alphas_cumprod, t, x_t) * x0[rows]) / extract(
            diffusion.sqrt_one_minus_alphas_cumprod, t, x_t
        )
        return diffusion.training_target(x0[rows], eps, t)

    t = torch.tensor([step.t for step in steps])
    x_t = diffusion.q_sample(x0, t, torch.randn(x0.shape, generator=torch.Generator().manual_seed(1)))
    targets = ddim_targets(teacher, diffusion, x_t, index, steps)
    torch.testing.assert_close(targets, x0, atol=1e-3, rtol=0)


def test_the_student_steps_of_one_and_two_step_schedules():
    diffusion = _diffusion("x0")
    steps = student_steps(diffusion, [1, 2])
    assert [(s.t, s.s, s.jump) for s in steps] == [(99, -1, 100), (99, 49, 50), (49, -1, 50)]
    assert [len(s.path.timesteps) for s in steps] == [100, 50, 50]  # every trained step on the way
    coarse = student_steps(diffusion, [1, 2], solver_steps=20)
    assert len(coarse[0].path.timesteps) == 20 and coarse[1].path.timesteps[0] == 99
    assert all(49 < t <= 99 for t in coarse[1].path.timesteps) and coarse[2].path.timesteps[0] == 49
    # The sampler's jumps agree with the steps' (the network is told which schedule it is in).
    assert step_jumps(100, respace(100, 1))[99] == 100 and step_jumps(100, respace(100, 2))[49] == 50


@pytest.mark.parametrize("k", [0, 4, 9])
def test_one_ddim_step_with_the_target_lands_on_the_teachers_solution(k):
    diffusion = _diffusion("x0")
    timesteps = respace(100, 10)
    steps = student_steps(diffusion, [10])
    assert [len(s.path.timesteps) for s in steps] == [10] * 10 and steps[0].path.timesteps[-1] == 90

    def net(x, t):  # any smooth network
        return 0.6 * x + torch.sin(t.float() / 20).view(-1, 1, 1)

    x_t = torch.randn(4, 5, 2, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    index = torch.full((4,), k)
    target = ddim_targets(lambda x, t, rows: net(x, t), diffusion, x_t, index, steps)
    teacher_x_s = run_steps(net, diffusion, None, steps[k].path, x_T=x_t)
    one = step_coefficients(diffusion, timesteps[k : k + 2], 0.0)  # DDIM from t_k; its first step
    student_x_s = one.x_coef[0] * x_t + one.out_coef[0] * target  # the x0 network outputs the target
    torch.testing.assert_close(student_x_s, teacher_x_s, atol=1e-9, rtol=1e-9)
    # The target is not the teacher's own one-step estimate: that is DDIM's error being removed.
    assert not torch.allclose(target, net(x_t, torch.full((4,), timesteps[k])), atol=1e-3)


def test_every_row_asks_a_student_step_for_more_than_the_teachers_one_step_output():
    """Each row: a window noised to the start t of a student step, that step's jump, and the DDIM target
    of the teacher's solution (not the teacher's own one-step output)."""
    from walkdiff.styled.distill import student_targets

    diffusion = _diffusion("eps")
    steps = student_steps(diffusion, [1, 2], solver_steps=10)

    def teacher(x, t, style, content):  # depends on every input, so misaligned rows would show
        return 0.5 * x + (t.float() / 100 + style + 10 * content).view(-1, 1, 1)

    n = 600
    batch = {"features": torch.randn(n, 4, 2), "style": torch.arange(n) % 8, "content": torch.arange(n) % 3}
    torch.manual_seed(0)
    x_t, t, jump, target = student_targets(teacher, diffusion, batch, steps)
    assert set(zip(t.tolist(), jump.tolist(), strict=True)) == {(99, 100), (99, 50), (49, 50)}
    one_step = teacher(x_t, t, batch["style"], batch["content"])
    assert (target - one_step).abs().amax(dim=(1, 2)).min() > 1e-4
    # Row by row as a batch of one: no row's target depends on another's labels.
    for row in (0, 7, 599):
        style, content = batch["style"][row : row + 1], batch["content"][row : row + 1]
        index = next(i for i, s in enumerate(steps) if (s.t, s.jump) == (t[row].item(), jump[row].item()))
        alone = ddim_targets(
            lambda x, tt, r, style=style, content=content: teacher(x, tt, style[r], content[r]),
            diffusion, x_t[row : row + 1], torch.tensor([index]), steps,
        )  # fmt: skip
        abar = extract(diffusion.alphas_cumprod, t[row : row + 1], alone)
        eps = (x_t[row : row + 1] - abar.sqrt() * alone) / (1 - abar).sqrt()
        torch.testing.assert_close(
            target[row : row + 1], diffusion.training_target(alone, eps, t[row : row + 1])
        )


def test_the_jump_embedding_starts_as_the_plain_denoiser_and_is_used_only_above_one():
    from walkdiff.models.denoiser import MotionDenoiser

    torch.manual_seed(0)
    net = MotionDenoiser(6, 3, 2, d_model=16, layers=1, heads=2, dropout=0.0).eval()
    x, t = torch.randn(4, 5, 6), torch.tensor([99, 50, 11, 0])
    style, content = torch.tensor([0, 1, 2, 0]), torch.tensor([0, 1, 0, 1])
    plain = net(x, t, style, content)
    with pytest.raises(ValueError, match="not distilled"):
        net(x, t, style, content, torch.full((4,), 11))
    net.add_jump_conditioning()
    jump = torch.tensor([11, 11, 1, 0])
    torch.testing.assert_close(net(x, t, style, content, jump), plain)  # zero at the start
    torch.nn.init.normal_(net.jump_mlp[2].weight)
    jumped = net(x, t, style, content, jump)
    assert not torch.allclose(jumped[:2], plain[:2], atol=1e-3)  # jumps of 11 move the output
    torch.testing.assert_close(jumped[2:], plain[2:])  # 1 and 0: the plain denoiser

    jumps = step_jumps(100, respace(100, 10))
    assert jumps[99] == jumps[89] == jumps[9] == 10 and jumps[0] == 0
    assert int((jumps > 0).sum()) == 10 and jumps[50] == 0


@pytest.fixture(scope="module")
def teacher_ckpt(tmp_path_factory):
    """A tiny StyledMotionDiffusion checkpoint (barely trained: the student only has to be reproducible)."""
    import lightning as L
    import synthetic

    from walkdiff.data.datamodule import MotionDataModule
    from walkdiff.models.styled_ddpm import StyledMotionDiffusion

    root = tmp_path_factory.mktemp("teacher")
    synthetic.xia_like_folder(root, walk_clips=8, frames=240)
    dm = MotionDataModule(
        root=str(root), cache_dir=str(root / "cache"), batch_size=8, window=24, preprocess_workers=1
    )
    L.seed_everything(0)
    model = StyledMotionDiffusion(dm.spec, d_model=32, layers=1, heads=2, prediction="x0", lambda_adv=0.0)
    trainer = synthetic.quiet_trainer(max_epochs=1, limit_train_batches=2, limit_val_batches=0)
    trainer.fit(model, dm)
    path = root / "teacher.ckpt"
    trainer.save_checkpoint(path)
    return path


def _slowed(monkeypatch, seconds: float) -> None:
    """Every batch of distillation takes `seconds` longer, as on a slower or busier machine."""
    import time

    from walkdiff.styled import distill

    targets = distill.student_targets
    monkeypatch.setattr(distill, "student_targets", lambda *a: time.sleep(seconds) or targets(*a))


def test_the_same_command_gives_the_same_student_on_a_fast_and_a_slow_machine(
    teacher_ckpt, tmp_path, monkeypatch
):
    from walkdiff.styled.distill import distill

    fast = distill(str(teacher_ckpt), str(tmp_path / "fast.ckpt"), steps=4, iterations=5, minutes=30)
    _slowed(monkeypatch, 0.2)
    slow = distill(str(teacher_ckpt), str(tmp_path / "slow.ckpt"), steps=4, iterations=5, minutes=30)
    assert fast["batches"] == slow["batches"] == 5 and not fast["stopped_by_minutes"]
    assert slow["minutes"] > fast["minutes"]
    weights = [torch.load(tmp_path / f"{n}.ckpt", weights_only=False)["state_dict"] for n in ("fast", "slow")]
    torch.testing.assert_close(weights[0], weights[1], rtol=0, atol=0, equal_nan=True)  # bit for bit
    teacher = torch.load(teacher_ckpt, weights_only=False)["state_dict"]
    assert not torch.equal(weights[0]["ema.module.input.weight"], teacher["ema.module.input.weight"])


def test_minutes_is_a_safety_net_that_says_how_much_was_done(teacher_ckpt, tmp_path, monkeypatch, capsys):
    from walkdiff.cli.main import main

    _slowed(monkeypatch, 0.3)
    out = tmp_path / "student.ckpt"
    args = ["distill", "--ckpt", str(teacher_ckpt), "--out", str(out), "--steps", "4", "--iterations", "40"]
    assert main([*args, "--minutes", "0.01"]) == 0  # 0.6 s: two batches of 0.3 s
    printed = capsys.readouterr()
    said = "for DDIM-4 (teacher: DPM-Solver++ over 100 steps): 40 batches (safety net: 0.01 min)"
    assert f"distilling {teacher_ckpt} {said}" in printed.out
    record = torch.load(out, weights_only=False)["distilled"]
    assert record["stopped_by_minutes"] and 1 <= record["batches"] < 40 and record["planned_batches"] == 40
    message = f"--minutes 0.01 stopped distillation after {record['batches']} of 40 batches"
    assert message in printed.err
    for bad, said in (
        ("0", "--minutes: expected a finite number in (0, inf]"),
        ("nan", "--minutes: expected a finite number"),
    ):
        assert main([*args, "--minutes", bad, "--overwrite"]) == 1
        assert said in capsys.readouterr().err
    assert main([*args[:-1], "0", "--overwrite"]) == 1
    assert "--iterations: expected a whole number >= 1, got '0'" in capsys.readouterr().err


def test_the_acceleration_term_weighs_frame_to_frame_error_not_a_steady_offset():
    from walkdiff.styled.distill import distill_loss

    target = torch.randn(64, 24, 8, generator=torch.Generator().manual_seed(3))
    offset = target + 0.1  # the same error on every frame: no acceleration
    assert distill_loss(offset, target, 5.0).item() == pytest.approx(0.01, rel=1e-4)
    noisy = target + 0.1 * torch.randn(target.shape, generator=torch.Generator().manual_seed(4))
    plain = distill_loss(noisy, target).item()
    # White error e: its second difference has variance 6 var(e).
    assert distill_loss(noisy, target, 1.0).item() == pytest.approx(7 * plain, rel=0.05)


def test_a_students_window_around_held_frames_gets_one_harmonising_pass(teacher_ckpt, tmp_path, monkeypatch):
    """1-2 steps see held frames as noise: a continuation window is noised again to the 2-step schedule's
    last level and denoised once with them held (the student's own step there). Free windows and the
    trained model's samplers are left as they were."""
    from walkdiff.models.styled_ddpm import StyledMotionDiffusion
    from walkdiff.styled.distill import distill
    from walkdiff.styled.generation import load_generator

    out = tmp_path / "student.ckpt"
    distill(str(teacher_ckpt), str(out), steps=[1, 2], iterations=2, minutes=30)
    student, teacher = load_generator(out), load_generator(teacher_ckpt)
    calls = []
    harmonised = StyledMotionDiffusion.harmonised
    monkeypatch.setattr(
        StyledMotionDiffusion,
        "harmonised",
        lambda self, *a, **k: calls.append(1) or harmonised(self, *a, **k),
    )
    style, content = torch.tensor([0, 1]), torch.tensor([0, 0])
    known = torch.randn(2, 24, student.spec["feature_dim"])
    mask = torch.zeros_like(known)
    mask[:, :8] = 1.0
    for steps in (1, 2):
        calls.clear()
        x = student.generate(style, content, sampler="ddim", steps=steps, inpaint=(mask, known))
        assert calls == [1]
        torch.testing.assert_close(x[:, :8], known[:, :8], rtol=0, atol=0)  # held frames stay exact
        free = student.generate(style, content, sampler="ddim", steps=steps)
        assert calls == [1]
        assert not torch.allclose(x[:, 8:], free[:, 8:])
        # The same draws by hand: the student's DDIM around the held frames, then the pass, which moves
        # the new frames (the held ones stay).
        seeded = student.generate(
            style, content, sampler="ddim", steps=steps, inpaint=(mask, known),
            generator=torch.Generator().manual_seed(7),
        )  # fmt: skip
        assert calls == [1, 1]
        draws = torch.Generator().manual_seed(7)
        model_fn = student.model_fn(style, content, 1.0, student.jumps("ddim", steps, 0.0))
        shape = (2, 24, student.spec["feature_dim"])
        with torch.no_grad():
            before = ddim_sample(
                model_fn, student.diffusion, shape, steps, 0.0, generator=draws, inpaint=(mask, known)
            )
            after = harmonised(student, before, style, content, 1.0, (mask, known), draws)
        torch.testing.assert_close(seeded, after)
        assert not torch.allclose(after[:, 8:], before[:, 8:])
    for model, sampler, steps in ((student, "ddim", 10), (teacher, "ddim", 2), (student, "dpmpp", 2)):
        model.generate(style, content, sampler=sampler, steps=steps, inpaint=(mask, known))
    assert calls == [1, 1]  # none more than the last loop's two
