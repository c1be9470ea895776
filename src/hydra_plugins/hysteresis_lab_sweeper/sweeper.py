"""Hydra glue for `hysteresis_lab.tuning.sweep`: config schema and the Sweeper plugin."""

from __future__ import annotations

import logging
import sys
from dataclasses import dataclass, field
from typing import Any

from hydra.core.config_store import ConfigStore
from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig


@dataclass
class HysteresisLabSweeperConf:
    _target_: str = "hydra_plugins.hysteresis_lab_sweeper.sweeper.HysteresisLabSweeper"
    study_name: str = "study"
    n_trials: int = 100
    sampler: str = "gp"  # gp (Gaussian-process BO, the study's method) | tpe | random
    seed: int = 0
    n_startup_trials: int = 10  # random trials before the model-based sampler takes over
    # auto: successive halving when trials train on the CPU, else median | hyperband |
    # successive_halving | median | none
    pruner: str = "auto"
    warmup_epochs: int = 10  # median pruning: epochs before a trial may be pruned
    min_epochs: int = 3  # successive halving and Hyperband: epochs to the first rung
    # minimised; several: a multi-objective study and its Pareto front (val_mse |
    # val_free_run_mse | train_seconds)
    objectives: list[str] = field(default_factory=lambda: ["val_mse"])
    storage: str | None = None  # default: sqlite under results_dir; see README for PostgreSQL
    results_dir: str = "outputs/optuna"
    grace_s: float = 120.0  # a running trial without heartbeat this long is re-run
    heartbeat_s: float = 10.0
    params: dict[str, Any] = field(default_factory=dict)


ConfigStore.instance().store(
    group="hydra/sweeper",
    name="hysteresis_lab",
    node=HysteresisLabSweeperConf,
    provider="hysteresis_lab",
)


class HysteresisLabSweeper(Sweeper):
    """Ask/tell loop over Hydra jobs against a shared Optuna storage."""

    def __init__(self, params: Any = None, **settings: Any) -> None:
        from hysteresis_lab.tuning.sweep import SweepSettings

        self.settings = SweepSettings(**settings)
        self.config: DictConfig | None = None
        self.launcher: Any = None
        self.job_idx = 0

    def setup(
        self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig
    ) -> None:
        from hydra.core.plugins import Plugins

        self.config = config
        self.launcher = Plugins.instance().instantiate_launcher(
            hydra_context=hydra_context, task_function=task_function, config=config
        )

    def sweep(self, arguments: list[str]) -> Any:
        from hysteresis_lab.errors import HysteresisLabError
        from hysteresis_lab.tuning.sweep import run_sweep

        def launch(batch: list[list[str]]) -> Any:
            returns = self.launcher.launch(batch, initial_job_idx=self.job_idx)
            self.job_idx += len(returns)
            return returns

        assert self.config is not None
        try:
            return run_sweep(self.settings, self.config, arguments, launch)
        except HysteresisLabError as exc:  # one clear line, no traceback
            logging.getLogger("hysteresis_lab").error("%s", exc)
            sys.exit(2)
