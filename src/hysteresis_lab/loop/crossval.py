"""A model structure on the folds of the identification record: scores and the keep rule.

Each fold's model (trained without the fold's held-out stretches) is scored on the free run
of those stretches (`held_out`); a structure's scores on every fold together are a
`FoldsCheck`, and `keep_refit` is the rule a refit must pass to stand: its free run stable on
every fold, its pooled held-out loss lower than the standing model's, and lower on a
majority of the folds (one fold, an outlier stretch, cannot carry it).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hysteresis_lab.evaluation.evaluate import scoring_start
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import beats_by
from hysteresis_lab.loop.data import Stretch
from hysteresis_lab.models.augment import for_model
from hysteresis_lab.workflows.pipeline import RunResult

#: a free run that leaves the measured output's range by more than this many times its
#: span (or is not finite) diverges: such a model is never the loop's result
DIVERGED_SPANS = 10.0


@dataclass
class HeldOut:
    """A model on held-out stretches (a fold's, `hysteresis_lab.loop.data`)."""

    #: mean over the stretches (and outputs) of the free-run MSE over the variance of the
    #: measured output there: unit-free, each stretch weighing the same
    loss: float
    rmse: dict[str, float]  # free-run RMSE per stretch
    #: the recordings on which the free run diverges
    diverging: list[str]
    #: the free run of each stretch's recording (whole recording)
    predictions: list[np.ndarray]
    #: held-out samples scored (a fold's weight in the pooled loss)
    samples: int = 1

    def to_dict(self) -> dict[str, Any]:
        return {"loss": self.loss, "rmse": self.rmse, "diverging": self.diverging}


def held_out(result: RunResult, stretches: Sequence[Stretch], n_init: int,
             device: str) -> HeldOut:
    """``result``'s model on ``stretches``: each recording simulated end to end from rest,
    scored over its stretch (after the model's start-up samples)."""
    predictions = free_run(result.model, for_model(result.model, [s.recording for s in stretches]),
                           result.window, device=device)
    n_skip = scoring_start(result.window, n_init)
    losses, rmse, samples = [], {}, 0
    for stretch, prediction in zip(stretches, predictions, strict=True):
        first = max(stretch.start, n_skip)
        y = stretch.recording.y[first:stretch.stop]
        mse = np.mean((y - prediction[first:stretch.stop]) ** 2, axis=0)
        losses.append(float(np.mean(mse / np.maximum(np.var(y, axis=0), 1e-300))))
        rmse[stretch.describe()] = float(np.sqrt(np.mean(mse)))
        samples += len(y)
    diverging = sorted({s.name for s, p in zip(stretches, predictions, strict=True)
                        if diverges(s.recording.y, p)})
    loss = float(np.mean(losses)) if not diverging else float("inf")
    return HeldOut(loss, rmse, diverging, list(predictions), samples)


def diverges(y: np.ndarray, prediction: np.ndarray) -> bool:
    """Whether a free run is not finite or leaves the measured output's range by more than
    `DIVERGED_SPANS` times its span."""
    prediction = np.asarray(prediction, dtype=float)
    if not np.all(np.isfinite(prediction)):
        return True
    low, high = np.min(y, axis=0), np.max(y, axis=0)
    margin = DIVERGED_SPANS * np.maximum(high - low, 1e-12)
    return bool(np.any(prediction < low - margin) or np.any(prediction > high + margin))


@dataclass
class FoldsCheck:
    """One structure on every fold: each fold's model on its held-out stretches (None: the
    fold's fit diverged in training)."""

    folds: list[HeldOut | None]

    @property
    def diverging(self) -> list[str]:
        """Where a fold's free run diverges (a fold whose fit diverged: ``fold <j>``)."""
        found = []
        for j, fold in enumerate(self.folds):
            found += [f"fold {j}"] if fold is None else [f"{name} (fold {j})"
                                                          for name in fold.diverging]
        return found

    @property
    def loss(self) -> float:
        """The folds' pooled held-out loss: their losses weighted by held-out samples (inf
        where a fold's fit diverged in training; a free run that diverges scores inf
        itself, `held_out`)."""
        if any(f is None for f in self.folds):
            return float("inf")
        weights = np.array([f.samples for f in self.folds], dtype=float)
        losses = np.array([f.loss for f in self.folds])
        return float(np.sum(weights * losses) / np.sum(weights))

    def fold_losses(self) -> list[float]:
        return [float("inf") if f is None else f.loss for f in self.folds]

    def to_dict(self) -> dict[str, Any]:
        rmse = {name: value for f in self.folds if f is not None for name, value in f.rmse.items()}
        return {"loss": self.loss, "rmse": rmse, "diverging": self.diverging,
                "folds": self.fold_losses()}


def keep_refit(refit: FoldsCheck, standing: FoldsCheck, min_gain: float,
               start: FoldsCheck | None = None) -> tuple[bool, str]:
    """Whether a refit stands, and why: stable on every fold, a pooled held-out loss lower
    than the standing model's by more than the share ``min_gain``, and lower on a majority of
    the folds; and, given the loop's ``start``, also better than the start on its pooled
    loss and a majority of its folds (a chain of small gains cannot end below the start on
    the folds that chose it)."""
    if refit.diverging:
        return False, f"the refit's free run diverges on {', '.join(refit.diverging)}"
    kept, reason = _beats(refit, standing, min_gain, "the standing model's")
    if kept and start is not None and start is not standing:
        kept, against_start = _beats(refit, start, 0.0, "the start's")
        if not kept:
            reason += f"; but against the start: {against_start}"
    return kept, reason


def _beats(refit: FoldsCheck, other: FoldsCheck, min_gain: float,
           whose: str) -> tuple[bool, str]:
    """Whether ``refit``'s pooled held-out loss is below ``other``'s by more than the share
    ``min_gain`` and lower on a majority of the folds, and the reason in words."""
    k = len(refit.folds)
    wins = sum(r < s for r, s in zip(refit.fold_losses(), other.fold_losses(), strict=True))
    gain = f" by more than loop.min_refit_gain={min_gain:g} of it" if min_gain else ""
    pooled = beats_by(refit.loss, other.loss, min_gain)
    verb = "beats" if pooled else "does not beat"
    reason = (f"the refit's pooled held-out loss over {k} folds {refit.loss:.4g} {verb} "
              f"{whose} {other.loss:.4g}{gain}; it is lower on {wins} of {k} folds")
    if pooled and 2 * wins <= k:
        reason += " (no majority)"
    return pooled and 2 * wins > k, reason
