"""Blender imports retargeted BVH and .glb files on each built-in rig, and poses them where walkdiff does.

Blender is not a dependency: the test runs where one is found, `WALKDIFF_BLENDER` (a `blender` executable,
or a Python with the `bpy` module from PyPI) or `blender` on the PATH, and is skipped elsewhere. It runs
Blender's own importers in a subprocess (`tests/blender_import.py`) and compares the distances between
every two joints at 0 s and 1 s with walkdiff's forward kinematics (distances: Blender turns the axes).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.retarget.files import retarget_file
from walkdiff.retarget.rigs import RIGS, SPECS

SCRIPT = Path(__file__).with_name("blender_import.py")


def blender_command() -> list[str]:
    found = os.environ.get("WALKDIFF_BLENDER") or shutil.which("blender")
    if not found:
        pytest.skip("no Blender here: set WALKDIFF_BLENDER to a blender executable or a Python with bpy")
    if Path(found).name.startswith("python"):
        return [found, str(SCRIPT)]
    return [found, "--background", "--factory-startup", "--python", str(SCRIPT), "--"]


def distances(points: np.ndarray) -> np.ndarray:
    return np.linalg.norm(points[:, None] - points[None], axis=-1)


def test_blender_imports_retargeted_bvh_and_glb_on_each_built_in_rig(xia_dir, tmp_path):
    command = blender_command()
    source = xia_dir / "proud_01_000.bvh"
    files = []
    for name in RIGS:
        for suffix in (".bvh", ".glb"):
            files.append(tmp_path / f"{name}{suffix}")
            retarget_file(str(source), name, str(files[-1]))
    run = subprocess.run([*command, *map(str, files)], capture_output=True, text=True, timeout=600)
    rows = [json.loads(line[8:]) for line in run.stdout.splitlines() if line.startswith("BLENDER ")]
    assert len(rows) == len(files), run.stderr[-2000:]
    for row, path in zip(rows, files, strict=True):
        motion = read_bvh(path.with_suffix(".bvh"))
        assert row["armatures"] == 1 and row["actions"] == 1, path
        names = [n for n in motion.skeleton.names if n in row["bones"]]
        assert len(names) >= motion.skeleton.num_joints - 1, (path, row["bones"])  # glTF: no static root
        scale = SPECS[path.stem].metres_per_unit if path.suffix == ".glb" else 1.0
        ours = motion_world_positions(motion) * scale
        stature = np.ptp(ours[0], axis=0).max()
        for seconds, pose in zip((0.0, 1.0), row["positions"], strict=True):
            frame = round(seconds * motion.fps)
            mine = ours[frame, [motion.skeleton.index(n) for n in names]]
            theirs = np.array([pose[n] for n in names])
            error = np.abs(distances(mine) - distances(theirs)).max() / stature
            assert error < 0.01, (path, seconds, error)
