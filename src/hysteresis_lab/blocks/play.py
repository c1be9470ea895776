"""Prandtl–Ishlinskii hysteresis: learnable play operators, the effects' own recursion.

The forward pass is `hysteresis_lab.effects.operators.play_recursion` (numba), which also
records which branch each output followed; the backward pass uses it: ``dp_k/dv_k = 1`` and
``dp_k/dr = -1 / +1`` where the output was pushed up (``v - r``) / down (``v + r``), and where
it was held the gradient passes on to ``p_{k-1}``.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import torch
from torch import Tensor, nn
from torch.nn import functional as F

from hysteresis_lab.blocks._util import from_numpy, inv_softplus, to_numpy64
from hysteresis_lab.blocks.step import StepState, frozen, play_step
from hysteresis_lab.effects.operators import play_recursion


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


class PlayOperators(nn.Module):
    """Prandtl–Ishlinskii operator ``w0 v + sum_i w_i play_{r_i}(v)``.

    Thresholds ``r_i = cumsum(softplus(raw))`` (positive, sorted), weights ``w0, w_i =
    softplus(raw)`` (non-negative). Initial thresholds evenly spaced up to ``max_threshold``
    (in the input's scaled units), initial weights ``w0`` and ``weight``.
    """

    def __init__(
        self,
        n_operators: int = 8,
        max_threshold: float = 0.8,
        w0: float = 1.0,
        weight: float = 0.05,
    ) -> None:
        super().__init__()
        if n_operators < 1 or max_threshold <= 0 or w0 <= 0 or weight <= 0:
            raise ValueError("need n_operators >= 1 and max_threshold, w0, weight > 0")
        step = max_threshold / n_operators
        self.raw_increments = nn.Parameter(torch.full((n_operators,), inv_softplus(step),
                                                      dtype=torch.float64))
        self.raw_w0 = nn.Parameter(torch.tensor(inv_softplus(w0), dtype=torch.float64))
        self.raw_weights = nn.Parameter(torch.full((n_operators,), inv_softplus(weight),
                                                   dtype=torch.float64))

    @property
    def thresholds(self) -> Tensor:
        return torch.cumsum(F.softplus(self.raw_increments), dim=0)

    @property
    def weights(self) -> Tensor:
        return F.softplus(self.raw_weights)

    @property
    def w0(self) -> Tensor:
        return F.softplus(self.raw_w0)

    def forward(self, v: Tensor) -> Tensor:
        """``v`` (B, T) -> (B, T)."""
        p = play(v, self.thresholds)
        return self.w0.to(v.dtype) * v + p @ self.weights.to(v.dtype)

    def state_names(self) -> list[str]:
        return [f"play{i}" for i in range(self.raw_weights.shape[0])]

    def step(self, v: Tensor, state: StepState) -> Tensor:
        """One sample (B,) -> (B,); state: the operators' outputs."""
        thresholds, w0, weights = frozen(self.thresholds, self.w0, self.weights)
        p = play_step(v, thresholds, state)
        return w0 * v + p @ weights

    def export(self) -> dict[str, Any]:
        with torch.no_grad():
            return {
                "w0": float(self.w0),
                "thresholds": self.thresholds.double().cpu().numpy().copy(),
                "weights": self.weights.double().cpu().numpy().copy(),
            }
