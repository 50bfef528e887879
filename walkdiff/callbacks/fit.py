"""The LightningCLI behind `walkdiff fit/validate/test` (and `bench train`): omegaconf configs, the MLflow run
records, and what is said after a fit."""

from __future__ import annotations

import sys
import time


def lightning_cli(args: list[str] | None, callbacks: list | None = None):
    """LightningCLI in omegaconf mode: `walkdiff fit --config conf/xia.yaml --model.lambda_adv 0.05`.

    `callbacks` join the config's (`walkdiff bench train --to-bar` times a run with them); returns the CLI.
    """
    from lightning.pytorch.cli import LightningCLI, SaveConfigCallback

    from walkdiff.common.tracking import absolute_uri, check_tracking_uri

    class LogConfigToMLflow(SaveConfigCallback):
        """MLflow's sqlite URI has no log_dir: the resolved config goes into the run instead."""

        def save_config(self, trainer, pl_module, stage) -> None:
            from walkdiff.common.tracking import log_text, run_params

            text = self.parser.dump(self.config, skip_none=False)
            log_text(trainer.logger, text, "config.yaml")
            if trainer.logger is not None:
                trainer.logger.log_hyperparams(run_params(self.config.as_dict()))

    class WalkdiffCLI(LightningCLI):
        def add_arguments_to_parser(self, parser) -> None:
            parser.link_arguments("data.spec", "model.init_args.data_spec", apply_on="instantiate")

        def before_fit(self) -> None:
            from walkdiff.callbacks.clock import ProgressLog
            from walkdiff.common.threads import CHOSEN

            open_run(self.trainer)
            self.trainer.callbacks.extend(callbacks or [])
            if not sys.stderr.isatty():  # a terminal has Lightning's progress bar; a log file gets lines
                self.trainer.callbacks.append(ProgressLog())
            for line in CHOSEN:
                print(f"walkdiff: {line}", file=sys.stderr)

        def after_fit(self) -> None:
            report_fit(self.trainer)

        def before_instantiate_classes(self) -> None:
            config = self.config[self.subcommand] if self.subcommand else self.config
            if config.trainer.strategy == "ddp":
                # Generator and discriminator steps alternate, so each backward leaves the other
                # network's parameters without gradients: DDP must be told to expect that.
                print("walkdiff: strategy ddp -> ddp_find_unused_parameters_true (GAN steps alternate)")
                config.trainer.strategy = "ddp_find_unused_parameters_true"
            logger = config.trainer.logger
            uri = getattr(getattr(logger, "init_args", None), "tracking_uri", None)
            if uri:
                logger.init_args.tracking_uri = uri = absolute_uri(uri)
                check_tracking_uri(uri)
            name = getattr(getattr(logger, "init_args", None), "run_name", None)
            if name:  # one name per run in the UI: the config's, and when it started
                logger.init_args.run_name = f"{name}-{time.strftime('%Y%m%d-%H%M%S')}"

    import lightning as L

    return WalkdiffCLI(
        L.LightningModule,
        L.LightningDataModule,  # MotionDataModule (walking) or SpeechDataModule (gestures), per config
        subclass_mode_model=True,
        subclass_mode_data=True,
        save_config_callback=LogConfigToMLflow,
        save_config_kwargs={"save_to_log_dir": False},
        # exit_on_error=False: a bad option or config raises, and `main` prints one message, not the usage.
        parser_kwargs={"parser_mode": "omegaconf", "exit_on_error": False},
        args=args,
    )


def open_run(trainer) -> None:
    """Before `fit`: what walkdiff records about every MLflow run (`walkdiff.callbacks.tracking`).

    Lightning closes its run as FAILED on an exception, Ctrl-C or SIGTERM; after SIGKILL nothing can, so
    the next `fit` into the experiment does (`walkdiff.common.tracking.close_dead_runs`).
    """
    from walkdiff.callbacks.checkpoints import mlflow_logger
    from walkdiff.callbacks.tracking import RunTracking

    if mlflow_logger(trainer) is not None and not any(isinstance(c, RunTracking) for c in trainer.callbacks):
        trainer.callbacks.append(RunTracking())


def report_fit(trainer) -> None:
    """After `fit`: where the checkpoints are, and whether max_time cut the planned steps short.

    A run stopped by time depends on the machine's speed (a busy machine trains fewer epochs), so it is
    said on the console and tagged in the MLflow run.
    """
    from lightning.pytorch.callbacks import Timer

    from walkdiff.callbacks.checkpoints import RunCheckpoint

    planned, done = trainer.max_steps, trainer.global_step
    timer = next((c for c in trainer.callbacks if isinstance(c, Timer)), None)
    timed_out = timer is not None and (timer.time_remaining("train") or 0) <= 0
    if timed_out and not 0 < planned <= done:
        message = (
            f"max_time stopped training after step {done} of {planned}: on a slower or busier machine "
            "the same command trains fewer steps; --trainer.max_time null trains them all"
        )
        print(f"walkdiff: {message}", file=sys.stderr)
        logger = trainer.logger
        if logger is not None and hasattr(logger, "run_id") and hasattr(logger.experiment, "set_tag"):
            logger.experiment.set_tag(
                logger.run_id, "walkdiff.stopped_by_max_time", f"step {done} of {planned}"
            )
    run_dirs = {c.run_dir for c in trainer.checkpoint_callbacks if isinstance(c, RunCheckpoint)} - {None}
    for run_dir in sorted(run_dirs):
        print(f"walkdiff: checkpoints of this run in {run_dir}")
    for callback in trainer.checkpoint_callbacks:
        if isinstance(callback, RunCheckpoint):
            for link, target in callback.links().items():
                print(f"walkdiff: checkpoint {link} -> {target}")
            continue
        for path in {callback.best_model_path, callback.last_model_path} - {""}:
            print(f"walkdiff: checkpoint {path}")
