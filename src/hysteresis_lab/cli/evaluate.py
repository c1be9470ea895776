"""``hysteresis-lab-evaluate``: score a saved model on test recordings without retraining.

Example::

    hysteresis-lab-evaluate checkpoint=outputs/train/ffnn_default/<run>/model.ckpt \
        data=csv data.train=run.csv data.test=[new_sine.csv]
"""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from hysteresis_lab.cli._app import CONFIG_PATH, report_errors
from hysteresis_lab.cli._interrupt import interruptible, run_console_app
from hysteresis_lab.cli._overrides import exit_on_unknown_choice
from hysteresis_lab.errors import ConfigError

log = logging.getLogger(__name__)


@report_errors
@interruptible(resumable=False)
def run(cfg: DictConfig) -> dict:
    """Load the model, score it on the data config's test recordings, write metrics.json."""
    from hysteresis_lab.data.factory import build_splits
    from hysteresis_lab.evaluation.evaluate import evaluate_model
    from hysteresis_lab.evaluation.plots import loops_figure, residuals_figure, save_figure
    from hysteresis_lab.evaluation.report import metrics_document
    from hysteresis_lab.models.augment import for_model
    from hysteresis_lab.models.io import load_model, model_window
    from hysteresis_lab.run_folder import RunFolder

    if OmegaConf.is_missing(cfg, "checkpoint") or not cfg.checkpoint:
        raise ConfigError(
            "no model to evaluate: checkpoint is not set. Fix: checkpoint=<model.ckpt or "
            "model.skops, or the run folder of hysteresis-lab-train that holds it>."
        )
    data_cfg = OmegaConf.to_container(cfg.data, resolve=True)
    if "test" in data_cfg and not data_cfg["test"]:
        raise ConfigError(
            f"no test file to evaluate on: data.test is empty (data={data_cfg.get('name')}). "
            "Fix: data.test=[new.csv] (a list of recordings to score)."
        )
    folder = RunFolder(Path(HydraConfig.get().runtime.output_dir))
    model = load_model(resolve_checkpoint(Path(str(cfg.checkpoint))))
    splits_cfg = data_cfg.get("splits") or {}
    if "train" in splits_cfg and not splits_cfg["train"] and data_cfg.get("test"):
        splits_cfg["train"] = data_cfg["test"][0]  # nothing is fitted; a stand-in for validation
    splits = build_splits(data_cfg)
    device = cfg.device
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    if device not in {"cpu", "cuda"}:
        raise ConfigError(f"device={device!r} is not one of auto, cpu, cuda. Fix: device=auto.")
    evaluation = evaluate_model(
        model,
        for_model(model, splits.test),
        model_window(model),
        n_init=splits.n_init,
        n_steps=cfg.get("n_step"),
        device=device,
        initial_state=str(cfg.evaluation.initial_state),
    )
    units = {"u": splits.test[0].u_units, "y": splits.test[0].y_units}
    document = metrics_document(
        str(getattr(model, "registry_name", type(model).__name__)),
        units,
        evaluation.metrics,
        train_seconds=0.0,
        extra={"checkpoint": str(cfg.checkpoint), "data": splits.name,
               "initial_state": str(cfg.evaluation.initial_state)},
    )
    folder.write_metrics(document)
    if cfg.plots:
        save_figure(loops_figure(splits.test, evaluation.predictions),
                    folder.figure("hysteresis_loops"))
        save_figure(residuals_figure(splits.test, evaluation.predictions),
                    folder.figure("residuals"))
    log.info("metrics written to %s", folder.metrics)
    return document


def resolve_checkpoint(path: Path) -> Path:
    """Accept a model file or a run folder that holds ``model.ckpt`` / ``model.skops``."""
    from hysteresis_lab.run_folder import RunFolder

    if path.is_dir():
        model_file = RunFolder(path).model_file()
        if model_file is not None:
            return model_file
        raise ConfigError(
            f"{path} holds no model.ckpt or model.skops. Fix: pass checkpoint=<run folder of "
            "hysteresis-lab-train> or the model file itself."
        )
    return path


@hydra.main(config_path=CONFIG_PATH, config_name="evaluate")
def _main(cfg: DictConfig) -> None:
    run(cfg)


def main() -> None:
    """Console-script entry point."""
    exit_on_unknown_choice("evaluate")
    run_console_app(_main)


if __name__ == "__main__":
    main()
