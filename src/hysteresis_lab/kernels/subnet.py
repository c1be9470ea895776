"""Compiled free run of `hysteresis_lab.models.subnet.SUBNET` (the reference is its torch
`simulate_recordings` loop): one recording step costs a few small dense layers in numba."""

from __future__ import annotations

import numba
import numpy as np
from torch import nn

from hysteresis_lab.kernels.jit_ops import JIT_FMA


def packed_mlp(seq: nn.Sequential) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An `mlp`'s Linear layers as (all W.T weights, all biases, layer widths), float64."""
    linears = [m for m in seq if isinstance(m, nn.Linear)]
    weights = np.concatenate([m.weight.detach().cpu().double().numpy().T.ravel()
                              for m in linears])
    biases = np.concatenate([m.bias.detach().cpu().double().numpy() for m in linears])
    dims = np.array([linears[0].in_features] + [m.out_features for m in linears], np.int64)
    return weights, biases, dims


@numba.njit(**JIT_FMA)
def _mlp(
    inp: np.ndarray, weights: np.ndarray, biases: np.ndarray, dims: np.ndarray,
    a: np.ndarray, b: np.ndarray,
) -> np.ndarray:
    """Dense layers with ReLU between them (none after the last); returns a view of ``a``."""
    a[: dims[0]] = inp
    offset_w, offset_b = 0, 0
    last = dims.shape[0] - 2
    for d in range(dims.shape[0] - 1):
        fan_in, fan_out = dims[d], dims[d + 1]
        for j in range(fan_out):
            b[j] = biases[offset_b + j]
        for i in range(fan_in):
            ai = a[i]
            # an unsigned index: no wraparound test per element, so the loop vectorises
            # into contiguous loads (a signed runtime offset makes LLVM gather instead)
            row = np.uint64(offset_w + i * fan_out)
            for j in range(fan_out):
                b[j] += ai * weights[row + np.uint64(j)]
        for j in range(fan_out):
            a[j] = b[j] if d == last or b[j] > 0.0 else 0.0
        offset_w += fan_in * fan_out
        offset_b += fan_out
    return a[: dims[-1]]


@numba.njit(**JIT_FMA)
def subnet_free_run(
    x0: np.ndarray, u: np.ndarray, lengths: np.ndarray, first_target: int, nk: int,
    A: np.ndarray, B: np.ndarray, C: np.ndarray,
    f_w: np.ndarray, f_b: np.ndarray, f_dims: np.ndarray,
    h_w: np.ndarray, h_b: np.ndarray, h_dims: np.ndarray,
) -> np.ndarray:
    """``y[k] = C x + h(x)``, ``x <- A x + B u[k-nk+1] + f([x, u[k-nk+1]])`` for every row.

    ``x0`` (R, nx) is the state at ``first_target``; ``u`` (R, T, nu) the scaled inputs, of
    which row ``r`` runs ``lengths[r]`` samples (the rest is padding, left at zero);
    ``A`` (nx, nx), ``B`` (nx, nu), ``C`` (ny, nx) as torch stores them (out x in).
    """
    rows, length, nu = u.shape
    nx, ny = A.shape[0], C.shape[0]
    width = max(f_dims.max(), h_dims.max())
    y = np.zeros((rows, length, ny))
    x = np.empty(nx)
    xu = np.empty(nx + nu)
    a = np.empty(width)
    b = np.empty(width)
    x_next = np.empty(nx)
    for r in range(rows):
        x[:] = x0[r]
        length = lengths[r]
        for k in range(first_target, length):
            h = _mlp(x, h_w, h_b, h_dims, a, b)
            for j in range(ny):
                acc = h[j]
                for i in range(nx):
                    acc += C[j, i] * x[i]
                y[r, k, j] = acc
            if k + 1 >= length:
                break
            uk = u[r, k - nk + 1]
            xu[:nx] = x
            xu[nx:] = uk
            f = _mlp(xu, f_w, f_b, f_dims, a, b)
            for i in range(nx):
                acc = f[i]
                for m in range(nx):
                    acc += A[i, m] * x[m]
                for m in range(nu):
                    acc += B[i, m] * uk[m]
                x_next[i] = acc
            x[:] = x_next
    return y
