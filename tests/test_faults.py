"""Faults a user meets: two writers on one output, a writer killed mid-write, a corrupted cache."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import synthetic
from PIL import Image

from walkdiff.cli.main import main
from walkdiff.common.files import clean_temporaries, output_lock, temporary_file, write_text
from walkdiff.data.datamodule import MotionDataModule
from walkdiff.models.styled_ddpm import StyledMotionDiffusion
from walkdiff.motion.bvh import read_bvh

SAMPLE = ["sample", "--style", "angry", "--seed", "3"]


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory) -> Path:
    """An untrained generator of a tiny size: the faults do not depend on what it learned."""
    root = tmp_path_factory.mktemp("faults")
    synthetic.xia_like_folder(root, walk_clips=6, frames=240)
    dm = MotionDataModule(root=str(root), cache_dir=str(root / "cache"), batch_size=8, preprocess_workers=1)
    L.seed_everything(0)
    model = StyledMotionDiffusion(dm.spec, d_model=32, layers=1, heads=2, lambda_adv=0.0)
    trainer = synthetic.quiet_trainer(max_epochs=1, limit_train_batches=1, limit_val_batches=0)
    trainer.fit(model, dm)
    path = root / "tiny.ckpt"
    trainer.save_checkpoint(path)
    return path


@pytest.fixture(autouse=True)
def plain_argv(monkeypatch):
    monkeypatch.setattr("sys.argv", ["walkdiff"])


def _walkdiff(*args: str) -> subprocess.Popen:
    env = {**os.environ, "WALKDIFF_PROGRESS": "0"}
    command = [sys.executable, "-m", "walkdiff.cli.main", *args]
    return subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(condition, process: subprocess.Popen, what: str, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if process.poll() is not None:
            pytest.fail(f"the writer ended before {what}: {process.communicate()[1][-2000:]}")
        if time.monotonic() > deadline:
            process.kill()
            pytest.fail(f"no {what} after {timeout} s")
        time.sleep(0.02)


def _dead_pid() -> int:
    finished = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True)
    return int(finished.stdout)


def test_a_second_writer_is_refused_with_the_holders_pid(ckpt, tmp_path, capsys):
    out = tmp_path / "out"
    lock = tmp_path / ".out.lock"
    # The second writer comes as soon as the lock is taken, long before the first has loaded its model.
    first = _walkdiff(*SAMPLE, "--ckpt", str(ckpt), "--out", str(out), "--frames", "300", "--num", "2")
    _wait_for(lock.exists, first, "lock")
    assert main([*SAMPLE, "--ckpt", str(ckpt), "--out", str(out), "--num", "1", "--overwrite"]) == 1
    err = capsys.readouterr().err
    assert f"PID {first.pid}" in err and "walkdiff sample" in err and str(out) in err
    assert "Traceback" not in err
    _, stderr = first.communicate(timeout=300)
    assert first.returncode == 0, stderr
    # The folder holds the first writer's run only, as its manifest describes, and the lock is gone.
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["settings"]["num"] == 2 and manifest["settings"]["frames"] == 300
    assert sorted(p.name for p in out.glob("*.bvh")) == sorted(manifest["files"])
    assert not lock.exists()


def test_a_killed_writer_leaves_no_partial_file_and_its_temporaries_go_with_the_next_run(ckpt, tmp_path):
    out = tmp_path / "out"
    writer = _walkdiff(*SAMPLE, "--ckpt", str(ckpt), "--out", str(out), "--frames", "400", "--num", "4")
    _wait_for(lambda: any(out.glob("*.bvh")), writer, "first clip")
    writer.send_signal(signal.SIGKILL)
    writer.communicate(timeout=30)
    # Whatever has a final name is whole: every BVH reads in full, every GIF has all its frames.
    for bvh in out.glob("*.bvh"):
        assert read_bvh(bvh).num_frames == 400
    for gif in out.glob("*.gif"):
        with Image.open(gif) as image:
            assert image.n_frames > 1
    assert not (out / "manifest.json").exists()
    # A temporary of a dead writer, as a kill during a write leaves it (whether or not this kill did).
    fd, planted = temporary_file(out / "angry_walk_000.bvh")
    os.close(fd)
    dead = planted.with_name(planted.name.replace(f".{os.getpid()}.", f".{_dead_pid()}."))
    planted.rename(dead)

    # The next write cleans up, even one that then refuses to replace the killed run's files unasked.
    again = _walkdiff(*SAMPLE, "--ckpt", str(ckpt), "--out", str(out), "--frames", "40", "--num", "2")
    _, stderr = again.communicate(timeout=300)
    assert again.returncode == 1 and "would overwrite" in stderr
    assert "temporary file(s) left in" in stderr and dead.name in stderr
    assert not list(out.rglob("*.tmp")) and not list(tmp_path.glob(".*.lock"))
    again = _walkdiff(
        *SAMPLE, "--ckpt", str(ckpt), "--out", str(out), "--frames", "40", "--num", "2", "--overwrite"
    )
    _, stderr = again.communicate(timeout=300)
    assert again.returncode == 0, stderr
    assert not list(out.rglob("*.tmp")) and not list(tmp_path.glob(".*.lock"))
    assert json.loads((out / "manifest.json").read_text())["settings"]["num"] == 2


def test_a_live_writers_temporaries_are_kept(tmp_path):
    fd, live = temporary_file(tmp_path / "clip.bvh")  # this process: alive
    os.close(fd)
    fd, dead = temporary_file(tmp_path / "clip.bvh")
    os.close(fd)
    dead = dead.rename(dead.with_name(dead.name.replace(f".{os.getpid()}.", f".{_dead_pid()}.")))
    assert clean_temporaries(tmp_path) == [dead]
    assert live.exists() and not dead.exists()


def test_the_lock_is_released_on_error_and_refuses_while_held(tmp_path):
    target = tmp_path / "report.json"
    with pytest.raises(RuntimeError), output_lock(target, "test"):
        raise RuntimeError
    assert not (tmp_path / ".report.json.lock").exists()
    with output_lock(target, "test"):
        script = (
            f"from walkdiff.common.files import output_lock\nwith output_lock({str(target)!r}, 'x'): pass"
        )
        holder = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
        assert (
            holder.returncode == 1
            and f"PID {os.getpid()}" in holder.stderr
            and "walkdiff test" in holder.stderr
        )
        write_text(target, "{}")
    assert target.read_text() == "{}"


def test_every_report_command_refuses_an_existing_output(tmp_path, capsys):
    (tmp_path / "report.json").write_text("{}")
    bench = tmp_path / "data.json"
    bench.write_text("{}")
    for args in (
        ["evaluate", "--evaluator", "e.ckpt", "--real-only", "--out", str(tmp_path)],
        ["evaluate-gesture", "--ckpt", "g.ckpt", "--out", str(tmp_path)],
        ["bench", "data", "--out", str(bench)],
    ):
        assert main(args) == 1
        err = capsys.readouterr().err
        assert "would overwrite" in err and "--overwrite" in err, args
    assert (tmp_path / "report.json").read_text() == "{}" and bench.read_text() == "{}"


def test_a_corrupted_cache_is_rebuilt_with_a_warning_naming_it(tmp_path):
    synthetic.xia_like_folder(tmp_path, walk_clips=3)

    def processed():
        dm = MotionDataModule(
            root=str(tmp_path), contents="all", cache_dir=str(tmp_path / "cache"), preprocess_workers=1
        )
        return dm._ensure_processed(progress=False)

    first = processed()
    first.cache_file.write_bytes(first.cache_file.read_bytes()[:200])  # a write cut short
    with pytest.warns(UserWarning, match=f"{first.cache_file}: unreadable feature cache"):
        rebuilt = processed()
    assert not rebuilt.from_cache and rebuilt.cache_file == first.cache_file
    np.testing.assert_array_equal(rebuilt.features[0], first.features[0])
    assert processed().from_cache
