"""Compiled CNN free run: every step of `_CNNKernel` in one numba call.

`hysteresis_lab.models.cnn._CNNKernel.step` evaluates the CNN on one regressor window per
recording with ~20 NumPy calls, so per-call overhead dominates a free run (~200,000 sequential
steps, mostly of a single recording). `cnn_free_run` runs the whole loop (regressor assembly,
``padding="same"`` convolutions + ReLU, global max pooling, dense head, feedback of the
prediction) in one compiled function with the same float32 arithmetic; only the summation
order of the products differs (float32 rounding), and the dense head runs in float32 like the
LSTM's (the step kernel uses float64 there). The matrix products and the dense head are those
of `hysteresis_lab.kernels.jit_ops`.

Functions compile on first use (``cache=True`` keeps the machine code between sessions).
"""

from __future__ import annotations

import numba
import numpy as np

from hysteresis_lab.kernels.jit_ops import (
    JIT,
    check_free_run_arrays,
    dense_head,
    matmul_add,
    packed_dense,
    term_array,
)


@numba.njit(**JIT)
def _conv_relu(x: np.ndarray, taps: np.ndarray, bias: np.ndarray, out: np.ndarray) -> None:
    """``out = relu(conv1d(x))`` with ``padding="same"``: ``x`` (L, in), ``taps`` (K, in, out).

    Tap ``d`` adds ``x[t + d - left] @ taps[d]`` to ``out[t]`` wherever that row exists (the
    zero padding contributes nothing, so it is skipped).
    """
    length = x.shape[0]
    size = taps.shape[0]
    left = (size - 1) // 2
    for t in range(length):
        out[t] = bias
    for d in range(size):
        t0 = max(0, left - d)
        t1 = min(length, length + left - d)
        if t1 > t0:
            matmul_add(x[t0 + d - left :], taps[d], out[t0:], t1 - t0, 1, -1)
    for t in range(length):
        row = out[t]
        for j in range(row.shape[0]):
            if row[j] < 0.0:  # ReLU (NaN stays NaN)
                row[j] = 0.0


@numba.njit(**JIT)
def _free_run(
    u: np.ndarray,
    y: np.ndarray,
    term: np.ndarray,
    active: np.ndarray,
    first_target: int,
    nk: int,
    taps0: np.ndarray,
    taps: np.ndarray,
    bias: np.ndarray,
    mask_u: np.ndarray,
    mask_y: np.ndarray,
    dense_w: np.ndarray,
    dense_b: np.ndarray,
    dense_dims: np.ndarray,
) -> None:
    """Every free-run step from ``first_target`` to the end; see `cnn_free_run`."""
    length_n, nu = u.shape[1], u.shape[2]
    ny = y.shape[2]
    units = bias.shape[1]
    length = mask_u.shape[0]
    has_term = term.shape[1] > 0
    x = np.zeros((length, nu + ny), np.float32)
    h_a = np.empty((length, units), np.float32)
    h_b = np.empty((length, units), np.float32)
    pooled = np.empty(units, np.float32)
    d_in = np.empty(dense_dims.max(), np.float32)
    d_out = np.empty(dense_dims.max(), np.float32)
    for k in range(first_target, length_n):
        for b in range(active[k]):
            # the regressor, oldest step first: u[k-nk-L+1+j] and y[k-L+j], masked
            for j in range(length):
                iu, iy = k - nk - length + 1 + j, k - length + j
                for i in range(nu):
                    x[j, i] = u[b, iu, i] * mask_u[j] if iu >= 0 else np.float32(0.0)
                for i in range(ny):
                    x[j, nu + i] = (np.float32(y[b, iy, i]) * mask_y[j] if iy >= 0
                                    else np.float32(0.0))
            _conv_relu(x, taps0, bias[0], h_a)
            for layer in range(taps.shape[0]):
                if layer % 2 == 0:
                    _conv_relu(h_a, taps[layer], bias[layer + 1], h_b)
                else:
                    _conv_relu(h_b, taps[layer], bias[layer + 1], h_a)
            h = h_b if taps.shape[0] % 2 == 1 else h_a
            for j in range(units):  # global max pooling over time (NaN propagates)
                m = h[0, j]
                for t in range(1, length):
                    v = h[t, j]
                    if v > m or v != v:
                        m = v
                pooled[j] = m
            out = dense_head(pooled, dense_w, dense_b, dense_dims, d_in, d_out)
            for i in range(ny):
                y[b, k, i] = np.float64(out[i]) + (term[b, k, i] if has_term else 0.0)


def cnn_free_run(
    u: np.ndarray,
    y: np.ndarray,
    active: np.ndarray,
    first_target: int,
    nk: int,
    taps: list[np.ndarray],
    bias: list[np.ndarray],
    mask_u: np.ndarray,
    mask_y: np.ndarray,
    dense: list[tuple[np.ndarray, np.ndarray]],
    term: np.ndarray | None = None,
) -> np.ndarray:
    """Free-run all rows of ``y`` (B, N, ny, scaled, float64) in place and return it.

    ``y[:, :first_target]`` holds the measured initial conditions; every later sample ``k``
    of the rows ``:active[k]`` is overwritten by the prediction (plus ``term[b, k]`` when
    given: an input-only output term). ``u`` (B, N, nu) holds the scaled inputs; ``taps`` the
    per-layer conv weights as (K, in, out), ``bias`` their biases (all layers K taps, ``out``
    channels); ``mask_u``/``mask_y`` (L,) mark the real lags per time step, oldest first;
    ``dense`` the (W.T, b) of the dense head (ReLU before each layer).
    """
    f32 = np.float32
    units = bias[0].shape[0]
    check_free_run_arrays(u, y, active, term, taps[0].shape[1])
    if any(t.shape != (taps[0].shape[0], units, units) for t in taps[1:]):
        raise ValueError(f"inconsistent conv taps {[t.shape for t in taps]}")
    if y.shape[1] <= first_target:
        return y
    _free_run(
        np.ascontiguousarray(u, dtype=f32),
        y,
        term_array(term, y),
        np.ascontiguousarray(active, dtype=np.int64),
        int(first_target),
        int(nk),
        np.ascontiguousarray(taps[0], dtype=f32),
        np.ascontiguousarray(np.array(taps[1:], dtype=f32)) if len(taps) > 1
        else np.zeros((0, taps[0].shape[0], units, units), f32),
        np.ascontiguousarray(np.array(bias, dtype=f32)),
        np.ascontiguousarray(mask_u, dtype=f32),
        np.ascontiguousarray(mask_y, dtype=f32),
        *packed_dense(dense, units),
    )
    return y
