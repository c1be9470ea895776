"""``hysteresis-lab-train``: train and evaluate one model, or the study's four.

Examples::

    hysteresis-lab-train                                   # FFNN on the simulated positioner
    hysteresis-lab-train model=lstm data=csv data.train=run.csv data.test=[sine.csv]
    hysteresis-lab-train experiment=paper                  # Table 2 + Figure 1
    hysteresis-lab-train -m hparams_search=ffnn            # Bayesian tuning (Optuna)

The return value is the sweep's objective: the validation MSE (scaled units), or the values of a
multi-objective study's ``sweep_trial.objectives`` (`hysteresis_lab.tuning.objectives`).
"""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from hysteresis_lab._console import filter_library_warnings, terminal
from hysteresis_lab.cli._app import CONFIG_PATH, report_errors
from hysteresis_lab.cli._interrupt import interruptible, run_console_app
from hysteresis_lab.cli._overrides import exit_on_unknown_choice, rename_command_line_overrides
from hysteresis_lab.errors import ConfigError

log = logging.getLogger(__name__)


@report_errors
@interruptible(resumable=True)
def run(cfg: DictConfig) -> float | list[float] | None:
    """Run the task the composed config describes; return the sweep objective."""
    from hysteresis_lab.data.spec import DataSpec
    from hysteresis_lab.lightning_trainer import TrainerSettings
    from hysteresis_lab.tuning.objectives import trial_value
    from hysteresis_lab.tuning.pruning import trial_callback
    from hysteresis_lab.workflows.paper import run_paper
    from hysteresis_lab.workflows.pipeline import train_from_config

    output_dir = Path(HydraConfig.get().runtime.output_dir)
    use_tensorboard = bool(cfg.logger.get("enabled", True))
    if cfg.task == "paper":
        models = OmegaConf.to_container(cfg.paper.models, resolve=True)
        run_paper(
            models,
            DataSpec.from_config(cfg.data),
            TrainerSettings.from_config(cfg.trainer),
            output_dir,
            seed=cfg.seed,
            use_tensorboard=use_tensorboard,
            workers=cfg.paper.get("workers", "auto"),
            resume=bool(cfg.paper.get("resume", True)),
            training=OmegaConf.to_container(cfg.training, resolve=True),
        )
        return None
    if cfg.task != "train":
        raise ConfigError(f"unknown task '{cfg.task}'. Fix: use task=train or experiment=paper.")
    pruning = trial_callback(
        OmegaConf.to_container(cfg.sweep_trial) if "sweep_trial" in cfg else None
    )
    result = train_from_config(cfg, output_dir, callbacks=[pruning] if pruning else None)
    log_run_files(output_dir)
    return trial_value(cfg, result, output_dir)


def log_run_files(output_dir: Path) -> None:
    """The run's last lines: where each file it wrote is."""
    from hysteresis_lab.run_folder import RunFolder

    folder = RunFolder(output_dir)
    model = folder.model_file()
    figures = [folder.figure(name) for name in ("hysteresis_loops", "residuals")]
    tensorboard = output_dir / folder.TENSORBOARD
    checkpoints = [name for name in (folder.CHECKPOINTS, folder.FREE_RUN_CHECKPOINTS)
                   if (output_dir / name).is_dir()]
    logs = sorted(output_dir.glob("*.log"))
    entries = {
        "model": model and f"{model.name} (hysteresis-lab-evaluate checkpoint={output_dir})",
        "scores": folder.metrics.is_file() and folder.METRICS,
        "figures": ", ".join(path.name for path in figures if path.is_file()),
        "TensorBoard": tensorboard.is_dir()
        and f"{folder.TENSORBOARD}/ (tensorboard --logdir {tensorboard})",
        "checkpoints": ", ".join(f"{name}/" for name in checkpoints),
        "full log": logs and logs[0].name,
    }
    log.info("run folder: %s", output_dir)
    for label, entry in entries.items():
        if entry:
            log.info("  %-12s %s", label, entry)


@hydra.main(config_path=CONFIG_PATH, config_name="train")
def _main(cfg: DictConfig) -> float | list[float] | None:
    with terminal():
        return run(cfg)


def main() -> None:
    """Console-script entry point."""
    filter_library_warnings()
    rename_command_line_overrides()
    exit_on_unknown_choice("train")
    run_console_app(_main)


if __name__ == "__main__":
    main()
