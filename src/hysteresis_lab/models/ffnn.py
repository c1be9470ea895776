"""FFNN (NARX MLP) on the flat regressor; the study's optimum is 4 layers of 100 neurons."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from torch import nn

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.base import NarxModule, mlp


class FFNN(NarxModule):
    """``num_layers`` linear layers in total (ReLU between, linear output)."""

    layout = "flat"

    def __init__(
        self, nu: int, ny: int, num_layers: int = 4, neurons: int = 100, **kwargs: Any
    ) -> None:
        super().__init__(nu=nu, ny=ny, **kwargs)
        if num_layers < 2 or neurons < 1:
            raise ConfigError(
                f"FFNN needs num_layers >= 2 and neurons >= 1 (got {num_layers}, {neurons})."
            )
        self.net = mlp(self.n_features, ny, neurons, num_layers - 1)

    def numpy_forward(self) -> Callable[[np.ndarray], np.ndarray]:
        """The network as a NumPy function (CPU free run: tiny matmuls cost ~1 µs in NumPy,
        several µs as torch ops)."""
        layers = [
            (
                m.weight.detach().cpu().double().numpy().T.copy(),
                m.bias.detach().cpu().double().numpy().copy(),
            )
            for m in self.net
            if isinstance(m, nn.Linear)
        ]

        def forward(x: np.ndarray) -> np.ndarray:
            h = x
            for i, (weight, bias) in enumerate(layers):
                h = h @ weight
                h += bias
                if i < len(layers) - 1:
                    np.maximum(h, 0.0, out=h)
            return h

        return forward
