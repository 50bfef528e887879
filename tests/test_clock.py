"""The training clock (batches, not epochs), the progress lines of a fit into a log file, and torch's
thread count following the cores the process may use."""

from __future__ import annotations

import io
import os
import types

import pytest
import torch

from walkdiff.callbacks.clock import Due, ProgressLog, step_folder
from walkdiff.common import threads
from walkdiff.common.errors import WalkdiffError


def _trainer(step: int, sanity: bool = False, rank0: bool = True, max_steps: int = 1800, **metrics):
    return types.SimpleNamespace(
        global_step=step, sanity_checking=sanity, is_global_zero=rank0, max_steps=max_steps,
        callback_metrics={k: torch.tensor(v) for k, v in metrics.items()},
    )  # fmt: skip


def test_a_measurement_is_due_at_the_first_validation_past_each_multiple():
    due = Due(every_n_steps=100)
    # Validations every 45 batches (an epoch's length) do not fall on the multiples of 100.
    fired = [step for step in range(45, 500, 45) if due(_trainer(step)) is not None]
    assert fired == [135, 225, 315, 405]  # past 100, 200, 300, 400: once each
    assert Due(10)(_trainer(10, sanity=True)) is None
    assert Due(10)(_trainer(10, rank0=False)) is None
    assert Due(10)(_trainer(10, rank0=False), rank_zero_only=False) == 10
    assert step_folder("metrics", 225) == "metrics/step_000225"
    with pytest.raises(ValueError, match="at least 1"):
        Due(0)


def test_progress_lines_say_step_loss_speed_and_eta(monkeypatch):
    out = io.StringIO()
    progress = ProgressLog(every_s=0.0, stream=out)
    clock = iter([100.0, 130.0, 160.0])
    monkeypatch.setattr("walkdiff.callbacks.clock.time.perf_counter", lambda: next(clock))
    progress.on_train_start(_trainer(0), None)
    progress.on_train_batch_end(_trainer(300, loss=0.25), None, None, None, 0)
    progress.on_train_end(_trainer(600, max_steps=600), None)
    first, last = out.getvalue().splitlines()
    assert first == "walkdiff: step 300/1800 (17%), loss 0.2500, 0.10 s/batch, ETA 2 min"
    assert last.startswith("walkdiff: step 600/600 (100%)") and last.endswith("ETA 0 s (done)")
    # The evaluator logs its loss per epoch only: that one is shown.
    assert "loss 0.5000" in progress.line(_trainer(10, **{"loss/train": 0.5}), 161.0)


def test_threads_follow_the_affinity_and_a_cgroup_quota(monkeypatch, tmp_path):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    quota = tmp_path / "cpu.max"
    monkeypatch.setattr(threads, "CGROUP_CPU_MAX", quota)
    assert threads.available_cores() == 4  # no cgroup file: the affinity alone
    quota.write_text("max 100000\n")
    assert threads.available_cores() == 4
    quota.write_text("150000 100000\n")  # 1.5 cores of quota: 2 threads
    assert threads.available_cores() == 2
    for variable in ("WALKDIFF_THREADS", "OMP_NUM_THREADS"):
        monkeypatch.delenv(variable, raising=False)
    assert threads.choose_threads(None) == (2, "the cores available to this process")
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert threads.choose_threads(None) == (3, "OMP_NUM_THREADS")
    monkeypatch.setenv("WALKDIFF_THREADS", "1")
    assert threads.choose_threads(None) == (1, "WALKDIFF_THREADS")
    assert threads.choose_threads("2") == (2, "--threads")
    with pytest.raises(
        WalkdiffError, match="--threads: expected a whole number of threads of at least 1, got 'x'"
    ):
        threads.choose_threads("x")


def test_the_threads_flag_sets_torch_threads_for_any_command(xia_dir, monkeypatch, capsys):
    from walkdiff.cli.main import main

    clip = str(xia_dir / "proud_01_000.bvh")
    monkeypatch.setenv("OMP_NUM_THREADS", str(torch.get_num_threads()))  # restored after the test
    before = torch.get_num_threads()
    try:
        assert main(["--threads", "1", "inspect", clip]) == 0
        assert torch.get_num_threads() == 1
        assert main(["inspect", clip, "--threads=2"]) == 0
        assert torch.get_num_threads() == 2
        assert main(["inspect", clip, "--threads"]) == 1
        assert "--threads: expected a number of threads after it" in capsys.readouterr().err
    finally:
        torch.set_num_threads(before)
