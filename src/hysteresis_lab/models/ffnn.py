"""FFNN (NARX MLP) on the flat regressor; the study's optimum is 4 layers of 100 neurons."""

from __future__ import annotations

from typing import Any

import numpy as np

from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.kernels.ffnn import FFNNKernel
from hysteresis_lab.kernels.interface import FreeRunKernel, dense_layers
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
        """Compiled free run (`hysteresis_lab.kernels.ffnn`), with the NumPy step of
        `FlatKernel` (the first layer's input part precomputed per chunk) for restarts."""
        return FFNNKernel(u_scaled, window, dense_layers(self.net))
