"""Linear dynamics with a Bouc–Wen restoring force and a static nonlinearity in their
feedback: the closed loop.

Model (per sample ``t``, one row)::

    y[t] = sum_i b_i e[t-i] - sum_{i>=1} a_i y[t-i]        (the dynamics, direct form)
    h_c[t] = advance(h_c[t-1], y[t] - y[t-1])               (Bouc–Wen states of the output)
    e[t] = x[t] - wh sum_c h_c[t - lag] - wy y[t - lag]     (the restoring force fed back)
           - phi(y[t - lag])                                (the static feedback)
    phi(y) = sum_k w_k (relu(y - c_k) - relu(-c_k))         (piecewise linear, phi(0) = 0)

as in the Bouc–Wen oscillator ``m y'' + c y' + k y + z(y) = u`` (``z`` a Bouc–Wen state driven
by the displacement ``y``). The Bouc–Wen update is `hysteresis_lab.physics.bouc_wen.advance`
(exact for an output moving linearly between samples), with ``a = alpha d``,
``r1 = beta - gamma``, ``r2 = beta + gamma`` as in `hysteresis_lab.blocks.BoucWen`. With a
delayed numerator (``b_0 = 0``) the loop is causal at ``lag = 0``; otherwise the force of the
previous sample is fed back (``lag = 1``). The forward pass and its adjoint are numba kernels
(float64) wrapped in a `torch.autograd.Function`: exact gradients w.r.t. the input, ``b, a``,
``wh, wy``, the Bouc–Wen parameters and the static feedback's weights ``w`` and knots ``c``
(none: both of length 0).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
import numpy as np
import torch
from torch import Tensor

from hysteresis_lab.blocks.step import StepState
from hysteresis_lab.physics.bouc_wen import advance, advance_grad
from hysteresis_lab.physics.tensors import from_numpy, to_numpy64

JIT = {"cache": True, "error_model": "numpy"}


@numba.njit(**JIT)
def feedback_states(
    x: np.ndarray, b: np.ndarray, a: np.ndarray, wh: float, wy: float, lag: int,
    ba: np.ndarray, r1: np.ndarray, r2: np.ndarray, w: np.ndarray, knots: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The closed loop from rest: outputs ``y`` (B, T), dynamics inputs ``e`` (B, T) and
    Bouc–Wen states ``h`` (B, T, C) for inputs ``x`` (B, T); ``a[0] = 1``."""
    n_b, n_t = x.shape
    n_c = ba.shape[0]
    y = np.zeros((n_b, n_t))
    e = np.zeros((n_b, n_t))
    h = np.zeros((n_b, n_t, n_c))
    for r in range(n_b):
        hc = np.zeros(n_c)
        y_prev = 0.0
        for t in range(n_t):
            if lag == 1:
                e[r, t] = x[r, t] - wh * hc.sum() - wy * y_prev - _phi(y_prev, w, knots)
            acc = 0.0
            for i in range(b.shape[0]):
                if t - i < 0:
                    break
                acc += b[i] * e[r, t - i]
            for i in range(1, a.shape[0]):
                if t - i < 0:
                    break
                acc -= a[i] * y[r, t - i]
            y[r, t] = acc
            dv = acc - y_prev
            if dv != 0.0:
                s = 1.0 if dv > 0.0 else -1.0
                for c in range(n_c):
                    hc[c] = advance(hc[c], abs(dv), s, ba[c], r1[c], r2[c])
            h[r, t, :] = hc
            y_prev = acc
            if lag == 0:
                e[r, t] = x[r, t] - wh * hc.sum() - wy * acc - _phi(acc, w, knots)
    return y, e, h


@numba.njit(**JIT)
def _phi(y: float, w: np.ndarray, c: np.ndarray) -> float:
    """The static feedback ``sum_k w_k (relu(y - c_k) - relu(-c_k))`` (zero at rest)."""
    out = 0.0
    for k in range(w.shape[0]):
        out += w[k] * (max(y - c[k], 0.0) - max(-c[k], 0.0))
    return out


@numba.njit(**JIT)
def _phi_slope(y: float, w: np.ndarray, c: np.ndarray) -> float:
    """``d phi / d y`` (the right-hand slope at a knot)."""
    out = 0.0
    for k in range(w.shape[0]):
        if y > c[k]:
            out += w[k]
    return out


@numba.njit(**JIT)
def feedback_backward(
    g: np.ndarray, y: np.ndarray, e: np.ndarray, h: np.ndarray, b: np.ndarray, a: np.ndarray,
    wh: float, wy: float, lag: int, ba: np.ndarray, r1: np.ndarray, r2: np.ndarray,
    w: np.ndarray, knots: np.ndarray,
) -> tuple[np.ndarray, ...]:
    """Adjoint of `feedback_states`: ``g`` (B, T) = dL/dy; returns dL/d(x, b, a, wh, wy, ba,
    r1, r2, w, c) (``wh, wy`` as 1-element arrays)."""
    n_b, n_t = y.shape
    n_c = ba.shape[0]
    gx = np.zeros((n_b, n_t))
    gb = np.zeros(b.shape[0])
    ga = np.zeros(a.shape[0])
    gwh = np.zeros(1)
    gwy = np.zeros(1)
    gba = np.zeros(n_c)
    gr1 = np.zeros(n_c)
    gr2 = np.zeros(n_c)
    gw = np.zeros(w.shape[0])
    gc = np.zeros(knots.shape[0])
    for r in range(n_b):
        # partial derivatives of every Bouc–Wen step: d h[t] / d h[t-1], d h[t] / d y[t]
        d_h = np.ones((n_t, n_c))
        d_y = np.zeros((n_t, n_c))
        d_p = np.zeros((n_t, n_c, 3))
        for t in range(n_t):
            step = y[r, t] - (y[r, t - 1] if t > 0 else 0.0)
            if step == 0.0:
                continue
            s = 1.0 if step > 0.0 else -1.0
            for c in range(n_c):
                h_prev = h[r, t - 1, c] if t > 0 else 0.0
                _, dh, dx, da_, dr1, dr2 = advance_grad(h_prev, abs(step), s, ba[c], r1[c],
                                                         r2[c])
                d_h[t, c] = dh
                d_y[t, c] = s * dx
                d_p[t, c, 0] = da_
                d_p[t, c, 1] = dr1
                d_p[t, c, 2] = dr2
        g_y = np.zeros(n_t)
        g_e = np.zeros(n_t)
        g_h = np.zeros((n_t, n_c))
        for t in range(n_t - 1, -1, -1):
            if lag == 0:  # e[t] feeds y[t+1..] (b_0 = 0) and reads h[t]
                acc = 0.0
                for i in range(1, b.shape[0]):
                    if t + i >= n_t:
                        break
                    acc += b[i] * g_y[t + i]
                g_e[t] = acc
                for c in range(n_c):
                    nxt = d_h[t + 1, c] * g_h[t + 1, c] if t + 1 < n_t else 0.0
                    g_h[t, c] = nxt - wh * g_e[t]
            else:  # h[t] feeds e[t+1]
                for c in range(n_c):
                    g_h[t, c] = (d_h[t + 1, c] * g_h[t + 1, c] - wh * g_e[t + 1]
                                 if t + 1 < n_t else 0.0)
            acc = g[r, t]
            if t + lag < n_t:  # y[t] is fed back into e[t + lag]
                acc -= (wy + _phi_slope(y[r, t], w, knots)) * g_e[t + lag]
            for i in range(1, a.shape[0]):
                if t + i >= n_t:
                    break
                acc -= a[i] * g_y[t + i]
            for c in range(n_c):
                acc += d_y[t, c] * g_h[t, c]
                if t + 1 < n_t:
                    acc -= d_y[t + 1, c] * g_h[t + 1, c]
            g_y[t] = acc
            if lag == 1:
                acc = 0.0
                for i in range(b.shape[0]):
                    if t + i >= n_t:
                        break
                    acc += b[i] * g_y[t + i]
                g_e[t] = acc
        for t in range(n_t):
            gx[r, t] = g_e[t]
            for i in range(lag ^ 1, b.shape[0]):  # b_0 reads nothing at lag 0
                if t - i < 0:
                    break
                gb[i] += g_y[t] * e[r, t - i]
            for i in range(1, a.shape[0]):
                if t - i < 0:
                    break
                ga[i] -= g_y[t] * y[r, t - i]
            if t - lag >= 0:
                gwh[0] -= g_e[t] * h[r, t - lag, :].sum()
                gwy[0] -= g_e[t] * y[r, t - lag]
            y_fed = y[r, t - lag] if t - lag >= 0 else 0.0
            for k in range(w.shape[0]):
                gw[k] -= g_e[t] * (max(y_fed - knots[k], 0.0) - max(-knots[k], 0.0))
                gc[k] += g_e[t] * w[k] * ((1.0 if y_fed > knots[k] else 0.0)
                                          - (1.0 if knots[k] < 0.0 else 0.0))
            for c in range(n_c):
                gba[c] += g_h[t, c] * d_p[t, c, 0]
                gr1[c] += g_h[t, c] * d_p[t, c, 1]
                gr2[c] += g_h[t, c] * d_p[t, c, 2]
    return gx, gb, ga, gwh, gwy, gba, gr1, gr2, gw, gc


class _FeedbackFunction(torch.autograd.Function):
    """``y (B, T)`` from ``x (B, T), b, a, wh, wy (), ba, r1, r2 (C,)``, the int ``lag`` and
    the static feedback's ``w, c (K,)``."""

    @staticmethod
    def forward(ctx: Any, x: Tensor, b: Tensor, a: Tensor, wh: Tensor, wy: Tensor, ba: Tensor,
                r1: Tensor, r2: Tensor, lag: int, w: Tensor, c: Tensor) -> Tensor:
        x_, b_, a_, ba_, r1_, r2_, w_, c_ = (to_numpy64(t) for t in (x, b, a, ba, r1, r2, w, c))
        weights = float(wh.detach()), float(wy.detach())
        y, e, h = feedback_states(x_, b_, a_, *weights, lag, ba_, r1_, r2_, w_, c_)
        ctx.saved = (y, e, h, b_, a_, *weights, lag, ba_, r1_, r2_, w_, c_)
        return from_numpy(y, x)

    @staticmethod
    def backward(ctx: Any, g: Tensor) -> tuple[Tensor | None, ...]:
        gx, gb, ga, gwh, gwy, gba, gr1, gr2, gw, gc = feedback_backward(to_numpy64(g),
                                                                        *ctx.saved)
        grads = (gx, gb, ga, gwh.reshape(()), gwy.reshape(()), gba, gr1, gr2)
        return (*(from_numpy(gr, g) for gr in grads), None, from_numpy(gw, g),
                from_numpy(gc, g))


def closed_loop(
    x: Tensor, b: Tensor, a: Tensor, wh: Tensor, wy: Tensor, ba: Tensor, r1: Tensor,
    r2: Tensor, lag: int, w: Tensor | None = None, c: Tensor | None = None,
) -> Tensor:
    """`feedback_states`' output ``y`` (B, T), differentiable w.r.t. every tensor argument;
    ``w, c``: the static feedback's weights and knots (None: none)."""
    if w is None or c is None:
        w = c = torch.zeros(0, dtype=torch.float64, device=x.device)
    return _FeedbackFunction.apply(x, b, a, wh, wy, ba, r1, r2, lag, w, c)


# ------------------------------------------------------------------ one sample of the loop
def loop_lag(dynamics: Any) -> int:
    """0 when the dynamics delay their input (a closed loop is causal as it is), else 1."""
    return 0 if int(dynamics.delay) > 0 else 1


def no_feedback(y: torch.Tensor) -> torch.Tensor:
    return torch.zeros_like(y)


def loop_state_names(dynamics: Any) -> list[str]:
    """A closed loop's step state: past dynamics' inputs ``e`` and outputs ``y``."""
    b, a = dynamics.polynomials()
    return [f"e{i}" for i in range(1, b.shape[0])] + [f"y{i}" for i in range(1, a.shape[0])]


def loop_step(
    b: torch.Tensor, a: torch.Tensor, lag: int, x: torch.Tensor, state: StepState,
    force: Callable[[torch.Tensor, torch.Tensor | None], torch.Tensor],
    n_hidden: int = 0,
    advance: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
) -> torch.Tensor:
    """One sample of the dynamics ``b, a`` in a closed loop, ``e = x - force(y_fed, h)``,
    ``x`` (B,) -> ``y`` (B,); state: the past ``e`` and ``y`` (newest first), then
    ``n_hidden`` states ``h`` of the force that ``advance(h, y - y_prev)`` moves on."""
    past_e = state.take(b.shape[0] - 1)
    past_y = state.take(a.shape[0] - 1)
    h = state.take(n_hidden) if n_hidden else None
    e = x - force(past_y[:, 0], h) if lag else torch.zeros_like(x)
    y = b[0] * e + past_e @ b[1:] - past_y @ a[1:]
    if advance is not None:
        h = advance(h, y - past_y[:, 0])
    if not lag:
        e = x - force(y, h)
    if b.shape[0] > 1:  # a numerator of one term (`StagePole`) keeps no past input
        state.put(torch.cat([e[:, None], past_e[:, :-1]], dim=1))
    state.put(torch.cat([y[:, None], past_y[:, :-1]], dim=1))
    if h is not None:
        state.put(h)
    return y
