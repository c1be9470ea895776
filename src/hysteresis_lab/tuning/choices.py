"""Samplers and pruners by name, with clear errors for unknown ones."""

from __future__ import annotations

import optuna

from hysteresis_lab.errors import ConfigError

SAMPLERS = ("gp", "tpe", "random")
#: ``auto``: multi-fidelity successive halving when the trials train on the CPU, median otherwise
PRUNERS = ("auto", "hyperband", "successive_halving", "median", "none")
#: Hyperband's and successive halving's share of trials kept at each rung is 1 / this
REDUCTION_FACTOR = 3
#: the default first rung of Hyperband and successive halving, in epochs
FIRST_RUNG_EPOCHS = 3


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


def resolve_pruner(name: str, accelerator: str | None) -> str:
    """The pruner ``name`` stands for: ``auto`` is successive halving for a study whose trials
    train on the CPU (``trainer.accelerator`` cpu, or auto without a GPU), median stopping
    otherwise. Successive halving rather than Hyperband: Hyperband hedges with brackets whose
    trials run far past the first rung unpruned, several times the epochs per trial."""
    check_pruner(name)
    if name != "auto":
        return name
    import torch

    on_cpu = accelerator == "cpu" or (
        accelerator in (None, "auto") and not torch.cuda.is_available()
    )
    return "successive_halving" if on_cpu else "median"


def check_pruner(name: str) -> None:
    if name not in PRUNERS:
        raise ConfigError(
            f"unknown pruner '{name}'. Fix: hydra.sweeper.pruner=one of {list(PRUNERS)}."
        )


def make_pruner(
    name: str,
    n_startup_trials: int = 5,
    n_warmup_steps: int = 10,
    max_resource: int | None = None,
    min_resource: int = FIRST_RUNG_EPOCHS,
) -> optuna.pruners.BasePruner:
    """Hyperband or successive halving (multi-fidelity: epochs are the resource, the first
    rung after ``min_resource`` epochs, ``max_resource`` the trials' ``max_epochs``; None:
    read off the first finished trial), median stopping after ``n_warmup_steps`` epochs, or
    no pruning. ``auto`` must have been resolved (`resolve_pruner`)."""
    check_pruner(name)
    if name == "median":
        return optuna.pruners.MedianPruner(
            n_startup_trials=n_startup_trials, n_warmup_steps=n_warmup_steps
        )
    min_resource = max(1, min_resource)
    if name in ("hyperband", "successive_halving") and (
        max_resource is not None and max_resource <= min_resource
    ):
        return optuna.pruners.NopPruner()  # no trial lives past its first rung
    if name == "successive_halving":
        return optuna.pruners.SuccessiveHalvingPruner(
            min_resource=min_resource, reduction_factor=REDUCTION_FACTOR
        )
    if name == "hyperband":
        return optuna.pruners.HyperbandPruner(
            min_resource=min_resource,
            max_resource=max_resource or "auto",
            reduction_factor=REDUCTION_FACTOR,
        )
    if name == "none":
        return optuna.pruners.NopPruner()
    raise ConfigError(f"pruner '{name}' must be resolved first (resolve_pruner).")
