"""Bouc–Wen hysteresis with an exact per-sample update (numba-compiled).

Model (Low & Guo 1995; Goldfarb & Celanovic 1997 for piezo actuators), with ``n = 1``::

    x = d * v - h,      dh/dt = alpha * d * dv/dt - beta * |dv/dt| * h - gamma * dv/dt * |h|

Between two samples the input moves linearly, so along ``v`` the state obeys the linear ODE
``dh/dv = alpha*d - (beta*s + gamma*sign(h)) * h`` (``s`` = direction of motion), solved in
closed form; a sign change of ``h`` inside the step is located exactly and the step split
there. The update is therefore exact for a piecewise-linear input, at any sampling rate.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def _advance(h: float, x: float, s: float, a: float, beta: float, gamma: float) -> float:
    """State after moving ``x >= 0`` volts in direction ``s`` (+1/-1), starting from ``h``."""
    if h * s < 0.0:  # moving against the state's sign: h heads towards zero and beyond
        rate = beta - gamma
        h_inf = s * a / rate
        h_new = h_inf + (h - h_inf) * math.exp(-rate * x)
        if h_new * s <= 0.0:
            return h_new
        x -= math.log((h - h_inf) / (-h_inf)) / rate  # distance used to reach h = 0
        h = 0.0
    rate = beta + gamma
    h_inf = s * a / rate
    return h_inf + (h - h_inf) * math.exp(-rate * x)


@numba.njit(cache=True)
def bouc_wen_state(
    v: np.ndarray, d: float, alpha: np.ndarray, beta: float, gamma: float
) -> np.ndarray:
    """Hysteretic state ``h`` (µm) for input ``v`` (V), starting at rest (v = 0, h = 0).

    ``alpha`` is per sample (a constant array for rate-independent hysteresis).
    """
    n = v.shape[0]
    h_out = np.empty(n)
    h = 0.0
    v_prev = 0.0
    for k in range(n):
        dv = v[k] - v_prev
        if dv != 0.0:
            s = 1.0 if dv > 0.0 else -1.0
            h = _advance(h, abs(dv), s, alpha[k] * d, beta, gamma)
        h_out[k] = h
        v_prev = v[k]
    return h_out
