"""Warnings about training data a model can learn little from: an input that never moves,
too few samples for the regression window.

Such data load and train without error, and the model they give is poor for a reason no
metric names (a constant 5 V input trains a model whose RMSE is the output's spread). A
warning says what is wrong and what data would do.
"""

from __future__ import annotations

import logging

import numpy as np

from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.data.windows import WindowSpec

log = logging.getLogger(__name__)

#: an input whose range over the training data is below this share of its largest |value|
#: does not move
CONSTANT_RELATIVE = 1e-9
#: fewer training windows than this many per regressor are too few to learn from
MIN_WINDOWS_PER_REGRESSOR = 10


def _files(splits: DatasetSplits) -> str:
    """The training recordings as a user knows them (their files where read from files)."""
    return ", ".join(str(r.metadata.get("path") or r.name) for r in splits.train)


def constant_inputs(splits: DatasetSplits) -> list[str]:
    """One line per input that does not move over all the training recordings."""
    u = np.concatenate([r.u for r in splits.train])
    lines = []
    for j, name in enumerate(splits.train[0].u_names):
        level = float(np.max(np.abs(u[:, j])))
        if float(np.ptp(u[:, j])) <= CONSTANT_RELATIVE * max(level, 1e-300):
            unit = splits.train[0].u_units
            lines.append(
                f"input '{name}' is constant ({u[0, j]:g} {unit}) in all the training data "
                f"({_files(splits)}): the model cannot learn how the output responds to it. "
                "Record with an input that moves over the range the model is for (a "
                "multisine, a sweep or steps of several levels)."
            )
    return lines


def too_short(splits: DatasetSplits, window: WindowSpec) -> list[str]:
    """A line when the training recordings give fewer than `MIN_WINDOWS_PER_REGRESSOR`
    windows per regressor of ``window``."""
    regressors = window.nb * splits.nu + window.na * splits.ny
    windows = sum(max(r.n_samples - window.first_target, 0) for r in splits.train)
    needed = MIN_WINDOWS_PER_REGRESSOR * regressors
    if windows >= needed:
        return []
    samples = sum(r.n_samples for r in splits.train)
    return [
        f"the training data ({_files(splits)}) hold {samples} samples "
        f"({samples / splits.fs:.3g} s at {splits.fs:g} Hz), {windows} windows for "
        f"{regressors} regressors (data.window na={window.na}, nb={window.nb}): too few to "
        f"learn from. Record at least {needed + window.first_target} samples "
        f"({MIN_WINDOWS_PER_REGRESSOR} windows per regressor), better several periods of the "
        "slowest dynamics the model is to show."
    ]


def warn_weak_excitation(splits: DatasetSplits, window: WindowSpec) -> list[str]:
    """Log a warning for each input that never moves and for too short training data;
    return the lines."""
    lines = [*constant_inputs(splits), *too_short(splits, window)]
    for line in lines:
        log.warning(line)
    return lines
