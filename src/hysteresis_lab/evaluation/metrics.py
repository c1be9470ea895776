"""Error metrics in physical units on a scoring window that skips the initial samples."""

from __future__ import annotations

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.errors import DataError


def _columns(values: np.ndarray) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    return values[:, None] if values.ndim == 1 else values


def rmse(measured: np.ndarray, predicted: np.ndarray) -> float:
    """Root-mean-square error per output channel, averaged over channels (as the FSM
    benchmark scores MIMO models)."""
    err = _columns(measured) - _columns(predicted)
    return float(np.mean(np.sqrt(np.mean(err**2, axis=0))))


def r2(measured: np.ndarray, predicted: np.ndarray) -> float:
    """Coefficient of determination 1 - SSE/SST per channel, averaged over channels."""
    y, p = _columns(measured), _columns(predicted)
    sse = np.sum((y - p) ** 2, axis=0)
    sst = np.sum((y - y.mean(axis=0)) ** 2, axis=0)
    return float(np.mean(1.0 - sse / np.where(sst > 0, sst, np.nan)))


def nrmse(measured: np.ndarray, predicted: np.ndarray) -> float:
    """RMSE divided by the standard deviation of the measurement (per channel, averaged)."""
    y, p = _columns(measured), _columns(predicted)
    err = np.sqrt(np.mean((y - p) ** 2, axis=0))
    std = y.std(axis=0)
    return float(np.mean(err / np.where(std > 0, std, np.nan)))


def score(measured: Recording, predicted: np.ndarray, n_skip: int = 0) -> dict[str, float]:
    """RMSE (the recording's output units), R² and NRMSE from sample ``n_skip`` on."""
    predicted = _columns(predicted)
    if predicted.shape != measured.y.shape:
        raise DataError(
            f"prediction has shape {predicted.shape} but the measurement {measured.y.shape}.",
            source=f"recording '{measured.name}'",
            fix="predict every sample of every output channel",
        )
    if n_skip >= measured.n_samples:
        raise DataError(
            f"nothing left to score after skipping {n_skip} samples.",
            source=f"recording '{measured.name}'",
            fix="use a longer recording",
        )
    y, p = measured.y[n_skip:], predicted[n_skip:]
    return {"rmse": rmse(y, p), "r2": r2(y, p), "nrmse": nrmse(y, p)}

