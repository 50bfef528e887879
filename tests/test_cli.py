"""`walkdiff inspect`, `walkdiff convert` and the LightningCLI front (config printing, overrides)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import synthetic
import yaml

from walkdiff.cli.main import main
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.mirror import mirror
from walkdiff.motion.representation import decode, encode, start_pose
from walkdiff.motion.resample import resample


@pytest.fixture(autouse=True)
def plain_argv(monkeypatch):
    """LightningCLI warns when given args while sys.argv holds pytest's own arguments."""
    monkeypatch.setattr("sys.argv", ["walkdiff"])


def test_inspect_reports_a_real_clip(xia_dir, tmp_path, capsys):
    clip = str(xia_dir / "neutral_01_000.bvh")
    assert main(["inspect", clip]) == 0
    out = capsys.readouterr().out
    assert "joints:    31" in out
    assert "120.00 fps" in out
    assert "root:      Hips" in out and "left LeftFoot / LeftToeBase" in out and "up +y" in out
    # CMU units are no human height in m, cm, mm or inches: said, and a 1.7 m body assumed.
    assert "1.7 m body assumed" in out.split("suspicious:")[1]
    profile = tmp_path / "xia.yaml"
    profile.write_text("units: 0.0564444\n")
    assert main(["inspect", clip, "--profile", str(profile)]) == 0
    out = capsys.readouterr().out
    assert "left toe" in out and "suspicious: none" in out and "1.36 m" in out


def test_inspect_flags_a_glitch(tmp_path, capsys):
    motion = synthetic.walking(120)
    motion.positions[60:, 0, 0] += 500.0  # the root teleports half way
    path = tmp_path / "glitch.bvh"
    synthetic.write_bvh(path, motion)
    assert main(["inspect", str(path)]) == 0
    assert "jumps faster than" in capsys.readouterr().out


def test_bad_file_gives_a_clear_error_and_exit_code(tmp_path, capsys):
    path = tmp_path / "broken.bvh"
    synthetic.write_bvh(path, synthetic.walking(10))
    lines = path.read_text().splitlines()
    lines[-1] = "oops " + lines[-1].split(" ", 1)[1]
    path.write_text("\n".join(lines) + "\n")
    assert main(["inspect", str(path)]) == 1
    err = capsys.readouterr().err
    assert f"{path}:{len(lines)}" in err and "oops" in err


def test_convert_round_trips_through_the_representation(xia_dir, tmp_path, capsys):
    source = xia_dir / "old_07_000.bvh"
    out = tmp_path / "same.bvh"
    assert main(["convert", str(source), str(out)]) == 0
    original, converted = read_bvh(source), read_bvh(out)
    error = np.abs(motion_world_positions(original) - motion_world_positions(converted)).max()
    assert error < 1e-3  # 6-decimal BVH text on both sides


def test_convert_resamples_and_mirrors(xia_dir, tmp_path):
    source = xia_dir / "proud_01_000.bvh"
    out = tmp_path / "mirrored30.bvh"
    assert main(["convert", str(source), str(out), "--fps", "30", "--mirror"]) == 0
    original, converted = read_bvh(source), read_bvh(out)
    assert converted.fps == pytest.approx(30.0)
    assert abs(converted.duration - original.duration) <= 1 / 30
    # The command is the library's resample -> mirror -> encode -> decode, placed at the clip's start.
    profile = synthetic.xia_profile(original)
    expected = mirror(resample(profile.to_canonical(original), 30), profile.body_pairs)
    position, heading = start_pose(expected, profile)
    expected = decode(encode(expected, profile), expected.skeleton, expected.frame_time, position, heading)
    expected = profile.to_file(expected)
    error = np.abs(motion_world_positions(converted) - motion_world_positions(expected)).max()
    assert error < 1e-3


def test_print_config_applies_command_line_overrides(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["fit", "--config", "conf/xia_cpu.yaml", "--model.lambda_adv", "0.05", "--print_config"])
    assert stop.value.code == 0
    config = yaml.safe_load(capsys.readouterr().out)
    assert config["model"]["init_args"]["lambda_adv"] == 0.05
    assert config["model"]["init_args"]["timesteps"] == 100
    assert config["trainer"]["precision"] == "32-true"


def test_unknown_tracking_uri_fails_before_training(xia_dir, capsys):
    code = main(
        [
            "fit",
            "--config",
            "conf/xia_cpu.yaml",
            "--trainer.logger.init_args.tracking_uri",
            "http://127.0.0.1:9/",
            "--trainer.max_epochs",
            "1",
        ]
    )
    assert code == 1
    assert "http://127.0.0.1:9/" in capsys.readouterr().err


def test_cli_offers_every_sampler_the_samplers_know():
    from walkdiff import diffusion
    from walkdiff.cli import options

    assert options.SAMPLERS == diffusion.SAMPLERS


def test_cli_fills_with_the_api_s_sampler_and_candidates():
    from walkdiff.cli import options
    from walkdiff.styled import edits

    assert (options.FILL_SAMPLER, options.FILL_STEPS, options.FILL_CANDIDATES) == (
        edits.FILL_SAMPLER, edits.FILL_STEPS, edits.CANDIDATES
    )  # fmt: skip


def test_cli_names_every_built_in_rig():
    from walkdiff.cli import options
    from walkdiff.retarget.rigs import RIGS

    assert options.RIG_NAMES == tuple(RIGS)


def test_convert_refuses_to_clobber_and_bad_rates(xia_dir, tmp_path, capsys):
    source = tmp_path / "clip.bvh"
    source.write_bytes((xia_dir / "old_07_000.bvh").read_bytes())
    assert main(["convert", str(source), str(source), "--mirror"]) == 1
    assert "the output is the input" in capsys.readouterr().err
    out = tmp_path / "out.bvh"
    out.write_text("keep me")
    assert main(["convert", str(source), str(out)]) == 1
    assert "--overwrite" in capsys.readouterr().err and out.read_text() == "keep me"
    assert main(["convert", str(source), str(out), "--overwrite"]) == 0
    for rate in ("0", "-30", "nan"):
        assert main(["convert", str(source), str(tmp_path / "r.bvh"), "--fps", rate]) == 1
        assert "--fps: expected a finite number in (0, inf]" in capsys.readouterr().err


def test_a_clip_without_frames_is_named(tmp_path, capsys):
    path = tmp_path / "empty.bvh"
    synthetic.write_bvh(path, synthetic.walking(10))
    text = path.read_text()
    head = text[: text.index("MOTION")]
    path.write_text(head + "MOTION\nFrames: 0\nFrame Time: 0.0333\n")
    assert main(["inspect", str(path)]) == 1
    line = head.count("\n") + 2
    assert f"{path}:{line}: Frames: 0: expected a clip of at least one frame" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--model.lambda_advv", "0.1"], "Option 'lambda_advv' is not accepted; see `walkdiff fit --help`"),
        (["--trainer.max_epochs", "many"], "Parser key \"trainer.max_epochs\": Expected a <class 'int'>"),
        (["--data.root", "/nonexistent"], "/nonexistent/xia: dataset folder not found"),
    ],
)
def test_fit_errors_are_one_message_not_the_usage(args, message, capsys, tmp_path, monkeypatch):
    config = Path(__file__).parents[1] / "conf" / "xia_cpu.yaml"
    monkeypatch.chdir(tmp_path)  # its mlruns/ lands here
    assert main(["fit", "--config", str(config), *args]) == 1
    # (MLflow's logger may print a "Logging error" about an earlier test's closed capture stream.)
    err = capsys.readouterr().err.splitlines()
    lines = [line for line in err if line.startswith("walkdiff")]
    assert len(lines) == 1 and message in lines[0]
    assert not any(line.startswith("usage:") for line in err)


def test_json_outputs_are_strict(tmp_path):
    """Reports and manifests never hold NaN or Infinity, which strict JSON readers refuse."""
    import json

    from walkdiff.common.files import write_json

    def refuse(constant):
        raise ValueError(f"non-standard JSON constant {constant}")

    path = write_json(tmp_path / "r.json", {"a": float("nan"), "b": [1.0, float("inf")], "c": {"d": 2}})
    assert json.loads(path.read_text(), parse_constant=refuse) == {"a": None, "b": [1.0, None], "c": {"d": 2}}


def test_target_map_is_a_deprecated_name_of_to_map(capsys):
    """The rig options are one group: retarget's --target-map is --to-map, said with a warning."""
    from walkdiff.cli.main import build_parser

    args = build_parser().parse_args(
        ["retarget", "a.bvh", "--to", "mixamo", "--out", "b.bvh", "--target-map", "m.yaml"]
    )
    assert args.to_map == "m.yaml" and "--target-map is deprecated; use --to-map" in capsys.readouterr().err
