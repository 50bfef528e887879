"""MLflow plumbing: the tracking URI, a reachability check, logging files into the active run, and closing
the runs of processes that were killed."""

from __future__ import annotations

import os
import socket
import sys
import tempfile
from pathlib import Path

from walkdiff.common.errors import WalkdiffError

DEFAULT_TRACKING_URI = "sqlite:///mlruns/mlflow.db"
DEFAULT_ARTIFACT_ROOT = "mlruns/artifacts"


def tracking_uri() -> str:
    return absolute_uri(os.environ.get("MLFLOW_TRACKING_URI", DEFAULT_TRACKING_URI))


def absolute_uri(uri: str) -> str:
    """A relative sqlite URI made absolute against the working directory.

    MLflow keeps one database engine per URI string for the life of the process: a relative
    `sqlite:///mlruns/mlflow.db` opened in one folder would keep writing there from any other.
    """
    if uri.startswith("sqlite:///") and not uri.startswith("sqlite:////"):
        return "sqlite:///" + str(Path(uri.removeprefix("sqlite:///")).resolve())
    return uri


def check_tracking_uri(uri: str) -> None:
    """Fail at start, with the URI named, when the tracking store cannot be opened."""
    from mlflow.tracking import MlflowClient

    if uri.startswith("sqlite:///"):
        folder = Path(uri.removeprefix("sqlite:///")).parent
        folder.mkdir(parents=True, exist_ok=True)
    # One quick try: MLflow's default HTTP retries with backoff take minutes to give up.
    quick = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "0", "MLFLOW_HTTP_REQUEST_TIMEOUT": "10"}
    saved = {k: os.environ.get(k) for k in quick}
    os.environ.update(quick)
    try:
        MlflowClient(tracking_uri=uri).search_experiments(max_results=1)
    except Exception as error:  # mlflow raises many types (network, sqlalchemy, MlflowException)
        reason = str(error).splitlines()[0][:200]
        raise WalkdiffError(
            f"MLflow tracking URI {uri!r} cannot be reached ({type(error).__name__}: {reason}). "
            "Use the default sqlite:///mlruns/mlflow.db, or start the server you point at."
        ) from None
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def log_file(logger, local_path: str | Path, artifact_dir: str | None = None) -> None:
    """Log one file into the run of a Lightning MLFlowLogger (no-op for other loggers)."""
    run_id = getattr(logger, "run_id", None)
    if run_id is None or not hasattr(logger, "experiment"):
        return
    logger.experiment.log_artifact(run_id, str(local_path), artifact_dir)


def log_text(logger, text: str, artifact_file: str) -> None:
    run_id = getattr(logger, "run_id", None)
    if run_id is None or not hasattr(logger, "experiment"):
        return
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / Path(artifact_file).name
        path.write_text(text)
        folder = str(Path(artifact_file).parent)
        logger.experiment.log_artifact(run_id, str(path), None if folder == "." else folder)


PID_TAG, HOST_TAG = "walkdiff.pid", "walkdiff.host"


def tag_process(client, run_id: str) -> None:
    """Record which process on which host writes a run, so that a later start can tell it was killed."""
    client.set_tag(run_id, PID_TAG, str(os.getpid()))
    client.set_tag(run_id, HOST_TAG, socket.gethostname())


def close_dead_runs(client, experiment_id: str) -> list[str]:
    """Mark KILLED the runs of an experiment still RUNNING whose process on this host has died.

    A `fit` killed with SIGKILL (or by the out-of-memory killer) cannot close its run; the next `fit`
    into the same experiment does. Runs of other hosts, or without the PID tag, are left alone: whether
    their process lives cannot be told from here. Returns the closed run ids.
    """
    from walkdiff.common.files import process_alive

    host = socket.gethostname()
    closed = []
    runs = client.search_runs([experiment_id], filter_string="attributes.status = 'RUNNING'")
    for run in runs:
        tags = run.data.tags
        pid = tags.get(PID_TAG, "")
        if tags.get(HOST_TAG) != host or not pid.isdigit() or process_alive(int(pid)):
            continue
        client.set_terminated(run.info.run_id, "KILLED")
        closed.append(run.info.run_id)
    if closed:
        print(
            f"walkdiff: marked {len(closed)} MLflow run(s) KILLED whose process on {host} had died: "
            + ", ".join(closed),
            file=sys.stderr,
        )
    return closed


def run_params(config: dict) -> dict[str, str]:
    """One readable MLflow parameter per setting of a fit config: every argument of the model and data
    (`model.lambda_adv`, `data.window`), the trainer settings the config changes from Lightning's
    defaults (`trainer.max_epochs`), the seed, and the model and data classes. Callbacks and the logger
    are left to the run's config.yaml; values that are not plain (lists, mappings) are written as JSON."""
    import inspect
    import json

    from lightning.pytorch import Trainer

    params: dict[str, object] = {"seed_everything": config.get("seed_everything")}
    for section in ("model", "data"):
        node = config.get(section) or {}
        params[section] = str(node.get("class_path", "")).rsplit(".", 1)[-1]
        for key, value in (node.get("init_args") or {}).items():
            if key != "data_spec":  # linked from the data module, not a setting
                params[f"{section}.{key}"] = value
    defaults = {k: p.default for k, p in inspect.signature(Trainer).parameters.items()}
    for key, value in (config.get("trainer") or {}).items():
        if key not in ("callbacks", "logger", "plugins") and value != defaults.get(key, object()):
            params[f"trainer.{key}"] = value
    return {
        key: value if isinstance(value, str | int | float | bool) or value is None else json.dumps(value)
        for key, value in params.items()
    }


# MLflow 3.17's UI opens an experiment on the pages of its sidebar's switch (GenAI, the default, or Model
# training; the browser remembers the last switch), whatever the experiment's tags say. An address that
# carries the switch opens the run list in any browser.
RUN_LIST = "#/experiments/{id}?workflowType=machine_learning"


def ui_addresses(uri: str, base: str) -> dict[str, str]:
    """Each experiment with runs in the store at `uri` -> the address of its run list in the MLflow UI
    served at `base` (`http://127.0.0.1:5000`). An sqlite store that does not exist yet has none (and is
    not created)."""
    from mlflow.tracking import MlflowClient

    uri = absolute_uri(uri)
    if uri.startswith("sqlite:///") and not Path(uri.removeprefix("sqlite:///")).is_file():
        return {}
    client = MlflowClient(tracking_uri=uri)
    return {
        experiment.name: f"{base.rstrip('/')}/{RUN_LIST.format(id=experiment.experiment_id)}"
        for experiment in client.search_experiments()
        if client.search_runs([experiment.experiment_id], max_results=1)
    }


def print_ui_addresses(uri: str, base: str) -> None:
    """What `make ui` says before it starts the server."""
    addresses = ui_addresses(uri, base)
    print(f"MLflow UI on {base} (Ctrl-C to stop). The runs of each experiment:")
    for name, address in sorted(addresses.items()):
        print(f"  {name}: {address}")
    if not addresses:
        print(f"  none yet in {uri}: `walkdiff fit --config ...` makes one")
    print('In the UI, switch the sidebar to "Model training" once: your browser then opens every experiment')
    print("on its runs (MLflow 3.17 opens experiments on its GenAI pages otherwise).")
