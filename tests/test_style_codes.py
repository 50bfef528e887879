"""Style from example clips (issue 30): the style encoder's codes, how training picks the example a window
is conditioned on, `--style-clip` on the commands and in the API, and what is refused.

Mechanics on a tiny model of real Xia walks (conftest `xia_tiny`); whether example clips give their style
is measured on trained models by `walkdiff bench style` (docs/evaluation.md)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import walkdiff
from walkdiff.cli.main import main
from walkdiff.data.datamodule import MotionDataModule
from walkdiff.models.style_encoder import CodeStyle, StyleEncoder, reference_windows
from walkdiff.models.style_examples import example_windows
from walkdiff.models.style_labels import parse_timeline
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.rotations import euler_to_matrix
from walkdiff.motion.skeleton import Motion
from walkdiff.styled import commands

FAST = dict(sampler="ddim", steps=2)


@pytest.fixture(scope="module")
def coded(xia_tiny):
    return walkdiff.load(xia_tiny["style_codes"])


def code_of(model, clip) -> np.ndarray:
    ((code, _),) = model.examples([clip])[0]
    return code.numpy()


def moved_on_the_ground(motion: Motion, degrees: float, shift: float) -> Motion:
    """The clip turned about the up axis and moved along the ground (the file's own axes)."""
    turn = SkeletonProfile.detect(motion).turn  # canonical = turn @ file; canonical up is +Y
    about_up = turn.T @ euler_to_matrix(np.array([degrees]), "Y") @ turn
    rotations, positions = motion.rotations.copy(), motion.positions.copy()
    rotations[:, 0] = about_up @ rotations[:, 0]
    positions[:, 0] = positions[:, 0] @ about_up.T + turn.T @ np.array([shift, 0.0, -shift])
    return Motion(motion.skeleton, rotations, positions, motion.frame_time)


def test_a_code_does_not_change_when_the_clip_moves_or_turns_on_the_ground(coded, xia_dir):
    clip = read_bvh(xia_dir / "old_02_000.bvh")
    code = code_of(coded, clip)
    assert np.linalg.norm(code) == pytest.approx(1.0, abs=1e-5)
    for degrees, shift in ((90.0, 0.0), (-137.0, 40.0), (0.0, -300.0)):
        np.testing.assert_allclose(code_of(coded, moved_on_the_ground(clip, degrees, shift)), code, atol=1e-4)


def test_crops_of_one_clip_are_closer_than_clips_of_other_styles(coded, xia_dir):
    """The codes of one clip's windows spread less than the codes of neutral against old clips."""
    model = coded.model

    def window_codes(name: str) -> np.ndarray:
        motion = coded.source(xia_dir / name)
        windows = example_windows(model, motion, name)
        return np.stack([model.style_code(w[None]).numpy() for w in windows])

    within = []
    for name in ("neutral_01_000.bvh", "old_01_000.bvh", "neutral_03_000.bvh", "old_03_000.bvh"):
        codes = window_codes(name)
        within.append(np.linalg.norm(codes - codes.mean(0), axis=1).mean())
    neutral = [code_of(coded, xia_dir / f"neutral_{c:02d}_000.bvh") for c in (1, 2, 3, 5)]
    old = [code_of(coded, xia_dir / f"old_{c:02d}_000.bvh") for c in (1, 2, 3, 5)]
    across = np.mean([np.linalg.norm(a - b) for a in neutral for b in old])
    assert max(within) < across, (within, across)


def test_training_conditions_each_window_on_another_clip_of_its_style():
    torch.manual_seed(0)
    features = torch.randn(6, 24, 5)
    styles = torch.tensor([0, 0, 1, 1, 0, 2])
    clips = ["a", "a#mirror", "b", "c", "d", "e"]
    crops, source = reference_windows(features, styles, clips, min_share=0.5)
    assert 12 <= crops.shape[1] <= 24 and crops.shape[0] == 6
    assert source[0].item() == 4 and source[1].item() == 4  # not the clip itself, nor its mirror
    assert {source[2].item(), source[3].item()} == {3, 2}
    assert source[5].item() == 5  # nothing else of style 2: its own window
    assert (styles[source] == styles).all()


def test_labels_are_the_stored_codes_and_guidance_uses_the_zero_code():
    style = CodeStyle(num_styles=3, code_dim=4, dim=8)
    codes = torch.nn.functional.normalize(torch.randn(3, 4), dim=-1)
    style.update_codes(codes, torch.tensor([0, 1, 2]))
    np.testing.assert_allclose(style.as_codes(torch.tensor([1])).numpy(), codes[1:2].numpy(), atol=1e-6)
    assert not style.as_codes(torch.tensor([style.null_id])).any()
    mixed = style.as_codes(torch.tensor([[0.5, 0.5, 0.0]]))
    assert mixed.norm().item() == pytest.approx(1.0, abs=1e-5)
    assert not style.drop(codes, 1.0).any()
    with pytest.raises(walkdiff.WalkdiffError, match="style_code_dim: 3 equals the number of styles"):
        CodeStyle(num_styles=3, code_dim=3, dim=8)
    encoder = StyleEncoder(feature_dim=5, code_dim=4)
    assert encoder(torch.randn(2, 12, 5)).norm(dim=-1).allclose(torch.ones(2))


def test_style_clip_on_sample_and_transfer_records_the_clips_and_is_the_api(
    coded, xia_tiny, xia_dir, tmp_path
):
    examples = f"{xia_dir / 'old_02_000.bvh'}:2,{xia_dir / 'old_05_000.bvh'}"
    out = tmp_path / "sampled"
    manifest = commands.sample(xia_tiny["style_codes"], out, style="neutral", style_clips=examples, num=2,
                               frames=40, seed=3, gif=False, guidance=2.0, **FAST)  # fmt: skip
    recorded = manifest["settings"]["style_clips"]
    assert [r["weight"] for r in recorded] == [2.0, 1.0] and len(recorded[0]["code"]) == 16
    assert manifest["files"][0].startswith("neutral+clip-old_02_000+clip-old_05_000_walk_")
    takes = coded.sample("neutral", num=2, frames=40, seed=3, guidance=2.0, style_clips=examples, **FAST)
    for name, take in zip(manifest["files"], takes, strict=True):
        assert take.to_bvh(tmp_path / name).read_text() == (out / name).read_text()
    source = str(xia_dir / "neutral_01_000.bvh")
    argv = ["transfer", "--ckpt", str(xia_tiny["style_codes"]), "--input", source,
            "--style-clip", str(xia_dir / "old_02_000.bvh"), "--out", str(tmp_path / "t"), "--no-gif",
            "--sampler", "ddim", "--steps", "2"]  # fmt: skip
    assert main(argv) == 0
    report = json.loads((tmp_path / "t" / "neutral_01_000_to_clip-old_02_000.json").read_text())
    assert report["settings"]["style_clips"][0]["clip"].endswith("old_02_000.bvh")


def test_what_style_clips_refuse(coded, xia_tiny, xia_dir, zeggs_dir, capsys):
    short = read_bvh(xia_dir / "old_02_000.bvh")
    short = short.slice(0, int(short.fps * 0.5))  # 0.5 s: 15 frames at the model's 30 fps, window 24
    with pytest.raises(walkdiff.WalkdiffError, match="needs at least one 24-frame window"):
        coded.sample(style_clips=[short], **FAST)
    with pytest.raises(walkdiff.WalkdiffError, match="another skeleton .* missing LHipJoint"):
        coded.sample(style_clips=str(zeggs_dir / "067_Speech_2_x_1_0.bvh"), **FAST)
    with pytest.raises(walkdiff.WalkdiffError, match="no style given"):
        coded.sample(**FAST)
    # The example as written: example clips as (clip, weight) pairs, a Motion among them
    walk = read_bvh(xia_dir / "neutral_01_000.bvh")
    restyled = coded.transfer(walk, style_clips=[(read_bvh(xia_dir / "old_02_000.bvh"), 0.5)], **FAST)
    assert restyled.settings["style_clips"][0]["weight"] == 0.5 and restyled.take.num_frames > 0
    with pytest.raises(walkdiff.WalkdiffError, match="^style proud: this model has no code for it"):
        coded.sample("proud", **FAST)
    with pytest.raises(walkdiff.WalkdiffError, match="weights > 0"):
        coded.sample(style_clips=f"{xia_dir / 'old_02_000.bvh'}:-1", **FAST)
    labels_only = walkdiff.load(xia_tiny["generator"])
    with pytest.raises(walkdiff.WalkdiffError, match="takes style labels only"):
        labels_only.sample(style_clips=str(xia_dir / "old_02_000.bvh"), **FAST)


def test_left_out_styles_are_out_of_training_and_validation_only(xia_dir):
    data = MotionDataModule(root=str(xia_dir.parent), leave_out_styles=["angry", "proud"])
    for split in ("train", "val"):
        assert not {data.source.styles[c.style] for c in data.splits[split]} & {"angry", "proud"}
    assert {"angry", "proud"} <= {data.source.styles[c.style] for c in data.splits["test"]}
    with pytest.raises(walkdiff.WalkdiffError, match="leave_out_styles: unknown style happy"):
        MotionDataModule(root=str(xia_dir.parent), leave_out_styles=["happy"])


# ---------------------------------------------------------------- style over time


def test_a_timeline_ramps_the_weights_over_the_transition(xia_tiny):
    model = walkdiff.load(xia_tiny["generator"]).model
    timeline = parse_timeline(model, "neutral@0,old@2s,neutral:0.5+old:0.5@4", transition=1.0)
    neutral, old = (model.spec["styles"].index(s) for s in ("neutral", "old"))
    assert timeline.times == (0.0, 2.0, 4.0) and timeline.label == "timeline-neutral-old-neutral0.5_old0.5"
    eased = 0.75 * 0.75 * (3 - 2 * 0.75)  # smoothstep three quarters of the way through the ramp
    for seconds, expected_old in ((0.0, 0.0), (1.5, 0.0), (2.0, 0.5), (2.25, eased), (2.5, 1.0), (4.5, 0.5)):
        weights = timeline.at(seconds)
        assert weights[old].item() == pytest.approx(expected_old)
        assert weights.sum().item() == pytest.approx(1.0) and weights[neutral].item() == pytest.approx(
            1 - expected_old
        )
    assert parse_timeline(model, "neutral@0,old@0.5s", transition=3.0).transition == 0.5  # keys' spacing
    assert parse_timeline(model, "neutral,old") is None
    for bad, message in (
        ("neutral@1,old@2", "first key must be at 0"),
        ("neutral@0,old@2,angry@1", "times rising from 0"),
        ("neutral@0,old@soon", "times rising from 0"),
        ("neutral@0,happy@2", "unknown style happy"),
    ):
        with pytest.raises(walkdiff.WalkdiffError, match=message):
            parse_timeline(model, bad)


def test_each_window_is_denoised_under_the_timeline_at_its_middle(xia_tiny, tmp_path):
    """Before the first transition the clip is the plain style's, frame for frame; after it, it is not;
    the command writes the timeline's plot and records it, and the API makes the same clip."""
    generator = walkdiff.load(xia_tiny["generator"])
    options = dict(num=1, frames=72, seed=4, sampler="ddim", steps=3, ground=False)  # grounding: whole clip
    plain = generator.sample("neutral", **options)[0].positions
    timed = generator.sample("neutral@0,old@1.6s", transition=0.4, **options)[0].positions
    np.testing.assert_allclose(timed[:24], plain[:24], atol=1e-4)  # windows 0-23 and 12-35 centre < 1.4 s
    assert np.abs(timed[48:] - plain[48:]).max() > 1e-3
    out = tmp_path / "timeline"
    manifest = commands.sample(xia_tiny["generator"], out, "neutral@0,old@1.6s", transition=0.4, gif=False,
                               **options)  # fmt: skip
    assert manifest["settings"]["timeline"]["keys"][1] == {"at_s": 1.6, "style": "old"}
    assert (out / "timeline-neutral-old_walk_timeline.png").stat().st_size > 0
    take = generator.sample("neutral@0,old@1.6s", transition=0.4, **options)[0]
    assert take.to_bvh(tmp_path / "api.bvh").read_text() == (out / manifest["files"][0]).read_text()
    with pytest.raises(walkdiff.WalkdiffError, match="starts after the clip ends"):
        generator.sample("neutral@0,old@3s", **options)
    with pytest.raises(walkdiff.WalkdiffError, match="a timeline .* is for sample"):
        generator.transfer(walkdiff.read_bvh(out / manifest["files"][0]), "neutral@0,old@1s", **FAST)


def test_the_path_walker_follows_a_timeline_frame_by_frame(xia_tiny, tmp_path, capsys):
    follower = walkdiff.load(xia_tiny["walker"])
    points, options = [[0, 0], [3, 0]], dict(speed=1.2, seed=2, sampler="ddim", steps=2)
    plain = follower.follow(points, "neutral", **options).positions
    timed = follower.follow(points, "neutral@0,old@1s", transition=0.5, **options).positions
    assert timed.shape == plain.shape
    np.testing.assert_allclose(timed[:22], plain[:22], atol=1e-5)  # before 0.75 s: neutral alone
    assert np.abs(timed[40:] - plain[40:]).max() > 1e-3
    path = tmp_path / "line.json"
    path.write_text(json.dumps({"points": points, "speed": 1.2}))
    argv = ["walk", "--ckpt", str(xia_tiny["walker"]), "--style", "neutral@0,old@1s", "--path", str(path),
            "--out", str(tmp_path / "out"), "--no-gif", "--sampler", "ddim", "--steps", "2"]  # fmt: skip
    assert main(argv) == 0
    manifest = json.loads(capsys.readouterr().out)
    assert manifest["timeline"]["keys"][1]["style"] == "old"
    assert (tmp_path / "out" / "timeline-neutral-old_line_timeline.png").exists()
    assert main(argv[:-5] + ["--stream", "--path", "-"]) == 1
    assert "a timeline (STYLE@SECONDS) is not for --stream" in capsys.readouterr().err
