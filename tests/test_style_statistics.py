"""Example clips' pose statistics matched while sampling (`--match-clips`, models/style_statistics.py).

The arithmetic on made-up windows; on a tiny model of real Xia walks, that a sample matched to a clip's
statistics is nearer them than the code alone makes it, and what the commands record and refuse. Whether
that gives styles never seen in training is measured by `walkdiff bench style` (docs/evaluation.md)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import walkdiff
from walkdiff.cli.main import main
from walkdiff.diffusion.gaussian import GaussianDiffusion
from walkdiff.models.style_examples import clip_statistics, example_windows
from walkdiff.models.style_statistics import MAX_SCALE, RunningMatch, StyleStatistics, matched_channels
from walkdiff.motion.representation import FeatureLayout, encode
from walkdiff.styled import commands

FAST = dict(sampler="ddim", steps=4)
JOINTS = 3
DIM = FeatureLayout(JOINTS).dim


def windows(batch: int, seed: int, scale: float = 1.0, shift: float = 0.0) -> torch.Tensor:
    return torch.randn(batch, 24, DIM, generator=torch.Generator().manual_seed(seed)) * scale + shift


def test_only_the_pose_and_the_root_speed_and_height_are_matched():
    layout = FeatureLayout(JOINTS)
    mask = matched_channels(DIM)
    assert mask[layout.rotations].all() and mask[layout.root_vel].all() and mask[layout.root_height].all()
    assert not mask[layout.heading_vel].any() and not mask[layout.contacts].any()


def test_matching_moves_each_window_to_the_example_mean_and_spread_by_the_strength():
    example = StyleStatistics.of(windows(5, 0, scale=2.0, shift=1.5))
    x0 = windows(3, 1)
    matched = x0 + example.shift(x0)
    mask = matched_channels(DIM).bool()
    torch.testing.assert_close(matched.mean(1)[:, mask], example.mean[mask].expand(3, -1), atol=1e-5, rtol=0)
    spread = matched.std(1, correction=0)[:, mask]
    torch.testing.assert_close(spread, example.spread[mask].expand(3, -1), atol=1e-4, rtol=1e-4)
    assert torch.equal(matched[..., ~mask], x0[..., ~mask])  # turning and contacts as sampled
    half = StyleStatistics.mixed([(example, 1.0)], strength=0.5)
    torch.testing.assert_close(x0 + half.shift(x0), x0 + 0.5 * example.shift(x0))
    still = torch.zeros(1, 24, DIM)  # a constant channel is not blown up to the example's spread
    still[0, ::2] = 1e-4
    assert (x0[:1] * 0 + still + example.shift(still)).std(1).max() <= MAX_SCALE * 1e-4


def test_a_batch_matches_each_sample_to_its_own_example_and_mixes_weigh_variances():
    a, b = StyleStatistics.of(windows(4, 2, shift=-1.0)), StyleStatistics.of(windows(4, 3, scale=3.0))
    both = StyleStatistics.stack([a, b])
    x0 = windows(2, 4)
    shifted = x0 + both.shift(x0)
    torch.testing.assert_close(shifted[:1], x0[:1] + a.shift(x0[:1]))
    torch.testing.assert_close(shifted[1:], x0[1:] + b.shift(x0[1:]))
    assert torch.equal(both.rows(1, 2).mean, b.mean[None])
    mixed = StyleStatistics.mixed([(a, 1.0), (b, 3.0)], strength=1.0)
    torch.testing.assert_close(mixed.mean, 0.25 * a.mean + 0.75 * b.mean)
    torch.testing.assert_close(mixed.spread.square(), 0.25 * a.spread.square() + 0.75 * b.spread.square())


@pytest.mark.parametrize("prediction", ["eps", "x0", "v"])
def test_the_guided_output_is_the_network_own_kind_with_the_clean_estimate_moved(prediction):
    diffusion = GaussianDiffusion(20, "linear", 1e-3, 0.2, prediction)
    example = StyleStatistics.of(windows(4, 5, shift=0.7))
    network = lambda x, t: 0.3 * x + 0.1  # noqa: E731
    x, t = windows(2, 6), torch.tensor([3, 17])
    out = example.guide(network, diffusion)(x, t)
    x0 = diffusion.predict_x0(network(x, t), x, t)
    torch.testing.assert_close(diffusion.predict_x0(out, x, t), x0 + example.shift(x0), atol=1e-4, rtol=1e-4)


def test_a_sample_matched_to_a_clip_has_statistics_nearer_it_than_its_code_alone(
    xia_tiny, xia_dir, tmp_path, capsys
):
    """On real Xia: the clip's window statistics against those of samples at --match-clips 1, 0.5 and 0;
    the command records the strength and refuses one outside [0, 1]."""
    coded = walkdiff.load(xia_tiny["style_codes"])
    model = coded.model
    clip = str(xia_dir / "old_02_000.bvh")
    target = StyleStatistics.of(example_windows(model, coded.source(clip), clip))
    mask = matched_channels(model.spec["feature_dim"]).bool()

    def distance(match: float) -> float:
        take = coded.sample(
            style_clips=clip, num=2, frames=24, seed=1, match_clips=match, ground=False, **FAST
        )
        sampled = [model.normalizer.normalize(torch.from_numpy(coded_features(coded, t))) for t in take]
        got = StyleStatistics.of(torch.stack(sampled))
        return float((got.mean - target.mean)[mask].norm() + (got.spread - target.spread)[mask].norm())

    alone, half, full = distance(0.0), distance(0.5), distance(1.0)
    assert full < half < alone, (full, half, alone)
    manifest = commands.sample(xia_tiny["style_codes"], tmp_path / "m", style_clips=clip, num=1, frames=24,
                               gif=False, match_clips=0.5, **FAST)  # fmt: skip
    assert manifest["settings"]["match_clips"] == 0.5
    assert manifest["settings"]["fix_feet"] is True  # matching moves channels apart: feet pinned by default
    alone = commands.sample(xia_tiny["style_codes"], tmp_path / "a", style_clips=clip, num=1, frames=24,
                            gif=False, match_clips=0.0, **FAST)  # fmt: skip
    assert alone["settings"]["fix_feet"] is False
    asked = commands.sample(xia_tiny["style_codes"], tmp_path / "n", style_clips=clip, num=1, frames=24,
                            gif=False, fix_feet=False, **FAST)  # fmt: skip
    assert asked["settings"]["fix_feet"] is False
    argv = ["sample", "--ckpt", str(xia_tiny["style_codes"]), "--style-clip", clip, "--match-clips", "2",
            "--out", str(tmp_path / "bad")]  # fmt: skip
    assert main(argv) == 1
    assert "--match-clips: expected a finite number in [0, 1], got '2'" in capsys.readouterr().err
    with pytest.raises(walkdiff.WalkdiffError, match=r"^match_clips must be in \[0, 1\]"):
        coded.sample(style_clips=clip, match_clips=-0.5, **FAST)


def coded_features(generator, take) -> np.ndarray:
    """A sampled take's features as the model encodes clips (the statistics' own terms)."""
    return encode(generator.source(take), generator.model.profile)


def test_an_example_clip_of_each_seen_style_gives_that_style(xia_tiny, xia_dir):
    """On real Xia: windows sampled from a clip of each style the model has seen (neutral, old) are
    nearer, in pose statistics, to other clips of that style than to clips of the other style; the
    reference clips are not the examples."""
    coded = walkdiff.load(xia_tiny["style_codes"])
    model = coded.model
    pose = FeatureLayout(model.skeleton.num_joints).rotations

    def statistics_of(names: list[str]) -> StyleStatistics:
        clips = [str(xia_dir / n) for n in names]
        return StyleStatistics.mixed([(coded_statistics(coded, c), 1.0) for c in clips], 1.0)

    references = {s: statistics_of([f"{s}_{c:02d}_000.bvh" for c in (3, 5, 6)]) for s in ("neutral", "old")}
    for style, other in (("neutral", "old"), ("old", "neutral")):
        takes = coded.sample(
            style_clips=str(xia_dir / f"{style}_04_000.bvh"), num=4, frames=24, seed=5, **FAST
        )
        made = torch.stack(
            [model.normalizer.normalize(torch.from_numpy(coded_features(coded, t))) for t in takes]
        )
        mean = made.mean(dim=(0, 1))[pose]
        own, others = (float((mean - references[s].mean[pose]).norm()) for s in (style, other))
        assert own < others, (style, own, others)


def coded_statistics(generator, clip: str) -> StyleStatistics:
    return StyleStatistics.of(example_windows(generator.model, generator.source(clip), clip))


# ---------------------------------------------------------------- frame by frame: the path walker


def test_running_match_moves_frames_to_the_example_with_its_own_recent_frames():
    target = StyleStatistics.mixed([(StyleStatistics.of(windows(4, 7, scale=2.0, shift=1.0)), 1.0)], 1.0)
    diffusion = GaussianDiffusion(20, "linear", 1e-3, 0.2, "x0")
    running = RunningMatch(target, span=10, diffusion=diffusion, last_step=0)
    layout = FeatureLayout(JOINTS)
    frames = torch.randn(240, 2, DIM, generator=torch.Generator().manual_seed(8)) * 0.8  # within MAX_SCALE
    made = []
    for frame in frames:
        moved = running.guide(lambda x, t, f=frame: f)(torch.zeros(2, DIM), torch.zeros(2, dtype=torch.long))
        made.append(moved)
    made = torch.stack(made[20:])  # after the running statistics have settled
    pose = layout.rotations
    assert (made.mean(0)[:, pose] - target.mean[pose]).abs().mean() < 0.2
    spread = made.std(0, correction=0)[:, pose].mean()
    assert abs(spread / target.spread[pose].mean() - 1) < 0.25
    speed = layout.root_vel  # left to the path and the commanded pace
    assert torch.equal(made[:, :, speed], frames[20:, :, speed])


def test_walk_takes_an_example_clip_and_records_it(xia_tiny, xia_dir, zeggs_dir, tmp_path, capsys):
    """The tiny walker on real Xia: a walk with an example clip has the clip's pose statistics nearer
    than the label alone; the command records the clips, and refuses a clip on another skeleton, streaming
    or not."""
    follower = walkdiff.load(xia_tiny["walker"])
    clip = str(xia_dir / "old_02_000.bvh")
    target = clip_statistics(follower.model, clip)
    pose = FeatureLayout(follower.model.skeleton.num_joints).rotations
    options = dict(seed=2, sampler="ddim", steps=2)

    def distance(style_clips) -> float:
        take = follower.follow([[0, 0], [0, 3]], "neutral", style_clips=style_clips, **options)
        walked = follower.model.normalizer.normalize(
            torch.from_numpy(encode(follower.source(take), follower.model.profile))
        )
        return float((walked.mean(0) - target.mean)[pose].norm())

    assert distance(clip) < 0.5 * distance(None)
    path = tmp_path / "line.json"
    path.write_text('{"points": [[0, 0], [0, 2]]}')
    argv = ["walk", "--ckpt", str(xia_tiny["walker"]), "--style", "neutral", "--style-clip", f"{clip}:2",
            "--match-clips", "0.5", "--path", str(path), "--out", str(tmp_path / "out"), "--no-gif",
            "--sampler", "ddim", "--steps", "2"]  # fmt: skip
    assert main(argv) == 0
    manifest = json.loads(capsys.readouterr().out)
    assert manifest["style_clips"] == [{"clip": clip, "weight": 2.0}] and manifest["match_clips"] == 0.5
    with pytest.raises(walkdiff.WalkdiffError, match="another skeleton .* missing LHipJoint"):
        follower.follow([[0, 0], [0, 3]], "neutral", style_clips=str(zeggs_dir / "067_Speech_2_x_1_0.bvh"))
    wrong = ["--style-clip", str(zeggs_dir / "067_Speech_2_x_1_0.bvh")]  # refused before any point is read
    assert main(argv[:5] + wrong + ["--path", "-", "--out", str(tmp_path / "s"), "--stream"]) == 1
    assert "another skeleton" in capsys.readouterr().err
