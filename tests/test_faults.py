"""Faults a user meets: two writers on one output, a writer killed mid-write, a full disk or a folder not
writable, a corrupted cache."""

from __future__ import annotations

import errno
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

from walkdiff.cli.main import main
from walkdiff.common import files
from walkdiff.common.errors import WalkdiffError
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


def test_a_killed_writer_leaves_no_partial_set_and_its_temporaries_go_with_the_next_run(ckpt, tmp_path):
    out = tmp_path / "out"
    fast = ["--ckpt", str(ckpt), "--out", str(out), "--sampler", "ddim", "--steps", "2"]
    quick = [*SAMPLE, *fast, "--frames", "40", "--num", "2"]
    assert main([*quick, "--no-gif"]) == 0
    earlier = {p.name: p.read_bytes() for p in out.iterdir()}
    writer = _walkdiff(*SAMPLE, *fast, "--frames", "400", "--num", "4", "--overwrite")
    # Its first clip is written, under a temporary name until the whole set is (its previews take seconds).
    _wait_for(lambda: any(out.glob(".angry_walk_000.bvh.*.tmp")), writer, "first clip")
    writer.send_signal(signal.SIGKILL)
    writer.communicate(timeout=30)
    # Nothing of the killed run has a final name: the set it was replacing is whole and unchanged.
    assert {p.name: p.read_bytes() for p in out.iterdir() if not p.name.endswith(".tmp")} == earlier
    left = [p.name for p in out.glob(".*.tmp")]
    assert left and all(f".{writer.pid}." in name for name in left)

    # The next write cleans up, even one that then refuses to replace the earlier files unasked.
    again = _walkdiff(*quick)
    _, stderr = again.communicate(timeout=300)
    assert again.returncode == 1 and "would overwrite" in stderr
    assert "temporary file(s) left in" in stderr and any(name in stderr for name in left)
    assert not list(out.rglob("*.tmp")) and not list(tmp_path.glob(".*.lock"))
    again = _walkdiff(*quick, "--overwrite")
    _, stderr = again.communicate(timeout=300)
    assert again.returncode == 0, stderr
    assert not list(out.rglob("*.tmp")) and not list(tmp_path.glob(".*.lock"))
    assert json.loads((out / "manifest.json").read_text())["settings"]["num"] == 2
    for bvh in out.glob("*.bvh"):
        assert read_bvh(bvh).num_frames == 40


def _failing(monkeypatch, name: str, error: OSError) -> None:
    """Writes of the output `name` fail with `error` (a full disk: the bytes go to /dev/full; a folder
    not writable: no temporary file can be made), as the system would fail them."""
    real = files.temporary_file

    def temporary(path):
        if Path(path).name != name:
            return real(path)
        if error.errno == errno.ENOSPC:
            fd, temp = real(path)
            os.close(fd)
            return os.open("/dev/full", os.O_WRONLY), temp
        raise error

    monkeypatch.setattr(files, "temporary_file", temporary)


@pytest.mark.parametrize(
    "error, cause",
    [
        (OSError(errno.ENOSPC, "No space left on device"), "no space left on device"),
        (PermissionError(errno.EACCES, "Permission denied"), "permission denied"),
    ],
)
def test_a_failed_write_names_the_file_and_leaves_no_partial_set(
    ckpt, tmp_path, capsys, monkeypatch, error, cause
):
    """A full disk or a folder not writable while `sample` writes its second clip: one line naming that
    file and the cause; no clip of the run is left without its manifest, and an earlier set it was asked
    to replace stays whole."""
    out = tmp_path / "out"
    args = [*SAMPLE, "--ckpt", str(ckpt), "--frames", "30", "--num", "2", "--preview-seconds", "0.5"]
    assert main([*args, "--out", str(out)]) == 0
    earlier = {p.name: p.read_bytes() for p in out.iterdir()}
    capsys.readouterr()
    _failing(monkeypatch, "angry_walk_001.bvh", error)
    for folder, more in ((out, ["--overwrite", "--seed", "4"]), (tmp_path / "new" / "out", [])):
        assert main([*args, "--out", str(folder), *more]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1] == f"walkdiff: error: {folder / 'angry_walk_001.bvh'}: cannot write ({cause})", err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == earlier, "the earlier set, whole"
    assert not (tmp_path / "new").exists(), "no folder left behind, empty or with part of a set"


def test_an_output_set_is_written_all_or_none(tmp_path):
    (tmp_path / "kept.txt").write_text("before")
    with pytest.raises(WalkdiffError), files.output_set(tmp_path / "a" / "b"):
        files.write_text(tmp_path / "a" / "b" / "one.txt", "1")
        files.write_text(tmp_path / "kept.txt", "after")
        assert not (tmp_path / "a" / "b" / "one.txt").exists(), "named only once all are written"
        with files.output_set(tmp_path / "c"):  # a command inside another's set joins it
            files.write_text(tmp_path / "a" / "b" / "two.txt", "2")
        assert not (tmp_path / "a" / "b" / "two.txt").exists()
        raise WalkdiffError("bad input midway")
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["kept.txt"]  # no folder, no temporary
    assert (tmp_path / "kept.txt").read_text() == "before"
    with files.output_set(tmp_path / "a"):
        files.write_text(tmp_path / "a" / "one.txt", "1")
        files.write_text(tmp_path / "a" / "one.txt", "2")
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a", "kept.txt", "one.txt"]
    assert (tmp_path / "a" / "one.txt").read_text() == "2"


def test_a_failed_file_operation_outside_the_writers_is_one_line(tmp_path, capsys, monkeypatch):
    def denied(args):
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path / "somewhere"))

    monkeypatch.setattr("walkdiff.cli.main.run_command", denied)
    assert main(["inspect", "x.bvh"]) == 1
    err = capsys.readouterr().err
    assert err == f"walkdiff: error: {tmp_path / 'somewhere'}: permission denied\n"


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
