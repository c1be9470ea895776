"""How long the loop's final refit trains: the epochs the folds showed are needed.

A fold's fit keeps the checkpoint whose loss is best on a random share of its own training
part (never on what the fold holds out, which judges it: `hysteresis_lab.loop.data`); the
epochs that checkpoint trained, per training stage, are in
the fit's ``metrics.json`` (``trained_epochs``, `hysteresis_lab.fitting.TrainResult.epochs`).
The whole-record refit holds nothing out, so it cannot choose its own epoch: it trains each
stage for the folds' median (rounded up; at least 1 epoch, at most the configured length)
and keeps its last weights.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: the trainer's length (``trainer.max_epochs``) sets these stages; ``fine_tune`` is
#: ``training.simulation_epochs``
TRAINER_STAGES = ("one_step", "simulation")
FINE_TUNE = "fine_tune"
#: the metrics-document key of a fit's epochs per stage
TRAINED_EPOCHS = "trained_epochs"


@dataclass(frozen=True)
class TrainingLength:
    """The final refit's epochs per stage (empty: its configured length, each stage keeping
    its best checkpoint on its training recordings) and where they came from."""

    #: stage -> epochs the final refit trains
    epochs: dict[str, int] = field(default_factory=dict)
    #: stage -> each fold's best epoch (epochs its kept weights trained)
    folds: dict[str, list[int]] = field(default_factory=dict)
    #: stage -> the configured length (the most the final refit trains)
    configured: dict[str, int] = field(default_factory=dict)
    #: why the configured length stands (None: the folds set it)
    fallback: str | None = None

    @property
    def from_folds(self) -> bool:
        return bool(self.epochs)

    def to_dict(self) -> dict[str, Any]:
        if not self.from_folds:
            return {"source": "configured", "configured": self.configured,
                    "reason": self.fallback}
        return {"source": "folds' median best epoch", "epochs": self.epochs,
                "fold_best_epochs": self.folds, "configured": self.configured,
                "kept": "last epoch's weights"}

    def describe(self) -> str:
        """One line for the report."""
        if not self.from_folds:
            return f"the configured length ({_stages(self.configured)}): {self.fallback}"
        per_fold = "; ".join(f"{stage} {', '.join(map(str, epochs))}"
                             for stage, epochs in self.folds.items())
        return (f"{_stages(self.epochs)}, the folds' median best epoch ({per_fold}; "
                f"configured {_stages(self.configured)}), its last weights kept")


def final_length(documents: Sequence[Mapping[str, Any] | None],
                 configured: Mapping[str, int]) -> TrainingLength:
    """The final refit's length from the fold fits' metrics ``documents`` (None: that fold's
    fit diverged) and the ``configured`` epochs per stage: each stage's median best epoch
    over the folds (rounded up, within ``[1, configured]``); the configured length where a
    fold did not record its epochs or the folds trained other stages."""
    configured = dict(configured)
    found = [None if d is None else d.get(TRAINED_EPOCHS) for d in documents]
    if not found or any(not f for f in found):
        return TrainingLength(configured=configured,
                              fallback="a fold's fit recorded no training epochs")
    stages = set(found[0])
    if any(set(f) != stages for f in found) or not stages <= set(configured):
        return TrainingLength(configured=configured,
                              fallback="the folds' fits trained different stages")
    order = [stage for stage in configured if stage in stages]  # the stages' training order
    folds = {stage: [int(f[stage]) for f in found] for stage in order}
    epochs = {stage: min(max(1, math.ceil(float(np.median(best)))), configured[stage])
              for stage, best in folds.items()}
    return TrainingLength(epochs, folds, {stage: configured[stage] for stage in order})


def configured_length(max_epochs: int | None, simulation_epochs: int | None) -> dict[str, int]:
    """The configured epochs per stage: ``trainer.max_epochs`` and
    ``training.simulation_epochs`` (where set)."""
    length = {stage: int(max_epochs) for stage in TRAINER_STAGES if max_epochs is not None}
    if simulation_epochs is not None:
        length[FINE_TUNE] = int(simulation_epochs)
    return length


def _stages(epochs: Mapping[str, int]) -> str:
    return ", ".join(f"{stage} {n} epoch{'s' * (n != 1)}" for stage, n in epochs.items())
