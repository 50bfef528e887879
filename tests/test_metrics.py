"""Known-answer tests of the evaluation metrics, including DDP-style state merging."""

from __future__ import annotations

import math
import statistics

import numpy as np
import pytest
import scipy.linalg
import torch
from torchmetrics.classification import MulticlassAccuracy, MulticlassConfusionMatrix

from walkdiff.common.errors import WalkdiffError
from walkdiff.metrics import (
    Diversity,
    FootSkating,
    FrechetMotionDistance,
    Jitter,
    Multimodality,
    format_summary,
    frechet_distance,
    summarize,
    summarize_runs,
)
from walkdiff.metrics.bootstrap import ClipStatistics, Reference, interval
from walkdiff.metrics.protocol import NON_NEGATIVE, PROPORTION


@pytest.fixture
def gen() -> torch.Generator:
    return torch.Generator().manual_seed(1234)


# --- Fréchet distance -------------------------------------------------------------------------------------


def test_frechet_distance_diagonal_closed_form(gen):
    mu1, mu2 = torch.randn(5, generator=gen), torch.randn(5, generator=gen)
    a, b = torch.rand(5, generator=gen) + 0.1, torch.rand(5, generator=gen) + 0.1
    # Commuting (diagonal) covariances: the trace term is sum (sqrt(a) - sqrt(b))^2.
    expected = (mu1 - mu2).square().sum() + (a.sqrt() - b.sqrt()).square().sum()
    got = frechet_distance(mu1, torch.diag(a), mu2, torch.diag(b))
    assert got.dtype == torch.float64
    assert got.item() == pytest.approx(expected.item(), rel=1e-6)


def test_frechet_distance_matches_matrix_square_root(gen):
    d = 6
    a, b = (
        torch.randn(d, d, generator=gen, dtype=torch.float64),
        torch.randn(d, d, generator=gen, dtype=torch.float64),
    )
    sigma1, sigma2 = a @ a.T + 0.1 * torch.eye(d), b @ b.T + 0.1 * torch.eye(d)
    mu1, mu2 = np.arange(d, dtype=float), np.ones(d)
    root = scipy.linalg.sqrtm(sigma1.numpy() @ sigma2.numpy()).real
    expected = np.sum((mu1 - mu2) ** 2) + np.trace(sigma1.numpy() + sigma2.numpy() - 2 * root)
    assert frechet_distance(mu1, sigma1, mu2, sigma2).item() == pytest.approx(expected, rel=1e-8)
    assert frechet_distance(mu1, sigma1, mu1, sigma1).item() == pytest.approx(0.0, abs=1e-8)


def test_frechet_distance_rejects_mismatched_shapes():
    with pytest.raises(WalkdiffError, match="means"):
        frechet_distance(torch.zeros(3), torch.eye(3), torch.zeros(4), torch.eye(4))


def test_fmd_identical_sets_is_zero(gen):
    feats = torch.randn(500, 16, generator=gen) * 3 + 1
    fmd = FrechetMotionDistance(num_features=16)
    fmd.update(feats, real=True)
    fmd.update(feats, real=False)
    assert abs(fmd.compute().item()) < 1e-3


def test_fmd_two_gaussians_closed_form(gen):
    # N(0, I) vs N(m, s^2 I): ||m||^2 + Tr(I + s^2 I - 2 s I) = ||m||^2 + D (1 - s)^2.
    d, n, s = 4, 40_000, 1.5
    m = torch.tensor([1.0, -0.5, 0.0, 2.0])
    expected = m.square().sum().item() + d * (1 - s) ** 2
    fmd = FrechetMotionDistance(num_features=d)
    for _ in range(4):  # several batches, as from a dataloader
        fmd.update(torch.randn(n // 4, d, generator=gen), real=True)
        fmd.update(m + s * torch.randn(n // 4, d, generator=gen), real=False)
    assert fmd.compute().item() == pytest.approx(expected, abs=0.05)


def test_fmd_keeps_real_statistics_when_asked(gen):
    real, fake = torch.randn(200, 3, generator=gen), torch.randn(200, 3, generator=gen) + 2
    fmd = FrechetMotionDistance(num_features=3, reset_real_features=False)
    fmd.update(real, real=True)
    fmd.update(fake, real=False)
    first = fmd.compute()
    fmd.reset()
    fmd.update(fake, real=False)
    assert torch.allclose(fmd.compute(), first)


def test_fmd_rejects_wrong_feature_size():
    with pytest.raises(WalkdiffError, match=r"\(B, 8\)"):
        FrechetMotionDistance(num_features=8).update(torch.zeros(4, 7), real=True)


# --- diversity and multimodality --------------------------------------------------------------------------


def test_diversity_of_simplex_vertices_is_edge_length():
    # Any two different vertices of a scaled simplex are 2.5 * sqrt(2) apart; pairs never repeat a sample.
    div = Diversity(num_pairs=300)
    div.update(2.5 * torch.eye(10))
    assert div.compute().item() == pytest.approx(2.5 * math.sqrt(2), rel=1e-12)


def test_diversity_converges_to_mean_pairwise_distance(gen):
    feats = torch.randn(30, 5, generator=gen, dtype=torch.float64)
    dist = torch.cdist(feats, feats)
    brute_force = dist.sum() / (30 * 29)  # mean over all pairs of different samples
    div = Diversity(num_pairs=20_000)
    div.update(feats)
    assert div.compute().item() == pytest.approx(brute_force.item(), rel=0.02)


def test_diversity_is_reproducible_and_seeded(gen):
    feats = torch.randn(50, 4, generator=gen)
    values = []
    for seed in (0, 0, 1):
        div = Diversity(seed=seed)
        div.update(feats)
        values.append(div.compute().item())
    assert values[0] == values[1]
    assert values[0] != values[2]


def test_diversity_needs_two_samples():
    div = Diversity()
    div.update(torch.zeros(1, 3))
    with pytest.raises(WalkdiffError, match="at least 2"):
        div.compute()


def test_multimodality_zero_for_identical_samples_per_class(gen):
    centers = torch.randn(4, 6, generator=gen)
    labels = torch.arange(4).repeat(5)
    mm = Multimodality()
    mm.update(centers[labels], labels)
    assert mm.compute().item() == pytest.approx(0.0, abs=1e-12)


def test_multimodality_mean_over_classes():
    # Class 0: two points 3 apart; class 1: two points 5 apart; class 2: one sample, no pair, left out.
    feats = torch.tensor([[0.0, 0.0], [3.0, 0.0], [10.0, 0.0], [10.0, 5.0], [50.0, 50.0]])
    labels = torch.tensor([0, 0, 1, 1, 2])
    mm = Multimodality(num_pairs=7)
    mm.update(feats, labels)
    assert mm.compute().item() == pytest.approx(4.0, rel=1e-12)


def test_multimodality_rejects_label_mismatch():
    with pytest.raises(WalkdiffError, match="labels"):
        Multimodality().update(torch.zeros(4, 2), torch.zeros(3))


def test_recognition_accuracy_recipe_from_the_package_docs(gen):
    logits, target = torch.randn(64, 5, generator=gen), torch.randint(5, (64,), generator=gen)
    acc = MulticlassAccuracy(num_classes=5, average="micro")
    acc.update(logits, target)
    assert acc.compute().item() == pytest.approx((logits.argmax(1) == target).float().mean().item())
    confusion = MulticlassConfusionMatrix(num_classes=5)
    confusion.update(logits, target)
    assert confusion.compute().diagonal().sum().item() == (logits.argmax(1) == target).sum().item()


# --- foot skating and jitter ------------------------------------------------------------------------------

FPS = 120.0


def _walker(frames: int, joints: int = 5) -> torch.Tensor:
    """Joint positions (1, F, J, 3) in float64 with the body moving forward."""
    t = torch.arange(frames, dtype=torch.float64) / FPS
    positions = torch.zeros(1, frames, joints, 3, dtype=torch.float64)
    positions[..., 2] = 1.3 * t[None, :, None]
    positions[..., 1] = torch.arange(joints, dtype=torch.float64)
    return positions


def test_foot_skating_zero_for_planted_foot():
    positions = _walker(40)
    positions[:, :, 3] = torch.tensor([0.2, 0.0, 0.7], dtype=torch.float64)  # planted foot
    skate = FootSkating(foot_joints=[3], fps=FPS, speed_threshold=0.1)
    skate.update(positions, torch.ones(1, 40, 1, dtype=torch.bool))
    out = skate.compute()
    assert out["skate_ratio"].item() == 0.0
    assert out["slide_speed"].item() == 0.0


def test_foot_skating_sliding_foot_at_constant_speed():
    frames, speed = 30, 0.8
    positions = _walker(frames)
    t = torch.arange(frames, dtype=torch.float64) / FPS
    # Horizontal slide along (3, 4)/5 at `speed`; the vertical bob must not count.
    positions[0, :, 4, 0] = 0.6 * speed * t
    positions[0, :, 4, 2] = 0.8 * speed * t
    positions[0, :, 4, 1] = 0.05 * torch.sin(40 * t)
    contacts = torch.ones(1, frames, 1)
    skate = FootSkating(foot_joints=[4], fps=FPS, speed_threshold=0.5)
    skate.update(positions, contacts)
    out = skate.compute()
    assert out["skate_ratio"].item() == 1.0
    assert out["slide_speed"].item() == pytest.approx(speed, rel=1e-9)
    # Below the threshold it is no longer skating, but the slide speed is still measured.
    slow = FootSkating(foot_joints=[4], fps=FPS, speed_threshold=1.0)
    slow.update(positions, contacts)
    assert slow.compute()["skate_ratio"].item() == 0.0
    assert slow.compute()["slide_speed"].item() == pytest.approx(speed, rel=1e-9)


def test_foot_skating_counts_only_contact_steps_of_each_foot():
    frames = 21
    positions = _walker(frames)  # joint 1 and 2 move forward at 1.3 units/s, like the body
    positions[:, :, 2] = 0.0  # foot on joint 2 planted
    contacts = torch.zeros(1, frames, 2)
    contacts[0, :11, 0] = 0.9  # foot on joint 1 labelled in contact over 10 steps, then in the air
    contacts[0, :, 1] = 1.0  # the planted foot is in contact over all 20 steps
    skate = FootSkating(foot_joints=[1, 2], fps=FPS, speed_threshold=1.0)
    skate.update(positions, contacts)
    out = skate.compute()
    assert out["skate_ratio"].item() == pytest.approx(10 / 30)
    assert out["slide_speed"].item() == pytest.approx(1.3 * 10 / 30, rel=1e-9)


def test_foot_skating_without_contact_is_nan_and_checks_shapes():
    skate = FootSkating(foot_joints=[1], fps=FPS, speed_threshold=1.0)
    skate.update(_walker(10), torch.zeros(1, 10, 1))
    assert math.isnan(skate.compute()["skate_ratio"].item())
    with pytest.raises(WalkdiffError, match="contacts"):
        skate.update(_walker(10), torch.zeros(1, 10, 2))
    with pytest.raises(WalkdiffError, match="foot joints"):
        FootSkating(foot_joints=[9], fps=FPS, speed_threshold=1.0).update(_walker(10), torch.zeros(1, 10, 1))


def test_jitter_zero_for_constant_velocity():
    jitter = Jitter(fps=FPS)
    jitter.update(_walker(50))
    assert jitter.compute().item() == pytest.approx(0.0, abs=1e-6)


def test_jitter_exact_for_cubic_trajectory(gen):
    # p(t) = c t^3 + b t^2 + v t + p0 has constant jerk 6 c, which the third finite difference gets exactly.
    frames, joints = 20, 3
    t = (torch.arange(frames, dtype=torch.float64) / FPS)[None, :, None, None]
    c, b, v, p0 = (torch.randn(1, 1, joints, 3, generator=gen, dtype=torch.float64) for _ in range(4))
    positions = c * t**3 + b * t**2 + v * t + p0
    jitter = Jitter(fps=FPS)
    jitter.update(positions.expand(2, -1, -1, -1))
    expected = (6 * c).norm(dim=-1).mean()
    assert jitter.compute().item() == pytest.approx(expected.item(), rel=1e-6)


def test_jitter_needs_four_frames():
    with pytest.raises(WalkdiffError, match="F >= 4"):
        Jitter(fps=FPS).update(_walker(3))


# --- DDP: states of two ranks merged equal one metric over everything -------------------------------------


def _ddp_cases(gen):
    feats = torch.randn(60, 4, generator=gen)
    labels = torch.randint(3, (60,), generator=gen)
    fake = feats * 1.5 + 0.3
    positions = torch.randn(6, 12, 5, 3, generator=gen, dtype=torch.float64).cumsum(1)
    contacts = torch.rand(6, 12, 2, generator=gen)
    return [
        (lambda: FrechetMotionDistance(4), lambda m, s: (m.update(feats[s], True), m.update(fake[s], False))),
        (lambda: Diversity(num_pairs=50), lambda m, s: m.update(feats[s])),
        (lambda: Multimodality(num_pairs=10), lambda m, s: m.update(feats[s], labels[s])),
        (
            lambda: FootSkating([1, 3], fps=30, speed_threshold=20.0),
            lambda m, s: m.update(positions[s], contacts[s]),
        ),
        (lambda: Jitter(fps=30), lambda m, s: m.update(positions[s])),
    ]


@pytest.mark.parametrize("case", range(5))
def test_merged_states_equal_one_metric_on_everything(gen, case):
    make, feed = _ddp_cases(gen)[case]
    size = 60 if case < 3 else 6
    whole, rank0, rank1 = make(), make(), make()
    feed(whole, slice(None))
    feed(rank0, slice(0, size // 2))
    feed(rank1, slice(size // 2, None))
    # merge_state puts the incoming state first: merging rank 0 into rank 1 keeps the rank order of a DDP
    # sync (that order decides which random pairs Diversity and Multimodality draw).
    rank1.merge_state(rank0)
    expected, got = whole.compute(), rank1.compute()
    if isinstance(expected, dict):
        expected, got = torch.stack(list(expected.values())), torch.stack(list(got.values()))
    assert torch.allclose(got.double(), expected.double(), rtol=1e-5, atol=1e-8)


# --- repeat aggregation -----------------------------------------------------------------------------------


def test_summarize_uses_population_std():
    values = [10.0, 12.0, 13.0, 17.0, 11.0]
    s = summarize(values)
    assert s["n"] == 5
    assert s["mean"] == pytest.approx(statistics.fmean(values))
    assert s["std"] == pytest.approx(statistics.pstdev(values))
    assert s["ci95"] == pytest.approx(1.96 * statistics.pstdev(values) / math.sqrt(5))


def test_summarize_runs_and_table_format():
    runs = [{"fmd": 1.0, "acc": 0.9}, {"fmd": 3.0, "acc": 0.8}]
    table = summarize_runs(runs)
    assert table["fmd"]["mean"] == pytest.approx(2.0)
    assert table["acc"]["std"] == pytest.approx(0.05)
    assert format_summary({"mean": 12.344, "ci95": 0.5551}) == "12.34 ± 0.56"
    assert format_summary(table["fmd"], decimals=3) == f"2.000 ± {1.96 / math.sqrt(2):.3f}"


def test_intervals_of_bounded_metrics_stay_in_their_range():
    # Two repeats of an accuracy: 0.95 ± 0.069 would reach 1.019; FMD 0.05 ± 0.069 would go below 0.
    table = summarize_runs(
        [{"style_acc": 1.0, "fmd": 0.0, "kid": 0.0}, {"style_acc": 0.9, "fmd": 0.1, "kid": 0.1}]
    )
    acc, fmd, kid = table["style_acc"], table["fmd"], table["kid"]
    assert acc["ci95"] == pytest.approx(1.96 * 0.05 / math.sqrt(2)) and acc["high"] == 1.0
    assert acc["low"] == pytest.approx(acc["mean"] - acc["ci95"]) and fmd["low"] == 0.0
    assert kid["low"] == pytest.approx(kid["mean"] - kid["ci95"])  # KID is unbiased: it may be < 0
    assert format_summary(acc, 3) == "0.950 [0.881, 1.000]"
    assert format_summary(kid, 3) == "0.050 ± 0.069"


def _clip_statistics(seed: int) -> ClipStatistics:
    """9 clips of 1 to 3 windows, about 90% of them recognised."""
    g = torch.Generator().manual_seed(seed)
    clip = torch.repeat_interleave(torch.arange(9), torch.randint(1, 4, (9,), generator=g))
    n = len(clip)
    zeros = torch.zeros(n)
    correct = {"style_acc": torch.rand(n, generator=g) < 0.9}
    reference = Reference.of(torch.randn(50, 4, generator=g).double())
    x = torch.randn(n, 4, generator=g).double()
    return ClipStatistics.of(
        x, clip, reference, correct, (zeros + 2, zeros + 1, zeros + 3), (zeros + 4, zeros + 2)
    )


def test_bootstrap_interval_of_an_accuracy_stays_in_0_1():
    """On few clips the bias-moved percentile range of an accuracy crossed 1 (0.889 [0.427, 1.027] in
    issue 33; 0.941 [0.791, 1.005] here with seed 0): a share gets the plain percentile range."""
    for seed in range(8):
        result = _clip_statistics(seed).bootstrap(200, seed=0)
        acc = result["style_acc"]
        assert 0 <= acc["low"] <= acc["value"] <= acc["high"] <= 1, (seed, acc)
        assert 0 <= result["skate_ratio"]["low"] <= result["skate_ratio"]["high"] <= 1
        assert result["fmd"]["low"] >= 0
    assert interval(np.array([0.8, 0.9, 1.0, 1.0]), 0.95, PROPORTION)[1] == 1.0
    low, high = interval(np.array([3.0, 4.0, 5.0]), 0.5, NON_NEGATIVE)  # moved down by the bias 3.5
    assert low == 0.0 and high == pytest.approx(1.45)


def test_summarize_rejects_empty_and_inconsistent_input():
    with pytest.raises(WalkdiffError, match="at least one"):
        summarize([])
    with pytest.raises(WalkdiffError, match="repetition 1"):
        summarize_runs([{"fmd": 1.0}, {"acc": 1.0}])
