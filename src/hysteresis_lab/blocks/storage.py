"""A first-order storage with a rim: the level of an upstream tank that overflows.

Per sample ``t`` (from an empty storage, ``s = 0``)::

    pre[t]   = s[t-1] + alpha (v[t] - s[t-1])      (a unit-gain first-order storage)
    spill[t] = w relu(pre[t] - c)                   (``w = 1``: all above the rim ``c`` spills)
    s[t]     = pre[t] - spill[t]                    (the level is held at the rim)

Below the rim it is a first-order low-pass; at the rim its level is held, so it drains from
the rim, not from where a linear storage would have risen to: a saturation of an internal
state, with memory, which no clip of the input or of the output gives. The forward pass and
its adjoint are numba kernels (float64) wrapped in a `torch.autograd.Function`: exact
gradients w.r.t. the input, ``alpha``, the rim ``c`` and the weight ``w``.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import torch
from torch import Tensor

from hysteresis_lab.blocks._util import from_numpy, to_numpy64

JIT = {"cache": True, "error_model": "numpy"}


@numba.njit(**JIT)
def rim_states(v: np.ndarray, alpha: float, rim: float, weight: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Levels ``s``, spills and the levels before the spill ``pre`` (each (B, T)) for inputs
    ``v`` (B, T), from empty storages."""
    n_b, n_t = v.shape
    s = np.zeros((n_b, n_t))
    spill = np.zeros((n_b, n_t))
    pre = np.zeros((n_b, n_t))
    for r in range(n_b):
        level = 0.0
        for t in range(n_t):
            p = level + alpha * (v[r, t] - level)
            out = weight * max(p - rim, 0.0)
            level = p - out
            pre[r, t] = p
            spill[r, t] = out
            s[r, t] = level
    return s, spill, pre


@numba.njit(**JIT)
def rim_backward(g_s: np.ndarray, g_spill: np.ndarray, v: np.ndarray, s: np.ndarray,
                 pre: np.ndarray, alpha: float, rim: float, weight: float
                 ) -> tuple[np.ndarray, float, float, float]:
    """Adjoint of `rim_states`: ``g_s, g_spill`` (B, T) = dL/d(s, spill); returns
    dL/d(v, alpha, rim, weight)."""
    n_b, n_t = v.shape
    gv = np.zeros((n_b, n_t))
    g_alpha, g_rim, g_weight = 0.0, 0.0, 0.0
    for r in range(n_b):
        g_pre_next = 0.0
        for t in range(n_t - 1, -1, -1):
            g_level = g_s[r, t] + (1.0 - alpha) * g_pre_next  # s[t] also feeds pre[t+1]
            g_out = g_spill[r, t] - g_level  # spill[t] leaves the level
            over = pre[r, t] - rim
            g_pre = g_level
            if over > 0.0:
                g_pre += weight * g_out
                g_weight += g_out * over
                g_rim -= g_out * weight
            s_prev = s[r, t - 1] if t > 0 else 0.0
            gv[r, t] = alpha * g_pre
            g_alpha += g_pre * (v[r, t] - s_prev)
            g_pre_next = g_pre
    return gv, g_alpha, g_rim, g_weight


class _RimFunction(torch.autograd.Function):
    """``(s, spill)`` (B, T) each from ``v`` (B, T) and the scalars ``alpha, rim, weight``."""

    @staticmethod
    def forward(ctx: Any, v: Tensor, alpha: Tensor, rim: Tensor,
                weight: Tensor) -> tuple[Tensor, Tensor]:
        v_ = to_numpy64(v)
        scalars = float(alpha.detach()), float(rim.detach()), float(weight.detach())
        s, spill, pre = rim_states(v_, *scalars)
        ctx.saved = (v_, s, pre, *scalars)
        return from_numpy(s, v), from_numpy(spill, v)

    @staticmethod
    def backward(ctx: Any, g_s: Tensor | None, g_spill: Tensor | None) -> tuple[Tensor, ...]:
        v_, s, pre, alpha, rim, weight = ctx.saved
        zeros = np.zeros_like(v_)
        gs = zeros if g_s is None else to_numpy64(g_s)
        gsp = zeros if g_spill is None else to_numpy64(g_spill)
        gv, ga, gc, gw = rim_backward(gs, gsp, v_, s, pre, alpha, rim, weight)
        ref = g_s if g_s is not None else g_spill
        return (from_numpy(gv, ref), *(torch.tensor(x, dtype=torch.float64, device=ref.device)
                                       for x in (ga, gc, gw)))


def rim_storage(v: Tensor, alpha: Tensor, rim: Tensor, weight: Tensor) -> tuple[Tensor, Tensor]:
    """The storage's levels and spills (B, T) each for inputs ``v`` (B, T), rate ``alpha``,
    rim ``rim`` and spill weight ``weight`` (scalars), from an empty storage; differentiable
    w.r.t. all four."""
    return _RimFunction.apply(v.double(), alpha, rim, weight)


def rim_step(v: Tensor, level: Tensor, alpha: Tensor, rim: Tensor,
             weight: Tensor) -> tuple[Tensor, Tensor]:
    """One sample of `rim_storage`: inputs and last levels (B,) -> (level, spill) (B,)."""
    pre = level + alpha * (v - level)
    spill = weight * torch.relu(pre - rim)
    return pre - spill, spill
