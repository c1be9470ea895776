"""``evaluation.initial_state=estimate``: each test recording's free run started from what its
first ``n_init`` samples show, as the benchmarks' ``n_init`` and MATLAB's ``compare`` do (those
samples are then not scored). A record taken on another day sits at another sensor offset and
may start where the actuator was left, neither of which a model simulated from rest can see.

A model that offers it (`ModelContract.free_run_from_estimated_start`: a physical model fits
the input level it was held at before the record and the offset) starts from its own
estimate. Any other (a NARX network, SUBNET) reads its state from measured outputs (its lags,
or its encoder's): it restarts at the first scored sample from the measured samples before
it, less the output offset its free run over those samples shows, and that offset is added
back to what it predicts."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.evaluation.predict import restarted_free_runs


def estimate_output_offset(
    recording: Recording, prediction: np.ndarray, first: int, n_skip: int
) -> np.ndarray:
    """The output offset (ny,) that takes the free run ``prediction`` to the measured output
    over samples ``first .. n_skip - 1`` (least squares: the mean difference)."""
    return np.mean(recording.y[first:n_skip] - prediction[first:n_skip], axis=0)


def free_runs_from_estimated_starts(
    model: Any, recordings: Sequence[Recording], free_runs: Sequence[np.ndarray],
    window: WindowSpec, n_skip: int, device: Any = None,
) -> list[np.ndarray]:
    """``free_runs`` (from rest, physical units) of ``recordings`` restarted from the start
    each recording's samples ``window.first_target .. n_skip - 1`` show (see the module
    docstring)."""
    s, first = model.scaler, window.first_target
    started = []
    for rec, prediction in zip(recordings, free_runs, strict=True):
        own = model.free_run_from_estimated_start(
            (rec.u - s.u_offset) / s.u_scale, (rec.y - s.y_offset) / s.y_scale, first, n_skip)
        if own is not None:
            run = np.array(prediction, dtype=float)
            run[first:] = (own * s.y_scale + s.y_offset)[first:]
            started.append(run)
            continue
        offset = estimate_output_offset(rec, prediction, first, n_skip)
        level = dataclasses.replace(rec, y=rec.y - offset)
        restarted = restarted_free_runs(model, [level], window, n_skip, device)[0]
        started.append(restarted + offset)
    return started
