"""The diffusion core against closed forms and analytic oracles (no network involved)."""

from __future__ import annotations

import math

import pytest
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion import (
    GaussianDiffusion,
    beta_schedule,
    ddim_sample,
    ddpm_sample,
    dpm_solver_sample,
    extract,
    guided,
    guided_batched,
    log_snr_timesteps,
    respace,
    run_steps,
    step_coefficients,
)

PREDICTIONS = ("eps", "x0", "v")


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


# ---------------------------------------------------------------- schedules


def test_unknown_schedule_lists_valid_names():
    with pytest.raises(WalkdiffError, match="linear, cosine, quad"):
        beta_schedule("sigmoid", 10)


def test_bad_betas_and_prediction_raise():
    with pytest.raises(WalkdiffError, match="beta_start"):
        beta_schedule("linear", 10, beta_start=0.1, beta_end=1.5)
    with pytest.raises(WalkdiffError, match="eps, x0, v"):
        GaussianDiffusion(10, prediction="score")


def test_linear_and_quad_endpoints():
    linear = beta_schedule("linear", 100)
    assert linear[0].item() == pytest.approx(1e-4) and linear[-1].item() == pytest.approx(0.02)
    quad = beta_schedule("quad", 100, 1e-4, 0.1)
    assert quad.dtype == torch.float64 and quad.shape == (100,)
    assert quad[0].item() == pytest.approx(1e-4, rel=1e-12) and quad[-1].item() == pytest.approx(
        0.1, rel=1e-12
    )
    steps = quad.sqrt().diff()
    assert torch.allclose(steps, steps[0].expand_as(steps), rtol=1e-9)  # evenly spaced in sqrt(beta)


def test_cosine_alphas_cumprod_match_formula():
    T, s = 50, 0.008
    betas = beta_schedule("cosine", T)
    abar = torch.cumprod(1 - betas, 0)

    def f(t: float) -> float:
        return math.cos((t / T + s) / (1 + s) * math.pi / 2) ** 2

    expected = torch.tensor([f(t) / f(0) for t in range(1, T + 1)], dtype=torch.float64)
    # The last beta hits the 0.999 cap (abar_T = 0 exactly), every other abar follows the formula.
    assert torch.allclose(abar[:-1], expected[:-1], rtol=1e-10, atol=0)
    assert betas.max().item() == pytest.approx(0.999) and betas[:-1].max() < 0.999


# ---------------------------------------------------------------- forward process


def test_buffers_are_float32_and_in_state_dict():
    diff = GaussianDiffusion(20, "quad", 1e-4, 0.1)
    state = diff.state_dict()
    for name in (
        "alphas_cumprod",
        "posterior_variance",
        "posterior_log_variance_clipped",
        "posterior_mean_coef1",
    ):
        assert state[name].dtype == torch.float32 and state[name].shape == (20,)
    assert torch.isfinite(diff.posterior_log_variance_clipped).all()
    other = GaussianDiffusion(20, "linear")
    other.load_state_dict(state)
    assert torch.equal(other.alphas_cumprod, diff.alphas_cumprod)


def test_q_sample_marginal_moments():
    diff = GaussianDiffusion(100, "linear")
    t = torch.tensor([0, 40, 99])
    x0 = torch.tensor([1.5, -2.0, 0.7]).reshape(3, 1, 1).expand(3, 200, 250)
    x_t = diff.q_sample(x0, t, torch.randn(x0.shape, generator=_gen(0)))
    abar = beta_schedule("linear", 100).neg().add(1).cumprod(0)[t].float()
    flat = x_t.reshape(3, -1)
    torch.testing.assert_close(flat.mean(1), abar.sqrt() * x0[:, 0, 0], atol=0.01, rtol=0)
    torch.testing.assert_close(flat.var(1), 1 - abar, atol=0.01, rtol=0.02)


def test_posterior_matches_bayes_rule():
    diff = GaussianDiffusion(30, "cosine")
    betas = beta_schedule("cosine", 30)
    abar = torch.cumprod(1 - betas, 0)
    t = torch.tensor([1, 7, 15, 28])
    x0 = torch.randn(4, 2, 3, generator=_gen(1))
    x_t = torch.randn(4, 2, 3, generator=_gen(2))
    mean, var, logvar = diff.q_posterior(x0, x_t, t)

    # Bayes: q(x_{t-1} | x0) = N(sqrt(abar_{t-1}) x0, 1 - abar_{t-1}),
    # q(x_t | x_{t-1}) = N(sqrt(alpha_t) x_{t-1}, beta_t).
    a_prev, beta = abar[t - 1].view(4, 1, 1), betas[t].view(4, 1, 1)
    precision = 1 / (1 - a_prev) + (1 - beta) / beta
    exp_var = 1 / precision
    exp_mean = exp_var * (
        a_prev.sqrt() * x0.double() / (1 - a_prev) + (1 - beta).sqrt() * x_t.double() / beta
    )
    torch.testing.assert_close(mean.double(), exp_mean, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(var.double(), exp_var, rtol=1e-4, atol=0)
    # The stated closed form: beta_t (1 - abar_{t-1}) / (1 - abar_t), and its log.
    closed = betas[1:] * (1 - abar[:-1]) / (1 - abar[1:])
    torch.testing.assert_close(diff.posterior_variance[1:].double(), closed, rtol=1e-5, atol=0)
    torch.testing.assert_close(logvar.exp().double(), exp_var, rtol=1e-4, atol=0)
    assert diff.posterior_variance[0] == 0


@pytest.mark.parametrize("prediction", PREDICTIONS)
def test_predictions_invert_training_targets(prediction):
    diff = GaussianDiffusion(100, "quad", 1e-4, 0.1, prediction=prediction)
    x0 = torch.randn(6, 3, 4, 5, generator=_gen(3))
    noise = torch.randn(x0.shape, generator=_gen(4))
    t = torch.tensor([0, 1, 30, 50, 98, 99])
    x_t = diff.q_sample(x0, t, noise)
    target = diff.training_target(x0, noise, t)
    torch.testing.assert_close(diff.predict_x0(target, x_t, t), x0, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(diff.predict_eps(target, x_t, t), noise, atol=2e-3, rtol=1e-4)
    if prediction == "v":
        abar = diff.alphas_cumprod[t].view(6, 1, 1, 1)
        torch.testing.assert_close(target, abar.sqrt() * noise - (1 - abar).sqrt() * x0)


def test_sample_timesteps_range_and_repeatability():
    diff = GaussianDiffusion(10)
    t = diff.sample_timesteps(2000, _gen(5))
    assert t.dtype == torch.long and t.shape == (2000,)
    assert t.min() == 0 and t.max() == 9
    assert torch.equal(t, diff.sample_timesteps(2000, _gen(5)))
    assert extract(diff.betas, t[:4], torch.zeros(4, 2, 3)).shape == (4, 1, 1)


# ---------------------------------------------------------------- samplers


def _oracle(diff: GaussianDiffusion, x0: torch.Tensor):
    """The exact network output for data that is always x0: eps follows from x_t."""
    calls = []

    def model_fn(x_t, t):
        calls.append(t)
        eps = (x_t - extract(diff.sqrt_alphas_cumprod, t, x_t) * x0) / extract(
            diff.sqrt_one_minus_alphas_cumprod, t, x_t
        )
        return diff.training_target(x0, eps, t)

    return model_fn, calls


@pytest.mark.parametrize("prediction", PREDICTIONS)
@pytest.mark.parametrize("schedule", ["linear", "quad", "cosine"])
def test_oracle_recovers_x0(prediction, schedule):
    diff = GaussianDiffusion(100, schedule, 1e-4, 0.1 if schedule == "quad" else 0.02, prediction=prediction)
    x0 = torch.randn(3, 4, 5, generator=_gen(6)) * 2
    model_fn, calls = _oracle(diff, x0)
    out = ddpm_sample(model_fn, diff, x0.shape, generator=_gen(7))
    torch.testing.assert_close(out, x0, atol=1e-4, rtol=0)
    assert len(calls) == 100 and calls[0].tolist() == [99] * 3 and calls[-1].tolist() == [0] * 3
    for steps in (100, 10):
        for eta in (0.0, 1.0):
            calls.clear()
            out = ddim_sample(model_fn, diff, x0.shape, steps=steps, eta=eta, generator=_gen(8))
            torch.testing.assert_close(out, x0, atol=1e-4, rtol=0)
            assert len(calls) == steps and calls[0][0] == 99 and calls[-1][0] == 100 // steps - 1
        calls.clear()
        out = dpm_solver_sample(model_fn, diff, x0.shape, steps=steps)
        torch.testing.assert_close(out, x0, atol=1e-4, rtol=0)
        assert len(calls) == steps and calls[0][0] == 99 and calls[-1][0] == 0


def test_respace_is_even_and_trailing():
    """Steps of T / K from T - 1: the last step starts at T / K - 1, not at the nearly clean t = 0."""
    assert respace(100, 10) == [99, 89, 79, 69, 59, 49, 39, 29, 19, 9]
    assert respace(100, 2) == [99, 49]
    assert respace(100, 1) == [99]
    assert respace(5, 5) == [4, 3, 2, 1, 0]
    ts = respace(1000, 37)
    assert ts[0] == 999 and len(set(ts)) == 37 and ts == sorted(ts, reverse=True) and 26 <= ts[-1] <= 27
    with pytest.raises(WalkdiffError, match=r"\[1, 100\]"):
        respace(100, 101)
    with pytest.raises(WalkdiffError, match="eta"):
        step_coefficients(GaussianDiffusion(10), [9, 0], eta=-0.5)


@pytest.mark.parametrize("prediction", PREDICTIONS)
def test_ddpm_step_is_the_posterior(prediction):
    """The precomputed a x + b out + sigma z equals q(x_{t-1} | x_t, predict_x0(out))."""
    diff = GaussianDiffusion(50, "cosine", prediction=prediction)
    steps = step_coefficients(diff, range(49, -1, -1), eta=1.0)
    x_t = torch.randn(50, 7, generator=_gen(9))
    out = torch.randn(50, 7, generator=_gen(10))
    t = torch.tensor(steps.timesteps)
    mean, var, _ = diff.q_posterior(diff.predict_x0(out, x_t, t), x_t, t)
    a, b = torch.tensor(steps.x_coef).view(50, 1), torch.tensor(steps.out_coef).view(50, 1)
    # Skip t = 49 where 1 / sqrt(abar) ~ 1e3 amplifies float32 round-off in the reference.
    torch.testing.assert_close((a * x_t + b * out)[1:], mean[1:], rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(torch.tensor(steps.sigma).float() ** 2, var.flatten(), rtol=1e-4, atol=1e-9)


def test_ddim_full_eta1_equals_ddpm():
    diff = GaussianDiffusion(100, "linear")
    model_fn = lambda x, t: 0.3 * x + torch.sin(t.float() / 10).view(-1, 1, 1)  # noqa: E731
    a = ddpm_sample(model_fn, diff, (2, 3, 4), generator=_gen(11))
    b = ddim_sample(model_fn, diff, (2, 3, 4), steps=100, eta=1.0, generator=_gen(11))
    torch.testing.assert_close(a, b, atol=1e-4, rtol=1e-4)


def _gaussian_sampler_std(diff: GaussianDiffusion, timesteps: list[int], s: float, eta: float) -> float:
    """Closed-form std of a sampler's output for data N(mu, s^2) with the optimal denoiser.

    Every quantity is affine in x_t, so each step maps the Gaussian to a Gaussian: with
    v_t = abar_t s^2 + 1 - abar_t, x0_hat - mu = sqrt(abar_t) s^2 / v_t (x_t - m_t) and
    eps_hat = sqrt(1 - abar_t) / v_t (x_t - m_t); the step is x_prev = sqrt(abar_prev) x0_hat
    + sqrt(1 - abar_prev - sigma^2) eps_hat + sigma z (the DDPM posterior when eta = 1, all steps).
    """
    abar = torch.cumprod(1 - diff.betas.double(), 0).tolist()
    var = abar[timesteps[0]] * s**2 + 1 - abar[timesteps[0]]
    for i, t in enumerate(timesteps):
        a, a_prev = abar[t], abar[timesteps[i + 1]] if i + 1 < len(timesteps) else 1.0
        sigma2 = eta**2 * (1 - a_prev) / (1 - a) * (1 - a / a_prev)
        v_t = a * s**2 + 1 - a
        slope = (math.sqrt(a_prev * a) * s**2 + math.sqrt((1 - a_prev - sigma2) * (1 - a))) / v_t
        var = slope**2 * var + sigma2
    return math.sqrt(var)


@pytest.mark.parametrize("prediction", ["eps", "v"])
def test_gaussian_data_oracle(prediction):
    """For data N(mu, s^2) the optimal denoiser is analytic; check the samples' mean and std."""
    diff = GaussianDiffusion(
        100, "cosine", prediction=prediction
    )  # abar_T ~ 2e-7: the N(0, I) prior is exact
    mu, s = torch.tensor([1.5, -0.5]), torch.tensor([0.5, 2.0])

    def model_fn(x_t, t):
        abar = extract(diff.alphas_cumprod, t, x_t)
        var_t = abar * s**2 + 1 - abar  # marginal variance of x_t
        eps = (1 - abar).sqrt() * (x_t - abar.sqrt() * mu) / var_t
        x0 = mu + abar.sqrt() * s**2 * (x_t - abar.sqrt() * mu) / var_t
        return diff.training_target(x0, eps, t)

    n = 20000  # standard error of the std: about 0.5 %
    runs = {
        "ddpm": (ddpm_sample(model_fn, diff, (n, 2), generator=_gen(12)), list(range(99, -1, -1)), 1.0),
        "ddim10": (ddim_sample(model_fn, diff, (n, 2), steps=10, generator=_gen(13)), respace(100, 10), 0.0),
    }
    for name, (sample, timesteps, eta) in runs.items():
        torch.testing.assert_close(sample.mean(0), mu, atol=4 * s.max().item() / n**0.5, rtol=0, msg=name)
        expected = torch.tensor([_gaussian_sampler_std(diff, timesteps, sd, eta) for sd in s.tolist()])
        torch.testing.assert_close(sample.std(0), expected, rtol=0.02, atol=0, msg=name)
    # DDPM's fixed posterior variance makes it only slightly under-dispersed at T = 100 (about 3 %), while
    # DDIM with 10 steps shrinks the std by about 15 %: a discretisation error of the sampler, not a bug.
    torch.testing.assert_close(runs["ddpm"][0].std(0), s, rtol=0.05, atol=0)
    ddim10 = runs["ddim10"][0].std(0) / s
    assert ((ddim10 > 0.8) & (ddim10 < 0.9)).all()


def test_log_snr_timesteps_are_even_in_lambda_distinct_and_in_range():
    diff = GaussianDiffusion(100, "linear", 1e-3, 0.2, prediction="x0")
    assert log_snr_timesteps(diff, 10) == [99, 90, 79, 67, 52, 34, 17, 6, 2, 0]
    assert log_snr_timesteps(diff, 100) == list(range(99, -1, -1))
    assert log_snr_timesteps(diff, 6, first=59)[0] == 59 and log_snr_timesteps(diff, 1, first=0) == [0]
    ts = log_snr_timesteps(diff, 40)  # finer than the grid near t = 0: pushed apart, still 40 steps
    assert len(ts) == 40 and ts[0] == 99 and ts[-1] == 0 and all(a > b for a, b in zip(ts, ts[1:]))
    with pytest.raises(WalkdiffError, match=r"\[1, 100\]"):
        log_snr_timesteps(diff, 0)


def test_dpm_solver_is_second_order_on_gaussian_data():
    """DDIM (eta 0) and DPM-Solver++(2M) integrate the same ODE; for data N(0, s^2) and the optimal
    denoiser its solution takes x_T ~ N(0, v_T) to std s. Both are affine in x_T, so their std error
    is deterministic. 2M on its log-SNR steps: within 2% at 10 steps where DDIM is 26% off."""
    diff = GaussianDiffusion(100, "linear", 1e-3, 0.2, prediction="x0")
    s = 0.5
    abar_T = float(diff.alphas_cumprod[-1])
    x_T = torch.randn(4000, 1, generator=_gen(30)).double()
    x_T *= math.sqrt(abar_T * s**2 + 1 - abar_T) / x_T.std()  # exactly the marginal's std

    def model_fn(x_t, t):
        abar = extract(diff.alphas_cumprod, t, x_t).double()
        return abar.sqrt() * s**2 * x_t / (abar * s**2 + 1 - abar)  # E[x0 | x_t] for x0 ~ N(0, s^2)

    def error(out: torch.Tensor) -> float:
        return abs(float(out.std() / s) - 1)

    ddim = [error(ddim_sample(model_fn, diff, None, steps=k, x_T=x_T)) for k in (10, 20, 40)]
    dpm = [error(dpm_solver_sample(model_fn, diff, None, steps=k, x_T=x_T)) for k in (10, 20, 40)]
    assert 0.2 < ddim[0] < 0.3 and dpm[0] < 0.02, (ddim, dpm)
    # Four times the steps: DDIM's error falls ~4x (first order), 2M's by more (7x here; the trained
    # grid's coarse last steps keep it from the ideal 16x).
    assert 3 < ddim[0] / ddim[2] < 5 and dpm[0] / dpm[2] > 6, (ddim, dpm)
    # Same steps, order 1 against order 2: the extrapolation is what removes the error.
    steps = log_snr_timesteps(diff, 10)
    first = run_steps(model_fn, diff, None, step_coefficients(diff, steps, 0.0, order=1), x_T=x_T)
    assert error(first) > 5 * dpm[0]
    with pytest.raises(WalkdiffError, match="order must be 1, or 2 with eta 0"):
        step_coefficients(diff, steps, 0.5, order=2)


def test_inpainting_keeps_known_region_and_noises_it_per_step():
    diff = GaussianDiffusion(100, "linear")
    known = torch.randn(2, 4000, generator=_gen(14)) + 3
    mask = torch.zeros(2, 4000, dtype=torch.bool)
    mask[:, :2000] = True
    seen = {}

    def model_fn(x, t):
        seen[int(t[0])] = x.clone()
        return 0.5 * x

    out = ddpm_sample(model_fn, diff, known.shape, generator=_gen(15), inpaint=(mask, known))
    assert torch.equal(out[mask], known[mask])
    assert not torch.allclose(out[~mask], known[~mask], atol=0.5)
    for t in (90, 50, 5):
        abar = diff.alphas_cumprod[t]
        z = (seen[t][mask] - abar.sqrt() * known[mask]) / (1 - abar).sqrt()
        assert abs(z.mean().item()) < 0.05 and abs(z.std().item() - 1) < 0.05
    # DDIM noises the known region to its own (respaced) levels; a float mask broadcasts over the batch.
    seen.clear()
    out = ddim_sample(model_fn, diff, known.shape, steps=10, inpaint=(mask[0].float(), known))
    assert torch.equal(out[mask], known[mask]) and sorted(seen) == sorted(respace(100, 10))
    for t in (99, 59, 9):
        abar = diff.alphas_cumprod[t]
        z = (seen[t][mask] - abar.sqrt() * known[mask]) / (1 - abar).sqrt()
        assert abs(z.mean().item()) < 0.05 and abs(z.std().item() - 1) < 0.05

    # A soft mask m holds its elements only while t >= (1 - m) T: m = 0.5 for the noisier half of the steps.
    seen.clear()
    soft = torch.where(mask[0], 0.5, 0.0)
    out = ddpm_sample(model_fn, diff, known.shape, generator=_gen(16), inpaint=(soft, known))
    for t, kept in ((99, True), (50, True), (49, False), (5, False)):
        abar = diff.alphas_cumprod[t]
        z = (seen[t][mask] - abar.sqrt() * known[mask]) / (1 - abar).sqrt()
        assert (abs(z.mean().item()) < 0.05 and abs(z.std().item() - 1) < 0.05) == kept, t
    assert not torch.allclose(out[mask], known[mask], atol=0.5)  # not pasted back at the end


def test_guidance():
    cond = lambda x, t: x + 1.0  # noqa: E731
    uncond = lambda x, t: 2.0 * x  # noqa: E731
    x, t = torch.randn(3, 5, generator=_gen(16)), torch.tensor([4, 4, 4])
    assert torch.equal(guided(cond, uncond, 1.0)(x, t), cond(x, t))
    torch.testing.assert_close(guided(cond, uncond, 3.0)(x, t), 2 * x + 3 * (x + 1 - 2 * x))

    batches = []

    def pair(x2, t2):  # one forward pass: the first half conditional, the second unconditional
        batches.append(x2.shape[0])
        half = x2.shape[0] // 2
        return torch.cat([cond(x2[:half], t2[:half]), uncond(x2[half:], t2[half:])])

    for w in (1.0, 2.5):
        torch.testing.assert_close(guided_batched(pair, w)(x, t), guided(cond, uncond, w)(x, t))
    assert batches == [6, 6]
    diff = GaussianDiffusion(20)
    torch.testing.assert_close(
        ddim_sample(guided_batched(pair, 1.0), diff, (3, 5), steps=5, generator=_gen(17)),
        ddim_sample(cond, diff, (3, 5), steps=5, generator=_gen(17)),
    )


def test_generator_repeatability_and_progress():
    diff = GaussianDiffusion(30, "quad", 1e-4, 0.1)
    model_fn = lambda x, t: 0.1 * x  # noqa: E731
    a = ddpm_sample(model_fn, diff, (2, 6), generator=_gen(18))
    assert torch.equal(a, ddpm_sample(model_fn, diff, (2, 6), generator=_gen(18)))
    assert not torch.allclose(a, ddpm_sample(model_fn, diff, (2, 6), generator=_gen(19)))
    x_T = torch.randn(2, 6, generator=_gen(20))
    det = ddim_sample(model_fn, diff, None, steps=7, x_T=x_T)
    assert torch.equal(det, ddim_sample(model_fn, diff, (2, 6), steps=7, x_T=x_T))
    with pytest.raises(WalkdiffError, match="shape"):
        ddim_sample(model_fn, diff, (3, 6), steps=7, x_T=x_T)

    hook = []
    ddim_sample(model_fn, diff, (2, 6), steps=4, progress=lambda done, total: hook.append((done, total)))
    assert hook == [(1, 4), (2, 4), (3, 4), (4, 4)]
    ddim_sample(model_fn, diff, (2, 6), steps=3, progress=True)


@pytest.mark.parametrize("prediction", ["x0", "eps", "v"])
def test_min_snr_weights_cap_the_x0_error_weight_at_gamma(prediction):
    """Min-SNR-γ: the x0 error's effective weight is min(SNR, γ) (up to the normalising mean)."""
    diffusion = GaussianDiffusion(100, "linear", 1e-3, 0.2, prediction)
    t = torch.arange(100)
    weights = diffusion.min_snr_weights(t, 5.0).double()
    assert weights.mean().item() == pytest.approx(1.0, rel=1e-5)
    abar = diffusion.alphas_cumprod.double()
    snr = abar / (1 - abar)
    x0_factor = {"x0": torch.ones_like(snr), "eps": snr, "v": snr + 1}[prediction]
    effective = weights * x0_factor  # the weight of the x0 error the output error stands for
    expected = snr.clamp(max=5.0)
    assert torch.allclose(effective / effective[-1], expected / expected[-1], rtol=1e-4)
