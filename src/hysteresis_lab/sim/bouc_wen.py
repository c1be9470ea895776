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


@numba.njit(cache=True, error_model="numpy")
def advance(h: float, x: float, s: float, a: float, r1: float, r2: float) -> float:
    """State after moving ``x >= 0`` (input units) in direction ``s`` (+1/-1) from ``h``.

    ``a = alpha * d``; ``r1 = beta - gamma`` is the rate while moving against the state's
    sign, ``r2 = beta + gamma`` while moving with it. The grey-box's differentiable cell
    (`hysteresis_lab.blocks.bouc_wen`) runs this same update.
    """
    if h * s < 0.0:  # against the state's sign: h heads towards zero and beyond
        h_inf = s * a / r1
        h_new = h_inf + (h - h_inf) * math.exp(-r1 * x)
        if h_new * s <= 0.0:
            return h_new
        x -= math.log((h - h_inf) / (-h_inf)) / r1  # distance used to reach h = 0
        h = 0.0
    h_inf = s * a / r2
    return h_inf + (h - h_inf) * math.exp(-r2 * x)


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
            h = advance(h, abs(dv), s, alpha[k] * d, beta - gamma, beta + gamma)
        h_out[k] = h
        v_prev = v[k]
    return h_out
