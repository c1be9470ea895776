"""NumPy free-run kernels: one simulation step costs a few small array operations.

Free-run simulation is inherently sequential (~200,000 steps for the 0.1 Hz test sine), so
per-step overhead dominates: a torch op costs ~5-10 µs on the CPU, a tiny NumPy matmul ~1 µs.
A model may offer ``free_run_kernel(u_scaled, window)`` returning a `FreeRunKernel`; the
simulator (`hysteresis_lab.evaluation.predict`) calls ``kernel.step(k, n, y)`` for
``k = first_target, first_target + 1, ...`` where ``y`` (B, N, ny) holds the *scaled* output
history (measured initial conditions, then the model's own predictions) and rows ``:n`` are the
recordings still running (the simulator sorts them longest first). A kernel may instead run
every step at once (``run_all``, see `FreeRunKernel`), e.g. in compiled code.

`FlatKernel` serves flat-regressor models whose first operation is linear in the regressor
(FFNN first layer, Nyström/SVR kernel dot products, linear SVR): the input part of that linear
map is precomputed for a chunk of steps at once, so each step only adds the output-lag part.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from torch import nn

from hysteresis_lab.data.windows import WindowSpec


class FreeRunKernel:
    """Interface of a fast free-run step (see the module docstring).

    A kernel may also offer ``run_all(y, active, first_target) -> y``: the whole simulation
    without restarts in one call (``y`` as for `step`, filled in place from
    ``first_target`` on for the rows ``:active[k]``); the simulator then uses it instead of
    the loop over `step`.
    """

    #: True when the kernel carries state between consecutive steps (no restarts allowed).
    stateful: bool = False

    def step(self, k: int, n: int, y: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError


def input_lags(u: np.ndarray, window: WindowSpec, ks: np.ndarray, rows: int) -> np.ndarray:
    """Flat input lags ``u[k-nk-nb+1 .. k-nk]`` (oldest first) of ``rows`` recordings at ``ks``.

    ``u`` is (B, N, nu); returns (rows, len(ks), nb*nu).
    """
    nb, nk = window.nb, window.nk
    wins = sliding_window_view(u[:rows], nb, axis=1)  # (rows, N-nb+1, nu, nb)
    picked = wins[:, ks - nk - nb + 1]  # (rows, T, nu, nb)
    return picked.transpose(0, 1, 3, 2).reshape(rows, len(ks), nb * u.shape[2])


class FlatKernel(FreeRunKernel):
    """``pre_u(x_u)`` precomputed per chunk of steps, then ``finish(pre, x_y)`` per step."""

    def __init__(
        self,
        u_scaled: np.ndarray,
        window: WindowSpec,
        pre_u: Callable[[np.ndarray], np.ndarray],
        finish: Callable[[np.ndarray, np.ndarray], np.ndarray],
        chunk: int = 1024,
    ) -> None:
        self.u, self.window, self.pre_u, self.finish, self.chunk = (
            u_scaled, window, pre_u, finish, chunk,
        )
        self._start = -1
        self._stop = -1
        self._pre = np.empty((0, 0, 0))

    def _fill(self, k: int, n: int) -> None:
        stop = min(k + self.chunk, self.u.shape[1])
        ks = np.arange(k, stop)
        xu = input_lags(self.u, self.window, ks, n)
        pre = self.pre_u(xu.reshape(n * len(ks), -1))
        self._pre = pre.reshape(n, len(ks), -1)
        self._start, self._stop = k, stop

    def step(self, k: int, n: int, y: np.ndarray) -> np.ndarray:
        if not self._start <= k < self._stop or n > self._pre.shape[0]:
            self._fill(k, n)
        na = self.window.na
        xy = y[:n, k - na : k].reshape(n, na * y.shape[2])
        return self.finish(self._pre[:n, k - self._start], xy)


def dense_layers(seq: nn.Sequential) -> list[tuple[np.ndarray, np.ndarray]]:
    """(W.T, b) of every Linear in an `mlp` (ReLU between, none after the last), float64."""
    return [
        (
            m.weight.detach().cpu().double().numpy().T.copy(),
            m.bias.detach().cpu().double().numpy().copy(),
        )
        for m in seq
        if isinstance(m, nn.Linear)
    ]


def run_dense(h: np.ndarray, layers: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """ReLU, then each layer of `dense_layers` (ReLU between them, linear output)."""
    for weight, bias in layers:
        h = np.maximum(h, 0.0) @ weight
        h += bias
    return h


def sequence_masks(window: WindowSpec) -> tuple[np.ndarray, np.ndarray]:
    """Per time step of the sequence layout (oldest first): 1 where u / y lags are real."""
    length = window.seq_len
    back = length - 1 - np.arange(length)  # lag index j of each step
    return (back < window.nb).astype(float), (back < window.na).astype(float)
