"""Faults of a real `walkdiff fit` process: killed with SIGKILL, then resumed from the stable last path."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import probes
import pytest
import synthetic
import torch

REPO = Path(__file__).parents[1]
EPOCHS, BATCHES = 4, 3
STEPS_PER_BATCH = 1  # the discriminator's step is not counted: global_step counts batches


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("tiny")
    synthetic.xia_like_folder(root, walk_clips=8, frames=240)
    return root


def walkdiff_fit(cwd: Path, *args: str, **popen) -> subprocess.Popen:
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join([str(REPO), str(REPO / "tests")]),
        PYTHONWARNINGS="ignore",
        WALKDIFF_PROGRESS="0",
        OMP_NUM_THREADS="1",
    )
    command = [sys.executable, "-m", "walkdiff.cli.main", "fit", *args]
    return subprocess.Popen(command, cwd=cwd, env=env, text=True, **popen)


def config(tiny_root: Path, folder: Path, name: str, callbacks: list[dict]) -> str:
    path = folder / f"{name}.yaml"
    text = probes.tiny_fit_config(tiny_root, "tiny", epochs=EPOCHS, batches=BATCHES, callbacks=callbacks)
    path.write_text(text)
    return str(path)


SLOW = {"class_path": "probes.SleepEachBatch", "init_args": {"seconds": 0.4}}


def slow_fit_until_its_first_checkpoint(tiny_root: Path, cwd: Path) -> tuple[subprocess.Popen, Path]:
    """A `walkdiff fit` of a few slowed epochs, running, with its last.ckpt written: (process, link)."""
    link = cwd / "checkpoints" / "tiny" / "last.ckpt"
    process = walkdiff_fit(
        cwd,
        "--config",
        config(tiny_root, cwd, "slow", [SLOW]),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    deadline = time.monotonic() + 60
    while not link.exists():
        if process.poll() is not None:
            pytest.fail(f"fit ended before its first checkpoint: {process.communicate()[1][-2000:]}")
        assert time.monotonic() < deadline, "no checkpoint within 60 s"
        time.sleep(0.05)
    return process, link


def test_kill_9_of_fit_resumes_at_the_right_step_and_closes_the_killed_run(tiny_root, tmp_path):
    killed, link = slow_fit_until_its_first_checkpoint(tiny_root, tmp_path)
    killed.send_signal(signal.SIGKILL)
    killed.communicate()  # also closes its stderr pipe
    assert killed.returncode == -signal.SIGKILL
    old_file = link.resolve()
    saved = torch.load(link, map_location="cpu", weights_only=False)
    assert saved["epoch"] < EPOCHS - 1, "killed before the end of training"

    record = {"class_path": "probes.RecordSteps", "init_args": {"path": str(tmp_path / "steps.json")}}
    resume = [
        "--config",
        config(tiny_root, tmp_path, "resume", [record]),
        "--ckpt_path",
        "checkpoints/tiny/last.ckpt",
    ]
    resumed = walkdiff_fit(tmp_path, *resume, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out, err = resumed.communicate(timeout=120)
    assert resumed.returncode == 0, err[-3000:]
    steps = json.loads((tmp_path / "steps.json").read_text())
    assert steps["first_step"] == saved["global_step"] == (saved["epoch"] + 1) * BATCHES * STEPS_PER_BATCH
    assert steps["last_step"] == EPOCHS * BATCHES * STEPS_PER_BATCH  # as an uninterrupted run
    assert steps["epochs"] == EPOCHS

    # The killed run is closed (said in one line), the resumed one finished; each has its own folder.
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path}/mlruns/mlflow.db")
    runs = client.search_runs([client.get_experiment_by_name("walkdiff-test").experiment_id])
    status = {run.info.run_id: run.info.status for run in runs}
    killed_id = old_file.parent.name
    assert len(status) == 2 and status.pop(killed_id) == "KILLED"
    [(resumed_id, resumed_status)] = status.items()
    assert resumed_status == "FINISHED"
    host = os.uname().nodename
    assert f"marked 1 MLflow run(s) KILLED whose process on {host} had died: {killed_id}" in err
    assert old_file.is_file(), "the killed run's checkpoint stays"
    assert link.is_symlink() and link.resolve() == link.parent / resumed_id / "last.ckpt"
    assert client.get_run(resumed_id).data.tags["walkdiff.checkpoints"] == str(link.resolve().parent)
    assert f"checkpoints of this run in {link.resolve().parent}" in out


def test_sigterm_of_fit_fails_the_run_and_the_command(tiny_root, tmp_path):
    """Lightning stops at the next batch on SIGTERM and closes its MLflow run FAILED; its bare SystemExit
    would leave exit status 0, so walkdiff says what happened and exits 143."""
    stopped, link = slow_fit_until_its_first_checkpoint(tiny_root, tmp_path)
    stopped.send_signal(signal.SIGTERM)
    _, err = stopped.communicate(timeout=60)
    assert stopped.returncode == 143
    assert "walkdiff: stopped by SIGTERM; its MLflow run, if any, is marked FAILED" in err
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path}/mlruns/mlflow.db")
    [run] = client.search_runs([client.get_experiment_by_name("walkdiff-test").experiment_id])
    assert run.info.status == "FAILED" and run.info.run_id == link.resolve().parent.name
