"""Compiled CNN free run: every step of `_CNNKernel` in one numba call.

`hysteresis_lab.models.cnn._CNNKernel.step` evaluates the CNN on one regressor window per
recording with ~20 NumPy calls, so per-call overhead dominates a free run (~200,000 sequential
steps, mostly of a single recording). `cnn_free_run` runs the whole loop (regressor assembly,
``padding="same"`` convolutions + ReLU, global max pooling, dense head, feedback of the
prediction) in one compiled function with the same float32 arithmetic; only the summation
order of the products differs (float32 rounding), and the dense head runs in float32 like the
LSTM's (the step kernel uses float64 there; the dense head is that of
`hysteresis_lab.kernels.jit_ops`).

As the window slides one step, most conv input rows are the previous window's rows moved by
one, so each layer keeps its rows' products with every tap and computes only those of the new
rows (with ``padding="same"``: the rows whose receptive field reaches the newest step or the
padding): at the study's size (L=10, K=5, two layers) 5 of the second layer's 10 rows. The
wide products are BLAS sgemm calls (``np.dot`` on float32 arrays).

Functions compile on first use (``cache=True`` keeps the machine code between sessions).
"""

from __future__ import annotations

import numba
import numpy as np

from hysteresis_lab.kernels.jit_ops import (
    JIT,
    JIT_FMA,
    check_free_run_arrays,
    dense_head,
    packed_dense,
    term_array,
)


@numba.njit(**JIT_FMA)
def _tap_sums(
    buf: np.ndarray, at: int, bias: np.ndarray, size: int, units: int, r0: int, r1: int,
    out: np.ndarray,
) -> None:
    """Rows ``r0:r1`` of ``conv1d(x)`` (``padding="same"``, before the ReLU) from per-tap
    products into ``out`` (flat, row ``r0`` first; ``bias``: tiled to all L rows, flat).

    ``buf[d]`` (flat) holds ``x[s] @ taps[d]`` of window row ``s`` in row ``at + s``. Tap
    ``d`` adds to the rows whose input row exists (the zero padding contributes nothing) in
    one flat loop.
    """
    length = bias.shape[0] // units
    left = (size - 1) // 2
    src = buf[left, (at + r0) * units : (at + r1) * units]  # the centre tap: every row
    dst, b = out[: (r1 - r0) * units], bias[r0 * units : r1 * units]
    for i in range(dst.shape[0]):
        dst[i] = src[i] + b[i]
    for d in range(size):
        t0, t1 = max(r0, left - d), min(r1, length + left - d)
        if d == left or t1 <= t0:
            continue
        start = (at + t0 + d - left) * units
        src = buf[d, start : start + (t1 - t0) * units]
        dst = out[(t0 - r0) * units : (t1 - r0) * units]
        for i in range(dst.shape[0]):
            dst[i] += src[i]


@numba.njit(**JIT_FMA)
def _products(
    x: np.ndarray, w: np.ndarray, w_last: np.ndarray, rows: np.ndarray, taps: np.ndarray,
    buf: np.ndarray, at: int, prod: np.ndarray,
) -> None:
    """Store ``x[i] @ w`` (``w``: (in, K*out), all taps side by side) as window row
    ``s = rows[i]`` of ``buf``: tap ``d`` in ``buf[d]`` row ``at + s``, for the taps
    ``taps[0, s] <= d < taps[1, s]`` the row meets while it stays in the buffer.

    Wide inputs go through BLAS (``np.dot``: sgemm) into ``prod``; an odd newest row (taps
    from ``taps[0, L-1]`` on only, ``w_last``: those columns of ``w``) goes by itself, as
    sgemm handles an odd row about as slowly as two. Narrow inputs (the regressor) go by
    hand, straight into ``buf``.
    """
    m = rows.shape[0]
    size = buf.shape[0]
    units = w.shape[1] // size
    length = taps.shape[1]
    if w.shape[0] < 16:
        for i in range(m):
            s = rows[i]
            xi = x[i]
            start = (at + s) * units
            for d in range(taps[0, s], taps[1, s]):
                dst = buf[d, start : start + units]
                w_c = w[0, d * units : (d + 1) * units]
                a = xi[0]
                for j in range(units):
                    dst[j] = a * w_c[j]
                for c in range(1, w.shape[0]):
                    w_c = w[c, d * units : (d + 1) * units]
                    a = xi[c]
                    for j in range(units):
                        dst[j] += a * w_c[j]
        return
    first = taps[0, length - 1]
    last = m % 2 == 1 and rows[m - 1] == length - 1 and first > 0
    n_full = m - 1 if last else m
    if n_full > 0:
        np.dot(x[:n_full], w, prod[:n_full])
    if last:
        np.dot(x[n_full:m], w_last, prod[n_full][: w_last.shape[1]].reshape(1, -1))
    for i in range(m):
        s = rows[i]
        start = (at + s) * units
        shift = first if last and i == n_full else 0
        for d in range(taps[0, s], taps[1, s]):
            src = prod[i, (d - shift) * units : (d - shift + 1) * units]
            dst = buf[d, start : start + units]
            for j in range(units):
                dst[j] = src[j]


@numba.njit(**JIT)
def _free_run(
    u: np.ndarray,
    y: np.ndarray,
    term: np.ndarray,
    active: np.ndarray,
    first_target: int,
    nk: int,
    w0: np.ndarray,
    w0_last: np.ndarray,
    w: np.ndarray,
    w_last: np.ndarray,
    bias: np.ndarray,
    changed: np.ndarray,
    n_changed: np.ndarray,
    taps: np.ndarray,
    mask_u: np.ndarray,
    mask_y: np.ndarray,
    dense_w: np.ndarray,
    dense_b: np.ndarray,
    dense_dims: np.ndarray,
) -> None:
    """Every free-run step from ``first_target`` to the end; see `cnn_free_run`.

    Each conv layer keeps, per recording, the per-tap products of its input rows (window
    row ``s`` in buffer row ``at + s``). As the window slides one step, row ``s`` is the
    previous window's row ``s + 1`` except at the rows ``changed[l, :n_changed[l]]``, so
    ``at`` moves on by one and only those rows' products are computed anew (every row at a
    recording's first step; every L steps the window moves back to the buffer's start).
    The conv outputs are always summed from the products in the same order, so the result
    does not depend on the reuse.
    """
    batch, length_n, nu = u.shape[0], u.shape[1], u.shape[2]
    ny = y.shape[2]
    length = mask_u.shape[0]
    n_layers, units = taps.shape[0], bias.shape[1] // length
    size = w0.shape[1] // units
    has_term = term.shape[1] > 0
    bufs = np.zeros((batch, n_layers, size, 2 * length * units), np.float32)
    ats = np.zeros(batch, np.int64)
    last = np.full(batch, -2, np.int64)  # the step each buffer holds
    every = np.arange(length)
    x = np.zeros((length, nu + ny), np.float32)
    h = np.zeros(length * units, np.float32)
    x_in = np.zeros((length, units), np.float32)
    x_flat = x_in.reshape(length * units)
    prod = np.zeros((length, size * units), np.float32)
    pooled = np.empty(units, np.float32)
    d_in = np.empty(dense_dims.max(), np.float32)
    d_out = np.empty(dense_dims.max(), np.float32)
    for k in range(first_target, length_n):
        for b in range(active[k]):
            fresh = last[b] != k - 1  # no previous window to reuse
            at = 0 if fresh else ats[b] + 1
            if at + length > 2 * length:  # back to the buffer's start, keeping rows 0..L-2
                for layer in range(n_layers):
                    for d in range(size):
                        row = bufs[b, layer, d]
                        for i in range((length - 1) * units):
                            row[i] = row[at * units + i]
                at = 0
            ats[b], last[b] = at, k
            rows = every if fresh else changed[0, : n_changed[0]]
            # the regressor rows, oldest step first: u[k-nk-L+1+j] and y[k-L+j], masked
            for r in range(rows.shape[0]):
                j = rows[r]
                iu, iy = k - nk - length + 1 + j, k - length + j
                for i in range(nu):
                    x[r, i] = u[b, iu, i] * mask_u[j] if iu >= 0 else np.float32(0.0)
                for i in range(ny):
                    x[r, nu + i] = (np.float32(y[b, iy, i]) * mask_y[j] if iy >= 0
                                    else np.float32(0.0))
            _products(x, w0, w0_last, rows, taps[0], bufs[b, 0], at, prod)
            for layer in range(1, n_layers):
                rows = every if fresh else changed[layer, : n_changed[layer]]
                i = 0
                while i < rows.shape[0]:  # the previous layer's output at rows, run by run
                    n = i + 1
                    while n < rows.shape[0] and rows[n] == rows[n - 1] + 1:
                        n += 1
                    run = x_flat[i * units : n * units]
                    _tap_sums(bufs[b, layer - 1], at, bias[layer - 1], size, units, rows[i],
                              rows[n - 1] + 1, run)
                    for j in range(run.shape[0]):
                        if run[j] < 0.0:  # ReLU (NaN stays NaN)
                            run[j] = 0.0
                    i = n
                _products(x_in, w[layer - 1], w_last[layer - 1], rows, taps[layer],
                          bufs[b, layer], at, prod)
            _tap_sums(bufs[b, n_layers - 1], at, bias[n_layers - 1], size, units, 0, length, h)
            for j in range(units):
                pooled[j] = h[j]
            for t in range(1, length):  # global max pooling over time (NaN propagates)
                row = h[t * units : (t + 1) * units]
                for j in range(units):
                    if row[j] > pooled[j] or row[j] != row[j]:
                        pooled[j] = row[j]
            for j in range(units):  # the ReLU after the pooling: max(relu(v)) = relu(max(v))
                if pooled[j] < 0.0:
                    pooled[j] = 0.0
            out = dense_head(pooled, dense_w, dense_b, dense_dims, d_in, d_out)
            for i in range(ny):
                y[b, k, i] = np.float64(out[i]) + (term[b, k, i] if has_term else 0.0)


def _reuse_plan(
    mask_u: np.ndarray, mask_y: np.ndarray, n_layers: int, size: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which products each conv layer computes anew per step, and which taps.

    Input row ``s`` is the previous window's row ``s + 1`` (*kept*) unless it is the newest
    or (regressor) a mask changes between them, or (conv output) a row it reads is not kept
    or is padding. Returns the new rows (n_layers, L; the first ``n[l]`` count), ``n``, and
    per layer and row the taps ``[lo, hi)`` (2, L) whose output rows exist while the row,
    once computed, is kept (its position falls by one per step).
    """
    length = len(mask_u)
    left = (size - 1) // 2
    kept = np.zeros(length, bool)
    kept[:-1] = (mask_u[:-1] == mask_u[1:]) & (mask_y[:-1] == mask_y[1:])
    rows = np.zeros((n_layers, length), np.int64)
    counts = np.zeros(n_layers, np.int64)
    taps = np.zeros((n_layers, 2, length), np.int64)
    for layer in range(n_layers):
        new = np.flatnonzero(~kept)
        rows[layer, : len(new)], counts[layer] = new, len(new)
        for s in range(length):
            lowest = s
            while lowest > 0 and kept[lowest - 1]:
                lowest -= 1
            # output row t = s - d + left must lie in 0..L-1 at some position s..lowest
            taps[layer, 0, s] = max(0, lowest + left - length + 1)
            taps[layer, 1, s] = min(size, s + left + 1)
        kept = np.array([t >= left and t - left + size < length
                         and bool(kept[t - left : t - left + size].all())
                         for t in range(length)])
    return rows, counts, taps


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
    size = taps[0].shape[0]
    changed, n_changed, tap_range = _reuse_plan(np.asarray(mask_u), np.asarray(mask_y),
                                                len(taps), size)
    # all taps of a layer side by side: (in, K*out), block d = taps[d]; and the columns of
    # the taps the newest row meets (the same for every layer after the first)
    wide = [np.ascontiguousarray(np.transpose(t, (1, 0, 2)).reshape(t.shape[1], size * units),
                                 dtype=f32) for t in taps]
    newest = [np.ascontiguousarray(m[:, tap_range[i, 0, -1] * units :])
              for i, m in enumerate(wide)]
    w, w_last = ((np.array(wide[1:]), np.array(newest[1:])) if len(taps) > 1
                 else (np.zeros((0, units, size * units), f32),) * 2)
    _free_run(
        np.ascontiguousarray(u, dtype=f32),
        y,
        term_array(term, y),
        np.ascontiguousarray(active, dtype=np.int64),
        int(first_target),
        int(nk),
        wide[0],
        newest[0],
        w,
        w_last,
        np.ascontiguousarray(np.tile(np.array(bias, dtype=f32), (1, len(mask_u)))),  # per row
        changed,
        n_changed,
        tap_range,
        np.ascontiguousarray(mask_u, dtype=f32),
        np.ascontiguousarray(mask_y, dtype=f32),
        *packed_dense(dense, units),
    )
    return y
