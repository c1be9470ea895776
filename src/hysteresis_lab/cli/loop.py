"""``hysteresis-lab-loop``: the closed residual loop (see `hysteresis_lab.workflows.loop`).

Example::

    hysteresis-lab-loop model=ffnn data=csv data.train=run.csv data.test=[s1.csv,s2.csv]
"""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from hysteresis_lab._console import SUMMARY, filter_library_warnings, log_file, terminal
from hysteresis_lab.cli._app import CONFIG_PATH, report_errors
from hysteresis_lab.cli._interrupt import interruptible, run_console_app
from hysteresis_lab.cli._overrides import exit_on_unknown_choice, rename_command_line_overrides

log = logging.getLogger(__name__)


@report_errors
@interruptible(resumable=True)
def run(cfg: DictConfig) -> dict:
    """Build the data, run the loop, return the report."""
    from hysteresis_lab.data.factory import build_splits
    from hysteresis_lab.data.spec import DataSpec
    from hysteresis_lab.errors import ConfigError
    from hysteresis_lab.lightning_trainer import TrainerSettings
    from hysteresis_lab.workflows.loop import LoopSettings, run_loop

    settings = OmegaConf.to_container(cfg.loop, resolve=True)
    unknown = set(settings) - set(LoopSettings.__dataclass_fields__)
    if unknown:
        raise ConfigError(
            f"unknown loop setting(s) {sorted(unknown)}. Valid: "
            f"{sorted(LoopSettings.__dataclass_fields__)}."
        )
    loop_settings = LoopSettings(**settings)  # checked before any data is built
    output_dir = Path(HydraConfig.get().runtime.output_dir)
    full_log = log_file()
    log.info("loop in %s: one line per round here%s", output_dir,
             f", each fit's own lines in {full_log}" if full_log else "", extra=SUMMARY)
    data = DataSpec.from_config(cfg.data)
    return run_loop(
        OmegaConf.to_container(cfg.model, resolve=True),
        data,
        TrainerSettings.from_config(cfg.trainer),
        build_splits(data),
        output_dir,
        loop_settings,
        seed=cfg.seed,
        use_tensorboard=bool(cfg.logger.enabled),
        training=OmegaConf.to_container(cfg.training, resolve=True),
    )


@hydra.main(config_path=CONFIG_PATH, config_name="loop")
def _main(cfg: DictConfig) -> None:
    with terminal(summary_only=True):
        run(cfg)


def main() -> None:
    """Console-script entry point."""
    filter_library_warnings()
    rename_command_line_overrides()
    exit_on_unknown_choice("loop")
    run_console_app(_main)


if __name__ == "__main__":
    main()
