"""CNN: Conv1d layers over time, global max pooling, dense layers (the study: 2 conv + 1 dense)."""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from hysteresis_lab.errors import ConfigError
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
                f"CNN needs conv_layers >= 1, num_layers > conv_layers and kernel_size >= 1; got "
                f"num_layers={num_layers}, conv_layers={conv_layers}, kernel_size={kernel_size}."
            )
        self.net = _ConvHead(self.n_features, units, conv_layers, kernel_size,
                             num_layers - conv_layers - 1, ny)
