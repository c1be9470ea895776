"""Stable linear dynamics of any order: a cascade of second-order sections.

Each section is ``(b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2)`` with the denominator
in the stability triangle's parametrisation ``a2 = rho^2 tanh(r2)``,
``a1 = rho (1 + a2) tanh(r1)`` (``rho = MAX_RADIUS``): every raw value gives poles inside the
unit circle and every stable section (poles within ``rho``) is reachable, complex or real
pole pairs alike. The numerators are free. `arx_least_squares` gives the
starting transfer function (a least-squares ARX fit), `StableSections.set_transfer_function`
puts it in this form, reflecting any pole outside the unit circle inside it first.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from scipy import signal
from torch import Tensor, nn

from hysteresis_lab.blocks.linear import iir_filter

MAX_RADIUS = 0.9999  # poles are kept at most this far out (float64 keeps them stable)


class StableSections(nn.Module):
    """``order`` poles (rounded up to whole sections) in a cascade, from rest."""

    def __init__(self, order: int = 4) -> None:
        super().__init__()
        if order < 1:
            raise ValueError(f"order must be >= 1, got {order}")
        n = (order + 1) // 2
        self.numerators = nn.Parameter(torch.zeros(n, 3, dtype=torch.float64))
        self.raw_denominators = nn.Parameter(torch.zeros(n, 2, dtype=torch.float64))
        with torch.no_grad():
            self.numerators[:, 0] = 1.0  # identity to start
        #: whole samples of pure delay before the sections (leading zeros of the numerator)
        self.register_buffer("delay", torch.zeros((), dtype=torch.long))

    @property
    def n_sections(self) -> int:
        return self.numerators.shape[0]

    def denominators(self) -> Tensor:
        """(n, 3): ``[1, a1, a2]`` per section, inside the stability triangle."""
        raw = self.raw_denominators.double()
        a2 = torch.tanh(raw[:, 1]) * MAX_RADIUS**2
        a1 = (1.0 + a2) * torch.tanh(raw[:, 0]) * MAX_RADIUS  # strictly inside: |a1| < 1 + a2
        return torch.stack([torch.ones_like(a1), a1, a2], dim=1)

    def forward(self, x: Tensor) -> Tensor:
        """``x`` (B, T) -> (B, T)."""
        delay = int(self.delay)
        if delay:
            x = nn.functional.pad(x, (delay, 0))[:, : x.shape[1]]
        a = self.denominators()
        for i in range(self.n_sections):
            x = iir_filter(x, self.numerators[i].double(), a[i])
        return x

    def set_transfer_function(self, b: np.ndarray, a: np.ndarray) -> None:
        """Start from ``b(z^-1) / a(z^-1)`` (as `scipy.signal.lfilter` takes them); poles
        outside the unit circle are reflected inside it first, and no pole lies beyond
        ``MAX_RADIUS``."""
        poles = np.roots(a)
        radius = np.abs(poles)
        poles = np.where(radius > 1.0, 1.0 / np.conj(poles), poles)
        radius = np.abs(poles)
        poles = np.where(radius > MAX_RADIUS, poles * MAX_RADIUS / np.maximum(radius, 1e-300),
                         poles)
        a = np.real(np.poly(poles))
        nonzero = np.flatnonzero(b)
        lead = int(nonzero[0]) if len(nonzero) else 0
        b = np.asarray(b, dtype=float)[lead:]
        n = max(len(a), len(b))
        sos = signal.tf2sos(np.pad(b, (0, n - len(b))), np.pad(a, (0, n - len(a))))
        if len(sos) > self.n_sections:
            raise ValueError(f"a transfer function of order {n - 1} needs {len(sos)} sections; "
                             f"this block has {self.n_sections}")
        identity = np.tile([1.0, 0.0, 0.0, 1.0, 0.0, 0.0], (self.n_sections - len(sos), 1))
        sos = np.vstack([sos, identity])
        a1, a2 = sos[:, 4], sos[:, 5]
        r2 = np.arctanh(np.clip(a2 / MAX_RADIUS**2, -0.999999, 0.999999))
        r1 = np.arctanh(np.clip(a1 / ((1.0 + a2) * MAX_RADIUS), -0.999999, 0.999999))
        with torch.no_grad():
            self.numerators.copy_(torch.as_tensor(sos[:, :3]))
            self.raw_denominators.copy_(torch.as_tensor(np.stack([r1, r2], axis=1)))
            self.delay.fill_(lead)

    def export(self) -> dict[str, Any]:
        with torch.no_grad():
            return {"delay": int(self.delay), "numerators": self.numerators.cpu().numpy().copy(),
                    "denominators": self.denominators().cpu().numpy().copy()}


def arx_least_squares(
    u: np.ndarray, y: np.ndarray, na: int, nb: int, nk: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ARX ``y[k] + a1 y[k-1] + ... = b_nk u[k-nk] + ... + c``: (b, a) in
    powers of z^-1 (``b`` has ``nk + nb`` entries, the first ``nk`` zero), for 1-D ``u`` and
    ``y``. The constant ``c`` takes an output offset (a rest position other than zero) and
    is not returned; demeaning ``y`` instead would bias the fit of a recording that starts
    at rest."""
    u = np.asarray(u, dtype=float).reshape(-1)
    y = np.asarray(y, dtype=float).reshape(-1)
    start = max(na, nk + nb - 1)
    rows = np.arange(start, len(y))
    columns = [-y[rows - i] for i in range(1, na + 1)]
    columns += [u[rows - nk - j] for j in range(nb)] + [np.ones(len(rows))]
    theta, *_ = np.linalg.lstsq(np.column_stack(columns), y[rows], rcond=None)
    a = np.concatenate([[1.0], theta[:na]])
    b = np.concatenate([np.zeros(nk), theta[na : na + nb]])
    return b, a
