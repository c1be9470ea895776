"""Bouc–Wen hysteresis: the exact per-sample update, its adjoint and the torch faces.

Model (Low & Guo 1995; Goldfarb & Celanovic 1997 for piezo actuators), with ``n = 1``::

    x = d * v - h,      dh/dt = alpha * d * dv/dt - beta * |dv/dt| * h - gamma * dv/dt * |h|

Between two samples the input moves linearly, so along ``v`` the state obeys the linear ODE
``dh/dv = alpha*d - (beta*s + gamma*sign(h)) * h`` (``s`` = direction of motion), solved in
closed form; a sign change of ``h`` inside the step is located exactly and the step split
there. The update is therefore exact for a piecewise-linear input, at any sampling rate.

`advance` is that update, written with ``a = alpha * d``, ``r1 = beta - gamma`` (the rate
while moving against the state's sign) and ``r2 = beta + gamma`` (moving with it);
`advance_grad` also returns its partial derivatives, from which `bw_backward` runs the
recursion in reverse (reverse-mode differentiation of the exact update, no smoothing).
`bouc_wen_state` is the simulator's single element (with an exponent ``n != 1`` integrated
numerically, `advance_exponent`); `bw_states` / `bw_backward` run ``C``
parallel elements on a batch, with an optional per-sample factor ``m`` (B, T) of ``a``
(rate-dependent hysteresis: the step into sample ``k`` runs with ``a * m[b, k]``; None: ``a``
as it is, which numba compiles on its own without the factor's branches). `BoucWenStates`
wraps them in a `torch.autograd.Function`; `bouc_wen_advance` is one step in torch
(``torch.where`` instead of branches, so that it traces to ONNX).
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
import torch
from torch import Tensor

from hysteresis_lab.physics.tensors import from_numpy, to_numpy64

JIT = {"cache": True, "error_model": "numpy"}


@numba.njit(**JIT)
def advance(h: float, x: float, s: float, a: float, r1: float, r2: float) -> float:
    """State after moving ``x >= 0`` (input units) in direction ``s`` (+1/-1) from ``h``.

    ``a = alpha * d``; ``r1 = beta - gamma`` is the rate while moving against the state's
    sign, ``r2 = beta + gamma`` while moving with it.
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


@numba.njit(**JIT)
def _exponent_slope(g: float, a: float, r1: float, r2: float, n: float) -> float:
    """``dg/dx`` of ``g = s h`` along the motion: ``a - r2 g^n`` with the state's sign,
    ``a + r1 |g|^n`` against it."""
    if g >= 0.0:
        return a - r2 * g**n
    return a + r1 * (-g) ** n


@numba.njit(**JIT)
def advance_exponent(
    h: float, x: float, s: float, a: float, r1: float, r2: float, n: float, x_max: float
) -> float:
    """`advance` for an exponent ``n != 1`` (``|h|^(n-1) h`` in place of ``h``): no closed
    form, so classical Runge–Kutta along the input, in steps of at most ``x_max``."""
    n_steps = max(1, int(math.ceil(x / x_max)))
    dx = x / n_steps
    g = s * h
    for _ in range(n_steps):
        k1 = _exponent_slope(g, a, r1, r2, n)
        k2 = _exponent_slope(g + 0.5 * dx * k1, a, r1, r2, n)
        k3 = _exponent_slope(g + 0.5 * dx * k2, a, r1, r2, n)
        k4 = _exponent_slope(g + dx * k3, a, r1, r2, n)
        g += dx * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
    return s * g


@numba.njit(cache=True)
def bouc_wen_state(
    v: np.ndarray, d: float, alpha: np.ndarray, beta: float, gamma: float, n: float = 1.0
) -> np.ndarray:
    """Hysteretic state ``h`` (µm) for input ``v`` (V), starting at rest (v = 0, h = 0), of
    exponent ``n`` (``dh/dt = alpha d v' - beta |v'| |h|^(n-1) h - gamma v' |h|^n``, Bouc
    1971; Wen 1976). ``alpha`` is per sample (a constant array for rate-independent
    hysteresis). ``n = 1`` takes the exact update (`advance`); any other exponent integrates
    each sample's input step in sub-steps over which the state's slope changes by at most
    about 5 % (its derivative is largest at the saturated state
    ``(alpha d / (beta + gamma))^(1/n)``, `advance_exponent`)."""
    r1, r2 = beta - gamma, beta + gamma
    count = v.shape[0]
    h_out = np.empty(count)
    h = 0.0
    v_prev = 0.0
    for k in range(count):
        dv = v[k] - v_prev
        if dv != 0.0:
            s = 1.0 if dv > 0.0 else -1.0
            a = alpha[k] * d
            if n == 1.0:
                h = advance(h, abs(dv), s, a, r1, r2)
            else:
                if a > 0.0:  # the slope's rate of change at saturation bounds the sub-step
                    h_sat = (a / r2) ** (1.0 / n)
                    x_max = 0.05 / (n * max(r1, r2) * h_sat ** (n - 1.0))
                else:
                    x_max = abs(dv)
                h = advance_exponent(h, abs(dv), s, a, r1, r2, n, x_max)
        h_out[k] = h
        v_prev = v[k]
    return h_out


@numba.njit(**JIT)
def advance_grad(
    h: float, x: float, s: float, a: float, r1: float, r2: float
) -> tuple[float, float, float, float, float, float]:
    """``advance`` and its partial derivatives w.r.t. ``h, x, a, r1, r2``."""
    if h * s < 0.0:
        h_inf = s * a / r1
        e = math.exp(-r1 * x)
        h_new = h_inf + (h - h_inf) * e
        if h_new * s <= 0.0:
            d_x = -r1 * (h - h_inf) * e
            d_a = (1.0 - e) * s / r1
            d_r1 = -x * (h - h_inf) * e - (1.0 - e) * h_inf / r1
            return h_new, e, d_x, d_a, d_r1, 0.0
        # crossing: x1 = log(1 - q) / r1 to reach zero (q = h r1 / (s a)), then x - x1 with r2
        x1 = math.log((h - h_inf) / (-h_inf)) / r1
        x2 = x - x1
        h_inf2 = s * a / r2
        e2 = math.exp(-r2 * x2)
        h_new = h_inf2 + (0.0 - h_inf2) * e2
        g_x2 = r2 * h_inf2 * e2
        q = h * r1 / (s * a)
        dx1_dh = -1.0 / (s * a - h * r1)
        dx1_da = q / (a * r1 * (1.0 - q))
        dx1_dr1 = -x1 / r1 - q / (r1 * r1 * (1.0 - q))
        d_a = (1.0 - e2) * s / r2 - g_x2 * dx1_da
        d_r2 = x2 * h_inf2 * e2 - (1.0 - e2) * h_inf2 / r2
        return h_new, -g_x2 * dx1_dh, g_x2, d_a, -g_x2 * dx1_dr1, d_r2
    h_inf = s * a / r2
    e = math.exp(-r2 * x)
    h_new = h_inf + (h - h_inf) * e
    d_x = -r2 * (h - h_inf) * e
    d_a = (1.0 - e) * s / r2
    d_r2 = -x * (h - h_inf) * e - (1.0 - e) * h_inf / r2
    return h_new, e, d_x, d_a, 0.0, d_r2


@numba.njit(**JIT)
def bw_states(
    v: np.ndarray, v0: np.ndarray, h0: np.ndarray, a: np.ndarray, r1: np.ndarray,
    r2: np.ndarray, m: np.ndarray | None,
) -> np.ndarray:
    """States ``h`` (B, T, C) of ``C`` parallel elements for inputs ``v`` (B, T).

    ``v0`` (B,): the input before the first sample; ``h0`` (B, C): the states there; ``m``:
    the per-sample factor of ``a`` (B, T), or None.
    """
    n_b, n_t = v.shape
    n_c = a.shape[0]
    out = np.empty((n_b, n_t, n_c))
    for b in range(n_b):
        for c in range(n_c):
            h = h0[b, c]
            v_prev = v0[b]
            for k in range(n_t):
                dv = v[b, k] - v_prev
                if dv != 0.0:
                    s = 1.0 if dv > 0.0 else -1.0
                    if m is None:  # noqa: SIM108 - an if on a None argument: numba prunes it
                        a_k = a[c]
                    else:
                        a_k = a[c] * m[b, k]
                    h = advance(h, abs(dv), s, a_k, r1[c], r2[c])
                out[b, k, c] = h
                v_prev = v[b, k]
    return out


@numba.njit(**JIT)
def bw_backward(
    v: np.ndarray, v0: np.ndarray, h0: np.ndarray, hs: np.ndarray, a: np.ndarray,
    r1: np.ndarray, r2: np.ndarray, m: np.ndarray | None, g: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
           np.ndarray]:
    """Adjoint of `bw_states`: ``g`` (B, T, C) = dL/dh; returns dL/d(v, v0, h0, a, r1, r2, m)
    (dL/dm is (B, 0) without a factor)."""
    n_b, n_t = v.shape
    n_c = a.shape[0]
    dv = np.zeros((n_b, n_t))
    dv0 = np.zeros(n_b)
    dh0 = np.zeros((n_b, n_c))
    da = np.zeros(n_c)
    dr1 = np.zeros(n_c)
    dr2 = np.zeros(n_c)
    if m is None:  # noqa: SIM108 - as in bw_states
        dm = np.zeros((n_b, 0))
    else:
        dm = np.zeros((n_b, n_t))
    for b in range(n_b):
        for c in range(n_c):
            mu = 0.0  # dL/dh_k, accumulated backwards
            for k in range(n_t - 1, -1, -1):
                mu += g[b, k, c]
                v_prev = v0[b] if k == 0 else v[b, k - 1]
                step = v[b, k] - v_prev
                if step == 0.0:
                    continue
                h_prev = h0[b, c] if k == 0 else hs[b, k - 1, c]
                s = 1.0 if step > 0.0 else -1.0
                if m is None:  # noqa: SIM108 - as in bw_states
                    a_k = a[c]
                else:
                    a_k = a[c] * m[b, k]
                _, d_h, d_x, d_a, d_r1, d_r2 = advance_grad(
                    h_prev, abs(step), s, a_k, r1[c], r2[c]
                )
                if m is None:
                    da[c] += mu * d_a
                else:
                    da[c] += mu * d_a * m[b, k]
                    dm[b, k] += mu * d_a * a[c]
                dr1[c] += mu * d_r1
                dr2[c] += mu * d_r2
                dv[b, k] += mu * s * d_x
                if k == 0:
                    dv0[b] -= mu * s * d_x
                else:
                    dv[b, k - 1] -= mu * s * d_x
                mu *= d_h
            dh0[b, c] = mu
    return dv, dv0, dh0, da, dr1, dr2, dm


class BoucWenStates(torch.autograd.Function):
    """``h (B, T, C)`` from ``v (B, T), v0 (B,), h0 (B, C), a, r1, r2 (C,)`` and, optionally,
    a per-sample factor ``m (B, T)`` of ``a`` (rate-dependent hysteresis)."""

    @staticmethod
    def forward(ctx: Any, v: Tensor, v0: Tensor, h0: Tensor, a: Tensor, r1: Tensor,
                r2: Tensor, m: Tensor | None = None) -> Tensor:
        arrays = [to_numpy64(t) for t in (v, v0, h0, a, r1, r2)]
        factor = None if m is None else to_numpy64(m)
        hs = bw_states(*arrays, factor)
        ctx.arrays = arrays
        ctx.factor = factor
        ctx.has_factor = m is not None
        ctx.hs = hs
        return from_numpy(hs, v)

    @staticmethod
    def backward(ctx: Any, g: Tensor) -> tuple[Tensor | None, ...]:
        v, v0, h0, a, r1, r2 = ctx.arrays
        *grads, dm = bw_backward(v, v0, h0, ctx.hs, a, r1, r2, ctx.factor, to_numpy64(g))
        return (*(from_numpy(gr, g) for gr in grads),
                from_numpy(dm, g) if ctx.has_factor else None)


def bouc_wen_advance(h: Tensor, dv: Tensor, a: Tensor, r1: Tensor, r2: Tensor) -> Tensor:
    """`advance` in torch for an input step ``dv`` (any sign, zero keeps
    ``h``), elementwise; ``h, dv`` broadcast against the per-element ``a, r1, r2``."""
    s = torch.where(dv > 0.0, torch.ones_like(dv), -torch.ones_like(dv))
    x = dv.abs()
    against = h * s < 0.0
    h_inf1 = s * a / r1
    h_new1 = h_inf1 + (h - h_inf1) * torch.exp(-r1 * x)
    done = against & (h_new1 * s <= 0.0)
    crossing = torch.log((h - h_inf1) / (-h_inf1)) / r1
    x_rest = torch.where(against, x - crossing, x)
    h_start = torch.where(against, torch.zeros_like(h), h)
    h_inf2 = s * a / r2
    h_new2 = h_inf2 + (h_start - h_inf2) * torch.exp(-r2 * x_rest)
    h_new = torch.where(done, h_new1, h_new2)
    return torch.where(dv != 0.0, h_new, h)
