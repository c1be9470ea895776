"""Score a fitted model on test recordings in every evaluation mode, each labelled."""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError, DataError
from hysteresis_lab.evaluation.initial_state import free_runs_from_estimated_starts
from hysteresis_lab.evaluation.metrics import score
from hysteresis_lab.evaluation.predict import check_n_step, free_run, n_step, one_step

log = logging.getLogger(__name__)


@dataclass
class Evaluation:
    """Per-test metrics (``{test: {"rmse_free_run": ...}}``) and the predictions behind them."""

    metrics: dict[str, dict[str, float]] = field(default_factory=dict)
    predictions: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


#: how a free run starts on each test recording (``evaluation.initial_state``): from rest as
#: the model was trained, or from the state and output offset the recording's first
#: ``n_init`` samples show (`hysteresis_lab.evaluation.initial_state`; not scored)
INITIAL_STATES = ("rest", "estimate")


def check_initial_state(initial_state: str, n_init: int, window: WindowSpec) -> None:
    """Raise `ConfigError` unless ``initial_state`` is one of `INITIAL_STATES` and, to
    estimate, the recordings have initial samples to estimate from."""
    if initial_state not in INITIAL_STATES:
        raise ConfigError(
            f"unknown evaluation.initial_state '{initial_state}'. Fix: "
            f"evaluation.initial_state=one of {list(INITIAL_STATES)}."
        )
    if initial_state == "estimate" and scoring_start(window, n_init) <= window.first_target:
        raise ConfigError(
            f"evaluation.initial_state=estimate reads the first data.n_init samples of each "
            f"test recording, and data.n_init={n_init} leaves none beyond the model's window "
            f"({window.first_target} samples). Fix: e.g. data.n_init="
            f"{window.first_target + 100}, or evaluation.initial_state=rest."
        )


@dataclass(frozen=True)
class Scoring:
    """How a run scores a model on test recordings (`evaluate_model`): an ``n_steps``
    horizon (None: no n-step scores), how each free run starts (``initial_state``, one of
    `INITIAL_STATES`), the ``device`` it simulates on and whether a progress bar shows."""

    n_steps: int | None = None
    initial_state: str = "rest"
    device: str | None = None
    progress: bool = False

    def check(self, data: DatasetSplits, window: WindowSpec) -> None:
        """Fail before training, not after it, when ``data``'s test recordings cannot be
        scored (none, or each too short for the model's ``window``) or ``n_steps`` is no
        horizon."""
        if not data.test:
            raise DataError(
                "has no test recordings to evaluate on.",
                source=f"data set '{data.name}'",
                fix="give some with data.test=[a.csv,b.csv], or train only with evaluate=false",
            )
        check_n_step(self.n_steps)
        start = scoring_start(window, data.n_init)
        for rec in data.test:
            if rec.n_samples <= start:
                raise DataError(
                    f"has {rec.n_samples} samples, but scoring starts at sample {start + 1} "
                    f"(the model's window na={window.na}, nb={window.nb}, nk={window.nk}, "
                    f"n_init={data.n_init}): nothing would be left to score.",
                    source=f"test recording '{rec.metadata.get('path', rec.name)}'",
                    fix="use a longer test recording, or smaller data.window.na / nb (or "
                    "n_init)",
                )

    def evaluate(self, model: Any, data: DatasetSplits, window: WindowSpec) -> Evaluation:
        """``model`` scored on ``data``'s test recordings."""
        return evaluate_model(
            model, data.test, window, n_init=data.n_init, n_steps=self.n_steps,
            device=self.device, progress=self.progress, initial_state=self.initial_state,
        )


def scoring_start(window: WindowSpec, n_init: int = 0) -> int:
    """The first scored sample of a recording: every mode takes the samples before it (the
    model's window, at least ``n_init``) from the measurement as initial conditions."""
    return max(window.first_target, n_init)


def evaluate_model(
    model: Any,
    recordings: list[Recording],
    window: WindowSpec,
    n_init: int = 0,
    n_steps: int | None = None,
    device: str | None = None,
    progress: bool = False,
    initial_state: str = "rest",
) -> Evaluation:
    """One-step-ahead prediction, free-run simulation and (optionally) n-step prediction.

    Scores start at `scoring_start` (the initial conditions every mode takes from the
    measurement are not scored). ``progress``: a progress bar over the modes (all
    recordings run together in each). ``initial_state``: ``"estimate"`` starts each free run
    from what its recording's first ``n_init`` samples show (`hysteresis_lab.evaluation.
    initial_state`); ``"rest"`` leaves it as simulated.
    """
    check_n_step(n_steps)  # before the other modes' work, not after it
    check_initial_state(initial_state, n_init, window)
    runs: dict[str, Callable[[], list[np.ndarray]]] = {
        "one_step": lambda: one_step(model, recordings, window),
        "free_run": lambda: free_run(model, recordings, window, device=device),
    }
    if n_steps is not None:
        runs[f"{int(n_steps)}_step"] = lambda: n_step(model, recordings, window, int(n_steps))
    modes = _run_modes(runs, len(recordings), progress)
    n_skip = scoring_start(window, n_init)
    if initial_state == "estimate":
        modes["free_run"] = free_runs_from_estimated_starts(
            model, recordings, modes["free_run"], window, n_skip, device)
    result = Evaluation()
    for position, rec in enumerate(recordings):
        result.predictions[rec.name] = {mode: preds[position] for mode, preds in modes.items()}
        metrics: dict[str, float] = {}
        for mode, preds in modes.items():
            for key, value in score(rec, preds[position], n_skip).items():
                metrics[f"{key}_{mode}"] = float(value)
        result.metrics[rec.name] = metrics
        log.info(
            "%-14s one-step RMSE %.4g %s (R² %.4f) | free-run RMSE %.4g %s (R² %.4f)",
            rec.name,
            metrics["rmse_one_step"],
            rec.y_units,
            metrics["r2_one_step"],
            metrics["rmse_free_run"],
            rec.y_units,
            metrics["r2_free_run"],
        )
    return result


def _run_modes(
    runs: dict[str, Callable[[], list[np.ndarray]]], n_recordings: int, progress: bool
) -> dict[str, list[np.ndarray]]:
    """Each mode's predictions, with a progress bar over the modes when ``progress``."""
    from tqdm import tqdm

    modes: dict[str, list[np.ndarray]] = {}
    with tqdm(total=len(runs), desc=f"Scoring {n_recordings} test recording(s)", unit="mode",
              disable=not progress, file=sys.stdout, dynamic_ncols=True,
              bar_format="{desc}: {percentage:3.0f}%|{bar}| {n}/{total} modes "
              "[{elapsed}{postfix}]") as bar:
        for mode, run in runs.items():
            bar.set_postfix_str(mode.replace("_", "-"))
            modes[mode] = run()
            bar.update()
        bar.set_postfix_str("done")
    return modes
