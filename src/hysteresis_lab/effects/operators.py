"""Causal input operators shared by the effects (numba for the recursive ones)."""

from __future__ import annotations

import numba
import numpy as np
from scipy import signal


@numba.njit(cache=True)
def play_recursion(
    u: np.ndarray, thresholds: np.ndarray, state: np.ndarray, out: np.ndarray,
    branch: np.ndarray,
) -> None:
    """The play-operator recursion ``p_k = max(u_k - r, min(u_k + r, p_{k-1}))``, in place.

    The one implementation shared by the effects and `hysteresis_lab.blocks.PlayOperators`.
    ``u`` (n,), ``thresholds`` (m,), ``state`` (m,) the outputs before the first sample (updated
    to the last), ``out`` (n, m) the outputs, ``branch`` (n, m) int8: +1 where the output
    follows ``u - r`` (pushed up), -1 where it follows ``u + r`` (pushed down), 0 where held.
    """
    n, m = u.shape[0], thresholds.shape[0]
    for k in range(n):
        for j in range(m):
            r = thresholds[j]
            upper = u[k] + r
            p = state[j]
            br = 0
            if upper < p:
                p = upper
                br = -1
            lower = u[k] - r
            if lower > p:
                p = lower
                br = 1
            state[j] = p
            out[k, j] = p
            branch[k, j] = br


@numba.njit(cache=True)
def play_operators(u: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Prandtl–Ishlinskii play (backlash) operators of ``u`` (1-D) for every threshold, at rest."""
    n, m = u.shape[0], thresholds.shape[0]
    out = np.empty((n, m))
    branch = np.empty((n, m), dtype=np.int8)
    play_recursion(u, thresholds, np.zeros(m), out, branch)
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
