"""SUBNET: a neural state-space model trained on the simulation error.

After Beintema, Tóth and Schoukens, "Deep subspace encoders for nonlinear system
identification", Automatica 156 (2023), and its reference implementation deepSI:

* encoder ``x[k] = psi(u[k-nk-nb+1 .. k-nk], y[k-na .. k-1])`` (a linear map plus an MLP on
  the NARX window, deepSI's residual network);
* state update ``x[k+1] = A x[k] + B u + f(x[k], u)``, ``u = u[k-nk+1]``;
* output ``y[k] = C x[k] + h(x[k])``;

``f``, ``h`` and ``psi`` are ReLU MLPs, the linear parts ``A, B, C`` sit beside them (a
linear model is the starting point, the networks add the nonlinearity). Trained on the
free-run error over ``horizon``-sample segments, each started by the encoder.

With ``linear_start`` (the default) training starts from a best linear approximation
(`initialise_from_recordings`, `hysteresis_lab.models.subnet_init`): ``A, B, C`` from a
least-squares ARX fit realised with ``nx`` states, the output offset in ``h``'s bias, the
networks' last layers at zero and the linear encoder fitted to the states that explain
the outputs, so the untrained model free-runs as the linear model does.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.windows import assemble, make_windows
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.kernels.subnet import packed_mlp, subnet_free_run
from hysteresis_lab.models.base import mlp
from hysteresis_lab.models.state_space import StateSpaceModule
from hysteresis_lab.models.subnet_init import LinearStart, linear_start, state_targets

log = logging.getLogger(__name__)

#: at most this many windows fit the linear encoder of the linear start
ENCODER_ROWS = 20_000


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
        linear_start: bool = True,
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
        self.encoder_linear = nn.Linear(self.n_features, nx)
        self.A = nn.Linear(nx, nx, bias=False)
        self.B = nn.Linear(nu, nx, bias=False)
        self.C = nn.Linear(nx, ny, bias=False)
        self.f = mlp(nx + nu, nx, neurons, hidden_layers)
        self.h = mlp(nx, ny, neurons, hidden_layers)
        with torch.no_grad():  # start near the linear model: the networks add to it
            for net in (self.f, self.h):
                net[-1].weight.mul_(0.1)
                net[-1].bias.zero_()
            self.encoder_linear.weight.zero_()  # the MLP alone until a linear start
            self.encoder_linear.bias.zero_()

    def input_columns(self) -> dict[str, int]:
        return {"B.weight": 0, "f.0.weight": self.nx}

    def load_state_dict(self, state_dict: Any, strict: bool = True, assign: bool = False) -> Any:
        """Also reads a model saved before the encoder's linear map (it was zero then)."""
        state = dict(state_dict)
        for name, value in self.encoder_linear.state_dict().items():
            state.setdefault(f"encoder_linear.{name}", torch.zeros_like(value))
        return super().load_state_dict(state, strict=strict, assign=assign)

    def encode(self, regressor: torch.Tensor) -> torch.Tensor:
        return self.encoder_linear(regressor) + self.encoder(regressor)

    def transition(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return self.A(x) + self.B(u) + self.f(torch.cat([x, u], dim=-1))

    def output(self, x: torch.Tensor) -> torch.Tensor:
        return self.C(x) + self.h(x)

    # ------------------------------------------------------------------ linear start
    def initialise_from_recordings(self, recordings: Sequence[Recording]) -> None:
        """Start from a best linear approximation of the training ``recordings`` (physical
        units; see the module docstring); keeps the random start, with a warning, when
        ``linear_start`` is off or no stable linear model comes out."""
        if not self.hparams.get("linear_start", True):
            return
        shift = self.window.nk - 1  # the state update reads u[k - nk + 1]
        us, ys = self._scaled(recordings)
        vs = [u[: len(u) - shift] for u in us]
        ys = [y[shift:] for y in ys]
        try:
            start = linear_start(vs, ys, self.nx)
        except (np.linalg.LinAlgError, ValueError) as exc:
            log.warning("SUBNET keeps its random start: no linear start (%s)", exc)
            return
        encoder = self._fit_linear_encoder(start, recordings, vs, ys)
        self._set_linear_start(start, *encoder)

    def _scaled(self, recordings: Sequence[Recording]) -> tuple[list[np.ndarray], ...]:
        """Scaled inputs and outputs (float64) of each recording."""
        scale = self._scale_arrays()
        us = [(rec.u - scale["u_offset"]) / scale["u_scale"] for rec in recordings]
        ys = [(rec.y - scale["y_offset"]) / scale["y_scale"] for rec in recordings]
        return us, ys

    def _scale_arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k).double().cpu().numpy()
                for k in ("u_offset", "u_scale", "y_offset", "y_scale")}

    def _fit_linear_encoder(
        self, start: LinearStart, recordings: Sequence[Recording], vs: list[np.ndarray],
        ys: list[np.ndarray],
    ) -> tuple[np.ndarray, np.ndarray]:
        """Least-squares affine map (weight (nx, features), bias (nx,)) from the NARX window
        to the state whose linear free run best explains the next outputs."""
        shift = self.window.nk - 1
        horizon = max(self.nx, 20)
        per_recording = max(1, ENCODER_ROWS // len(recordings))
        rng = np.random.default_rng(0)
        scale = self._scale_arrays()
        features, targets = [], []
        for rec, v, y, x0 in zip(recordings, vs, ys, start.x0, strict=True):
            states = state_targets(start, v, y, x0, horizon)
            windows = make_windows(rec, self.window, dtype=np.float64)
            rows = np.flatnonzero(windows.index - shift < len(states))
            if len(rows) > per_recording:
                rows = np.sort(rng.choice(rows, per_recording, replace=False))
            windows = windows.take(rows)
            u_past = (windows.u_past - scale["u_offset"]) / scale["u_scale"]
            y_past = (windows.y_past - scale["y_offset"]) / scale["y_scale"]
            features.append(assemble(u_past, y_past, "flat"))
            targets.append(states[windows.index - shift])
        x = np.vstack(features)
        x = np.column_stack([x, np.ones(len(x))])
        gram = x.T @ x
        ridge = 1e-6 * np.trace(gram) / len(gram)
        solution = np.linalg.solve(gram + ridge * np.eye(len(gram)), x.T @ np.vstack(targets))
        return solution[:-1].T, solution[-1]

    def _set_linear_start(
        self, start: LinearStart, encoder_weight: np.ndarray, encoder_bias: np.ndarray
    ) -> None:
        """The parameters of the linear start; every network's last layer at zero."""
        def put(param: torch.Tensor, value: np.ndarray) -> None:
            param.copy_(torch.as_tensor(value, dtype=param.dtype))

        with torch.no_grad():
            put(self.A.weight, start.A)
            put(self.B.weight, start.B)
            put(self.C.weight, start.C)
            for net in (self.f, self.h, self.encoder):
                net[-1].weight.zero_()
                net[-1].bias.zero_()
            put(self.h[-1].bias, start.c0)
            put(self.encoder_linear.weight, encoder_weight)
            put(self.encoder_linear.bias, encoder_bias)

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
