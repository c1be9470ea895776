"""SUBNET: a neural state-space model trained on the simulation error.

After Beintema, Tóth and Schoukens, "Deep subspace encoders for nonlinear system
identification", Automatica 156 (2023), and its reference implementation deepSI:

* encoder ``x[k] = psi(u[k-nk-nb+1 .. k-nk], y[k-na .. k-1])`` (an MLP on the NARX window);
* state update ``x[k+1] = A x[k] + B u + f(x[k], u)``, ``u = u[k-nk+1]``;
* output ``y[k] = C x[k] + h(x[k])``;

``f``, ``h`` and ``psi`` are ReLU MLPs, the linear parts ``A, B, C`` sit beside them (a
linear model is the starting point, the networks add the nonlinearity). Trained on the
free-run error over ``horizon``-sample segments, each started by the encoder.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.kernels.subnet import packed_mlp, subnet_free_run
from hysteresis_lab.models.base import mlp
from hysteresis_lab.models.state_space import StateSpaceModule


class SUBNET(StateSpaceModule):
    """Encoder + residual state update + residual output (see the module docstring)."""

    def __init__(
        self,
        nu: int,
        ny: int,
        nx: int = 8,
        neurons: int = 64,
        hidden_layers: int = 2,
        encoder_neurons: int = 64,
        encoder_layers: int = 2,
        objective: str = "simulation",
        **kwargs: Any,
    ) -> None:
        super().__init__(nu=nu, ny=ny, objective=objective, **kwargs)
        bad = [f"{name}={value!r}" for name, value, low in (
            ("nx", nx, 1), ("neurons", neurons, 1), ("hidden_layers", hidden_layers, 0),
            ("encoder_neurons", encoder_neurons, 1), ("encoder_layers", encoder_layers, 0),
        ) if not (isinstance(value, int) and value >= low)]
        if bad:
            raise ConfigError(
                f"SUBNET sizes out of range: {', '.join(bad)} (nx, neurons >= 1; layers >= 0). "
                "Fix: e.g. model.nx=8 model.neurons=64 model.hidden_layers=2."
            )
        self.nx = nx
        self.encoder = mlp(self.n_features, nx, encoder_neurons, encoder_layers)
        self.A = nn.Linear(nx, nx, bias=False)
        self.B = nn.Linear(nu, nx, bias=False)
        self.C = nn.Linear(nx, ny, bias=False)
        self.f = mlp(nx + nu, nx, neurons, hidden_layers)
        self.h = mlp(nx, ny, neurons, hidden_layers)
        with torch.no_grad():  # start near the linear model: the networks add to it
            for net in (self.f, self.h):
                net[-1].weight.mul_(0.1)
                net[-1].bias.zero_()

    def input_columns(self) -> dict[str, int]:
        return {"B.weight": 0, "f.0.weight": self.nx}

    def encode(self, regressor: torch.Tensor) -> torch.Tensor:
        return self.encoder(regressor)

    def transition(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return self.A(x) + self.B(u) + self.f(torch.cat([x, u], dim=-1))

    def output(self, x: torch.Tensor) -> torch.Tensor:
        return self.C(x) + self.h(x)

    def compiled_free_run(
        self, x0: np.ndarray, u: np.ndarray, lengths: np.ndarray, first_target: int
    ) -> np.ndarray | None:
        def weight(layer: nn.Linear) -> np.ndarray:
            return np.ascontiguousarray(layer.weight.detach().cpu().double().numpy())

        return subnet_free_run(
            np.ascontiguousarray(x0, dtype=np.float64),
            np.ascontiguousarray(u, dtype=np.float64), lengths,
            first_target, self.window.nk,
            weight(self.A), weight(self.B), weight(self.C),
            *packed_mlp(self.f), *packed_mlp(self.h),
        )
