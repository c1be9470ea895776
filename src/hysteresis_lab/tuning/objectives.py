"""What a sweep's trial returns: one value, or several for a multi-objective (Pareto) study.

Every objective is minimised:

* ``val_mse``: the model's validation selection loss (scaled units; one-step MSE for the
  one-step objective, the free-run MSE over ``horizon`` segments for the simulation one);
* ``val_free_run_mse``: the free run over each whole validation recording, from its input
  alone, MSE in scaled units (the first ``window.first_target`` samples, measured initial
  conditions, not scored); +inf when the free run diverges (an unstable model);
* ``train_seconds``: the wall-clock seconds the fit took (data preparation and scoring aside).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError

log = logging.getLogger(__name__)

OBJECTIVES = {
    "val_mse": "validation MSE (scaled)",
    "val_free_run_mse": "validation free-run MSE (scaled)",
    "train_seconds": "training seconds",
}
#: the objectives of a study that sets none: the single-objective study of the paper
DEFAULT_OBJECTIVES = ("val_mse",)
#: user attributes of a pruned trial of a multi-objective study: its objectives as its model
#: stood when pruned (a point at its own fidelity, `hysteresis_lab.tuning.pareto`), and the
#: epochs it had trained
STOPPED_VALUES, STOPPED_EPOCHS = "stopped_values", "stopped_epochs"


def check_objectives(names: Sequence[str]) -> tuple[str, ...]:
    """``names`` as a tuple; `ConfigError` for an empty, repeated or unknown one."""
    names = tuple(names)
    unknown = [n for n in names if n not in OBJECTIVES]
    if not names or unknown or len(set(names)) != len(names):
        raise ConfigError(
            f"hydra.sweeper.objectives={list(names)} is not a list of distinct objectives. "
            f"Fix: e.g. hydra.sweeper.objectives=[val_free_run_mse,train_seconds]; each one of "
            f"{list(OBJECTIVES)}."
        )
    return names


def free_run_mse(model: Any, recordings: Sequence[Recording], window: WindowSpec) -> float:
    """MSE (scaled units) of ``model``'s free run over ``recordings``, all samples and outputs
    after the measured initial conditions; +inf when the free run diverges (NaN or inf)."""
    from hysteresis_lab.evaluation.predict import free_run

    scale = np.asarray(model.scaler.y_scale, dtype=float)
    first = window.first_target
    errors = [
        ((predicted[first:] - np.asarray(rec.y, dtype=float)[first:]) / scale).ravel()
        for rec, predicted in zip(recordings, free_run(model, recordings, window), strict=True)
    ]
    with np.errstate(over="ignore", invalid="ignore"):
        mse = float(np.mean(np.square(np.concatenate(errors))))
    return mse if math.isfinite(mse) else math.inf


def stopped_values(names: Sequence[str], model: Any, datamodule: Any, val_loss: float,
                   seconds: float) -> list[float]:
    """The objectives ``names`` of a trial pruned after ``seconds`` of training, for
    ``model`` as it stands: ``val_loss`` (the epoch's validation loss), the free run over
    the validation recordings of ``datamodule`` (a `WindowDataModule`, or a free-run
    module over one), the seconds."""
    windows = getattr(datamodule, "windows", datamodule)
    values: list[float] = []
    for name in names:
        if name == "val_mse":
            values.append(float(val_loss))
        elif name == "train_seconds":
            values.append(float(seconds))
        else:
            recordings = windows.splits.val
            values.append(free_run_mse(model, recordings, model.window) if recordings
                          else math.inf)
    return values


def trial_value(cfg: Mapping[str, Any], result: Any, output_dir: Path) -> float | list[float]:
    """The value(s) the run of ``cfg`` returns to its sweep (``sweep_trial.objectives``):
    ``result.val_mse`` alone by default, else one value per objective in order."""
    names = check_objectives((cfg.get("sweep_trial") or {}).get("objectives") or DEFAULT_OBJECTIVES)
    if names == DEFAULT_OBJECTIVES:
        return result.val_mse
    values: list[float] = []
    for name in names:
        if name == "val_mse":
            values.append(float(result.val_mse))
        elif name == "train_seconds":
            values.append(float(result.document["train_seconds"]))
        else:
            values.append(_validation_free_run_mse(cfg, result, output_dir))
    log.info(
        "trial objectives: %s",
        ", ".join(f"{name} {value:.4g}" for name, value in zip(names, values, strict=True)),
    )
    return values


def _validation_free_run_mse(cfg: Mapping[str, Any], result: Any, output_dir: Path) -> float:
    """The free-run MSE of ``result.model`` over the validation recordings of ``cfg``'s data,
    with the input channels the model reads (its effects' operators, its baseline)."""
    from hysteresis_lab.workflows.pipeline import RunConfig, prepare_data

    data = prepare_data(RunConfig.from_config(cfg, output_dir)).inputs
    if not data.val:
        raise ConfigError(no_validation_recordings(data.name))
    return free_run_mse(result.model, data.val, result.window)


def no_validation_recordings(data_name: str) -> str:
    """The error of a free-run objective on a data set without validation recordings."""
    return (
        f"the objective val_free_run_mse simulates the validation recordings, and data set "
        f"'{data_name}' has none (its validation windows are drawn from the training "
        "recordings). Fix: give a validation recording (data=csv: data.val=[val.csv]; the "
        "simulated data: data.splits.val_samples=20000), or tune on the one-step error: "
        "hydra.sweeper.objectives=[val_mse,train_seconds]."
    )
