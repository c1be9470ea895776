"""A GRU over the regressor sequence, its last hidden state mapped to the next output."""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from hysteresis_lab.models.base import NarxModule


class _GRUHead(nn.Module):
    def __init__(self, n_features: int, units: int, gru_layers: int, n_outputs: int) -> None:
        super().__init__()
        self.gru = nn.GRU(n_features, units, num_layers=gru_layers, batch_first=True)
        self.head = nn.Linear(units, n_outputs)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        hidden, _ = self.gru(x)
        return self.head(hidden[:, -1])


class GRUNet(NarxModule):
    """GRU NARX model: ``gru_layers`` GRU layers of ``units`` cells, then a linear output."""

    layout = "sequence"

    def __init__(self, nu: int, ny: int, gru_layers: int = 1, units: int = 64, **kwargs: Any):
        super().__init__(nu=nu, ny=ny, **kwargs)
        self.net = _GRUHead(nu + ny, units, gru_layers, ny)
