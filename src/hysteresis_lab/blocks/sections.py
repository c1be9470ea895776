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

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from scipy import signal
from torch import Tensor, nn

from hysteresis_lab.blocks.step import StepState, delay_step, frozen
from hysteresis_lab.physics.filters import iir_filter, tdf2_step

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

    def polynomials(self) -> tuple[Tensor, Tensor]:
        """The whole cascade as one transfer function ``b(z^-1) / a(z^-1)`` (the delay's
        leading zeros in ``b``, ``a[0] = 1``), differentiable w.r.t. the parameters."""
        a = self.denominators()
        b_total, a_total = self.numerators[0].double(), a[0]
        for i in range(1, self.n_sections):
            b_total = polymul(b_total, self.numerators[i].double())
            a_total = polymul(a_total, a[i])
        return nn.functional.pad(b_total, (int(self.delay), 0)), a_total

    def state_names(self) -> list[str]:
        return [f"delay_{i}" for i in range(int(self.delay))] + [
            f"section{i}_z{j}" for i in range(self.n_sections) for j in (1, 2)]

    def step(self, x: Tensor, state: StepState) -> Tensor:
        """One sample (B,) -> (B,): the delay buffer, then two states per section."""
        x = delay_step(int(self.delay), x, state)
        b, a = frozen(self.numerators.double(), self.denominators())
        for i in range(self.n_sections):
            x = tdf2_step(b[i], a[i], x, state)
        return x

    def set_transfer_function(self, b: np.ndarray, a: np.ndarray) -> None:
        """Start from ``b(z^-1) / a(z^-1)`` (as `scipy.signal.lfilter` takes them); poles
        outside the unit circle are reflected inside it first, and no pole lies beyond
        ``MAX_RADIUS``."""
        a = np.atleast_1d(np.real(np.poly(held_poles(a))))
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


def polymul(p: Tensor, q: Tensor) -> Tensor:
    """The product of two polynomials (coefficient vectors), differentiable."""
    return nn.functional.conv1d(p.reshape(1, 1, -1), q.flip(0).reshape(1, 1, -1),
                                padding=q.shape[0] - 1).reshape(-1)


def arx_least_squares(
    u: np.ndarray | Sequence[np.ndarray], y: np.ndarray | Sequence[np.ndarray], na: int,
    nb: int, nk: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ARX ``y[k] + a1 y[k-1] + ... = sum_j (b_j,nk u_j[k-nk] + ...) + c``:
    (b, a) in powers of z^-1, ``b`` with ``nk + nb`` entries (the first ``nk`` zero) for a
    1-D ``u``, (inputs, nk + nb) for ``u`` of shape (T, inputs); one denominator for all
    inputs (a MISO fit of one output). ``u`` and ``y`` may also be lists of recordings, whose
    regressions are stacked (none spans two recordings). The constant ``c`` takes an output
    offset (a rest position other than zero) and is not returned; demeaning ``y`` instead
    would bias the fit of a recording that starts at rest."""
    us = [u] if isinstance(u, np.ndarray) else list(u)
    ys = [y] if isinstance(y, np.ndarray) else list(y)
    single = np.asarray(us[0]).ndim == 1
    rows, targets = [], []
    for u_rec, y_rec in zip(us, ys, strict=True):
        u2 = np.asarray(u_rec, dtype=float).reshape(len(u_rec), -1)
        y1 = np.asarray(y_rec, dtype=float).reshape(-1)
        start = max(na, nk + nb - 1)
        k = np.arange(start, len(y1))
        columns = [-y1[k - i] for i in range(1, na + 1)]
        columns += [u2[k - nk - j, c] for c in range(u2.shape[1]) for j in range(nb)]
        rows.append(np.column_stack([*columns, np.ones(len(k))]))
        targets.append(y1[k])
    theta, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(targets), rcond=None)
    a = np.concatenate([[1.0], theta[:na]])
    numerators = theta[na:-1].reshape(-1, nb)
    b = np.hstack([np.zeros((len(numerators), nk)), numerators])
    return (b[0] if single else b), a


#: Steiglitz–McBride iterations of `steiglitz_mcbride`
SM_ITERATIONS = 10


def _reflected_poles(a: np.ndarray) -> np.ndarray:
    """The poles of the denominator ``a``, those outside the unit circle reflected inside."""
    poles = np.roots(a).astype(complex)
    return np.where(np.abs(poles) > 1.0, 1.0 / np.conj(poles), poles)


def held_poles(a: np.ndarray) -> np.ndarray:
    """The poles of the denominator ``a`` as `StableSections` holds them: reflected inside
    the unit circle, and none beyond `MAX_RADIUS`."""
    poles = _reflected_poles(a)
    radius = np.abs(poles)
    return np.where(radius > MAX_RADIUS, poles * MAX_RADIUS / np.maximum(radius, 1e-300), poles)


def stable_denominator(a: np.ndarray) -> np.ndarray:
    """``a`` with every pole outside the unit circle reflected inside it."""
    poles = _reflected_poles(a)
    return np.real(np.poly(poles)) if len(poles) else np.asarray(a, dtype=float)


def slowest_rate(a: np.ndarray) -> float:
    """The slowest mode of the denominator ``a`` as `StableSections` holds it
    (`held_poles`): ``min |ln p|`` over its poles, in radians per sample (``inf`` without
    poles)."""
    poles = held_poles(a)
    poles = poles[np.abs(poles) > 0.0]
    return float(np.min(np.abs(np.log(poles)))) if len(poles) else np.inf


def nyquist_share(b: np.ndarray, a: np.ndarray) -> float:
    """The largest gain at Nyquist over the largest static gain of ``b / a`` (``b``: one
    numerator per input, rows; ``a`` with its poles reflected inside the unit circle,
    `stable_denominator`)."""
    a = stable_denominator(np.asarray(a, dtype=float))
    b = np.atleast_2d(np.asarray(b, dtype=float))
    alternating = (-1.0) ** np.arange(max(b.shape[1], len(a)))
    nyquist = np.abs(b @ alternating[: b.shape[1]]) / max(abs(a @ alternating[: len(a)]), 1e-300)
    static = np.abs(b.sum(axis=1)) / max(abs(a.sum()), 1e-300)
    return float(nyquist.max() / max(static.max(), 1e-300))


def free_run_error(
    u: Sequence[np.ndarray], y: Sequence[np.ndarray], b: np.ndarray, a: np.ndarray
) -> float:
    """Variance of the free-run error of ``b / a`` (shapes as `arx_least_squares` gives
    them) from rest over the recordings ``u``, ``y``; the mean is left out (an output offset
    is fitted apart). ``inf`` where the run does not stay finite."""
    b2 = np.atleast_2d(b)
    errors = []
    for u_rec, y_rec in zip(u, y, strict=True):
        u2 = np.asarray(u_rec, dtype=float).reshape(len(u_rec), -1)
        run = sum(signal.lfilter(b2[j], a, u2[:, j]) for j in range(u2.shape[1]))
        errors.append(np.asarray(y_rec, dtype=float).reshape(-1) - run)
    with np.errstate(all="ignore"):
        error = float(np.var(np.concatenate(errors)))
    return error if np.isfinite(error) else np.inf


def steiglitz_mcbride(
    u: np.ndarray | Sequence[np.ndarray], y: np.ndarray | Sequence[np.ndarray], na: int,
    nb: int, nk: int = 1, iterations: int = SM_ITERATIONS,
) -> tuple[np.ndarray, np.ndarray]:
    """The Steiglitz–McBride fit: `arx_least_squares` again on inputs and outputs
    prefiltered by ``1 / a`` of the previous fit (stabilised), ``iterations`` times from the
    ARX fit; the iterate whose free run (`free_run_error`) is closest to ``y`` is returned
    (the ARX fit where no prefiltered data stay finite).
    Plain ARX minimises the equation error, which weighs the free-run error by ``|a|``: on
    data sampled far above their band it can put the poles the data barely excite (a mode
    above the input band, seen only in start transients) far from where the free run wants
    them; the prefiltered fit weighs the free-run error itself. Same arguments and shapes as
    `arx_least_squares`."""
    us = [u] if isinstance(u, np.ndarray) else list(u)
    ys = [y] if isinstance(y, np.ndarray) else list(y)
    b, a = arx_least_squares(us, ys, na, nb, nk)
    best = (np.inf, b, a)
    for _ in range(iterations):
        prefilter = stable_denominator(a)
        with np.errstate(all="ignore"):
            u_f = [signal.lfilter([1.0], prefilter, np.asarray(x, dtype=float), axis=0)
                   for x in us]
            y_f = [signal.lfilter([1.0], prefilter, np.asarray(x, dtype=float), axis=0)
                   for x in ys]
        if not all(np.all(np.isfinite(x)) for x in (*u_f, *y_f)):
            break
        b, a = arx_least_squares(u_f, y_f, na, nb, nk)
        error = free_run_error(us, ys, b, stable_denominator(a))
        if error < best[0]:
            best = (error, b, a)
    return best[1], best[2]
