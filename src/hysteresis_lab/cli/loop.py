"""``hysteresis-lab-loop``: the closed residual loop (see `hysteresis_lab.loop.driver`).

Example::

    hysteresis-lab-loop model=ffnn data=csv data.train=run.csv data.test=[s1.csv,s2.csv]

`run_fresh_loop` runs the same loop from a script (the studies in ``experiments/`` and
``benchmarks/``), in the calling process.
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from hysteresis_lab._console import SUMMARY, filter_library_warnings, log_file, terminal
from hysteresis_lab.cli._app import CONFIG_PATH, report_errors
from hysteresis_lab.cli._interrupt import interruptible, run_console_app
from hysteresis_lab.cli._overrides import exit_on_unknown_choice, rename_command_line_overrides
from hysteresis_lab.errors import HysteresisLabError
from hysteresis_lab.run_folder import LoopFolder

log = logging.getLogger(__name__)

#: the line format of the console app's full log (Hydra's file handler)
LOG_FORMAT = "[%(asctime)s][%(name)s][%(levelname)s] - %(message)s"


@report_errors
@interruptible(resumable=True)
def run(cfg: DictConfig) -> dict:
    """Build the data, run the loop into Hydra's run folder, return the report."""
    return run_config(cfg, Path(HydraConfig.get().runtime.output_dir))


def run_config(cfg: DictConfig, output_dir: Path) -> dict:
    """Build the data of a composed ``loop`` config, run the loop into ``output_dir``,
    return the report."""
    from hysteresis_lab.data.factory import build_splits
    from hysteresis_lab.data.spec import DataSpec
    from hysteresis_lab.errors import ConfigError
    from hysteresis_lab.lightning_trainer import TrainerSettings
    from hysteresis_lab.loop.driver import LoopSettings, run_loop

    settings = OmegaConf.to_container(cfg.loop, resolve=True)
    unknown = set(settings) - set(LoopSettings.__dataclass_fields__)
    if unknown:
        raise ConfigError(
            f"unknown loop setting(s) {sorted(unknown)}. Valid: "
            f"{sorted(LoopSettings.__dataclass_fields__)}."
        )
    loop_settings = LoopSettings(**settings)  # checked before any data is built
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
        plots=bool(cfg.plots),
    )


def run_fresh_loop(overrides: Sequence[str], folder: Path) -> tuple[dict[str, Any], float]:
    """Run the loop of ``hysteresis-lab-loop <overrides>`` in this process into ``folder``,
    emptied first (the loop would reuse the fits it finds there); its report as written
    (``loop_report.json``) and its wall time in s. The folder holds what the console app
    leaves there: the config (``.hydra/config.yaml``, which `hysteresis_lab.loop.checks`
    reads) and the full log (``loop.log``). A config or data error is a RuntimeError naming
    the command."""
    from hysteresis_lab.api import compose

    folder = Path(folder).resolve()
    if folder.exists():
        shutil.rmtree(folder)
    start = time.perf_counter()
    try:
        cfg = compose(*overrides, config="loop")
        hydra_dir = folder / ".hydra"
        hydra_dir.mkdir(parents=True)
        OmegaConf.save(cfg, hydra_dir / "config.yaml")
        OmegaConf.save(OmegaConf.create(list(overrides)), hydra_dir / "overrides.yaml")
        with _full_log(folder / "loop.log"):
            run_config(cfg, folder)
    except HysteresisLabError as exc:
        raise RuntimeError(f"hysteresis-lab-loop {' '.join(overrides)} failed:\n{exc}") from exc
    seconds = time.perf_counter() - start
    return json.loads(LoopFolder(folder).report_json.read_text()), seconds


@contextmanager
def _full_log(path: Path) -> Iterator[None]:
    """Every line the package logs at INFO and above also goes to ``path`` while it runs."""
    handler = logging.FileHandler(path)
    handler.setFormatter(logging.Formatter(LOG_FORMAT))
    package = logging.getLogger("hysteresis_lab")
    level = package.level
    package.setLevel(logging.INFO)
    package.addHandler(handler)
    try:
        yield
    finally:
        package.removeHandler(handler)
        package.setLevel(level)
        handler.close()


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
