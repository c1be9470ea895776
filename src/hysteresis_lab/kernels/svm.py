"""Compiled SVM free run: the folded kernel machine's steps in numba, a chunk at a time.

`hysteresis_lab.models.svm.SVMModel` folds its prediction to ``f(x @ C + ...) @ W + b`` over
``m`` components ``C`` (Nyström landmarks or support vectors). The input part of ``x @ C`` is
precomputed per chunk of steps with NumPy (`FlatKernel`'s ``pre_u``); `_steps` then does, per
step and recording, the output-lag part, the kernel function and the weighted sum in one
compiled loop (float64, like the NumPy step), feeding each prediction back.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba
import numpy as np

from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.kernels.interface import FlatKernel, input_lags
from hysteresis_lab.kernels.jit_ops import JIT, term_array

#: kernel function codes of `_steps`
KERNEL_CODES = {"rbf": 0, "sigmoid": 1, "poly": 2}


@numba.njit(**JIT)
def _steps(
    pre: np.ndarray, y: np.ndarray, term: np.ndarray, active: np.ndarray, start: int,
    stop: int, na: int, cy: np.ndarray, weights: np.ndarray, bias: np.ndarray, kind: int,
    gamma: float, degree: int, comp_sq: np.ndarray,
) -> None:
    """Predict samples ``start .. stop-1`` of the rows ``:active[k]`` of ``y`` in place.

    ``pre`` (rows, stop-start, m): the input part per step; ``cy`` (na*ny, m): the output-lag
    part of the components; rbf: ``exp(2g (pre + xy.c - |xy|^2/2) - g|c|^2)``, sigmoid:
    ``tanh(pre + g xy.c)``, poly: ``(pre + g xy.c)^degree``.
    """
    ny = y.shape[2]
    width, m = cy.shape
    xy = np.empty(width)
    z = np.empty(m)
    out = np.empty(ny)
    has_term = term.shape[1] > 0
    for k in range(start, stop):
        for b in range(active[k]):
            sq = 0.0
            for i in range(na):
                for o in range(ny):
                    v = y[b, k - na + i, o]
                    xy[i * ny + o] = v
                    sq += v * v
            z[:] = 0.0
            for i in range(width):
                a = xy[i]
                row = cy[i]
                for j in range(m):
                    z[j] += a * row[j]
            p = pre[b, k - start]
            out[:] = bias
            for j in range(m):
                if kind == 0:
                    f = math.exp(2.0 * gamma * (p[j] + z[j] - 0.5 * sq) - gamma * comp_sq[j])
                elif kind == 1:
                    f = math.tanh(p[j] + gamma * z[j])
                else:
                    f = (p[j] + gamma * z[j]) ** degree
                for o in range(ny):
                    out[o] += f * weights[j, o]
            for o in range(ny):
                y[b, k, o] = out[o] + (term[b, k, o] if has_term else 0.0)


class SVMKernel(FlatKernel):
    """`FlatKernel` (its NumPy ``step`` is the reference) with a compiled ``run_all``."""

    def __init__(
        self,
        u_scaled: np.ndarray,
        window: WindowSpec,
        pre_u: Callable[[np.ndarray], np.ndarray],
        finish: Callable[[np.ndarray, np.ndarray], np.ndarray],
        kernel: str,
        cy: np.ndarray,
        weights: np.ndarray,
        bias: np.ndarray,
        gamma: float,
        degree: int,
        comp_sq: np.ndarray,
    ) -> None:
        super().__init__(u_scaled, window, pre_u, finish)
        self.kind = KERNEL_CODES[kernel]
        self.cy, self.weights = np.ascontiguousarray(cy), np.ascontiguousarray(weights)
        self.bias, self.comp_sq = np.asarray(bias, float), np.asarray(comp_sq, float)
        self.gamma, self.degree = float(gamma), int(degree)

    def run_all(self, y: np.ndarray, active: np.ndarray, first_target: int,
                term: np.ndarray | None = None) -> np.ndarray:
        """Every step from ``first_target`` on, a chunk of steps per compiled call."""
        if not (y.dtype == np.float64 and y.flags.c_contiguous):
            raise ValueError("y must be a C-contiguous float64 array (it is filled in place)")
        extra = term_array(term, y)
        active = np.ascontiguousarray(active, dtype=np.int64)
        for start in range(first_target, y.shape[1], self.chunk):
            rows = int(active[start])
            if rows == 0:
                break
            ks = np.arange(start, min(start + self.chunk, y.shape[1]))
            xu = input_lags(self.u, self.window, ks, rows)
            pre = self.pre_u(xu.reshape(rows * len(ks), -1)).reshape(rows, len(ks), -1)
            _steps(np.ascontiguousarray(pre, dtype=np.float64), y, extra, active, start,
                   int(ks[-1]) + 1, self.window.na, self.cy, self.weights, self.bias,
                   self.kind, self.gamma, self.degree, self.comp_sq)
        return y
