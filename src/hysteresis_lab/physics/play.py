"""The Prandtl–Ishlinskii play (backlash) operator: its recursion (numba), its batched form
with the adjoint, the differentiable torch operator and its one-sample step.

The forward pass records which branch each output followed; the backward pass uses it:
``dp_k/dv_k = 1`` and ``dp_k/dr = -1 / +1`` where the output was pushed up (``v - r``) /
down (``v + r``), and where it was held the gradient passes on to ``p_{k-1}``.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import torch
from torch import Tensor

from hysteresis_lab.physics.tensors import StateReader, from_numpy, to_numpy64


@numba.njit(cache=True)
def play_recursion(
    u: np.ndarray, thresholds: np.ndarray, state: np.ndarray, out: np.ndarray,
    branch: np.ndarray,
) -> None:
    """The play-operator recursion ``p_k = max(u_k - r, min(u_k + r, p_{k-1}))``, in place.

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


def spread_thresholds(amplitude: float, n_operators: int) -> np.ndarray:
    """``n_operators`` play thresholds evenly over an input of peak ``amplitude``:
    ``r_i = i amplitude / (n + 1)``, i = 1 ... n (Kuhnen's choice): every operator opens
    within the range the input sweeps, whatever its units or scaling."""
    if n_operators < 1 or not amplitude > 0:
        raise ValueError(f"need n_operators >= 1 and amplitude > 0, not {n_operators}, "
                         f"{amplitude}")
    return amplitude * np.arange(1, n_operators + 1) / (n_operators + 1)


def spread_over(signal: np.ndarray, n_operators: int) -> np.ndarray:
    """`spread_thresholds` over ``signal``'s own peak ``max |signal|``."""
    return spread_thresholds(max(float(np.max(np.abs(signal))), 1e-12), n_operators)


@numba.njit(cache=True)
def play_batch(v: np.ndarray, thresholds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Play outputs (B, T, m) of ``v`` (B, T), at rest, and the branches (int8)."""
    n_b, n_t = v.shape
    m = thresholds.shape[0]
    out = np.empty((n_b, n_t, m))
    branch = np.empty((n_b, n_t, m), dtype=np.int8)
    for b in range(n_b):
        play_recursion(v[b], thresholds, np.zeros(m), out[b], branch[b])
    return out, branch


@numba.njit(cache=True)
def play_backward(branch: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """dL/dv (B, T) and dL/dr (m,) from dL/dp ``g`` (B, T, m) and the forward's branches."""
    n_b, n_t, m = g.shape
    dv = np.zeros((n_b, n_t))
    dr = np.zeros(m)
    for b in range(n_b):
        for j in range(m):
            carry = 0.0
            for k in range(n_t - 1, -1, -1):
                lam = g[b, k, j] + carry
                br = branch[b, k, j]
                if br == 0:
                    carry = lam
                else:
                    dv[b, k] += lam
                    dr[j] -= br * lam
                    carry = 0.0
    return dv, dr


class _PlayFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, v: Tensor, thresholds: Tensor) -> Tensor:
        out, branch = play_batch(to_numpy64(v), to_numpy64(thresholds))
        ctx.branch = branch
        return from_numpy(out, v)

    @staticmethod
    def backward(ctx: Any, g: Tensor) -> tuple[Tensor, Tensor]:
        dv, dr = play_backward(ctx.branch, to_numpy64(g))
        return from_numpy(dv, g), from_numpy(dr, g)


def play(v: Tensor, thresholds: Tensor) -> Tensor:
    """Play operators (B, T, m) of ``v`` (B, T) at rest, differentiable in both."""
    return _PlayFunction.apply(v, thresholds.to(device=v.device, dtype=v.dtype))


def play_step(v: Tensor, thresholds: Tensor, state: StateReader) -> Tensor:
    """Play operators (B, m) of ``v`` (B,): ``p = max(v - r, min(v + r, p_prev))``."""
    p = state.take(thresholds.shape[0])
    vv = v[:, None]
    p = torch.maximum(vv - thresholds, torch.minimum(vv + thresholds, p))
    state.put(p)
    return p
