"""CNN: Conv1d layers over time, global max pooling, dense layers (the study: 2 conv + 1 dense)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.kernels.cnn import cnn_free_run
from hysteresis_lab.kernels.interface import FreeRunKernel, dense_layers, run_dense, sequence_masks
from hysteresis_lab.models.base import NarxModule, mlp


class _ConvHead(nn.Module):
    def __init__(self, n_features: int, units: int, conv_layers: int, kernel_size: int,
                 n_dense: int, ny: int):
        super().__init__()
        layers: list[nn.Module] = []
        channels = n_features
        for _ in range(conv_layers):
            layers += [nn.Conv1d(channels, units, kernel_size, padding="same"), nn.ReLU()]
            channels = units
        self.conv = nn.Sequential(*layers)
        self.dense = mlp(units, ny, units, n_dense)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        features = self.conv(x.transpose(1, 2))  # (B, features, time)
        return self.dense(features.amax(dim=2))  # global max pooling over time


class CNNNet(NarxModule):
    """``conv_layers`` Conv1d + ReLU, global max pooling, dense layers up to ``num_layers``."""

    layout = "sequence"

    def __init__(self, nu: int, ny: int, num_layers: int = 3, conv_layers: int = 2,
                 units: int = 83, kernel_size: int = 5, **kwargs: Any) -> None:
        super().__init__(nu=nu, ny=ny, **kwargs)
        if conv_layers < 1 or num_layers <= conv_layers or kernel_size < 1 or units < 1:
            raise ConfigError(
                "CNN needs conv_layers >= 1, num_layers > conv_layers (the output layer is "
                f"dense), kernel_size >= 1 and units >= 1; got num_layers={num_layers}, "
                f"conv_layers={conv_layers}, kernel_size={kernel_size}, units={units}. Fix: e.g. "
                "model.num_layers=3 model.conv_layers=2 model.kernel_size=5 model.units=83."
            )
        self.net = _ConvHead(self.n_features, units, conv_layers, kernel_size,
                             num_layers - conv_layers - 1, ny)

    def free_run_kernel(self, u_scaled: np.ndarray, window: WindowSpec) -> FreeRunKernel:
        """NumPy free-run step (per-tap convolutions, float32); `run_all` runs it compiled."""
        return _CNNKernel(self.net, u_scaled, window)


class _CNNKernel(FreeRunKernel):
    """One CNN evaluation per step on the sequence regressor, as NumPy im2col matmuls."""

    def __init__(self, head: _ConvHead, u_scaled: np.ndarray, window: WindowSpec) -> None:
        self.convs = []  # (per-tap weights (K, in, out), bias, left pad, padded buffer)
        batch, length = u_scaled.shape[0], window.seq_len
        for m in head.conv:
            if isinstance(m, nn.Conv1d):
                weight = m.weight.detach().cpu().float().numpy()  # (out, in, K)
                total = m.kernel_size[0] - 1  # padding="same", dilation 1
                buffer = np.zeros((batch, length + total, weight.shape[1]), np.float32)
                self.convs.append(
                    (weight.transpose(2, 1, 0).copy(), m.bias.detach().cpu().float().numpy(),
                     total // 2, buffer)
                )
        self.dense = dense_layers(head.dense)
        self.window = window
        # u lags, oldest first, come from u[k-nk-L+1 .. k-nk]: pad the front with L zeros
        self.u = np.concatenate(
            [np.zeros((u_scaled.shape[0], length, u_scaled.shape[2])), u_scaled], axis=1
        ).astype(np.float32)
        mask_u, mask_y = sequence_masks(window)
        self.mask_u = mask_u.astype(np.float32)[None, :, None]
        self.mask_y = mask_y.astype(np.float32)[None, :, None]
        self.seq_masks = (mask_u.astype(np.float32), mask_y.astype(np.float32))
        self.all_real = bool(mask_u.all() and mask_y.all())

    def step(self, k: int, n: int, y: np.ndarray) -> np.ndarray:
        length, nk = self.window.seq_len, self.window.nk
        start = k - nk + 1  # index of u[k-nk-L+1] in the padded u
        x_u = self.u[:n, start : start + length]
        if k >= length:
            x_y = y[:n, k - length : k].astype(np.float32)
        else:
            x_y = np.zeros((n, length, y.shape[2]), np.float32)
            x_y[:, length - k :] = y[:n, :k]
        if not self.all_real:
            x_u, x_y = x_u * self.mask_u, x_y * self.mask_y
        nu = x_u.shape[2]
        h = x_u  # replaced by each layer's output
        for layer, (taps, bias, left, buffer) in enumerate(self.convs):
            padded = buffer[:n]  # zero borders = padding="same"
            if layer == 0:
                padded[:, left : left + length, :nu] = x_u
                padded[:, left : left + length, nu:] = x_y
            else:
                padded[:, left : left + length] = h
            h = padded[:, :length] @ taps[0]
            for d in range(1, len(taps)):
                h += padded[:, d : d + length] @ taps[d]
            h += bias
            np.maximum(h, 0.0, out=h)
        return run_dense(h.max(axis=1).astype(np.float64), self.dense)

    def run_all(self, y: np.ndarray, active: np.ndarray, first_target: int,
                term: np.ndarray | None = None) -> np.ndarray:
        """Every step from ``first_target`` on at once (compiled, see `cnn_free_run`).

        ``y`` (B, N, ny) float64 holds the measured initial conditions and is filled in place
        with the predictions (plus ``term[b, k]`` if given) of the rows ``:active[k]``.
        """
        length = self.window.seq_len
        return cnn_free_run(
            self.u[:, length:], y, active, first_target, self.window.nk,
            [taps for taps, _, _, _ in self.convs], [bias for _, bias, _, _ in self.convs],
            *self.seq_masks,
            [(w.astype(np.float32), b.astype(np.float32)) for w, b in self.dense],
            term=term,
        )
