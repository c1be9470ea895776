"""Error metrics in physical units on a scoring window that skips the initial samples."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.errors import DataError


def rmse(measured: np.ndarray, predicted: np.ndarray) -> float:
    """Root-mean-square error over all samples and channels."""
    return float(np.sqrt(np.mean((np.asarray(measured) - np.asarray(predicted)) ** 2)))


def r2(measured: np.ndarray, predicted: np.ndarray) -> float:
    """Coefficient of determination 1 - SSE/SST per channel, averaged over channels."""
    y = np.atleast_2d(np.asarray(measured, dtype=float).T).T
    p = np.atleast_2d(np.asarray(predicted, dtype=float).T).T
    sse = np.sum((y - p) ** 2, axis=0)
    sst = np.sum((y - y.mean(axis=0)) ** 2, axis=0)
    return float(np.mean(1.0 - sse / np.where(sst > 0, sst, np.nan)))


def nrmse(measured: np.ndarray, predicted: np.ndarray) -> float:
    """RMSE divided by the standard deviation of the measurement (per channel, averaged)."""
    y = np.atleast_2d(np.asarray(measured, dtype=float).T).T
    p = np.atleast_2d(np.asarray(predicted, dtype=float).T).T
    err = np.sqrt(np.mean((y - p) ** 2, axis=0))
    std = y.std(axis=0)
    return float(np.mean(err / np.where(std > 0, std, np.nan)))


def score(measured: Recording, predicted: np.ndarray, n_skip: int = 0) -> dict[str, float]:
    """RMSE (the recording's output units), R² and NRMSE from sample ``n_skip`` on."""
    predicted = np.asarray(predicted, dtype=float).reshape(measured.n_samples, -1) \
        if np.size(predicted) == measured.y.size else np.asarray(predicted)
    if predicted.shape != measured.y.shape:
        raise DataError(
            f"prediction has shape {predicted.shape} but the measurement {measured.y.shape}.",
            source=f"recording '{measured.name}'",
            fix="predict every sample of every output channel",
        )
    if n_skip >= measured.n_samples:
        raise DataError(f"nothing left to score after skipping {n_skip} samples.",
                        source=f"recording '{measured.name}'", fix="use a longer recording")
    y, p = measured.y[n_skip:], predicted[n_skip:]
    return {"rmse": rmse(y, p), "r2": r2(y, p), "nrmse": nrmse(y, p)}


def summarise(per_test: Mapping[str, Mapping[str, float]]) -> dict[str, dict[str, float]]:
    """Mean and sample standard deviation of every metric over the test recordings."""
    keys = sorted({k for m in per_test.values() for k in m})
    values = {k: np.array([m[k] for m in per_test.values() if k in m]) for k in keys}
    return {
        "mean": {k: float(v.mean()) for k, v in values.items()},
        "std": {k: float(v.std(ddof=1)) if len(v) > 1 else 0.0 for k, v in values.items()},
    }
