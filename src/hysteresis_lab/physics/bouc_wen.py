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

An exponent ``n != 1`` (``|h|^(n-1) h`` in place of ``h``) has no closed form: the step is
integrated along the input by classical Runge–Kutta in sub-steps (`advance_exponent`, their
length from `substep_length`), and `advance_exponent_grad` differentiates that scheme
(forward-mode through the sub-steps, so the gradient is the scheme's own, exponent
included). At ``n = 1`` every kernel takes the exact update.

`bouc_wen_state` is the simulator's single element; `bw_states` / `bw_backward` run ``C``
parallel elements, each with its exponent, on a batch, with an optional per-sample factor
``m`` (B, T) of ``a`` (rate-dependent hysteresis: the step into sample ``k`` runs with
``a * m[b, k]``; None: ``a`` as it is, which numba compiles on its own without the factor's
branches). `BoucWenStates` wraps them in a `torch.autograd.Function`; `bouc_wen_advance` is
one step in torch (``torch.where`` instead of branches, so that it traces to ONNX) and
`bouc_wen_advance_exponent` the sub-stepped one.
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


#: the slope's largest relative change over one Runge–Kutta sub-step (`substep_length`): the
#: simulator's, and the models' (ten times coarser: the scheme is still stable and within
#: 0.1 % of the flow per sub-step, and a fit runs it a thousand times)
SIMULATOR_SLOPE_CHANGE = 0.05
MODEL_SLOPE_CHANGE = 0.5


@numba.njit(**JIT)
def substep_length(a: float, r1: float, r2: float, n: float, x: float,
                   change: float) -> float:
    """The longest Runge–Kutta sub-step (input units) of `advance_exponent` for a step of
    length ``x``: the state's slope changes by at most about ``change`` (relative) over it
    (the slope's derivative, ``n r |h|^(n-1)``, is largest at the saturated state
    ``(a / r2)^(1/n)``); ``x`` itself where ``a <= 0`` (no saturated state)."""
    if a > 0.0:
        h_sat = (a / r2) ** (1.0 / n)
        return change / (n * max(r1, r2) * h_sat ** (n - 1.0))
    return x


@numba.njit(**JIT)
def _slope_partials(
    g: float, a: float, r1: float, r2: float, n: float
) -> tuple[float, float, float, float, float]:
    """`_exponent_slope` and its partial derivatives w.r.t. ``g, r1, r2, n`` (w.r.t. ``a``:
    one)."""
    if g > 0.0:
        gn = g**n
        return a - r2 * gn, -r2 * n * gn / g, 0.0, -gn, -r2 * gn * math.log(g)
    if g < 0.0:
        m = -g
        mn = m**n
        return a + r1 * mn, -r1 * n * mn / m, mn, 0.0, r1 * mn * math.log(m)
    return a, 0.0, 0.0, 0.0, 0.0


@numba.njit(**JIT)
def _stage_tangent(
    g: float, tg: np.ndarray, c: float, k_prev: float, tk_prev: np.ndarray, dx: float,
    tdx: np.ndarray, a: float, r1: float, r2: float, n: float, tk: np.ndarray,
) -> float:
    """One Runge–Kutta stage ``k = f(g + c dx k_prev)``; its tangent (w.r.t. ``h0, x, a, r1,
    r2, n``) into ``tk``."""
    arg = g + c * dx * k_prev
    f, f_g, f_r1, f_r2, f_n = _slope_partials(arg, a, r1, r2, n)
    for i in range(6):
        tk[i] = f_g * (tg[i] + c * (dx * tk_prev[i] + k_prev * tdx[i]))
    tk[2] += 1.0
    tk[3] += f_r1
    tk[4] += f_r2
    tk[5] += f_n
    return f


@numba.njit(**JIT)
def advance_exponent_grad(
    h: float, x: float, s: float, a: float, r1: float, r2: float, n: float, x_max: float,
    work: np.ndarray,
) -> tuple[float, float, float, float, float, float, float]:
    """`advance_exponent` and its partial derivatives w.r.t. ``h, x, a, r1, r2, n`` (those of
    the Runge–Kutta scheme itself; the sub-step count is held). ``work``: a (6, 6) scratch."""
    n_steps = max(1, int(math.ceil(x / x_max)))
    dx = x / n_steps
    tg, tdx, tk1, tk2, tk3, tk4 = work[0], work[1], work[2], work[3], work[4], work[5]
    tg[:] = 0.0
    tg[0] = 1.0
    tdx[:] = 0.0
    tdx[1] = 1.0 / n_steps
    tk4[:] = 0.0  # the first stage's "previous stage": none
    g = s * h
    for _ in range(n_steps):
        k1 = _stage_tangent(g, tg, 0.0, 0.0, tk4, dx, tdx, a, r1, r2, n, tk1)
        k2 = _stage_tangent(g, tg, 0.5, k1, tk1, dx, tdx, a, r1, r2, n, tk2)
        k3 = _stage_tangent(g, tg, 0.5, k2, tk2, dx, tdx, a, r1, r2, n, tk3)
        k4 = _stage_tangent(g, tg, 1.0, k3, tk3, dx, tdx, a, r1, r2, n, tk4)
        total = k1 + 2.0 * k2 + 2.0 * k3 + k4
        for i in range(6):
            tg[i] += (dx * (tk1[i] + 2.0 * tk2[i] + 2.0 * tk3[i] + tk4[i]) + total * tdx[i]) / 6.0
        g += dx * total / 6.0
        tk4[:] = 0.0
    return s * g, tg[0], s * tg[1], s * tg[2], s * tg[3], s * tg[4], s * tg[5]


@numba.njit(**JIT)
def _slope_at_one(g: float, a: float, r1: float, r2: float) -> tuple[float, float, float]:
    """At ``n = 1``: the slope ``a - r g``, ``df/dg = -r`` and ``df/dn = -r g ln|g|``."""
    if g > 0.0:
        return a - r2 * g, -r2, -r2 * g * math.log(g)
    if g < 0.0:
        return a - r1 * g, -r1, -r1 * g * math.log(-g)
    return a, -r2, 0.0


@numba.njit(**JIT)
def exponent_derivative_at_one(
    h: float, x: float, s: float, a: float, r1: float, r2: float, x_max: float
) -> float:
    """``d advance_exponent / dn`` at ``n = 1``: the exponent's component of
    `advance_exponent_grad` alone (a scalar sensitivity ``S' = f_g S + f_n`` carried through
    the same Runge–Kutta sub-steps), at a fraction of its cost."""
    n_steps = max(1, int(math.ceil(x / x_max)))
    dx = x / n_steps
    g = s * h
    sens = 0.0
    for _ in range(n_steps):
        k1, j1, q1 = _slope_at_one(g, a, r1, r2)
        t1 = j1 * sens + q1
        k2, j2, q2 = _slope_at_one(g + 0.5 * dx * k1, a, r1, r2)
        t2 = j2 * (sens + 0.5 * dx * t1) + q2
        k3, j3, q3 = _slope_at_one(g + 0.5 * dx * k2, a, r1, r2)
        t3 = j3 * (sens + 0.5 * dx * t2) + q3
        k4, j4, q4 = _slope_at_one(g + dx * k3, a, r1, r2)
        t4 = j4 * (sens + dx * t3) + q4
        g += dx * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
        sens += dx * (t1 + 2.0 * t2 + 2.0 * t3 + t4) / 6.0
    return s * sens


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
                x_max = substep_length(a, r1, r2, n, abs(dv), SIMULATOR_SLOPE_CHANGE)
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
    r2: np.ndarray, m: np.ndarray | None, n: np.ndarray,
) -> np.ndarray:
    """States ``h`` (B, T, C) of ``C`` parallel elements for inputs ``v`` (B, T).

    ``v0`` (B,): the input before the first sample; ``h0`` (B, C): the states there; ``m``:
    the per-sample factor of ``a`` (B, T), or None; ``n`` (C,): the exponents (1: the exact
    update).
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
                    if n[c] == 1.0:
                        h = advance(h, abs(dv), s, a_k, r1[c], r2[c])
                    else:
                        x_max = substep_length(a_k, r1[c], r2[c], n[c], abs(dv),
                                               MODEL_SLOPE_CHANGE)
                        h = advance_exponent(h, abs(dv), s, a_k, r1[c], r2[c], n[c], x_max)
                out[b, k, c] = h
                v_prev = v[b, k]
    return out


@numba.njit(**JIT)
def bw_backward(
    v: np.ndarray, v0: np.ndarray, h0: np.ndarray, hs: np.ndarray, a: np.ndarray,
    r1: np.ndarray, r2: np.ndarray, m: np.ndarray | None, n: np.ndarray, g: np.ndarray,
    want_n: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
           np.ndarray, np.ndarray]:
    """Adjoint of `bw_states`: ``g`` (B, T, C) = dL/dh; returns dL/d(v, v0, h0, a, r1, r2, m,
    n) (dL/dm is (B, 0) without a factor). ``want_n``: compute dL/dn (else zeros); at an
    exponent of 1 it is the Runge–Kutta scheme's derivative along the exact states (the
    exact update has no exponent to differentiate)."""
    n_b, n_t = v.shape
    n_c = a.shape[0]
    dv = np.zeros((n_b, n_t))
    dv0 = np.zeros(n_b)
    dh0 = np.zeros((n_b, n_c))
    da = np.zeros(n_c)
    dr1 = np.zeros(n_c)
    dr2 = np.zeros(n_c)
    dn = np.zeros(n_c)
    work = np.empty((6, 6))
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
                d_n = 0.0
                if n[c] == 1.0:
                    _, d_h, d_x, d_a, d_r1, d_r2 = advance_grad(
                        h_prev, abs(step), s, a_k, r1[c], r2[c]
                    )
                    if want_n:
                        x_max = substep_length(a_k, r1[c], r2[c], 1.0, abs(step),
                                               MODEL_SLOPE_CHANGE)
                        d_n = exponent_derivative_at_one(h_prev, abs(step), s, a_k, r1[c],
                                                         r2[c], x_max)
                else:
                    x_max = substep_length(a_k, r1[c], r2[c], n[c], abs(step),
                                           MODEL_SLOPE_CHANGE)
                    _, d_h, d_x, d_a, d_r1, d_r2, d_n = advance_exponent_grad(
                        h_prev, abs(step), s, a_k, r1[c], r2[c], n[c], x_max, work
                    )
                if m is None:
                    da[c] += mu * d_a
                else:
                    da[c] += mu * d_a * m[b, k]
                    dm[b, k] += mu * d_a * a[c]
                dr1[c] += mu * d_r1
                dr2[c] += mu * d_r2
                dn[c] += mu * d_n
                dv[b, k] += mu * s * d_x
                if k == 0:
                    dv0[b] -= mu * s * d_x
                else:
                    dv[b, k - 1] -= mu * s * d_x
                mu *= d_h
            dh0[b, c] = mu
    return dv, dv0, dh0, da, dr1, dr2, dm, dn


class BoucWenStates(torch.autograd.Function):
    """``h (B, T, C)`` from ``v (B, T), v0 (B,), h0 (B, C), a, r1, r2 (C,)`` and, optionally,
    a per-sample factor ``m (B, T)`` of ``a`` (rate-dependent hysteresis) and the exponents
    ``n (C,)`` (None: 1, the exact update)."""

    @staticmethod
    def forward(ctx: Any, v: Tensor, v0: Tensor, h0: Tensor, a: Tensor, r1: Tensor,
                r2: Tensor, m: Tensor | None = None, n: Tensor | None = None) -> Tensor:
        arrays = [to_numpy64(t) for t in (v, v0, h0, a, r1, r2)]
        factor = None if m is None else to_numpy64(m)
        exponents = np.ones(arrays[3].shape[0]) if n is None else to_numpy64(n)
        hs = bw_states(*arrays, factor, exponents)
        ctx.arrays = arrays
        ctx.factor = factor
        ctx.exponents = exponents
        ctx.has_factor = m is not None
        ctx.has_exponent = n is not None
        ctx.hs = hs
        return from_numpy(hs, v)

    @staticmethod
    def backward(ctx: Any, g: Tensor) -> tuple[Tensor | None, ...]:
        v, v0, h0, a, r1, r2 = ctx.arrays
        want_n = bool(ctx.has_exponent and ctx.needs_input_grad[7])
        *grads, dm, dn = bw_backward(v, v0, h0, ctx.hs, a, r1, r2, ctx.factor, ctx.exponents,
                                     to_numpy64(g), want_n)
        return (*(from_numpy(gr, g) for gr in grads),
                from_numpy(dm, g) if ctx.has_factor else None,
                from_numpy(dn, g) if want_n else None)


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


def _torch_slope(g: Tensor, a: Tensor, r1: Tensor, r2: Tensor, n: Tensor) -> Tensor:
    """`_exponent_slope` elementwise."""
    magnitude = g.abs() ** n
    return torch.where(g >= 0.0, a - r2 * magnitude, a + r1 * magnitude)


def bouc_wen_advance_exponent(h: Tensor, dv: Tensor, a: Tensor, r1: Tensor, r2: Tensor,
                              n: Tensor) -> Tensor:
    """`bouc_wen_advance` for exponents ``n`` (broadcast like ``a``): the exact update where
    ``n = 1``, elsewhere `advance_exponent`'s sub-steps (`substep_length`), the same scheme
    as `bw_states`. The sub-step count is read from the values (an exported step holds the
    count of the input it was traced with)."""
    exact = bouc_wen_advance(h, dv, a, r1, r2)
    h, dv, a, r1, r2, n = torch.broadcast_tensors(h, dv, a, r1, r2, n)
    x = dv.abs()
    s = torch.where(dv > 0.0, torch.ones_like(dv), -torch.ones_like(dv))
    h_sat = (a / r2) ** (1.0 / n)
    x_max = torch.where(a > 0.0, MODEL_SLOPE_CHANGE / (n * torch.maximum(r1, r2)
                                                      * h_sat ** (n - 1.0)), x)
    counts = torch.clamp(torch.ceil(x / x_max), min=1.0)
    counts = torch.where(x > 0.0, counts, torch.ones_like(counts))
    dx = x / counts
    g = s * h
    for i in range(int(counts.max()) if counts.numel() else 0):
        k1 = _torch_slope(g, a, r1, r2, n)
        k2 = _torch_slope(g + 0.5 * dx * k1, a, r1, r2, n)
        k3 = _torch_slope(g + 0.5 * dx * k2, a, r1, r2, n)
        k4 = _torch_slope(g + dx * k3, a, r1, r2, n)
        g = torch.where(counts > i, g + dx * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0, g)
    stepped = torch.where(dv != 0.0, s * g, h)
    return torch.where(n == 1.0, exact, stepped)
