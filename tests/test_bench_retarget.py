"""`walkdiff bench retarget` end to end on two short clips, and the rig variants it is built on.

The benchmark's figures are checked for shape (every section there, every number finite), not for
their values: those are the benchmark's to say (docs/benchmarks.md). Only the same-proportion cases,
whose answer is known exactly, must pass.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from walkdiff.bench.retarget import Z_UP, world
from walkdiff.bench.rig_variants import axes_and_units, random_turns, reframe, rotation_order
from walkdiff.cli.main import main
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.rigs import RIGS

SAME = 5  # same-proportion cases
OTHER = ["legs 0.8x", "legs 1.25x", "arms 1.2x", "longer spine (+2 joints)", "hips 0.6x", "hips 1.6x"]
OTHER += ["big: 1.5x, hips 1.3x"]
REAL = [*(f"xia -> {name}" for name in RIGS), "xia -> zeggs", "zeggs -> xia", "xia -> zeggs -> xia"]
CIRCLING = ["xia -> big", "big -> xia", "xia -> zeggs", "big -> zeggs"]  # issue 46: a 2 m character, circling


def numbers(node, path=""):
    """(path, value) of every number and flag below `node`; None (a JSON null) counts as one."""
    if isinstance(node, dict):
        for key, value in node.items():
            yield from numbers(value, f"{path}/{key}")
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from numbers(value, f"{path}/{i}")
    elif node is None or isinstance(node, int | float):
        yield path, node


def test_the_benchmark_writes_every_section_and_refuses_to_overwrite(xia_dir, zeggs_dir, tmp_path, capsys):
    assert xia_dir.parent == zeggs_dir.parent
    out = tmp_path / "retarget.json"
    command = ["bench", "retarget", "--out", str(out), "--clips", "2", "--frames", "60"]
    assert main([*command, "--data", str(xia_dir.parent)]) == 0
    printed = capsys.readouterr().out
    assert "bench retarget: 2 Xia clips (<= 60 frames)" in printed and "checks:" in printed
    result = json.loads(out.read_text())
    assert [c["frames"] for c in result["clips"]] == [60, 60]
    assert len(result["same_proportions"]) == SAME
    assert list(result["other_proportions"]) == OTHER
    assert sorted(result["real_pairs"]) == sorted(REAL)
    assert list(result["circling"]) == CIRCLING and len(result["circling_clips"]["clips"]) == 2
    assert "circling round 2 m:" in printed
    for case in result["circling"].values():
        for figure in ("legs_with_ik_worst_median_deg", "skate_ratio", "contacts_kept_own"):
            assert {"value", "target", "pass"} <= set(case[figure]), figure
    assert set(result["contacts_kept_readings"]) == {"contacts_kept_own", "contacts_kept_scaled"}
    for case in [*result["other_proportions"].values(), *result["real_pairs"].values()][:-1]:
        for figure in ("bones_p95_deg", "skate_ratio", "contacts_kept_own", "below_floor", "sides_kept"):
            assert {"value", "target", "pass"} <= set(case[figure]), figure
    for case in result["same_proportions"].values():  # the answer is known: these must hold
        assert case["position_error_max"]["pass"] and case["round_trip_max"]["pass"]
    assert result["speed"]["frames"] == 60 and len(result["speed"]) >= 5
    sections = ("same_proportions", "other_proportions", "real_pairs", "circling", "speed", "checks")
    for path, value in numbers({s: result[s] for s in sections}):
        assert value is not None and math.isfinite(value), path
    assert result["checks"]["checked"] > 50
    assert result["checks"]["passed"] + len(result["checks"]["failed"]) == result["checks"]["checked"]

    assert main(command) == 1
    assert "pass --overwrite to replace them" in capsys.readouterr().err


def test_a_missing_dataset_is_named(tmp_path, capsys):
    assert main(["bench", "retarget", "--out", str(tmp_path / "r.json"), "--data", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert "dataset folder not found" in err and str((tmp_path / "xia").resolve()) in err


def test_axes_units_and_frames_keep_world_positions(xia_dir):
    """`axes_and_units` turns and scales the world positions, nothing else; `reframe` keeps them and turns
    the world rotations by the given frames; another rotation order changes only the channel names."""
    clip = read_bvh(xia_dir / "neutral_01_000.bvh").slice(0, 30)
    points, rotations = world(clip)
    size = np.abs(points).max()
    moved = axes_and_units(clip, Z_UP, 0.05)
    assert np.abs(world(moved)[0] - 0.05 * points @ Z_UP.T).max() < 1e-12 * size
    assert np.abs(world(moved)[1] - Z_UP @ rotations @ Z_UP.T).max() < 1e-12
    assert moved.skeleton.offsets[1:] == pytest.approx(0.05 * clip.skeleton.offsets[1:] @ Z_UP.T)
    turns = random_turns(clip.skeleton.num_joints, seed=3)
    assert np.abs(turns @ np.swapaxes(turns, -1, -2) - np.eye(3)).max() < 1e-12
    assert np.linalg.det(turns) == pytest.approx(np.ones(len(turns)))
    turned = reframe(clip, turns)
    assert np.abs(world(turned)[0] - points).max() < 1e-12 * size
    assert np.abs(world(turned)[1] - rotations @ turns).max() < 1e-12
    both = axes_and_units(turned, Z_UP, 100.0)
    assert np.abs(world(both)[0] - 100.0 * points @ Z_UP.T).max() < 1e-12 * 100.0 * size
    ordered = rotation_order(clip, "XYZ")
    assert ordered.skeleton.rotation_order(1) == "XYZ" and np.array_equal(ordered.rotations, clip.rotations)
