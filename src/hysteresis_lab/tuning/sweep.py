"""The sweep loop: ask a trial, run it as a Hydra job, tell the result — resumable and shared.

Used by the Hydra sweeper plugin ``hydra/sweeper=hysteresis_lab``
(`hydra_plugins.hysteresis_lab_sweeper`). Any number of workers (processes, hosts) may run
the same command against one storage; together they run exactly ``n_trials`` counted trials.
With several ``objectives`` the study is multi-objective (every objective minimised) and its
result is a Pareto front (`hysteresis_lab.tuning.pareto`); its trials report their epochs for
pruning to a single-objective companion study (`pruning_study_name`).
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
from hysteresis_lab.tuning.choices import (
    FIRST_RUNG_EPOCHS,
    make_pruner,
    make_sampler,
    resolve_pruner,
)
from hysteresis_lab.tuning.objectives import (
    OBJECTIVES,
    STOPPED_EPOCHS,
    STOPPED_VALUES,
    check_objectives,
    no_validation_recordings,
)
from hysteresis_lab.tuning.pruning import pruning_study_name
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
    pruner: str = "auto"
    warmup_epochs: int = 10
    min_epochs: int = FIRST_RUNG_EPOCHS
    objectives: Sequence[str] = ("val_mse",)
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
    objectives = check_objectives(settings.objectives)
    pruner_name = resolve_pruner(
        settings.pruner, OmegaConf.select(config, "trainer.accelerator", default=None)
    )
    max_epochs = OmegaConf.select(config, "trainer.max_epochs", default=None)
    pruner = make_pruner(
        pruner_name,
        n_warmup_steps=settings.warmup_epochs,
        max_resource=None if max_epochs is None else int(max_epochs),
        min_resource=settings.min_epochs,
    )
    if "val_free_run_mse" in objectives:
        _check_validation_recordings(config)
    results_dir = Path(settings.results_dir)
    url = resolve_storage_url(settings.storage, settings.study_name, results_dir)
    storage = open_storage(url)
    probe = optuna.create_study(
        study_name=settings.study_name,
        storage=storage,
        load_if_exists=True,
        directions=["minimize"] * len(objectives),
    )
    _check_same_objectives(probe, objectives)
    companion = None
    if len(objectives) > 1:  # Optuna prunes single-objective studies only
        companion = optuna.create_study(
            study_name=pruning_study_name(settings.study_name),
            storage=storage,
            direction="minimize",
            load_if_exists=True,
            pruner=pruner,
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
        "study '%s' in %s: %s sampler, %s pruner, %d trials wanted, minimising %s",
        settings.study_name,
        redact(url),
        settings.sampler,
        pruner_name,
        settings.n_trials,
        " and ".join(OBJECTIVES[name] for name in objectives),
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
        values = {name: suggest(trial, name, dist) for name, dist in space.items()}
        overrides = [f"{name}={value}" for name, value in values.items()]
        reports_to = trial
        if companion is not None:
            reports_to = companion.ask()
            trial.set_user_attr(PRUNING_TRIAL, reports_to.number)
        epochs = values.get("trainer.max_epochs", fixed.get("trainer.max_epochs", max_epochs))
        overrides += [
            f"sweep_trial.study={reports_to.study.study_name}",
            f"sweep_trial.number={reports_to.number}",
            f"sweep_trial.pruner={pruner_name}",
            f"sweep_trial.warmup_epochs={settings.warmup_epochs}",
            f"sweep_trial.min_epochs={settings.min_epochs}",
            f"sweep_trial.max_epochs={'null' if epochs is None else int(epochs)}",
            f"sweep_trial.objectives=[{','.join(objectives)}]",
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
        if companion is not None:
            _copy_stop(companion, reports_to, trial)
        _tell(study, trial, result, len(objectives))
        if companion is not None:
            _tell_companion(companion, reports_to, study, trial)
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
        objectives,
    )


#: user attribute of a multi-objective study's trial: its trial number in the pruning study
PRUNING_TRIAL = "pruning_trial"


def _check_same_objectives(study: optuna.Study, objectives: Sequence[str]) -> None:
    """A stored study keeps its number of objectives; the names are kept in its attributes."""
    stored = study.user_attrs.get("objectives")
    if stored is None and len(study.directions) == len(objectives):
        study.set_user_attr("objectives", list(objectives))  # a new study (or an older one)
        return
    if stored == list(objectives):
        return
    raise ConfigError(
        f"study '{study.study_name}' was run with the objectives "
        f"{stored or f'<{len(study.directions)} unnamed>'}, not {list(objectives)}. Fix: the "
        "same hydra.sweeper.objectives, or a new hydra.sweeper.study_name."
    )


def _check_validation_recordings(config: DictConfig) -> None:
    """Before any trial: a free-run objective needs the data set's validation recordings."""
    from hysteresis_lab.data.factory import build_splits
    from hysteresis_lab.data.spec import DataSpec

    splits = build_splits(DataSpec.from_config(config.data))
    if not splits.val:
        raise ConfigError(no_validation_recordings(splits.name))


def _copy_stop(companion: optuna.Study, reports: optuna.trial.Trial,
               trial: optuna.trial.Trial) -> None:
    """A pruned trial's objectives at its stop (`STOPPED_VALUES`, recorded on the pruning
    study's trial it reported to) onto the multi-objective trial itself."""
    attrs = companion._storage.get_trial(reports._trial_id).user_attrs  # noqa: SLF001
    for key in (STOPPED_VALUES, STOPPED_EPOCHS):
        if key in attrs:
            trial.set_user_attr(key, attrs[key])


def _tell_companion(
    companion: optuna.Study,
    reports: optuna.trial.Trial,
    study: optuna.Study,
    trial: optuna.trial.Trial,
) -> None:
    """Close the pruning study's trial as its multi-objective trial ended (complete: with
    its first objective), so that the pruners see the rungs it reached."""
    frozen = study._storage.get_trial(trial._trial_id)  # noqa: SLF001
    if frozen.state == TrialState.COMPLETE:
        companion.tell(reports, frozen.values[0])
    else:
        companion.tell(reports, state=frozen.state)


def _tell(
    study: optuna.Study, trial: optuna.trial.Trial, result: Any, n_objectives: int = 1
) -> None:
    """Record a job's outcome: its value(s), pruned, or failed (NaN, exception)."""
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
    values = _usable_values(value, n_objectives)
    if values is None:
        log.warning("trial %d returned %s: marked failed", trial.number, value)
        study.tell(trial, state=TrialState.FAIL)
        return
    study.tell(trial, values[0] if n_objectives == 1 else values)


def _usable_values(value: Any, n_objectives: int) -> list[float] | None:
    """The job's return as ``n_objectives`` floats; None when it is not that. A single
    objective must be finite; in a multi-objective study +inf stands for a free run that
    diverged (`hysteresis_lab.tuning.objectives.free_run_mse`): a result the sampler learns
    from, which the Pareto front leaves out."""
    raw = value if isinstance(value, Sequence) and not isinstance(value, str) else [value]
    try:
        values = [float(v) for v in raw]
    except (TypeError, ValueError):
        return None
    allowed = math.isfinite if n_objectives == 1 else (lambda v: v == math.inf or math.isfinite(v))
    if len(values) != n_objectives or not all(allowed(v) for v in values):
        return None
    return values
