"""Same command, same seed, same files: every generating command writes the BVH (and glb) bytes it wrote
at BASE (first the commit before the generation layer was routed through the API, issue 43; moved to the
commit from which checkpoints carry the grounding tolerance, which older packages cannot load).

How: the package as it was at BASE is taken out of git (`git archive`) into a temporary folder, and the
same command lines run on the same tiny checkpoints once with that package and once with this one, each
in a fresh interpreter; the motion files must be equal byte for byte. Timings, latencies and absolute
paths (JSON manifests, stdout) are not compared. A change meant to change outputs moves BASE to the
commit that makes it, saying so in its message.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tarfile
from io import BytesIO
from pathlib import Path

import numpy as np
import pytest
import synthetic

from walkdiff.motion.bvh import write_bvh

ROOT = Path(__file__).resolve().parents[1]
# Checkpoints carry ground_tolerance from this commit on (the packages before it refuse them).
BASE = "186c4d13aed14dacddba335f1921fd94f9a42978"

# Each command with a file for stdin ("-": none), run by the package under test in one interpreter;
# stdout (the streams' JSON lines) goes to a file per command.
DRIVER = """
import json, sys
from walkdiff.cli.main import main
for name, stdin, words in json.load(open(sys.argv[1])):
    with open(stdin if stdin != "-" else "/dev/null", "rb") as given, open(name + ".out", "w") as out:
        sys.stdin, sys.stdout = type("In", (), {"buffer": given})(), out
        code = main(words)
    sys.stdout = sys.__stdout__
    assert code == 0, f"{name}: exit {code}"
"""


def base_package(folder: Path) -> Path:
    """The walkdiff package as it was at BASE, unpacked under `folder`."""
    try:
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", "--format=tar", BASE, "walkdiff"],
            capture_output=True, check=True,
        ).stdout  # fmt: skip
    except (OSError, subprocess.CalledProcessError) as error:
        pytest.skip(f"needs the git history with commit {BASE[:10]} (a clone, not an export): {error}")
    with tarfile.open(fileobj=BytesIO(archive)) as tar:
        tar.extractall(folder, filter="data")
    return folder


def run_commands(package: Path, work: Path, commands: list) -> dict[str, bytes]:
    """The motion files the commands write with `package` on the path: name relative to `work` -> bytes."""
    work.mkdir()
    plan = work / "commands.json"
    plan.write_text(json.dumps(commands))
    env = os.environ | {"PYTHONPATH": str(package), "OMP_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-c", DRIVER, str(plan)], cwd=work, env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return {
        str(p.relative_to(work)): p.read_bytes()
        for p in sorted(work.rglob("*"))
        if p.suffix in (".bvh", ".glb")
    }


def test_generating_commands_write_the_bytes_they_wrote_at_base(styled, walker, gestures, tmp_path):
    ckpt, takes = gestures
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    write_bvh(inputs / "mine.bvh", synthetic.walking(120, fps=60.0, seed=3))
    (inputs / "corner.json").write_text(json.dumps({"points": [[0, 0], [0, 6], [6, 6]], "speed": 12.0}))
    (inputs / "points.jsonl").write_text("".join(f'{{"x": 0, "z": {z}}}\n' for z in np.arange(0, 7, 1.5)))
    (inputs / "script.jsonl").write_text('{"t": 0.5, "key": "ArrowLeft"}\n{"t": 1.2}\n')
    (inputs / "control.jsonl").write_text('{"frames": 10}\n{"direction": [1, 0], "frames": 10}\n')
    fast, out = ["--sampler", "ddim", "--steps", "2"], lambda name: ["--out", name]
    commands = [
        ("sample", "-", ["sample", "--ckpt", str(styled), "--style", "angry:0.7,old:0.3", "--num", "2",
                         "--frames", "40", "--seed", "5", "--fix-feet", "--no-gif", *fast, *out("sample")]),
        ("transfer", "-", ["transfer", "--ckpt", str(styled), "--input", str(inputs / "mine.bvh"), "--style",
                           "old", "--seed", "2", "--keep-trajectory", "--no-gif", "--sampler", "dpmpp",
                           "--steps", "4", *out("transfer")]),
        ("walk", "-", ["walk", "--ckpt", str(walker), "--style", "old", "--path", str(inputs / "corner.json"),
                       "--seed", "1", "--no-gif", *fast, *out("walk")]),
        ("walk_stream", "-", ["walk", "--stream", "--ckpt", str(walker), "--style", "old", "--speed", "12",
                              "--path", str(inputs / "points.jsonl"), "--idle", "0.05", "--seed", "1", *fast,
                              *out("walk_stream")]),
        ("gesture", "-", ["gesture", "--ckpt", str(ckpt), "--audio", str(takes / "b.wav"), "--seed", "4",
                          "--smooth", "--streams", "2", "--preview-seconds", "0.3", *fast, *out("gesture")]),
        ("gesture_stream", "-", ["gesture", "--stream", "--ckpt", str(ckpt), "--audio", str(takes / "b.wav"),
                                 "--idle", "0.05", "--seed", "4", "--smooth", *fast, *out("gesture_stream")]),
        ("play", "-", ["play", "--ckpt", str(walker), "--script", str(inputs / "script.jsonl"), "--style",
                       "old", "--seed", "1", "--steps", "2", *out("play")]),
        ("control", str(inputs / "control.jsonl"), ["control", "--ckpt", str(walker), "--style", "old",
                                                     "--characters", "2", "--seed", "1", "--steps", "2",
                                                     *out("control")]),
    ]  # fmt: skip
    before = run_commands(base_package(tmp_path / "base"), tmp_path / "at_base", commands)
    now = run_commands(ROOT, tmp_path / "now", commands)
    folders = {name.split("/")[0] for name in before}
    assert folders == {name for name, _, _ in commands}, "every command wrote motion at BASE"
    assert sorted(now) == sorted(before)
    changed = [name for name in before if now[name] != before[name]]
    assert not changed, f"files whose bytes changed since {BASE[:10]}: {changed}"
