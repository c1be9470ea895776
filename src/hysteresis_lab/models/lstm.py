"""LSTM over the regressor sequence, then dense layers (the study: 2 LSTM + 1 dense, 66 units)."""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from hysteresis_lab.errors import ConfigError
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
                f"LSTM needs lstm_layers >= 1 and num_layers > lstm_layers (the output layer is "
                f"dense); got num_layers={num_layers}, lstm_layers={lstm_layers}."
            )
        self.net = _LSTMHead(self.n_features, units, lstm_layers, num_layers - lstm_layers - 1,
                             ny)
