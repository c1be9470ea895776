"""Score a fitted model on test recordings in every evaluation mode, each labelled."""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.evaluation.metrics import score
from hysteresis_lab.evaluation.predict import check_n_step, free_run, n_step, one_step

log = logging.getLogger(__name__)


@dataclass
class Evaluation:
    """Per-test metrics (``{test: {"rmse_free_run": ...}}``) and the predictions behind them."""

    metrics: dict[str, dict[str, float]] = field(default_factory=dict)
    predictions: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


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
) -> Evaluation:
    """One-step-ahead prediction, free-run simulation and (optionally) n-step prediction.

    Scores start at `scoring_start` (the initial conditions every mode takes from the
    measurement are not scored). ``progress``: a progress bar over the modes (all
    recordings run together in each).
    """
    check_n_step(n_steps)  # before the other modes' work, not after it
    runs: dict[str, Callable[[], list[np.ndarray]]] = {
        "one_step": lambda: one_step(model, recordings, window),
        "free_run": lambda: free_run(model, recordings, window, device=device),
    }
    if n_steps is not None:
        runs[f"{int(n_steps)}_step"] = lambda: n_step(model, recordings, window, int(n_steps))
    modes = _run_modes(runs, len(recordings), progress)
    n_skip = scoring_start(window, n_init)
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
