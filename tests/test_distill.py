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
