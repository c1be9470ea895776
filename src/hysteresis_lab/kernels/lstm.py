"""Compiled LSTM free run: the whole "wavefront" loop of `_LSTMKernel` in one numba call.

`hysteresis_lab.models.lstm._LSTMKernel` advances the ``L`` in-flight windows of every
recording by one LSTM time step per simulation step. With NumPy each step costs ~30 array
calls, so Python/NumPy overhead dominates the ~200,000 sequential steps of a free run.
`lstm_free_run` runs every step (warm-up, gates, cell update, dense head, feedback of the
prediction) inside one compiled function, with the same arithmetic in float32:

* the gate pre-activations are the same matrix products (the ``i, f, o`` rows halved, so
  ``sigmoid(z) = 0.5 tanh(z/2) + 0.5`` and one tanh serves all gates); only the summation
  order of the products differs (float32 rounding);
* tanh is evaluated in float64 and rounded once to float32 (`_tanh_rows`): branch-free, so
  LLVM vectorises it (NumPy's tanh in numba is a scalar libm call, ~16 ns, which alone
  would cap a free run at ~9,000 steps/s), and within 0.5 units in the last place of the
  exact tanh, i.e. correctly rounded but for rare near-ties (NumPy's float32 tanh, which
  the step-by-step kernel uses, is off by up to ~1.4 units);
* the prediction is rounded to float64 and written to the output history ``y`` exactly as
  the step-by-step driver does, so the next step reads it back the same way.

Functions compile on first use (``cache=True`` keeps the machine code between sessions).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from hysteresis_lab.kernels.jit_ops import (
    JIT,
    JIT_FMA,
    check_free_run_arrays,
    dense_head,
    matmul_add,
    packed_dense,
    term_array,
)

#: expm1(z) / z on 0 <= z <= 10/16: degree-8 least-squares fit at 200 Chebyshev nodes
#: (relative error < 5e-14 in exact arithmetic); scaled by 16^-(i+1) (exactly) for z = |x|
_EXPM1 = tuple(c / 16.0 ** (i + 1) for i, c in enumerate((
    1.000000000000039, 0.49999999998961653, 0.16666666710783198, 0.041666659458456635,
    0.008333392227677112, 0.0013886193393519263, 0.00019913386363867814,
    2.3688000294065463e-05, 3.6604050439964922e-06,
)))


@numba.njit(**JIT_FMA)
def _tanh_rows(a: np.ndarray, rows: int, start: int, stop: int) -> None:
    """In place: ``a[r, start:stop] = tanh(a[r, start:stop])`` for ``r < rows`` (float32).

    ``tanh|x| = m / (m + 2)`` with ``m = expm1(2|x|)``: a polynomial gives ``expm1`` of
    ``2|x| / 32``, five doublings ``expm1(2z) = m (m + 2)`` the rest (relative error
    ~1e-12 in float64, then one rounding to float32). ``|x|`` is clamped at 10, where tanh
    rounds to 1 in float32; NaN propagates. No branches or calls: the loop vectorises.
    """
    c0, c1, c2, c3, c4, c5, c6, c7, c8 = _EXPM1
    for r in range(rows):
        row = a[r]
        for j in range(start, stop):
            x = np.float64(row[j])
            z = abs(x)
            z = 10.0 if z > 10.0 else z
            p = c8 * z + c7
            p = p * z + c6
            p = p * z + c5
            p = p * z + c4
            p = p * z + c3
            p = p * z + c2
            p = p * z + c1
            p = p * z + c0
            m = p * z
            m *= m + 2.0
            m *= m + 2.0
            m *= m + 2.0
            m *= m + 2.0
            m *= m + 2.0
            t = m / (m + 2.0)
            row[j] = np.float32(math.copysign(t, x))


@numba.njit(**JIT)
def _cell_update(
    gates: np.ndarray, h: np.ndarray, c: np.ndarray, scratch: np.ndarray, rows: int
) -> None:
    """LSTM cell update of ``rows`` rows from the gate pre-activations (``i, f, o`` halved)."""
    hidden = h.shape[1]
    _tanh_rows(gates, rows, 0, 4 * hidden)
    for r in range(rows):
        g, cr, sr = gates[r], c[r], scratch[r]
        for j in range(hidden):
            gate_i = g[j] * np.float32(0.5) + np.float32(0.5)
            gate_f = g[hidden + j] * np.float32(0.5) + np.float32(0.5)
            cell = cr[j] * gate_f
            cell += gate_i * g[2 * hidden + j]
            cr[j] = cell
            sr[j] = cell
    _tanh_rows(scratch, rows, 0, hidden)
    for r in range(rows):
        g, hr, sr = gates[r], h[r], scratch[r]
        for j in range(hidden):
            hr[j] = (g[3 * hidden + j] * np.float32(0.5) + np.float32(0.5)) * sr[j]


@numba.njit(**JIT)
def _add_inputs(
    gates: np.ndarray, x_u: np.ndarray, x_y: np.ndarray, wih0: np.ndarray, bias: np.ndarray,
    mask_u: np.ndarray, mask_y: np.ndarray, k: int, row0: int, p_u: np.ndarray,
    p_y: np.ndarray,
) -> None:
    """Layer 0: add the newest sample's projection (+ bias) to the ``L`` windows at ``row0``.

    ``x_u`` (nu,) and ``x_y`` (ny,) are the input and output lags every in-flight window
    consumes now; the window in slot ``s`` is at time step ``L - 1 - (s - k) % L``, whose
    lags are masked where ``na`` or ``nb`` is shorter than ``L``.
    """
    nu, width = x_u.shape[0], gates.shape[1]
    length = mask_u.shape[0]
    p_u[:] = 0.0
    p_y[:] = 0.0
    for i in range(nu):
        a, w_i = x_u[i], wih0[i]
        for j in range(width):
            p_u[j] += a * w_i[j]
    for i in range(x_y.shape[0]):
        a, w_i = np.float32(x_y[i]), wih0[nu + i]
        for j in range(width):
            p_y[j] += a * w_i[j]
    for s in range(length):
        step = length - 1 - (s - k) % length
        mu, my = mask_u[step], mask_y[step]
        g = gates[row0 + s]
        for j in range(width):
            g[j] += (mu * p_u[j] + my * p_y[j]) + bias[j]


@numba.njit(**JIT)
def _free_run(
    u: np.ndarray,
    y: np.ndarray,
    term: np.ndarray,
    active: np.ndarray,
    first_target: int,
    nk: int,
    wih0: np.ndarray,
    wih: np.ndarray,
    whh: np.ndarray,
    bias: np.ndarray,
    mask_u: np.ndarray,
    mask_y: np.ndarray,
    dense_w: np.ndarray,
    dense_b: np.ndarray,
    dense_dims: np.ndarray,
) -> None:
    """Every free-run step from the warm-up to the end; see `lstm_free_run`."""
    batch, length_n = u.shape[:2]
    ny = y.shape[2]
    layers, hidden, width = whh.shape
    length = mask_u.shape[0]
    has_term = term.shape[1] > 0
    h = np.zeros((layers, batch * length, hidden), np.float32)
    c = np.zeros((layers, batch * length, hidden), np.float32)
    gates = np.empty((batch * length, width), np.float32)
    scratch = np.empty((batch * length, hidden), np.float32)
    p_u = np.empty(width, np.float32)
    p_y = np.empty(width, np.float32)
    d_in = np.empty(dense_dims.max(), np.float32)
    d_out = np.empty(dense_dims.max(), np.float32)
    for k in range(first_target - length + 1, length_n):
        n = active[max(k, first_target)]  # the warm-up runs the rows of the first target
        rows = n * length
        slot = k % length  # window k completes now
        fresh = (k - 1) % length  # freed at the previous step: its h is zero
        for layer in range(layers):
            gates[:rows] = 0.0
            for source in range(2 if layer > 0 else 1):  # one call site: less to compile
                if source == 0:
                    x, w, skip = h[layer], whh[layer], fresh
                else:
                    x, w, skip = h[layer - 1], wih[layer - 1], -1
                matmul_add(x, w, gates, rows, length, skip)
            if layer == 0:
                for b in range(n):
                    _add_inputs(gates, u[b, max(k - nk, 0)], y[b, max(k - 1, 0)], wih0,
                                bias[0], mask_u, mask_y, k, b * length, p_u, p_y)
            else:
                for r in range(rows):
                    g, bl = gates[r], bias[layer]
                    for j in range(width):
                        g[j] += bl[j]
            _cell_update(gates, h[layer], c[layer], scratch, rows)
        for b in range(n):
            row = b * length + slot
            out = dense_head(h[layers - 1, row], dense_w, dense_b, dense_dims, d_in, d_out)
            if k >= first_target:
                for i in range(ny):
                    y[b, k, i] = np.float64(out[i]) + (term[b, k, i] if has_term else 0.0)
            for layer in range(layers):  # the slot starts window k + L
                h[layer, row] = 0.0
                c[layer, row] = 0.0


def lstm_free_run(
    u: np.ndarray,
    y: np.ndarray,
    active: np.ndarray,
    first_target: int,
    nk: int,
    wih: list[np.ndarray],
    whh: list[np.ndarray],
    bias: list[np.ndarray],
    mask_u: np.ndarray,
    mask_y: np.ndarray,
    dense: list[tuple[np.ndarray, np.ndarray]],
    term: np.ndarray | None = None,
) -> np.ndarray:
    """Free-run all rows of ``y`` (B, N, ny, scaled, float64) in place and return it.

    ``y[:, :first_target]`` holds the measured initial conditions; every later sample
    ``k`` of the rows ``:active[k]`` is overwritten by the prediction (plus ``term[b, k]``
    when given: an input-only output term, e.g. a linear effect path). ``u`` (B, N, nu) holds
    the scaled inputs; ``wih``/``whh``/``bias`` the per-layer LSTM weights transposed to
    (in, 4H) with the ``i, f, o`` gates halved, ``bias`` the summed biases;
    ``mask_u``/``mask_y`` (L,) mark the real lags per time step, oldest first; ``dense`` the
    (W.T, b) of the dense head (ReLU before each layer).
    """
    f32 = np.float32
    hidden = whh[0].shape[0]
    check_free_run_arrays(u, y, active, term, wih[0].shape[0])
    if y.shape[1] <= first_target:
        return y
    _free_run(
        np.ascontiguousarray(u, dtype=f32),
        y,
        term_array(term, y),
        np.ascontiguousarray(active, dtype=np.int64),
        int(first_target),
        int(nk),
        np.ascontiguousarray(wih[0], dtype=f32),
        np.ascontiguousarray(np.array(wih[1:], dtype=f32)) if len(wih) > 1
        else np.zeros((0, hidden, whh[0].shape[1]), f32),
        np.ascontiguousarray(np.array(whh, dtype=f32)),
        np.ascontiguousarray(np.array(bias, dtype=f32)),
        np.ascontiguousarray(mask_u, dtype=f32),
        np.ascontiguousarray(mask_y, dtype=f32),
        *packed_dense(dense, hidden),
    )
    return y
