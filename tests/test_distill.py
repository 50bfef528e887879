"""The distillation targets: what one DDIM step must predict to land where the teacher's ODE lands."""

from __future__ import annotations

import pytest
import torch

from walkdiff.diffusion import PREDICTIONS, GaussianDiffusion, extract, respace, run_steps, step_coefficients
from walkdiff.distill import ddim_targets, teacher_paths


def _diffusion(prediction: str) -> GaussianDiffusion:
    return GaussianDiffusion(100, "linear", 1e-3, 0.2, prediction=prediction)


@pytest.mark.parametrize("prediction", PREDICTIONS)
def test_an_exact_teacher_asks_the_student_for_the_data_itself(prediction):
    """For data that is always x0 the teacher's ODE is exact and one DDIM step with x0 lands on it."""
    diffusion = _diffusion(prediction)
    x0 = torch.randn(10, 6, 3, generator=torch.Generator().manual_seed(0))
    timesteps = respace(100, 10)
    step = torch.arange(10)  # every kept step, the last (to clean data) included

    def teacher(x_t, t, rows):
        eps = (x_t - extract(diffusion.sqrt_alphas_cumprod, t, x_t) * x0[rows]) / extract(
            diffusion.sqrt_one_minus_alphas_cumprod, t, x_t
        )
        return diffusion.training_target(x0[rows], eps, t)

    t = torch.tensor(timesteps)
    x_t = diffusion.q_sample(x0, t, torch.randn(x0.shape, generator=torch.Generator().manual_seed(1)))
    targets = ddim_targets(teacher, diffusion, x_t, step, timesteps, teacher_paths(diffusion, timesteps))
    torch.testing.assert_close(targets, x0, atol=1e-3, rtol=0)


def test_one_ddim_step_with_the_target_lands_on_the_teachers_solution():
    diffusion = _diffusion("x0")
    timesteps = respace(100, 10)
    paths = teacher_paths(diffusion, timesteps)
    assert [len(p.timesteps) for p in paths] == [11] * 9 and paths[0].timesteps[-1] == 89

    def net(x, t):  # any smooth network
        return 0.6 * x + torch.sin(t.float() / 20).view(-1, 1, 1)

    x_t = torch.randn(4, 5, 2, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    for k in (0, 4, 8):
        step = torch.full((4,), k)
        target = ddim_targets(lambda x, t, rows: net(x, t), diffusion, x_t, step, timesteps, paths)
        teacher_x_s = run_steps(net, diffusion, None, paths[k], x_T=x_t)
        one = step_coefficients(diffusion, timesteps[k : k + 2], 0.0)  # DDIM from t_k; its first step
        student_x_s = one.x_coef[0] * x_t + one.out_coef[0] * target  # the x0 network outputs the target
        torch.testing.assert_close(student_x_s, teacher_x_s, atol=1e-9, rtol=1e-9)
        # The target is not the teacher's own one-step estimate: that is DDIM's error being removed.
        assert not torch.allclose(target, net(x_t, torch.full((4,), timesteps[k])), atol=1e-3)


def test_the_preserved_share_is_held_to_the_teacher_without_a_jump():
    """Preserved rows (jump 0, any step) learn the teacher's own output; the others a DDIM target at a
    kept step, with the jump to the next kept step."""
    from walkdiff.distill import student_targets

    diffusion = _diffusion("eps")
    timesteps = respace(100, 10)
    paths = teacher_paths(diffusion, timesteps)

    def teacher(x, t, style, content):  # depends on every input, so misaligned rows would show
        return 0.5 * x + (t.float() / 100 + style + 10 * content).view(-1, 1, 1)

    n = 4000
    batch = {"features": torch.randn(n, 4, 2), "style": torch.arange(n) % 8, "content": torch.arange(n) % 3}
    torch.manual_seed(0)
    x_t, t, jump, target = student_targets(teacher, diffusion, batch, timesteps, paths, 0.25)
    held = jump == 0
    assert abs(held.float().mean().item() - 0.25) < 0.03
    assert len(set(t[held].tolist())) > 90  # every trained step, the kept ones too
    assert set(t[~held].tolist()) == set(timesteps)
    expected_jumps = {99: 11, 88: 11, 11: 11, 0: 1}
    assert all(jump[i].item() == expected_jumps.get(t[i].item(), 11) for i in torch.nonzero(~held)[:, 0])
    style, content = batch["style"], batch["content"]
    torch.testing.assert_close(target[held], teacher(x_t[held], t[held], style[held], content[held]))
    # The distilled rows ask for something else than the teacher's one-step output (but the last step).
    moved = ~held & (t > 0)
    one_step = teacher(x_t[moved], t[moved], style[moved], content[moved])
    assert (target[moved] - one_step).abs().amax(dim=(1, 2)).min() > 1e-4

    small = {k: v[:200] for k, v in batch.items()}
    assert (student_targets(teacher, diffusion, small, timesteps, paths, 0.0)[2] > 0).all()


def test_the_jump_embedding_starts_as_the_plain_denoiser_and_is_used_only_above_one():
    from walkdiff.diffusion import step_jumps
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
    assert jumps[99] == jumps[88] == jumps[11] == 11 and jumps[0] == 1
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

    from walkdiff import distill

    targets = distill.student_targets
    monkeypatch.setattr(distill, "student_targets", lambda *a: time.sleep(seconds) or targets(*a))


def test_the_same_command_gives_the_same_student_on_a_fast_and_a_slow_machine(
    teacher_ckpt, tmp_path, monkeypatch
):
    from walkdiff.distill import distill

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
    from walkdiff.cli import main

    _slowed(monkeypatch, 0.3)
    out = tmp_path / "student.ckpt"
    args = ["distill", "--ckpt", str(teacher_ckpt), "--out", str(out), "--steps", "4", "--iterations", "40"]
    assert main([*args, "--minutes", "0.01"]) == 0  # 0.6 s: two batches of 0.3 s
    printed = capsys.readouterr()
    assert f"distilling {teacher_ckpt} for DDIM-4: 40 batches (safety net: 0.01 min)" in printed.out
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
