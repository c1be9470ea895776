"""Causal input operators shared by the effects (numba for the recursive ones)."""

from __future__ import annotations

import numba
import numpy as np
from scipy import signal


@numba.njit(cache=True)
def play_operators(u: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Prandtl–Ishlinskii play (backlash) operators of ``u`` (1-D) for every threshold, at rest."""
    n, m = u.shape[0], thresholds.shape[0]
    out = np.empty((n, m))
    state = np.zeros(m)
    for k in range(n):
        for j in range(m):
            r = thresholds[j]
            state[j] = max(u[k] - r, min(u[k] + r, state[j]))
            out[k, j] = state[j]
    return out


def lowpass_bank(u: np.ndarray, fs: float, time_constants_s: np.ndarray) -> np.ndarray:
    """Unit-gain first-order low-passes of ``u`` (1-D), one column per time constant."""
    columns = []
    for tau in time_constants_s:
        pole = np.exp(-1.0 / (fs * tau))
        columns.append(signal.lfilter([1.0 - pole], [1.0, -pole], u))
    return np.column_stack(columns)


def resonator_bank(
    u: np.ndarray, fs: float, frequencies_hz: np.ndarray, q: float = 5.0
) -> np.ndarray:
    """Band-pass (second-order, quality ``q``) outputs of ``u`` at each frequency below fs/2."""
    columns = []
    for f in frequencies_hz:
        if f >= 0.45 * fs:
            continue
        b, a = signal.iirpeak(f, q, fs=fs)
        columns.append(signal.lfilter(b, a, u))
    return np.column_stack(columns) if columns else np.zeros((len(u), 0))


def rate(u: np.ndarray, fs: float) -> np.ndarray:
    """Backward-difference rate of change (units per second)."""
    return np.diff(u, prepend=u[0]) * fs


def dead_zone(u: np.ndarray, width: float) -> np.ndarray:
    return np.sign(u) * np.maximum(np.abs(u) - width, 0.0)
