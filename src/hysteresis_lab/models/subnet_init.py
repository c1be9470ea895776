"""The linear starting point of SUBNET: a stable state-space model of the model's order.

Simulation-error training from random ``A, B, C`` lands in poor local minima; deepSI-style
practice starts the linear part from a best linear approximation instead. Here, on the
scaled training recordings (``v[t]`` the input the state update reads, ``y[t]`` the output):

1. a least-squares MIMO ARX model (`arx_markov`) gives the impulse response (Markov
   parameters) ``M_k = C A^(k-1) B``;
2. the eigensystem realisation algorithm (`era`, Ho–Kalman) realises them with ``nx``
   states; poles outside the unit circle are reflected inside (`stabilise`);
3. given ``A`` and ``C``, the output is linear in ``B``, the output offset ``c0`` and each
   recording's initial state, so these are refitted on the *simulation* error by least
   squares (`refit_output_error`);
   Steps 1-3 run for a few ARX orders (`linear_start`); unstable ARX models are skipped
   and the start with the lowest simulation error on the recordings is kept;
4. the state each time step should start from (`state_targets`) is the simulated state
   corrected by the least-squares state that explains the next ``J`` output errors; the
   encoder is fitted to it (in `hysteresis_lab.models.subnet`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numba
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from hysteresis_lab.kernels.jit_ops import JIT

log = logging.getLogger(__name__)

#: poles are kept at most this far out
MAX_RADIUS = 0.999
#: the Markov parameters ERA reads: at most this many lags
MAX_LAGS = 400
#: the ARX fit uses at most this many equations (rows) and parameters per output
ARX_ROWS = 60_000
ARX_PARAMETERS = 200


@dataclass
class LinearStart:
    """``x[t+1] = A x[t] + B v[t]``, ``y[t] = C x[t] + c0``; ``x0`` per recording."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    c0: np.ndarray
    x0: list[np.ndarray]

    def simulate(self, v: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States (T, nx) and outputs (T, ny) of the input ``v`` (T, nu) from ``x0``."""
        x = _states(self.A, np.ascontiguousarray(v @ self.B.T),
                    np.asarray(x0, dtype=np.float64))
        return x, x @ self.C.T + self.c0


@numba.njit(**JIT)
def _states(a: np.ndarray, drive: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """``x[t+1] = a x[t] + drive[t]`` from ``x[0] = x0``: (T, nx)."""
    x = np.empty((drive.shape[0], x0.shape[0]))
    state = x0.copy()
    for t in range(drive.shape[0]):
        x[t] = state
        state = a @ state + drive[t]
    return x


def arx_markov(
    vs: list[np.ndarray], ys: list[np.ndarray], order: int, lags: int = MAX_LAGS
) -> np.ndarray:
    """Markov parameters (lags, ny, nu), ``[k]`` the response at lag ``k + 1``, of the
    least-squares MIMO ARX model ``y[t] = sum_i Phi_i y[t-i] + sum_i Gamma_i v[t-i] + c``
    (``order`` lags of each) fitted on all recordings."""
    ny, nu = ys[0].shape[1], vs[0].shape[1]
    rows, targets = [], []
    for v, y in zip(vs, ys, strict=True):
        n = len(y)
        if n <= order + 1:
            continue
        t = np.arange(order, n)
        past_y = [y[t - i] for i in range(1, order + 1)]
        past_v = [v[t - i] for i in range(1, order + 1)]
        rows.append(np.column_stack([*past_y, *past_v, np.ones(len(t))]))
        targets.append(y[t])
    if not rows:
        raise ValueError(f"no recording is longer than the ARX order {order} + 1")
    x, target = np.vstack(rows), np.vstack(targets)
    if len(x) > ARX_ROWS:  # the rows are independent equations: a random share suffices
        keep = np.random.default_rng(0).choice(len(x), ARX_ROWS, replace=False)
        x, target = x[keep], target[keep]
    theta, *_ = np.linalg.lstsq(x, target, rcond=None)
    phi = [theta[i * ny : (i + 1) * ny].T for i in range(order)]
    gamma = [theta[order * ny + i * nu : order * ny + (i + 1) * nu].T for i in range(order)]
    markov = np.zeros((lags, ny, nu))
    for k in range(lags):  # markov[k]: lag k + 1
        m = gamma[k].copy() if k < order else np.zeros((ny, nu))
        for i in range(min(k, order)):
            m += phi[i] @ markov[k - 1 - i]
        markov[k] = m
    return markov


def era(markov: np.ndarray, nx: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``A, B, C`` of order ``nx`` realising the Markov parameters (lags, ny, nu) by the
    eigensystem realisation algorithm (balanced: the Hankel matrix's SVD)."""
    lags, ny, nu = markov.shape
    rows = (lags - 1) // 2
    hankel = np.block([[markov[i + j] for j in range(rows)] for i in range(rows)])
    shifted = np.block([[markov[i + j + 1] for j in range(rows)] for i in range(rows)])
    u, s, vt = np.linalg.svd(hankel, full_matrices=False)
    nx = min(nx, int(np.sum(s > s[0] * 1e-12)) if s[0] > 0 else 0)
    if nx < 1:
        raise ValueError("the ARX model's impulse response is zero")
    root = np.sqrt(s[:nx])
    a = (u[:, :nx] / root).T @ shifted @ (vt[:nx].T / root)
    b = (root[:, None] * vt[:nx])[:, :nu]
    c = (u[:, :nx] * root)[:ny]
    return a, b, c


def stabilise(a: np.ndarray, max_radius: float = MAX_RADIUS) -> np.ndarray:
    """``a`` with every eigenvalue outside the unit circle reflected inside it (``1 / conj``)
    and none beyond ``max_radius``; unchanged when it is stable already."""
    eigenvalues, vectors = np.linalg.eig(a)
    radius = np.abs(eigenvalues)
    if radius.max(initial=0.0) <= max_radius:
        return a
    moved = np.where(radius > 1.0, 1.0 / np.conj(eigenvalues), eigenvalues)
    moved = np.where(np.abs(moved) > max_radius,
                     moved * max_radius / np.maximum(np.abs(moved), 1e-300), moved)
    stable = np.real(vectors @ np.diag(moved) @ np.linalg.inv(vectors))
    if np.abs(np.linalg.eigvals(stable)).max() > max_radius + 1e-6:  # ill-conditioned basis
        stable = a * (max_radius / radius.max())
    log.info("linear start: %d pole(s) outside radius %.4f moved inside",
             int(np.sum(radius > max_radius)), max_radius)
    return stable


@numba.njit(**JIT)
def _regressors(a: np.ndarray, c: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(T, ny, nx*nu + nx): the output's derivative by ``B`` (columns ``B[:, i]`` for input
    i in turn) and by the initial state, for ``x[t+1] = A x[t] + B v[t]``."""
    nx, nu = a.shape[0], v.shape[1]
    g = np.zeros((nx, nx * (nu + 1)))
    for j in range(nx):
        g[j, nx * nu + j] = 1.0
    out = np.empty((v.shape[0], c.shape[0], g.shape[1]))
    for t in range(v.shape[0]):
        out[t] = c @ g
        g = a @ g
        for i in range(nu):
            for j in range(nx):
                g[j, i * nx + j] += v[t, i]
    return out


def refit_output_error(
    a: np.ndarray, c: np.ndarray, vs: list[np.ndarray], ys: list[np.ndarray]
) -> LinearStart:
    """``B``, the output offset and each recording's initial state that minimise the
    simulation error for the given ``A`` and ``C`` (linear least squares; the initial states
    are eliminated recording by recording)."""
    nx, ny, nu = a.shape[0], c.shape[0], vs[0].shape[1]
    n_theta = nx * nu + ny
    gram = np.zeros((n_theta, n_theta))
    rhs = np.zeros(n_theta)
    parts = []
    for v, y in zip(vs, ys, strict=True):
        reg = _regressors(a, c, np.ascontiguousarray(v, dtype=np.float64))
        shared = np.concatenate([reg[:, :, : nx * nu],
                                 np.broadcast_to(np.eye(ny), (len(v), ny, ny))], axis=2)
        shared = shared.reshape(-1, n_theta)
        initial = reg[:, :, nx * nu :].reshape(-1, nx)
        target = y.reshape(-1)
        # eliminate the initial state: project onto the complement of its columns
        initial_gram = initial.T @ initial
        initial_gram += 1e-12 * np.trace(initial_gram) * np.eye(nx)
        to_initial = np.linalg.solve(initial_gram, initial.T @ np.column_stack([shared, target]))
        cross = initial.T @ shared
        gram += shared.T @ shared - cross.T @ to_initial[:, :-1]
        rhs += shared.T @ target - cross.T @ to_initial[:, -1]
        parts.append((to_initial[:, :-1], to_initial[:, -1]))
    ridge = 1e-9 * np.trace(gram) / n_theta
    theta = np.linalg.solve(gram + ridge * np.eye(n_theta), rhs)
    b = theta[: nx * nu].reshape(nu, nx).T
    x0 = [initial_target - initial_shared @ theta for initial_shared, initial_target in parts]
    return LinearStart(a, b, c, theta[nx * nu :], x0)


def linear_start(
    vs: list[np.ndarray], ys: list[np.ndarray], nx: int, arx_orders: list[int] | None = None
) -> LinearStart:
    """A stable linear state-space model of order ``nx`` fitted to the scaled recordings
    (see the module docstring): one per ARX order in ``arx_orders`` (default ``nx / ny``
    rounded up, ``nx`` and ``2 nx``, each at most a tenth of the longest recording and at most
    `ARX_PARAMETERS` per output), the one
    with the lowest simulation error on the recordings kept."""
    longest = max(len(y) for y in ys)
    ny = ys[0].shape[1]
    orders = arx_orders or [-(-nx // ny), nx, 2 * nx]
    most = min(longest // 10, ARX_PARAMETERS // (ny + vs[0].shape[1]))
    orders = sorted({max(1, min(order, most)) for order in orders})
    lags = int(min(MAX_LAGS, max(2 * nx + 3, longest // 4)))
    best, best_error = None, np.inf
    for order in orders:
        try:
            start = _start_of_order(vs, ys, nx, order, lags)
        except (np.linalg.LinAlgError, ValueError) as exc:
            log.info("linear start: ARX(%d) gives none (%s)", order, exc)
            continue
        error = simulation_rmse(start, vs, ys)
        log.info("linear start: ARX(%d) -> ERA order %d: spectral radius %.4f, simulation "
                 "RMSE %.4g (scaled)", order, nx, float(np.abs(np.linalg.eigvals(start.A)).max()),
                 error)
        if error < best_error:
            best, best_error = start, error
    if best is None:
        raise ValueError("no ARX order gave a finite simulation error")
    return best


def _start_of_order(
    vs: list[np.ndarray], ys: list[np.ndarray], nx: int, order: int, lags: int
) -> LinearStart:
    """The linear start from an ARX model of ``order`` lags; ValueError when that ARX model
    is unstable (its impulse response grows) or the result is not finite."""
    markov = arx_markov(vs, ys, order, lags)
    size = np.abs(markov).max(axis=(1, 2))
    growing = size[-max(1, lags // 4) :].max() > 2.0 * size[: max(1, lags // 2)].max()
    if not np.all(np.isfinite(size)) or growing:
        raise ValueError("the ARX model is unstable")
    a, _, c = era(markov, nx)
    a = stabilise(a)
    if a.shape[0] < nx:  # a realisation of lower order: pad with states at rest
        pad = nx - a.shape[0]
        a = np.block([[a, np.zeros((a.shape[0], pad))],
                      [np.zeros((pad, a.shape[0])), np.zeros((pad, pad))]])
        c = np.concatenate([c, np.zeros((c.shape[0], pad))], axis=1)
    start = refit_output_error(a, c, vs, ys)
    if not all(np.all(np.isfinite(m)) for m in (start.A, start.B, start.C, start.c0)):
        raise ValueError("the realisation is not finite")
    return start


def simulation_rmse(start: LinearStart, vs: list[np.ndarray], ys: list[np.ndarray]) -> float:
    """RMSE of the free runs of ``start`` (each from its recording's initial state)."""
    squares = [np.sum((start.simulate(v, x0)[1] - y) ** 2)
               for v, y, x0 in zip(vs, ys, start.x0, strict=True)]
    return float(np.sqrt(np.sum(squares) / sum(y.size for y in ys)))


def state_targets(
    start: LinearStart, v: np.ndarray, y: np.ndarray, x0: np.ndarray, horizon: int
) -> np.ndarray:
    """The states ``x[t]`` (T', nx) whose free run best explains ``y[t .. t+horizon-1]``
    (the simulated state plus the least-squares state of the next ``horizon`` output
    errors), for t = 0 .. T' - 1."""
    x, y_sim = start.simulate(v, x0)
    horizon = max(1, min(horizon, len(y)))
    observability = np.vstack([start.C @ np.linalg.matrix_power(start.A, j)
                               for j in range(horizon)])
    error = y - y_sim  # (T, ny)
    windows = sliding_window_view(error, horizon, axis=0)  # (T-h+1, ny, h)
    stacked = windows.transpose(0, 2, 1).reshape(len(windows), -1)
    correction = stacked @ np.linalg.pinv(observability).T
    return x[: len(windows)] + correction
