"""What a `walkdiff fit` run shows in MLflow: a model-training experiment, one name per run, one
readable parameter per setting, the git commit, system metrics, and the best and last checkpoints."""

from __future__ import annotations

import json
from pathlib import Path

import probes
import pytest
import synthetic
from mlflow.tracking import MlflowClient

from walkdiff.cli.main import main


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("tiny")
    synthetic.xia_like_folder(root, walk_clips=8, frames=240)
    return root


def test_a_fit_run_reads_at_a_glance(tiny_root, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("sys.argv", ["walkdiff"])
    monkeypatch.setattr("walkdiff.callbacks.tracking.SYSTEM_METRICS_SECONDS", 1)
    best = {
        "class_path": "walkdiff.callbacks.checkpoints.RunCheckpoint",
        "init_args": {
            "dirpath": "checkpoints/glance",
            "filename": "best-{epoch:04d}",
            "monitor": "diffusion/val",
        },
    }
    slow = {"class_path": "probes.SleepEachBatch", "init_args": {"seconds": 0.4}}  # > 1 s: system metrics
    samples = {
        "class_path": "walkdiff.callbacks.samples.SampleClips",
        "init_args": {"every_n_steps": 2, "sampler": "ddim", "steps": 2, "seconds": 2},
    }
    config = tmp_path / "glance.yaml"
    config.write_text(
        probes.tiny_fit_config(tiny_root, "glance", epochs=2, batches=2, callbacks=[best, slow, samples])
    )
    for _ in range(2):
        assert main(["fit", "--config", str(config)]) == 0

    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path}/mlruns/mlflow.db")
    experiment = client.get_experiment_by_name("walkdiff-test")
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"  # the UI opens on runs
    runs = client.search_runs([experiment.experiment_id])
    names = [run.info.run_name for run in runs]
    assert len(set(names)) == 2 and all(name.startswith("glance-") for name in names)

    run = runs[0]
    params = run.data.params
    # One parameter per setting, none twice (no `lambda_adv` beside `model.init_args.lambda_adv`).
    assert params["model.lambda_adv"] == "0.05" and params["data.window"] == "24"
    assert params["trainer.max_steps"] == "4" and params["model"] == "StyledMotionDiffusion"
    sections = ("model.", "data.", "trainer.")
    assert all(key in ("seed_everything", "model", "data") or key.startswith(sections) for key in params)
    assert not [key for key in params if "init_args" in key or "callbacks" in key or "logger" in key]
    assert "lambda_adv" not in params
    # The hyperparameters: every argument of the model and data module, and the trainer settings the
    # config changes (max_steps, limit_train_batches, ...); the rest of the trainer is Lightning's own.
    import inspect

    from walkdiff.data.datamodule import MotionDataModule
    from walkdiff.models.styled_ddpm import StyledMotionDiffusion

    arguments = [
        set(inspect.signature(c).parameters) - {"data_spec"}
        for c in (StyledMotionDiffusion, MotionDataModule)
    ]
    trainer = [key for key in params if key.startswith("trainer.")]
    assert 0 < len(trainer) <= 12, trainer
    assert len(params) <= 1.2 * (sum(map(len, arguments)) + len(trainer))

    assert len(run.data.tags["mlflow.source.git.commit"]) == 40
    assert run.data.tags["walkdiff.git_dirty"] in ("true", "false")
    assert any(key.startswith("system/cpu_utilization") for key in run.data.metrics), run.data.metrics.keys()

    # The styles' filmstrip as an image at each validation's step (MLflow's image view steps through them).
    images = [a.path for a in client.list_artifacts(run.info.run_id, "images")]
    filmstrips = [
        path for path in images if path.startswith("images/samples~styles+step+") and path.endswith(".png")
    ]
    assert len(filmstrips) == 2, images  # after batches 2 and 4
    previews = {a.path for a in client.list_artifacts(run.info.run_id, "samples")}
    assert previews == {"samples/step_000002", "samples/step_000004"}

    files = {a.path for a in client.list_artifacts(run.info.run_id, "checkpoints")}
    assert files == {"checkpoints/best.ckpt", "checkpoints/last.ckpt", "checkpoints/index.json"}
    index = json.loads(Path(client.download_artifacts(run.info.run_id, "checkpoints/index.json")).read_text())
    assert index["best.ckpt"]["monitor"] == "diffusion/val" and index["best.ckpt"]["score"] > 0
    assert index["last.ckpt"]["monitor"] is None

    # Every checkpoint names the run that wrote it; a run that uses it (a generator's metrics use the
    # evaluator's) is tagged with that run.
    from walkdiff.callbacks.tracking import checkpoint_tags

    newest = max(runs, key=lambda r: r.info.start_time)
    tags = checkpoint_tags(tmp_path / "checkpoints" / "glance" / "last.ckpt", "evaluator")
    assert tags["walkdiff.evaluator_run"] == f"{experiment.experiment_id}/{newest.info.run_id}"
    assert tags["walkdiff.evaluator_checkpoint"].endswith(f"{newest.info.run_id}/last.ckpt")
