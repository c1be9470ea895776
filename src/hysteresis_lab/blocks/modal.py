"""`ModalDynamics`: MIMO structural dynamics as shared lightly damped modes.

    y_o = sum_j ( D_oj x_j + sum_m R_ojm mode_m(x_j) + Q_ojm rate_m(x_j) )

Every mode ``m`` is a `SecondOrderMode` (unit DC gain, stable for any parameter value) shared
by all input/output pairs, as the modes of one structure are: only its residue (how strongly
input ``j`` excites it and output ``o`` sees it) differs per pair. The residue is complex in
general (non-proportional damping, non-collocated sensors): ``R_ojm`` weights the mode's
response ``mode_m = w^2 / (s^2 + 2 zeta w s + w^2)``, ``Q_ojm`` its quadrature ``rate_m =
w s / (s^2 + 2 zeta w s + w^2)`` (the same poles, zero DC gain, the same peak), both
discretised as `mode_coefficients` (bilinear, prewarped). ``D_oj`` is the static
feedthrough of the modes above the modelled ones (residual stiffness). Residues and
feedthrough are linear in the output, so given the modes they are a least-squares fit
(`fit_residues`). Both responses of a mode share its poles: one all-pole pass ``x / A(z)``
per input and mode, then two three-tap numerators.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from hysteresis_lab.blocks.linear import SecondOrderMode
from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.physics.filters import iir_filter, mode_coefficients


class ModalDynamics(nn.Module):
    """``ny`` outputs from ``nu`` inputs through shared second-order modes (see above);
    residues and feedthrough start at zero."""

    def __init__(
        self,
        fs: float,
        ny: int,
        nu: int,
        frequencies_hz: Sequence[float],
        dampings: Sequence[float],
        *,
        fmin: float = 1.0,
    ) -> None:
        super().__init__()
        if len(frequencies_hz) != len(dampings) or ny < 1 or nu < 1:
            raise ValueError(f"need one damping per frequency and ny, nu >= 1 (got "
                             f"{list(frequencies_hz)}, {list(dampings)}, ny={ny}, nu={nu})")
        self.fs, self.ny, self.nu = float(fs), int(ny), int(nu)
        self.modes = nn.ModuleList(SecondOrderMode(fs, float(f), float(z), fmin=fmin)
                                   for f, z in zip(frequencies_hz, dampings, strict=True))
        self.residues = nn.Parameter(torch.zeros(ny, nu, len(self.modes), dtype=torch.float64))
        self.quadrature = nn.Parameter(torch.zeros(ny, nu, len(self.modes), dtype=torch.float64))
        self.feedthrough = nn.Parameter(torch.zeros(ny, nu, dtype=torch.float64))

    @property
    def n_modes(self) -> int:
        return len(self.modes)

    def coefficients(self) -> tuple[Tensor, Tensor, Tensor]:
        """Per mode the numerators of its response and of its quadrature (M, 3) and its
        denominator (M, 3)."""
        if not self.n_modes:
            empty = self.feedthrough.new_zeros(0, 3)
            return empty, empty, empty
        num, rate, den = [], [], []
        for mode in self.modes:
            frequency = mode.frequency_hz[0]
            b, a = mode_coefficients(frequency, mode.damping[0], self.fs)
            c = 1.0 / torch.tan(torch.pi * frequency / self.fs)
            num.append(b)
            rate.append(c * b[0] * b.new_tensor([1.0, 0.0, -1.0]))
            den.append(a)
        return torch.stack(num), torch.stack(rate), torch.stack(den)

    def responses(self, x: Tensor) -> Tensor:
        """Every mode's response and quadrature to every input: ``x`` (B, T, nu) ->
        (B, T, nu, 2 n_modes), the responses first."""
        n_b, n_t, nu = x.shape
        if not self.n_modes:
            return x.new_zeros(n_b, n_t, nu, 0)
        rows = x.permute(0, 2, 1).reshape(n_b * nu, n_t)  # one pass per mode for all inputs
        num, rate, den = self.coefficients()
        one = torch.ones(1, dtype=torch.float64)
        out = []
        for m in range(self.n_modes):
            w = iir_filter(rows, one, den[m])  # (B nu, T)
            lags = torch.stack([w, nn.functional.pad(w, (1, 0))[:, :-1],
                                nn.functional.pad(w, (2, 0))[:, :-2]], dim=-1)
            out += [lags @ num[m].to(w.dtype), lags @ rate[m].to(w.dtype)]
        out = out[0::2] + out[1::2]
        stacked = torch.stack(out, dim=-1)  # (B nu, T, 2M)
        return stacked.reshape(n_b, nu, n_t, 2 * self.n_modes).permute(0, 2, 1, 3)

    def weights(self) -> Tensor:
        """The residues and quadrature residues side by side (ny, nu, 2 n_modes)."""
        return torch.cat([self.residues, self.quadrature], dim=-1)

    def combine(self, x: Tensor, responses: Tensor) -> Tensor:
        """The outputs (B, T, ny) from the inputs and their modal responses."""
        y = torch.einsum("btj,oj->bto", x, self.feedthrough.to(x.dtype))
        if self.n_modes:
            y = y + torch.einsum("btjm,ojm->bto", responses, self.weights().to(x.dtype))
        return y

    def forward(self, x: Tensor) -> Tensor:
        """``x`` (B, T, nu) -> ``y`` (B, T, ny), from rest."""
        return self.combine(x, self.responses(x))

    def state_names(self) -> list[str]:
        """Per input, per mode: its all-pole pass's last two values."""
        return [f"input{j}.mode{m}_w{i}" for j in range(self.nu) for m in range(self.n_modes)
                for i in (1, 2)]

    def step(self, x: Tensor, state: StepState) -> Tensor:
        """One sample ``x`` (B, nu) -> ``y`` (B, ny) (`hysteresis_lab.blocks.step`)."""
        num, rate, den, residues, quadrature, feedthrough = frozen(
            *self.coefficients(), self.residues, self.quadrature, self.feedthrough)
        y = x @ feedthrough.T
        for j in range(self.nu):
            for m in range(self.n_modes):
                past = state.take(2)  # w[k-1], w[k-2]
                w = x[:, j] - past[:, 0] * den[m, 1] - past[:, 1] * den[m, 2]
                lags = torch.stack([w, past[:, 0], past[:, 1]], dim=-1)
                state.put(lags[:, :2])
                y = y + (lags @ num[m])[:, None] * residues[:, j, m][None] \
                    + (lags @ rate[m])[:, None] * quadrature[:, j, m][None]
        return y

    def set_modes(self, frequencies_hz: Sequence[float], dampings: Sequence[float]) -> None:
        """Move the modes to new frequencies and dampings (as many as there are)."""
        for mode, f, z in zip(self.modes, frequencies_hz, dampings, strict=True):
            f = float(np.clip(f, 1.01 * mode.fmin, 0.98 * mode.fmax))
            fresh = SecondOrderMode(self.fs, float(f), float(z), fmin=mode.fmin, fmax=mode.fmax)
            mode.load_state_dict(fresh.state_dict())

    def fit_residues(self, xs: Sequence[Tensor], ys: Sequence[np.ndarray]) -> np.ndarray:
        """Set residues and feedthrough by least squares from inputs ``xs`` ((T, nu) each,
        float64) to outputs ``ys`` ((T, ny) each) with a constant per output; returns the
        constants (ny,). The normal equations are summed recording by recording."""
        gram: np.ndarray | float = 0.0
        cross: np.ndarray | float = 0.0
        with torch.no_grad():
            for x, y in zip(xs, ys, strict=True):
                r = self.responses(x[None].double())[0].reshape(len(x), -1).cpu().numpy()
                columns = np.hstack([r, x.double().cpu().numpy(), np.ones((len(x), 1))])
                gram = gram + columns.T @ columns
                cross = cross + columns.T @ np.asarray(y, dtype=float).reshape(len(x), -1)
        theta, *_ = np.linalg.lstsq(np.asarray(gram), np.asarray(cross), rcond=None)
        n_r = 2 * self.nu * self.n_modes
        weights = theta[:n_r].T.reshape(self.ny, self.nu, 2 * self.n_modes)
        with torch.no_grad():
            self.residues.copy_(torch.as_tensor(weights[..., : self.n_modes]))
            self.quadrature.copy_(torch.as_tensor(weights[..., self.n_modes:]))
            self.feedthrough.copy_(torch.as_tensor(theta[n_r: n_r + self.nu].T))
        return theta[-1]

    def linear_weights(self) -> list[nn.Parameter]:
        """The parameters the output is linear in (`fit_residues` sets them)."""
        return [self.residues, self.quadrature, self.feedthrough]

    def export(self) -> dict[str, Any]:
        """Mode frequencies (Hz) and dampings, residues and quadrature residues (ny, nu,
        modes), feedthrough (ny, nu)."""
        with torch.no_grad():
            return {
                "fs": self.fs,
                "frequency_hz": np.array([float(m.frequency_hz[0]) for m in self.modes]),
                "damping": np.array([float(m.damping[0]) for m in self.modes]),
                "residues": self.residues.cpu().numpy().copy(),
                "quadrature": self.quadrature.cpu().numpy().copy(),
                "feedthrough": self.feedthrough.cpu().numpy().copy(),
            }
