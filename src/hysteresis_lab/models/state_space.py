"""`StateSpaceModule`: models whose memory is a state, not a window of measured outputs.

A state-space model simulates ``x[k+1] = f(x[k], u[k-nk+1])``, ``y[k] = h(x[k])`` from an
initial state. The NARX machinery still serves it: the regression windows (``na`` past
outputs, ``nb`` past inputs) are what its *encoder* reads to estimate the state, so

* one-step prediction = ``h(encoder(window))`` (the `NarxModule` ``forward`` contract);
* free run = the encoder on the first ``first_target`` measured samples, then ``f`` and
  ``h`` alone (`simulate_scaled` for training, `simulate_recordings` for evaluation);
* n-step prediction = free runs whose state is re-encoded at every restart.

Subclasses implement `encode`, `transition` and `output` in torch (scaled units) and may
offer a compiled free run (`compiled_free_run`). Declared effects enter as ordinary inputs.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hysteresis_lab.data.windows import WindowSpec, assemble
from hysteresis_lab.models.base import NarxModule
from hysteresis_lab.models.export import export_narx, export_state_space_step
from hysteresis_lab.models.settings import refuse_output_effects


class StateSpaceModule(NarxModule):
    """Base of encoder + state-transition + output models (see the module docstring)."""

    layout = "flat"
    simulation_trained = True

    def export_onnx(self, path: Path | str, opset: int = 17) -> Path:
        """The one-step file (its encoder gives the initial state) and ``<stem>_step.onnx``,
        the simulation step; returns the one-step file's path."""
        path = export_narx(self, path, opset)
        export_state_space_step(self, path.with_name(f"{path.stem}_step.onnx"), opset)
        return path

    # ------------------------------------------------------------------ the model
    def encode(self, regressor: torch.Tensor) -> torch.Tensor:  # pragma: no cover
        """Flat scaled regressor (B, nb*nu + na*ny) -> state (B, nx) at the target sample."""
        raise NotImplementedError

    def transition(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:  # pragma: no cover
        """State (B, nx) and scaled input (B, nu) -> next state (B, nx)."""
        raise NotImplementedError

    def output(self, x: torch.Tensor) -> torch.Tensor:  # pragma: no cover
        """State (B, nx) -> scaled output (B, ny)."""
        raise NotImplementedError

    def compiled_free_run(
        self, x0: np.ndarray, u: np.ndarray, lengths: np.ndarray, first_target: int
    ) -> np.ndarray | None:
        """Optional fast free run: states (B, nx) at ``first_target``, scaled inputs (B, T, nu)
        of which row b runs ``lengths[b]`` samples -> scaled outputs (B, T, ny) from
        ``first_target`` on; None when the model has none (the torch loop runs)."""
        return None

    def _channel_routes(
        self, effects: Sequence[str], feature_context: dict[str, Any] | None, effect_path: str
    ) -> list[str]:
        """Every input channel, measured or effect operator, is an input of the state model
        (effects on the model's own output have none: refused)."""
        refuse_output_effects(effects, type(self).__name__)
        return ["base"] * self.nu

    def _old_input_positions(self, name: str, old_nu: int) -> torch.Tensor | None:
        """Warm starts (the loop adds effect channels after the inputs): the encoder reads
        the flat NARX regressor; ``input_columns`` names the other parameters whose columns
        are [state..., inputs...] (the state columns ``state_columns`` wide)."""
        columns = self.input_columns()
        if name in columns:
            width = columns[name]
            return torch.as_tensor(list(range(width)) + [width + i for i in range(old_nu)])
        return super()._old_input_positions(name, old_nu)

    def input_columns(self) -> dict[str, int]:
        """Parameters whose input side is [state (n columns), inputs]: name -> n."""
        return {}

    # ------------------------------------------------------------------ NARX contract
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """One-step prediction: the output of the state the encoder reads from the window."""
        return self.output(self.encode(x))

    def _regressor_at(self, u: torch.Tensor, y: torch.Tensor, k: int) -> torch.Tensor:
        w = self.window
        return assemble(u[:, k - w.nk - w.nb + 1 : k - w.nk + 1], y[:, k - w.na : k], "flat")

    def simulate_scaled(self, u: torch.Tensor, y_initial: torch.Tensor) -> torch.Tensor:
        """Differentiable free run: scaled inputs (B, T, nu) and the first ``first_target``
        measured outputs -> predictions of samples first_target..T-1 (B, T - ft, ny)."""
        w = self.window
        start = w.first_target
        x = self.encode(self._regressor_at(u, y_initial, start))
        predictions = []
        for k in range(start, u.shape[1]):
            predictions.append(self.output(x))
            if k + 1 < u.shape[1]:
                x = self.transition(x, u[:, k - w.nk + 1])
        return torch.stack(predictions, 1)

    def simulate_recordings(
        self, u: np.ndarray, y_meas: np.ndarray, reset: np.ndarray, window: WindowSpec,
        lengths: np.ndarray | None = None,
    ) -> np.ndarray:
        """Evaluation's free run of all rows (scaled, (B, T, ·)), row b over its first
        ``lengths[b]`` samples (default: all); the state is re-encoded from the measurement
        where ``reset`` (T, B) is set (n-step prediction)."""
        if lengths is None:
            lengths = np.full(u.shape[0], u.shape[1])
        ft = window.first_target
        device = next(self.parameters()).device
        with torch.inference_mode():
            u_t = torch.as_tensor(u, dtype=torch.float32, device=device)
            y_t = torch.as_tensor(y_meas, dtype=torch.float32, device=device)
            x = self.encode(self._regressor_at(u_t, y_t, ft))
            out = np.array(y_meas, dtype=np.float64)
            if not reset.any() and device.type == "cpu":
                compiled = self.compiled_free_run(
                    x.double().numpy(), u, np.asarray(lengths, dtype=np.int64), ft
                )
                if compiled is not None:
                    out[:, ft:] = compiled[:, ft:]
                    return out
            restart_steps = set(np.flatnonzero(reset.any(axis=1)).tolist())
            predictions = torch.empty(u.shape[0], u.shape[1], y_meas.shape[2], device=device)
            for k in range(ft, u.shape[1]):
                if k in restart_steps:
                    rows = torch.as_tensor(reset[k], device=device)
                    x[rows] = self.encode(self._regressor_at(u_t[rows], y_t[rows], k))
                predictions[:, k] = self.output(x)
                if k + 1 < u.shape[1]:
                    x = self.transition(x, u_t[:, k - self.window.nk + 1])
            out[:, ft:] = predictions[:, ft:].double().cpu().numpy()
        return out
