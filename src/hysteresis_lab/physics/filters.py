"""Linear recursions: first-order filter banks (creep, the amplifier), resonators, the
structure's modes, and an IIR filter with exact gradients, with their one-sample steps.

`iir_filter` runs ``scipy.signal.lfilter`` (float64, batched over rows, starting at rest) in
a `torch.autograd.Function`. Its backward pass is the adjoint filter: with ``A y = B x``,
``lam = A^{-T} g`` is the time-reversed all-pole filter of the time-reversed gradient, then
``dL/dx = B^T lam``, ``dL/db_i = sum_k lam_k x_{k-i}`` and ``dL/da_j = -sum_k lam_k y_{k-j}``.
`tdf2_step` is one sample of the same filter (transposed direct form II) in torch.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from scipy import signal
from torch import Tensor

from hysteresis_lab.physics.tensors import StateReader, from_numpy, to_numpy64


def first_order_lowpass(x: np.ndarray, fs: float, time_constant_s: float) -> np.ndarray:
    """Unit-DC-gain first-order low-pass (step-invariant discretisation), starting at rest."""
    pole = np.exp(-1.0 / (fs * time_constant_s))
    return signal.lfilter([1.0 - pole], [1.0, -pole], x)


def lowpass_bank(u: np.ndarray, fs: float, time_constants_s: np.ndarray) -> np.ndarray:
    """Unit-gain first-order low-passes of ``u`` (1-D), one column per time constant."""
    return np.column_stack([first_order_lowpass(u, fs, tau) for tau in time_constants_s])


def resonator_bank(
    u: np.ndarray, fs: float, frequencies_hz: np.ndarray, q: float = 5.0
) -> np.ndarray:
    """Band-pass (second-order, quality ``q``) outputs of ``u`` at each frequency below fs/2."""
    columns = []
    for f in frequencies_hz:
        if f >= 0.45 * fs:
            continue
        b, a = signal.iirpeak(f, q, fs=fs)
        columns.append(signal.lfilter(b, a, u))
    return np.column_stack(columns) if columns else np.zeros((len(u), 0))


def mode_filter(x: np.ndarray, fs: float, frequency_hz: float, damping: float) -> np.ndarray:
    """Second-order resonance ``wn^2 / (s^2 + 2 zeta wn s + wn^2)``; bilinear, prewarped at wn."""
    wn = 2.0 * np.pi * frequency_hz
    warped = 2.0 * fs * np.tan(wn / (2.0 * fs))
    b, a = signal.bilinear([warped**2], [1.0, 2.0 * damping * warped, warped**2], fs)
    return signal.lfilter(b, a, x)


def mode_coefficients_np(f: float, zeta: float, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """`mode_coefficients` in NumPy (float64)."""
    c = 1.0 / math.tan(math.pi * f / fs)
    a0 = c * c + 2.0 * zeta * c + 1.0
    return (np.array([1.0, 2.0, 1.0]) / a0,
            np.array([1.0, 2.0 * (1.0 - c * c) / a0, (c * c - 2.0 * zeta * c + 1.0) / a0]))


class _IIRFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, x: Tensor, b: Tensor, a: Tensor) -> Tensor:
        x64, b64, a64 = to_numpy64(x), to_numpy64(b), to_numpy64(a)
        y = signal.lfilter(b64, a64, x64, axis=-1)
        ctx.arrays = (x64, y, b64, a64)
        return from_numpy(y, x)

    @staticmethod
    def backward(ctx: Any, g: Tensor) -> tuple[Tensor | None, ...]:
        x, y, b, a = ctx.arrays
        g64 = to_numpy64(g)
        lam = signal.lfilter([1.0], a, g64[..., ::-1], axis=-1)[..., ::-1]
        n_t = x.shape[-1]
        dx = db = da = None
        if ctx.needs_input_grad[0]:
            dx = from_numpy(signal.lfilter(b, [1.0], lam[..., ::-1], axis=-1)[..., ::-1], g)
        if ctx.needs_input_grad[1]:
            db_ = np.array([np.sum(lam[..., i:] * x[..., : n_t - i]) for i in range(len(b))])
            db = from_numpy(db_, g)
        if ctx.needs_input_grad[2]:
            da_ = np.array([-np.sum(lam[..., j:] * y[..., : n_t - j]) for j in range(len(a))])
            da = from_numpy(da_, g)
        return dx, db, da


def iir_filter(x: Tensor, b: Tensor, a: Tensor) -> Tensor:
    """``lfilter(b, a, x)`` along the last axis of ``x`` (at rest), differentiable in all three.

    Runs on the CPU in float64 and returns ``x``'s dtype and device.
    """
    return _IIRFunction.apply(x, b.to(x.device), a.to(x.device))


def mode_coefficients(frequency_hz: Tensor, damping: Tensor, fs: float) -> tuple[Tensor, Tensor]:
    """Bilinear (prewarped at the natural frequency) unit-DC-gain resonance ``(b, a)``.

    Same filter as `mode_filter`: with ``c = 1 / tan(pi f / fs)``,
    ``b = [1, 2, 1] / a0`` and ``a = [1, 2 (1 - c^2) / a0, (c^2 - 2 zeta c + 1) / a0]``,
    ``a0 = c^2 + 2 zeta c + 1``.
    """
    c = 1.0 / torch.tan(math.pi * frequency_hz / fs)
    a0 = c * c + 2.0 * damping * c + 1.0
    one = torch.ones_like(a0)
    b = torch.stack([one, 2.0 * one, one]) / a0
    a = torch.stack([one, 2.0 * (1.0 - c * c) / a0, (c * c - 2.0 * damping * c + 1.0) / a0])
    return b, a


def tdf2_step(b: Tensor, a: Tensor, x: Tensor, state: StateReader) -> Tensor:
    """One sample of ``lfilter(b, a, .)`` (transposed direct form II, ``a[0] = 1``): input
    (B,) -> output (B,); ``max(len(b), len(a)) - 1`` states."""
    n = max(b.shape[0], a.shape[0])
    if n == 1:
        return b[0] * x
    b = torch.cat([b, b.new_zeros(n - b.shape[0])]) if b.shape[0] < n else b
    a = torch.cat([a, a.new_zeros(n - a.shape[0])]) if a.shape[0] < n else a
    z = state.take(n - 1)
    y = z[:, 0] + b[0] * x
    nxt = [(z[:, i + 1] if i + 1 < n - 1 else 0.0) + x * b[i + 1] - y * a[i + 1]
           for i in range(n - 1)]
    state.put(torch.stack(nxt, dim=1))
    return y
