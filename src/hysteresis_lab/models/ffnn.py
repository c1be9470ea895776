"""FFNN (NARX MLP) on the flat regressor; the study's optimum is 4 layers of 100 neurons."""

from __future__ import annotations

from typing import Any

import numpy as np

from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.kernels.interface import FlatKernel, FreeRunKernel, dense_layers, run_dense
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
                f"FFNN needs num_layers >= 2 and neurons >= 1 (got num_layers={num_layers}, "
                f"neurons={neurons}). Fix: e.g. model.num_layers=4 model.neurons=100 (the "
                "study's search space: 3-5 layers, 25-100 neurons)."
            )
        self.net = mlp(self.n_features, ny, neurons, num_layers - 1)

    def free_run_kernel(self, u_scaled: np.ndarray, window: WindowSpec) -> FreeRunKernel:
        """NumPy free-run step: the first layer's input part is precomputed per chunk."""
        layers = dense_layers(self.net)
        w1, b1 = layers[0]
        split = window.nb * self.nu
        w1u, w1y = w1[:split], w1[split:]

        def pre_u(xu: np.ndarray) -> np.ndarray:
            return xu @ w1u + b1

        def finish(pre: np.ndarray, xy: np.ndarray) -> np.ndarray:
            return run_dense(pre + xy @ w1y, layers[1:])

        return FlatKernel(u_scaled, window, pre_u, finish)
