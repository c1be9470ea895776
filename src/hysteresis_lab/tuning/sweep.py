"""The sweep loop: ask a trial, run it as a Hydra job, tell the result — resumable and shared.

Used by the Hydra sweeper plugin ``hydra/sweeper=hysteresis_lab``
(`hydra_plugins.hysteresis_lab_sweeper`). Any number of workers (processes, hosts) may run
the same command against one storage; together they run exactly ``n_trials`` counted trials.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import optuna
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import OverrideParseException
from hydra_plugins.hydra_optuna_sweeper._impl import create_params_from_overrides
from omegaconf import DictConfig, OmegaConf
from optuna.distributions import (
    BaseDistribution,
    CategoricalDistribution,
    FloatDistribution,
    IntDistribution,
)
from optuna.trial import TrialState

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.tuning import bookkeeping
from hysteresis_lab.tuning.choices import make_pruner, make_sampler
from hysteresis_lab.tuning.results import sweep_data, write_results
from hysteresis_lab.tuning.storage import STORAGE_ENV, open_storage, redact, resolve_storage_url

log = logging.getLogger(__name__)

Launch = Callable[[list[list[str]]], Sequence[Any]]


@dataclass
class SweepSettings:
    """The sweeper's configuration (``hydra.sweeper.*``)."""

    study_name: str
    n_trials: int = 100
    sampler: str = "gp"
    seed: int = 0
    n_startup_trials: int = 10
    pruner: str = "median"
    warmup_epochs: int = 10
    storage: str | None = None
    results_dir: str = "outputs/optuna"
    grace_s: float = 120.0
    heartbeat_s: float = 10.0


def parse_search_space(
    params: dict[str, str], config: DictConfig
) -> tuple[dict[str, BaseDistribution], dict[str, Any]]:
    """Distributions and fixed values from ``hydra.sweeper.params``; errors before training."""
    lines = [f"{key}={value}" for key, value in params.items()]
    try:
        OverridesParser.create().parse_overrides(lines)
        space, fixed, _ = create_params_from_overrides(lines)
    except (OverrideParseException, ValueError, AssertionError) as exc:
        raise ConfigError(f"invalid search space in hydra.sweeper.params: {exc}") from None
    for name in space:
        if OmegaConf.select(config, name, default="__missing__") == "__missing__":
            raise ConfigError(
                f"search-space parameter '{name}' is not in the config. Fix: correct the name "
                "in hydra.sweeper.params (e.g. model.neurons, training.lr)."
            )
    for name, dist in space.items():
        low, high = getattr(dist, "low", None), getattr(dist, "high", None)
        if low is not None and high is not None and low > high:
            raise ConfigError(f"search space of '{name}' has low {low} > high {high}.")
    return space, fixed


def suggest(trial: optuna.trial.Trial, name: str, dist: BaseDistribution) -> Any:
    if isinstance(dist, FloatDistribution):
        return trial.suggest_float(name, dist.low, dist.high, log=dist.log, step=dist.step)
    if isinstance(dist, IntDistribution):
        return trial.suggest_int(name, dist.low, dist.high, log=dist.log, step=dist.step)
    if isinstance(dist, CategoricalDistribution):
        return trial.suggest_categorical(name, dist.choices)
    raise ConfigError(f"unsupported distribution {dist!r} for '{name}'.")


def run_sweep(
    settings: SweepSettings, config: DictConfig, arguments: list[str], launch: Launch
) -> dict[str, Any]:
    """Run trials until the study holds ``n_trials`` counted ones; write the results."""
    params = OmegaConf.to_container(config.hydra.sweeper.params or {}, resolve=False)
    # command-line sweeps (model.neurons=range(25,101)) extend or replace the config's space
    params = {**params, **dict(a.split("=", 1) for a in arguments if "=" in a)}
    space, fixed = parse_search_space(params, config)
    if not space:
        raise ConfigError("the search space is empty. Fix: choose hparams_search=<model>.")
    make_sampler(settings.sampler, 0)  # validate names before touching the storage
    pruner = make_pruner(settings.pruner, n_warmup_steps=settings.warmup_epochs)
    results_dir = Path(settings.results_dir)
    url = resolve_storage_url(settings.storage, settings.study_name, results_dir)
    storage = open_storage(url)
    probe = optuna.create_study(
        study_name=settings.study_name, storage=storage, direction="minimize", load_if_exists=True
    )
    # a fresh seed per (re)start: a resumed GP/TPE sampler must not replay its first points
    sampler = make_sampler(
        settings.sampler, settings.seed + len(probe.trials), settings.n_startup_trials
    )
    study = optuna.load_study(
        study_name=settings.study_name, storage=storage, sampler=sampler, pruner=pruner
    )
    os.environ[STORAGE_ENV] = url  # the jobs report intermediate values here; never logged
    log.info(
        "study '%s' in %s: %s sampler, %s pruner, %d trials wanted",
        settings.study_name,
        redact(url),
        settings.sampler,
        settings.pruner,
        settings.n_trials,
    )
    fixed_overrides = [f"{k}={v}" for k, v in fixed.items()]
    while True:
        bookkeeping.discard_stale(study, settings.grace_s)
        finished, running = bookkeeping.progress(study)
        if finished + running >= settings.n_trials:
            break
        trial = bookkeeping.ask_claimed(study)
        if bookkeeping.is_surplus(study, trial, settings.n_trials):
            bookkeeping.discard(study, trial, "surplus: another worker took the last slot")
            break
        overrides = [f"{name}={suggest(trial, name, dist)}" for name, dist in space.items()]
        overrides += [
            f"sweep_trial.study={settings.study_name}",
            f"sweep_trial.number={trial.number}",
            f"sweep_trial.pruner={settings.pruner}",
            f"sweep_trial.warmup_epochs={settings.warmup_epochs}",
        ]
        log.info(
            "trial %d (%d/%d finished): %s",
            trial.number,
            finished,
            settings.n_trials,
            " ".join(overrides[: len(space)]),
        )
        with bookkeeping.Heartbeat(trial, settings.heartbeat_s):
            (result,) = launch([fixed_overrides + overrides])
        _tell(study, trial, result)
    finished, running = bookkeeping.progress(study)
    log.info("%d trials finished, %d still running on other workers", finished, running)
    model_name = str(OmegaConf.select(config, "model.name"))
    return write_results(
        study,
        model_name,
        fixed,
        results_dir / settings.study_name,
        results_dir / "best" / "experiment",
        sweep_data(config),
    )


def _tell(study: optuna.Study, trial: optuna.trial.Trial, result: Any) -> None:
    """Record a job's outcome: its value, pruned, or failed (NaN, exception)."""
    try:
        value = result.return_value  # re-raises the job's exception
    except optuna.TrialPruned as exc:
        log.info("trial %d pruned: %s", trial.number, exc)
        study.tell(trial, state=TrialState.PRUNED)
        return
    except Exception as exc:  # a failed trial must not stop the study
        log.warning("trial %d failed: %s: %s", trial.number, type(exc).__name__, exc)
        study.tell(trial, state=TrialState.FAIL)
        return
    try:
        value = float(value)
    except (TypeError, ValueError):
        value = math.nan
    if not math.isfinite(value):
        log.warning("trial %d returned %s: marked failed", trial.number, value)
        study.tell(trial, state=TrialState.FAIL)
        return
    study.tell(trial, value)
