"""What a finished sweep leaves behind: best config, trials table, history and importance plots,
and for a multi-objective study its Pareto front (`hysteresis_lab.tuning.pareto`)."""

from __future__ import annotations

import csv
import json
import logging
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import optuna
import yaml
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import OverrideType
from matplotlib.figure import Figure
from omegaconf import DictConfig, OmegaConf
from optuna.trial import TrialState

from hysteresis_lab.tuning.bookkeeping import counted
from hysteresis_lab.tuning.objectives import DEFAULT_OBJECTIVES, OBJECTIVES
from hysteresis_lab.tuning.pareto import pareto_front, write_front

log = logging.getLogger(__name__)


def first_best_trial(study: optuna.Study) -> int | None:
    """Number of the trial at which the final best value (of the first objective) was first
    reached."""
    complete = [
        t
        for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
        if counted(t) and t.values and math.isfinite(t.values[0])
    ]
    if not complete:
        return None
    best = min(t.values[0] for t in complete)
    return min(t.number for t in complete if t.values[0] <= best)


def best_trial(study: optuna.Study) -> optuna.trial.FrozenTrial:
    """The trial with the lowest first objective (the error): the best trial of a
    single-objective study, the front's most accurate trial of a multi-objective one.
    `ValueError` when no trial completed."""
    if len(study.directions) == 1:
        return study.best_trial
    front = pareto_front(study)
    if not front:
        raise ValueError("no complete trial")
    return front[0]


def sweep_data(config: DictConfig) -> dict[str, Any]:
    """The data the sweep's trials trained on, as the sweep's command line chose it: its
    ``data`` choice and every ``data.*`` value the command line set (``data.train=...``),
    read from the ``hydra`` node of the sweep's config; empty outside a Hydra app."""
    hydra_cfg = config.get("hydra") if isinstance(config, DictConfig) else None
    if hydra_cfg is None:
        return {}
    choice = OmegaConf.select(hydra_cfg, "runtime.choices.data", default=None)
    data: dict[str, Any] = {"choice": choice, "values": {}}
    parsed = OverridesParser.create().parse_overrides(
        list(OmegaConf.select(hydra_cfg, "overrides.task", default=[]) or []))
    for override in parsed:
        key = override.key_or_group
        if not key.startswith("data.") or override.package is not None:
            continue
        if override.is_sweep_override():  # tuned: among the best trial's parameters
            continue
        if override.type == OverrideType.DEL:
            log.warning("the best-trial file cannot repeat the override %s: add it to the "
                        "training command yourself", override.input_line)
            continue
        data["values"][key.removeprefix("data.")] = override.value()
    return data


def best_config(
    study: optuna.Study, model_name: str, data: dict[str, Any] | None = None
) -> dict[str, Any]:
    """A ``# @package _global_`` experiment config with the best trial's tuned values and the
    sweep's data (`sweep_data`), so that it trains on what the trial trained on."""
    params = dict(best_trial(study).params)
    defaults: list[dict[str, Any]] = [{"override /model": model_name}]
    if data and data.get("choice"):
        defaults.append({"override /data": data["choice"]})
    config: dict[str, Any] = {"defaults": defaults, "model": {}}
    values = {f"data.{k}": v for k, v in (data or {}).get("values", {}).items()}
    for dotted, value in {**values, **params}.items():
        node = config
        *parents, leaf = dotted.split(".")
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = value
    return config


def write_results(
    study: optuna.Study,
    model_name: str,
    fixed: dict[str, Any],
    directory: Path,
    experiment_dir: Path,
    data: dict[str, Any] | None = None,
    objectives: Sequence[str] = DEFAULT_OBJECTIVES,
) -> dict[str, Any]:
    """Write trials.csv, best_<study>.yaml, history and importance PNGs, summary.json, and
    with several ``objectives`` the Pareto front (pareto.csv, pareto.md, pareto.png); the
    best config is then the front's lowest-error trial. ``data``: the sweep's data
    (`sweep_data`), repeated in best_<study>.yaml."""
    directory.mkdir(parents=True, exist_ok=True)
    objectives = list(objectives)
    trials = study.get_trials(deepcopy=False)
    write_trials_csv(trials, directory / "trials.csv", objectives)
    summary: dict[str, Any] = {
        "study": study.study_name,
        "objectives": objectives,
        "n_trials": sum(counted(t) for t in trials),
        "states": {s.name: sum(t.state == s and counted(t) for t in trials) for s in TrialState},
    }
    if len(objectives) > 1:
        front = write_front(study, directory, objectives)
        summary["pareto_front"] = [
            {"trial": p.number, "values": dict(zip(objectives, p.values, strict=True)),
             "params": p.params, "pruned_at_epoch": p.stopped_epochs} for p in front]
    try:
        best = best_trial(study)
    except ValueError:
        log.warning("no completed trial yet: nothing to report as best")
        (directory / "summary.json").write_text(json.dumps(summary, indent=2))
        return summary
    experiment_dir.mkdir(parents=True, exist_ok=True)
    config_name = f"best_{study.study_name}"
    config_path = experiment_dir / f"{config_name}.yaml"
    scores = ", ".join(f"{OBJECTIVES.get(name, name)} {value:.4e}"
                       for name, value in zip(objectives, best.values, strict=True))
    header = (
        f"# @package _global_\n# Best of Optuna study '{study.study_name}' "
        f"(trial {best.number}, {scores}).\n"
        "# It trains on the sweep's data: its data choice and data.* settings are below.\n"
    )
    config = best_config(study, model_name, data)
    config_path.write_text(header + yaml.safe_dump(config, sort_keys=False))
    summary.update(
        {
            "best_value": best.values[0],
            "best_params": best.params,
            "best_trial": best.number,
            "first_reached_at_trial": first_best_trial(study),
            "best_config": str(config_path),
            "use_it": f"hysteresis-lab-train experiment={config_name}",
        }
    )
    _plot(study, directory, OBJECTIVES.get(objectives[0], objectives[0]))
    (directory / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    log.info(
        "best %s %.4e at trial %d (first reached at trial %s); train it with: %s",
        OBJECTIVES.get(objectives[0], objectives[0]),
        best.values[0],
        best.number,
        summary["first_reached_at_trial"],
        summary["use_it"],
    )
    return summary


def write_trials_csv(
    trials: list[optuna.trial.FrozenTrial], path: Path,
    objectives: Sequence[str] = DEFAULT_OBJECTIVES,
) -> Path:
    """One row per trial: number, state, value (one column per objective when there are
    several), parameters, timing, worker, discarded."""
    names = sorted({name for t in trials for name in t.params})
    value_columns = ["value"] if len(objectives) == 1 else list(objectives)
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(
            [
                "number",
                "state",
                *value_columns,
                *names,
                "seconds",
                "worker_host",
                "worker_pid",
                "discarded",
            ]
        )
        for t in trials:
            seconds = t.duration.total_seconds() if t.duration else ""
            writer.writerow(
                [
                    t.number,
                    t.state.name,
                    *(t.values or [""] * len(value_columns)),
                    *[t.params.get(n, "") for n in names],
                    seconds,
                    t.user_attrs.get("worker_host", ""),
                    t.user_attrs.get("worker_pid", ""),
                    t.user_attrs.get("discarded", ""),
                ]
            )
    return path


def _plot(study: optuna.Study, directory: Path, target_name: str) -> None:
    """History and parameter importances of the first objective (the error)."""
    import matplotlib.pyplot as plt
    from optuna.visualization import matplotlib as ovm

    plots = {
        "optimization_history.png": ovm.plot_optimization_history,
        "param_importances.png": ovm.plot_param_importances,
    }
    target = None if len(study.directions) == 1 else (lambda t: t.values[0])
    for name, plot in plots.items():
        try:
            axes = plot(study, target=target, target_name=target_name)
        except (ValueError, RuntimeError) as exc:  # e.g. importances need >= 2 trials
            log.warning("could not draw %s: %s", name, exc)
            continue
        figure: Figure = axes.get_figure()
        figure.set_size_inches(7, 4.5)
        figure.tight_layout()
        figure.savefig(directory / name, dpi=110)
        plt.close(figure)
