"""Prune hopeless trials: report the validation loss after every epoch to the shared study.

Epochs are the fidelity of multi-fidelity pruning (Hyperband, successive halving). A
multi-objective study cannot take intermediate values (Optuna prunes single-objective studies
only), so its trials report to a single-objective companion study (`pruning_study_name`)
whose trial the sweeper names in ``sweep_trial``."""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Sequence

import lightning as L
import optuna

from hysteresis_lab.tuning.choices import FIRST_RUNG_EPOCHS, make_pruner
from hysteresis_lab.tuning.objectives import STOPPED_EPOCHS, STOPPED_VALUES, stopped_values
from hysteresis_lab.tuning.storage import STORAGE_ENV

log = logging.getLogger(__name__)


class PruningCallback(L.Callback):
    """Report ``val_loss`` per epoch; raise `optuna.TrialPruned` when the pruner says so.

    A NaN validation loss prunes the trial at once (the study goes on with the next). With
    several ``objectives`` (a Pareto study), a pruned trial first records them for its model
    as it stands (`STOPPED_VALUES`: the free run over the validation recordings, the seconds
    trained so far) on the trial it reports to.
    """

    def __init__(self, trial: optuna.trial.Trial, monitor: str = "val_loss",
                 objectives: Sequence[str] = ()) -> None:
        self.trial, self.monitor = trial, monitor
        self.objectives = tuple(objectives)
        self._started: float | None = None

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self._started is None:  # the first stage's start: the fit's clock
            self._started = time.perf_counter()

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking:
            return
        value = trainer.callback_metrics.get(self.monitor)
        if value is None:
            return
        value = float(value)
        if not math.isfinite(value):
            raise optuna.TrialPruned(
                f"{self.monitor} became {value} at epoch {trainer.current_epoch}"
            )
        self.trial.report(value, step=trainer.current_epoch)
        if self.trial.should_prune():
            self._record_stop(trainer, pl_module, value)
            raise optuna.TrialPruned(
                f"pruned at epoch {trainer.current_epoch} ({self.monitor}={value:.3e})"
            )

    def _record_stop(self, trainer: L.Trainer, pl_module: L.LightningModule,
                     value: float) -> None:
        """A Pareto study's pruned trial: its objectives now (`STOPPED_VALUES`); where they
        cannot be scored, it is pruned without its point (a warning says why)."""
        if len(self.objectives) < 2:
            return
        seconds = time.perf_counter() - (self._started or time.perf_counter())
        try:
            values = stopped_values(self.objectives, pl_module, trainer.datamodule, value,
                                    seconds)
        except Exception as exc:  # the trial is pruned all the same
            log.warning("pruned trial %d not scored at its stop (%s: %s): it stays off the "
                        "Pareto table", self.trial.number, type(exc).__name__, exc)
            return
        self.trial.set_user_attr(STOPPED_VALUES, values)
        self.trial.set_user_attr(STOPPED_EPOCHS, trainer.current_epoch + 1)


def pruning_study_name(study_name: str) -> str:
    """The single-objective study a multi-objective study's trials report their epochs to."""
    return f"{study_name}.pruning"


def trial_callback(sweep_trial: dict | None) -> PruningCallback | None:
    """The pruning callback of the sweep trial this job runs (``sweep_trial`` config node)."""
    url = os.environ.get(STORAGE_ENV)
    if not sweep_trial or sweep_trial.get("number") is None or not url:
        return None
    max_epochs = sweep_trial.get("max_epochs")
    pruner = make_pruner(
        sweep_trial.get("pruner", "median"),
        n_warmup_steps=int(sweep_trial.get("warmup_epochs", 10)),
        max_resource=None if max_epochs is None else int(max_epochs),
        min_resource=int(sweep_trial.get("min_epochs", FIRST_RUNG_EPOCHS)),
    )
    study = optuna.load_study(study_name=sweep_trial["study"], storage=url, pruner=pruner)
    trial_number = int(sweep_trial["number"])
    trial_id = study._storage.get_trial_id_from_study_id_trial_number(  # noqa: SLF001
        study._study_id,
        trial_number,  # noqa: SLF001
    )
    return PruningCallback(optuna.trial.Trial(study, trial_id),
                           objectives=sweep_trial.get("objectives") or ())
