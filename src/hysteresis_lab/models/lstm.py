"""LSTM over the regressor sequence, then dense layers (the study: 2 LSTM + 1 dense, 66 units)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.kernels.interface import FreeRunKernel, dense_layers, run_dense, sequence_masks
from hysteresis_lab.kernels.lstm import lstm_free_run
from hysteresis_lab.models.base import NarxModule, mlp


class _LSTMHead(nn.Module):
    def __init__(self, n_features: int, units: int, lstm_layers: int, n_dense: int, ny: int):
        super().__init__()
        self.lstm = nn.LSTM(n_features, units, num_layers=lstm_layers, batch_first=True)
        self.dense = mlp(units, ny, units, n_dense)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        hidden, _ = self.lstm(x)
        return self.dense(torch.relu(hidden[:, -1]))


class LSTMNet(NarxModule):
    """``lstm_layers`` LSTM layers, ``num_layers - lstm_layers - 1`` hidden dense, linear output."""

    layout = "sequence"

    def __init__(self, nu: int, ny: int, num_layers: int = 3, lstm_layers: int = 2,
                 units: int = 66, **kwargs: Any) -> None:
        super().__init__(nu=nu, ny=ny, **kwargs)
        if lstm_layers < 1 or num_layers <= lstm_layers or units < 1:
            raise ConfigError(
                "LSTM needs lstm_layers >= 1, num_layers > lstm_layers (the output layer is "
                f"dense) and units >= 1; got num_layers={num_layers}, lstm_layers={lstm_layers}, "
                f"units={units}. Fix: e.g. model.num_layers=3 model.lstm_layers=2 model.units=66."
            )
        self.net = _LSTMHead(self.n_features, units, lstm_layers, num_layers - lstm_layers - 1,
                             ny)

    def free_run_kernel(self, u_scaled: np.ndarray, window: WindowSpec) -> FreeRunKernel:
        """NumPy "wavefront" free-run step (see `_LSTMKernel`)."""
        return _LSTMKernel(self.net, self.nu, u_scaled, window)


class _LSTMKernel(FreeRunKernel):
    """Free-run LSTM that advances all in-flight windows one time step per sample.

    Every window restarts the LSTM from a zero state, so consecutive windows share no state;
    but at simulation step ``k`` the windows ``k, k+1, ..., k+L-1`` all consume the same newest
    sample (``u[k-nk]``, ``y[k-1]``) at different time steps. Keeping those ``L`` partial windows
    in a ring buffer, one step is one batched LSTM cell update per layer (``L`` rows per
    recording, one shared input projection) instead of ``L`` sequential cell updates, and
    window ``k`` completes just in time to predict ``y[k]``. The arithmetic is exactly that of
    `torch.nn.LSTM` on each window (float32).
    """

    stateful = True

    def __init__(self, head: _LSTMHead, nu: int, u_scaled: np.ndarray, window: WindowSpec):
        lstm = head.lstm
        hidden = lstm.hidden_size
        # sigmoid(z) = 0.5 tanh(z/2) + 0.5: halve the i, f, o rows so one tanh serves all gates
        half = np.ones(4 * hidden, dtype=np.float32)
        half[: 2 * hidden] = 0.5
        half[3 * hidden :] = 0.5

        def param(name: str) -> np.ndarray:
            return getattr(lstm, name).detach().cpu().float().numpy()

        self.wih = [(param(f"weight_ih_l{i}") * half[:, None]).T.copy()
                    for i in range(lstm.num_layers)]
        self.whh = [(param(f"weight_hh_l{i}") * half[:, None]).T.copy()
                    for i in range(lstm.num_layers)]
        self.bias = [(param(f"bias_ih_l{i}") + param(f"bias_hh_l{i}")) * half
                     for i in range(lstm.num_layers)]
        self.dense = [(w.astype(np.float32), b.astype(np.float32))
                      for w, b in dense_layers(head.dense)]
        self.hidden, self.nu = hidden, nu
        self.u = u_scaled.astype(np.float32)
        self.window = window
        length = window.seq_len
        batch = u_scaled.shape[0]
        # h and c of every layer in one array, so finishing a window zeroes them in one call
        self.state = np.zeros((2 * lstm.num_layers, batch, length, hidden), np.float32)
        mask_u, mask_y = sequence_masks(window)  # per time step, oldest first
        self.seq_masks = (mask_u.astype(np.float32), mask_y.astype(np.float32))
        # at step k, slot s holds window k + m with m = (s - k) % L, at time step L-1-m
        slots = np.arange(length)
        m = (slots[None, :] - np.arange(length)[:, None]) % length  # [k % L, slot]
        self.mask_u = mask_u[length - 1 - m].astype(np.float32)[:, None, :, None]
        self.mask_y = mask_y[length - 1 - m].astype(np.float32)[:, None, :, None]
        self.all_real = bool(mask_u.all() and mask_y.all())
        self.next_k: int | None = None

    def _advance(self, k: int, n: int, y: np.ndarray) -> np.ndarray:
        """Feed sample (u[k-nk], y[k-1]) to the L in-flight windows; finish window k."""
        length, hidden = self.window.seq_len, self.hidden
        x_u = self.u[:n, max(k - self.window.nk, 0)]
        x_y = y[:n, max(k - 1, 0)]
        w0 = self.wih[0]
        p_u = x_u @ w0[: self.nu]
        p_y = x_y.astype(np.float32) @ w0[self.nu :]
        if self.all_real:
            p_u += p_y
            p_u += self.bias[0]
            inputs = p_u[:, None, :]  # input projection + bias, shared by the L windows
        else:
            r = k % length
            inputs = self.mask_u[r] * p_u[:, None, :] + self.mask_y[r] * p_y[:, None, :]
            inputs += self.bias[0]
        below = None
        for layer, (wih, whh, bias) in enumerate(zip(self.wih, self.whh, self.bias, strict=True)):
            h, c = self.state[2 * layer, :n], self.state[2 * layer + 1, :n]
            gates = (h.reshape(n * length, hidden) @ whh).reshape(n, length, 4 * hidden)
            if below is None:
                gates += inputs
            else:
                gates += (below.reshape(n * length, hidden) @ wih).reshape(gates.shape)
                gates += bias
            t = np.tanh(gates, out=gates)
            sig = t * 0.5
            sig += 0.5
            c *= sig[..., hidden : 2 * hidden]
            c += sig[..., :hidden] * t[..., 2 * hidden : 3 * hidden]
            np.multiply(sig[..., 3 * hidden :], np.tanh(c), out=h)
            below = h
        slot = k % length
        out = run_dense(self.state[-2, :n, slot], self.dense)
        self.state[:, :n, slot] = 0.0  # the slot now starts window k + L
        return out.astype(np.float64)

    def step(self, k: int, n: int, y: np.ndarray) -> np.ndarray:
        if self.next_k is None:  # warm up: the windows k..k+L-2 start before k
            for kk in range(k - self.window.seq_len + 1, k):
                self._advance(kk, n, y)
        elif k != self.next_k:
            raise RuntimeError(f"LSTM kernel stepped to {k}, expected {self.next_k}")
        self.next_k = k + 1
        return self._advance(k, n, y)

    def run_all(self, y: np.ndarray, active: np.ndarray, first_target: int,
                term: np.ndarray | None = None) -> np.ndarray:
        """Every step from ``first_target`` on at once (compiled), from a fresh state.

        ``y`` (B, N, ny) float64 holds the measured initial conditions and is filled in place
        with the predictions (plus ``term[b, k]`` if given) of the rows ``:active[k]``.
        """
        return lstm_free_run(self.u, y, active, first_target, self.window.nk, self.wih,
                             self.whh, self.bias, *self.seq_masks, self.dense, term=term)
