"""Compiled FFNN free run: every step of `hysteresis_lab.models.ffnn.FFNN`'s NARX loop in one
numba call (the reference is the torch step, ``free_run(..., fast=False)``).

A step is the MLP on the flat regressor ``[u lags | y lags]``: in the NumPy `FlatKernel`
each step still costs several NumPy calls (~10 µs); here the whole loop runs compiled, in
float64 like `FlatKernel`. A layer skips the inputs the ReLU zeroed (about half of them); its
loop over the outputs vectorises.
"""

from __future__ import annotations

import numba
import numpy as np

from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.kernels.interface import FlatKernel, run_dense
from hysteresis_lab.kernels.jit_ops import JIT_FMA, check_free_run_arrays, term_array


class FFNNKernel(FlatKernel):
    """The NumPy step of `FlatKernel` (restarts, n-step) and `run_all`, the compiled loop."""

    def __init__(
        self, u_scaled: np.ndarray, window: WindowSpec, layers: list[tuple[np.ndarray, ...]]
    ) -> None:
        w1, b1 = layers[0]
        split = window.nb * u_scaled.shape[2]
        w1u, w1y = w1[:split], w1[split:]

        def pre_u(xu: np.ndarray) -> np.ndarray:
            return xu @ w1u + b1

        def finish(pre: np.ndarray, xy: np.ndarray) -> np.ndarray:
            return run_dense(pre + xy @ w1y, layers[1:])

        super().__init__(u_scaled, window, pre_u, finish)
        self.layers = layers

    def run_all(self, y: np.ndarray, active: np.ndarray, first_target: int,
                term: np.ndarray | None = None) -> np.ndarray:
        """Every step from ``first_target`` on at once (compiled, see `ffnn_free_run`)."""
        w = self.window
        return ffnn_free_run(self.u, y, active, first_target, w.nk, w.nb, w.na, self.layers,
                             term)


@numba.njit(**JIT_FMA)
def _dense(
    a: np.ndarray, n_in: int, weights: np.ndarray, offset: int, bias: np.ndarray,
    offset_b: int, out: np.ndarray, n_out: int,
) -> None:
    """``out[:n_out] = relu(a[:n_in]) @ W + bias`` (``W`` row-major (n_in, n_out) in
    ``weights`` from ``offset``, the bias from ``offset_b``); inputs the ReLU zeroed are
    skipped (NaN propagates, as in torch)."""
    for j in range(n_out):
        out[j] = bias[offset_b + j]
    for i in range(n_in):
        value = a[i]
        if value > 0.0 or value != value:
            # an unsigned index: no wraparound test per element, so the loop vectorises
            # into contiguous loads (a signed runtime offset makes LLVM gather instead)
            row = np.uint64(offset + i * n_out)
            for j in range(n_out):
                out[j] += value * weights[row + np.uint64(j)]


@numba.njit(**JIT_FMA)
def _free_run(
    u: np.ndarray, y: np.ndarray, term: np.ndarray, active: np.ndarray, first_target: int,
    nk: int, nb: int, na: int, first_w: np.ndarray, first_b: np.ndarray,
    weights: np.ndarray, biases: np.ndarray, dims: np.ndarray,
) -> None:
    """Every step from ``first_target`` on; see `ffnn_free_run`."""
    batch, length = u.shape[:2]
    nu, ny = u.shape[2], y.shape[2]
    hidden = first_b.shape[0]
    width = max(hidden, dims.max())
    a = np.empty(width)
    b = np.empty(width)
    has_term = term.shape[1] > 0
    for k in range(first_target, length):
        for r in range(active[k]):
            for j in range(hidden):
                a[j] = first_b[j]
            for lag in range(nb):  # u[k-nk-nb+1+lag], oldest first
                for c in range(nu):
                    value = u[r, k - nk - nb + 1 + lag, c]
                    row = np.uint64((lag * nu + c) * hidden)
                    for j in range(hidden):
                        a[j] += value * first_w[row + np.uint64(j)]
            for lag in range(na):  # y[k-na+lag], oldest first
                for c in range(ny):
                    value = y[r, k - na + lag, c]
                    row = np.uint64((nb * nu + lag * ny + c) * hidden)
                    for j in range(hidden):
                        a[j] += value * first_w[row + np.uint64(j)]
            offset_w, offset_b = 0, 0
            for d in range(dims.shape[0] - 1):
                n_in, n_out = dims[d], dims[d + 1]
                _dense(a, n_in, weights, offset_w, biases, offset_b, b, n_out)
                for j in range(n_out):
                    a[j] = b[j]
                offset_w += n_in * n_out
                offset_b += n_out
            for c in range(ny):
                y[r, k, c] = a[c] + (term[r, k, c] if has_term else 0.0)


def ffnn_free_run(
    u: np.ndarray, y: np.ndarray, active: np.ndarray, first_target: int, nk: int, nb: int,
    na: int, layers: list[tuple[np.ndarray, np.ndarray]], term: np.ndarray | None = None,
) -> np.ndarray:
    """Free-run the rows ``:active[k]`` of ``y`` (B, N, ny, scaled float64) in place from
    ``first_target`` on and return it; ``u`` (B, N, nu) scaled inputs, ``layers`` the MLP's
    (W.T, b) pairs (`hysteresis_lab.kernels.interface.dense_layers`), ``term`` an optional
    input-only output term added to every prediction."""
    first_w, first_b = layers[0]
    check_free_run_arrays(u, y, active, term, u.shape[2] + y.shape[2])
    if first_w.shape[0] != nb * u.shape[2] + na * y.shape[2]:
        raise ValueError(f"first layer takes {first_w.shape[0]} regressors, the window gives "
                         f"{nb * u.shape[2] + na * y.shape[2]}")
    if y.shape[1] <= first_target:
        return y
    rest = layers[1:]
    dims = np.array([first_w.shape[1]] + [w.shape[1] for w, _ in rest], dtype=np.int64)
    _free_run(
        np.ascontiguousarray(u, dtype=np.float64), y, term_array(term, y),
        np.ascontiguousarray(active, dtype=np.int64), int(first_target), int(nk), int(nb),
        int(na), np.ascontiguousarray(first_w, dtype=np.float64).ravel(),
        np.ascontiguousarray(first_b, dtype=np.float64),
        np.concatenate([np.ravel(w) for w, _ in rest]).astype(np.float64),
        np.concatenate([np.ravel(b) for _, b in rest]).astype(np.float64), dims,
    )
    return y
