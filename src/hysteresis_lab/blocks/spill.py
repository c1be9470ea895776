"""Storages that overflow: the spill of first-order storages filled by a signal.

Each storage ``m`` fills from the input ``v`` at the rate ``alpha_m`` and cannot rise above
its rim ``c_m``; what would rise above it spills::

    s_pre[t] = s[t-1] + alpha_m (v[t] - s[t-1])     (a tank, a capacitor, an integrator stage)
    spill[t] = relu(s_pre[t] - c_m)
    s[t]     = s_pre[t] - spill[t]                  (the level stays at the rim)

from rest (``s = 0``). Below the rim the storage is a unit-gain first-order low-pass; at the
rim its level is held, so the storage drains from the rim, not from where a linear storage
would have risen to: a saturation of an internal state, with memory, which no clip of the
input or of the output gives. The spill is what the storage loses, in the input's units
(``spill / alpha`` is the input that did not reach the level). The forward pass and its
adjoint are numba kernels (float64) wrapped in a `torch.autograd.Function`: exact gradients
w.r.t. the input, the rates and the rims (the forward recursion is
`hysteresis_lab.effects.operators.spill_states`, shared with the effect's operators).
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import torch
from torch import Tensor

from hysteresis_lab.blocks._util import from_numpy, to_numpy64
from hysteresis_lab.effects.operators import spill_states

JIT = {"cache": True, "error_model": "numpy"}


@numba.njit(**JIT)
def spill_backward(g: np.ndarray, v: np.ndarray, spill: np.ndarray, level: np.ndarray,
                   alpha: np.ndarray) -> tuple[np.ndarray, ...]:
    """Adjoint of `spill_states`: ``g`` (B, T, M) = dL/d spill; returns dL/d(v, alpha, rim)."""
    n_b, n_t = v.shape
    n_m = alpha.shape[0]
    gv = np.zeros((n_b, n_t))
    ga = np.zeros(n_m)
    gc = np.zeros(n_m)
    for r in range(n_b):
        for m in range(n_m):
            g_s = 0.0  # dL / d s[t] (the level after the sample)
            for t in range(n_t - 1, -1, -1):
                s_prev = level[r, t - 1, m] if t > 0 else 0.0
                if spill[r, t, m] > 0.0:  # s[t] = rim, spill = pre - rim
                    g_pre = g[r, t, m]
                    gc[m] += g_s - g[r, t, m]
                else:  # s[t] = pre, no spill
                    g_pre = g_s
                gv[r, t] += alpha[m] * g_pre
                ga[m] += (v[r, t] - s_prev) * g_pre
                g_s = (1.0 - alpha[m]) * g_pre
    return gv, ga, gc


class _SpillFunction(torch.autograd.Function):
    """``spill (B, T, M)`` from ``v (B, T)`` and ``alpha, rim (M,)``."""

    @staticmethod
    def forward(ctx: Any, v: Tensor, alpha: Tensor, rim: Tensor) -> Tensor:
        v_, a_, c_ = (to_numpy64(t) for t in (v, alpha, rim))
        spill, level = spill_states(v_, a_, c_)
        ctx.saved = (v_, spill, level, a_)
        return from_numpy(spill, v)

    @staticmethod
    def backward(ctx: Any, g: Tensor) -> tuple[Tensor | None, ...]:
        gv, ga, gc = spill_backward(to_numpy64(g), *ctx.saved)
        return from_numpy(gv, g), from_numpy(ga, g), from_numpy(gc, g)


def storage_spill(v: Tensor, alpha: Tensor, rim: Tensor) -> Tensor:
    """The storages' spills (B, T, M) for inputs ``v`` (B, T), rates ``alpha`` in (0, 1] and
    rims ``rim`` (M,), from empty storages; differentiable w.r.t. all three."""
    return _SpillFunction.apply(v, alpha, rim)
