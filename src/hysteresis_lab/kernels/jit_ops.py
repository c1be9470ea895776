"""Compiled building blocks shared by the numba free-run kernels (LSTM, CNN), and the checks
and packing their Python entry points share."""

from __future__ import annotations

import numba
import numpy as np

# error_model="numpy": no Python zero-division checks, so the element loops vectorise.
JIT = {"cache": True, "error_model": "numpy"}
# Products and polynomial terms may be fused into FMAs (a rounding-level change only).
JIT_FMA = {**JIT, "fastmath": {"contract"}}


@numba.njit(**JIT_FMA)
def matmul_add(
    x: np.ndarray, w: np.ndarray, out: np.ndarray, rows: int, period: int, skip: int
) -> None:
    """``out[r] += x[r] @ w`` for ``r < rows`` except ``r % period == skip`` (zero rows).

    Eight rows of ``w`` at a time are applied to every row of ``x`` (they stay in L1 while
    the output row streams); the inner loop over the output columns vectorises.
    """
    depth, width = w.shape
    k = 0
    while k + 8 <= depth:
        w0, w1, w2, w3 = w[k], w[k + 1], w[k + 2], w[k + 3]
        w4, w5, w6, w7 = w[k + 4], w[k + 5], w[k + 6], w[k + 7]
        for r in range(rows):
            if r % period == skip:
                continue
            xr = x[r]
            a0, a1, a2, a3 = xr[k], xr[k + 1], xr[k + 2], xr[k + 3]
            a4, a5, a6, a7 = xr[k + 4], xr[k + 5], xr[k + 6], xr[k + 7]
            o = out[r]
            for j in range(width):
                o[j] += ((a0 * w0[j] + a1 * w1[j]) + (a2 * w2[j] + a3 * w3[j])) + (
                    (a4 * w4[j] + a5 * w5[j]) + (a6 * w6[j] + a7 * w7[j])
                )
        k += 8
    while k < depth:
        w0 = w[k]
        for r in range(rows):
            if r % period == skip:
                continue
            a0 = x[r, k]
            o = out[r]
            for j in range(width):
                o[j] += a0 * w0[j]
        k += 1


@numba.njit(**JIT)
def dense_head(
    h: np.ndarray, dense_w: np.ndarray, dense_b: np.ndarray, dims: np.ndarray,
    d_in: np.ndarray, d_out: np.ndarray,
) -> np.ndarray:
    """ReLU, then each dense layer (ReLU between); returns a view of ``d_in`` (ny,)."""
    for i in range(h.shape[0]):
        d_in[i] = h[i]
    offset_w, offset_b = 0, 0
    for d in range(dims.shape[0] - 1):
        fan_in, fan_out = dims[d], dims[d + 1]
        w = dense_w[offset_w : offset_w + fan_in * fan_out]
        b = dense_b[offset_b : offset_b + fan_out]
        if fan_out == 1:  # one output: a scalar sum (the same additions, in the same order)
            acc = np.float32(0.0)
            for i in range(fan_in):
                a = np.float32(0.0) if d_in[i] < 0.0 else d_in[i]  # ReLU (NaN stays NaN)
                acc += a * w[i]
            d_in[0] = acc + b[0]
        else:
            for j in range(fan_out):
                d_out[j] = 0.0
            for i in range(fan_in):
                a = np.float32(0.0) if d_in[i] < 0.0 else d_in[i]  # ReLU (NaN stays NaN)
                w_i = w[i * fan_out : (i + 1) * fan_out]
                for j in range(fan_out):
                    d_out[j] += a * w_i[j]
            for j in range(fan_out):
                d_in[j] = d_out[j] + b[j]
        offset_w += fan_in * fan_out
        offset_b += fan_out
    return d_in[: dims[-1]]


def check_free_run_arrays(
    u: np.ndarray, y: np.ndarray, active: np.ndarray, term: np.ndarray | None, n_in: int
) -> None:
    """The compiled loops do not check bounds: check what they index here (``n_in``: the
    width the first layer expects, nu + ny)."""
    if not (y.dtype == np.float64 and y.flags.c_contiguous):
        raise ValueError("y must be a C-contiguous float64 array (it is filled in place)")
    if (u.shape[:2] != y.shape[:2] or len(active) < y.shape[1] or n_in != u.shape[2] + y.shape[2]
            or (term is not None and term.shape != y.shape)):
        raise ValueError(f"inconsistent shapes: u {u.shape}, y {y.shape}, active "
                         f"{np.shape(active)}, first layer width {n_in}, term "
                         f"{None if term is None else term.shape}")


def term_array(term: np.ndarray | None, y: np.ndarray) -> np.ndarray:
    """The optional input-only output term as the compiled loops take it (empty: none)."""
    if term is None:
        return np.zeros((y.shape[0], 0, y.shape[2]))
    return np.ascontiguousarray(term, dtype=np.float64)


def packed_dense(
    dense: list[tuple[np.ndarray, np.ndarray]], width: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The dense head's (W.T, b) pairs as `dense_head` takes them: all weights, all biases,
    and the layer widths starting with ``width`` (float32, int64)."""
    dims = [width] + [w.shape[1] for w, _ in dense]
    return (
        np.concatenate([np.ravel(w) for w, _ in dense]).astype(np.float32),
        np.concatenate([np.ravel(b) for _, b in dense]).astype(np.float32),
        np.array(dims, dtype=np.int64),
    )
