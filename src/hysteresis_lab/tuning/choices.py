"""Samplers and pruners by name, with clear errors for unknown ones."""

from __future__ import annotations

import optuna

from hysteresis_lab.errors import ConfigError

SAMPLERS = ("gp", "tpe", "random")
PRUNERS = ("median", "hyperband", "none")


def make_sampler(name: str, seed: int, n_startup_trials: int = 10) -> optuna.samplers.BaseSampler:
    """Gaussian-process BO (the study's method), TPE or random search."""
    if name == "gp":
        return optuna.samplers.GPSampler(seed=seed, n_startup_trials=n_startup_trials)
    if name == "tpe":
        return optuna.samplers.TPESampler(seed=seed, n_startup_trials=n_startup_trials)
    if name == "random":
        return optuna.samplers.RandomSampler(seed=seed)
    raise ConfigError(
        f"unknown sampler '{name}'. Fix: hydra.sweeper.sampler=one of {list(SAMPLERS)}."
    )


def make_pruner(
    name: str, n_startup_trials: int = 5, n_warmup_steps: int = 10
) -> optuna.pruners.BasePruner:
    """Median stopping (default), Hyperband, or no pruning."""
    if name == "median":
        return optuna.pruners.MedianPruner(
            n_startup_trials=n_startup_trials, n_warmup_steps=n_warmup_steps
        )
    if name == "hyperband":
        return optuna.pruners.HyperbandPruner(min_resource=n_warmup_steps)
    if name == "none":
        return optuna.pruners.NopPruner()
    raise ConfigError(f"unknown pruner '{name}'. Fix: hydra.sweeper.pruner=one of {list(PRUNERS)}.")
