"""The MLflow UI as a user sees it, in a real headless Chromium, on a real `walkdiff fit` run: the address
`make ui` prints opens the run list, the run's artifacts list the best and last checkpoints, and it shows
about one parameter per hyperparameter. Screenshots of each page are kept in the test's folder."""

from __future__ import annotations

import io
import os
import socket
import subprocess
import sys
import time
from pathlib import Path
from urllib.request import urlopen

import numpy as np
import probes
import pytest
import synthetic
import yaml
from mlflow.tracking import MlflowClient
from PIL import Image

from walkdiff.common.tracking import ui_addresses
from walkdiff.preview.browser import Browser, find_chromium

# CI installs Debian's chromium (.ci/run); elsewhere the browser test runs where one is installed.
REQUIRE_BROWSER = os.environ.get("WALKDIFF_REQUIRE_BROWSER") == "1"
browser = pytest.mark.skipif(
    find_chromium() is None and not REQUIRE_BROWSER, reason="no chromium here (CI installs it)"
)
SERVER_START_S = 180  # the MLflow server starts in ~5 s on a quiet machine; a busy one takes longer
PAGE_S = 90  # one page of the UI rendered (its first load parses several MB of JavaScript)


@pytest.fixture(scope="module")
def ui(tmp_path_factory):
    """One epoch of a tiny generator trained by the `walkdiff fit` command into an sqlite store under its
    working directory, with a monitored ("best") checkpoint beside the last one; and `make ui`'s server
    (the same command, from this venv) on that store, on a free port, started while the run trains."""
    assert find_chromium() is not None, "CI must have chromium: .ci/run installs Debian's package"
    work = tmp_path_factory.mktemp("mlflow_ui")
    synthetic.xia_like_folder(work / "data", walk_clips=8, frames=240)
    best = {
        "class_path": "walkdiff.callbacks.checkpoints.RunCheckpoint",
        "init_args": {
            "dirpath": "checkpoints/ui",
            "filename": "best-{epoch:04d}",
            "monitor": "diffusion/val",
        },
    }
    config = probes.tiny_fit_config(work / "data", "ui", epochs=3, batches=1, callbacks=[best])
    (work / "ui.yaml").write_text(config)
    (work / "mlruns").mkdir()
    uri = f"sqlite:///{work}/mlruns/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    client.search_experiments()  # creates the store's tables, so that server and run can share it

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    log = open(work / "server.log", "w")  # closed below
    server = subprocess.Popen(
        [
            Path(sys.executable).parent / "mlflow", "server", "--backend-store-uri", uri,
            "--default-artifact-root", "./mlruns/artifacts",
            "--host", "127.0.0.1", "--port", str(port), "--workers", "1",
        ],
        cwd=work, env=os.environ | {"MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"},
        stdout=log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        env = {k: v for k, v in os.environ.items() if k != "MLFLOW_TRACKING_URI"} | {"WALKDIFF_PROGRESS": "0"}
        fit = subprocess.run(
            [sys.executable, "-m", "walkdiff.cli", "fit", "--config", "ui.yaml", "--trainer.max_epochs", "1"],
            cwd=work, env=env, capture_output=True, text=True, timeout=600,
        )  # fmt: skip
        assert fit.returncode == 0, fit.stderr[-3000:]
        experiment = client.get_experiment_by_name("walkdiff-test")
        (run,) = client.search_runs([experiment.experiment_id])

        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + SERVER_START_S
        while True:
            assert server.poll() is None, (work / "server.log").read_text()[-3000:]
            try:
                with urlopen(f"{base}/health", timeout=5) as answer:
                    if answer.status == 200:
                        break
            except OSError:
                pass
            assert time.monotonic() < deadline, f"no MLflow server after {SERVER_START_S} s"
            time.sleep(0.5)
        yield {"work": work, "uri": uri, "client": client, "experiment": experiment, "run": run, "base": base}
    finally:
        server.terminate()
        server.wait(timeout=60)
        log.close()


def _element_box(page: Browser, text: str) -> tuple[int, int, int, int]:
    """The on-screen box (left, top, right, bottom) of the innermost element showing exactly `text`."""
    box = page.evaluate(
        "(() => { const all = [...document.querySelectorAll('body *')].filter("
        f"e => e.innerText && e.innerText.trim() === {text!r} && e.getBoundingClientRect().width > 0);"
        " const r = all[all.length - 1].getBoundingClientRect();"
        " return [r.left, r.top, r.right, r.bottom].map(Math.round); })()"
    )
    return tuple(box)


def _ink(png: bytes, box: tuple[int, int, int, int]) -> int:
    """Pixels of text (far darker or lighter than the background) in a box of a screenshot."""
    grey = np.asarray(Image.open(io.BytesIO(png)).convert("L")).astype(int)
    left, top, right, bottom = box
    patch = grey[top:bottom, left:right]
    return int((np.abs(patch - np.median(patch)) > 80).sum())


@browser
def test_the_address_make_ui_prints_opens_the_run_list(ui, tmp_path):
    experiment, name = ui["experiment"], ui["run"].info.run_name
    addresses = ui_addresses(ui["uri"], ui["base"])
    assert set(addresses) == {"walkdiff-test"}, addresses
    with Browser(addresses["walkdiff-test"], width=1400, height=900, timeout=PAGE_S) as page:
        page.wait_for(f"document.body && document.body.innerText.includes({name!r})")
        # The runs table of the experiment, not its GenAI pages (traces, token usage).
        assert f"/experiments/{experiment.experiment_id}/runs?" in page.url, page.url
        assert "workflowType=machine_learning" in page.url
        assert "Run Name" in page.text() and "Token Usage" not in page.text()
        png = page.screenshot(tmp_path / "run_list.png")
        assert _ink(png, _element_box(page, name)) > 30  # the run's name is drawn


@browser
def test_switching_the_sidebar_once_opens_every_experiment_on_its_runs(ui):
    """What README tells users who click through the experiment list instead."""
    experiment = ui["experiment"]
    with Browser(f"{ui['base']}/#/experiments", width=1400, height=900, timeout=PAGE_S) as page:
        link = f"a[href='#/experiments/{experiment.experiment_id}']"
        page.wait_for(f"!!document.querySelector({link!r})")
        page.evaluate(
            "[...document.querySelectorAll('body *')].filter("
            "e => e.children.length === 0 && e.innerText === 'Model training')[0].click()"
        )
        page.evaluate(f"document.querySelector({link!r}).click()")
        page.wait_for(f"location.hash.startsWith('#/experiments/{experiment.experiment_id}/')")
        page.wait_for(f"document.body.innerText.includes({ui['run'].info.run_name!r})")
        assert f"/experiments/{experiment.experiment_id}/runs?" in page.url, page.url


@browser
def test_the_artifacts_list_the_best_and_last_checkpoints(ui, tmp_path):
    experiment, run_id = ui["experiment"], ui["run"].info.run_id
    files = {a.path for a in ui["client"].list_artifacts(run_id, "checkpoints")}
    assert files == {"checkpoints/best.ckpt", "checkpoints/last.ckpt", "checkpoints/index.json"}
    address = (
        f"{ui['base']}/#/experiments/{experiment.experiment_id}/runs/{run_id}/artifacts/checkpoints/index.json"
        "?workflowType=machine_learning"
    )
    with Browser(address, width=1400, height=900, timeout=PAGE_S) as page:
        # The tree lists both checkpoints; the preview of index.json says what chose the best one.
        page.wait_for("document.body && document.body.innerText.includes('diffusion/val')")
        text = page.text()
        assert "best.ckpt" in text and "last.ckpt" in text, text[:2000]

        def drawn():  # the tree unfolds in steps: both names in one screenshot
            png = page.screenshot()
            return (
                png
                if all(_ink(png, _element_box(page, f)) > 20 for f in ("best.ckpt", "last.ckpt"))
                else None
            )

        (tmp_path / "artifacts.png").write_bytes(page.wait_until(drawn, "best.ckpt and last.ckpt drawn"))


@browser
def test_the_run_shows_about_one_parameter_per_hyperparameter(ui, tmp_path):
    experiment, found = ui["experiment"], ui["run"]
    # The hyperparameters the run was configured with: every init argument of its model and data module
    # (the resolved config it logged), the trainer settings its config and command line gave, the seed.
    config = yaml.safe_load(
        Path(ui["client"].download_artifacts(found.info.run_id, "config.yaml")).read_text()
    )
    model, data = (set(config[part]["init_args"]) - {"data_spec"} for part in ("model", "data"))
    given = yaml.safe_load((ui["work"] / "ui.yaml").read_text())["trainer"]
    trainer = set(given) - {"logger", "callbacks"}  # the command line's --trainer.max_epochs is among them
    hyperparameters = len(model) + len(data) + len(trainer) + 1
    logged = found.data.params
    assert len(logged) <= 1.2 * hyperparameters, sorted(logged)
    assert {f"model.{k}" for k in model} | {f"data.{k}" for k in data} <= set(logged)
    assert logged["trainer.max_epochs"] == "1"

    address = f"{ui['base']}/#/experiments/{experiment.experiment_id}/runs/{found.info.run_id}"
    address += "?workflowType=machine_learning"
    with Browser(address, width=1400, height=900, timeout=PAGE_S) as page:
        shown = page.wait_for(
            "(document.body && document.body.innerText.match(/Parameters \\((\\d+)\\)/) || [])[1]"
        )
        heading = page.evaluate(  # the innermost element saying "Parameters (N)", into view
            "(() => { const all = [...document.querySelectorAll('body *')].filter("
            "e => /^Parameters \\(\\d+\\)$/.test((e.innerText || '').trim()));"
            " all[all.length - 1].scrollIntoView(); return all[all.length - 1].innerText.trim(); })()"
        )
        assert heading == f"Parameters ({shown})"
        page.screenshot(tmp_path / "parameters.png")
    assert int(shown) == len(logged)
    assert int(shown) <= 1.2 * hyperparameters
    print(f"{shown} parameters shown for {hyperparameters} hyperparameters")


def test_make_ui_on_a_store_that_does_not_exist_yet_lists_nothing_and_creates_nothing(tmp_path, capsys):
    from walkdiff.common.tracking import print_ui_addresses

    store = tmp_path / "mlruns" / "mlflow.db"
    assert ui_addresses(f"sqlite:///{store}", "http://127.0.0.1:5000") == {}
    print_ui_addresses(f"sqlite:///{store}", "http://127.0.0.1:5000")
    assert "none yet" in capsys.readouterr().out and not store.exists()
