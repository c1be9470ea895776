"""Linear blocks: the amplifier lag, creep, modes, delay, on the physics floor's IIR filter
with exact gradients (`hysteresis_lab.physics.filters.iir_filter`).

Filter coefficients are computed from the raw parameters in float64 (a module converted to
float32 keeps accurate poles), so every parametrisation below is stable for any raw value.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from hysteresis_lab.blocks._util import as_float_array, logit
from hysteresis_lab.blocks.step import StepState, delay_step, frozen
from hysteresis_lab.physics.filters import iir_filter, mode_coefficients, tdf2_step

__all__ = ["CreepBank", "Delay", "FirstOrderLag", "SecondOrderMode", "iir_filter",
           "mode_coefficients"]

DAMPING_EPS = 1e-4
DAMPING_MAX = 4.0  # heavily overdamped; far beyond it a pole reaches z = 1 in float64


class FirstOrderLag(nn.Module):
    """Unit-DC-gain first-order low-pass (the amplifier), learnable cutoff.

    Step-invariant discretisation as `hysteresis_lab.physics.filters.first_order_lowpass`: pole
    ``exp(-2 pi f_c / fs)`` in (0, 1) for any ``f_c = min_cutoff_hz + exp(raw)``, hence always
    stable.
    """

    def __init__(self, fs: float, cutoff_hz: float, *, min_cutoff_hz: float = 1.0) -> None:
        super().__init__()
        if not 0 < min_cutoff_hz < cutoff_hz or fs <= 0:
            raise ValueError(f"need fs > 0 and 0 < min_cutoff_hz < cutoff_hz (got {fs}, "
                             f"{min_cutoff_hz}, {cutoff_hz})")
        self.fs = float(fs)
        self.min_cutoff_hz = float(min_cutoff_hz)
        self.raw_cutoff = nn.Parameter(
            torch.tensor(math.log(cutoff_hz - min_cutoff_hz), dtype=torch.float64))

    @property
    def cutoff_hz(self) -> Tensor:
        return self.min_cutoff_hz + self.raw_cutoff.double().exp()

    def coefficients(self) -> tuple[Tensor, Tensor]:
        pole = torch.exp(-2.0 * math.pi * self.cutoff_hz / self.fs)
        one = torch.ones_like(pole)
        return (1.0 - pole).reshape(1), torch.stack([one, -pole])

    def forward(self, x: Tensor) -> Tensor:
        """``x`` (B, T) -> (B, T)."""
        return iir_filter(x, *self.coefficients())

    def state_names(self) -> list[str]:
        return ["lag"]

    def step(self, x: Tensor, state: StepState) -> Tensor:
        """One sample (B,) -> (B,) (`hysteresis_lab.blocks.step`)."""
        return tdf2_step(*frozen(*self.coefficients()), x, state)

    def export(self) -> dict[str, Any]:
        return {"fs": self.fs, "cutoff_hz": float(self.cutoff_hz.detach())}


class CreepBank(nn.Module):
    """Creep ``x + sum_i w_i lowpass_tau_i(x)``: fixed time constants, learnable weights.

    As the simulator's creep (there every weight is ``weight_per_decade``).
    """

    def __init__(
        self,
        fs: float,
        time_constants_s: Sequence[float] = (0.1, 1.0, 10.0, 100.0),
        weights: float | Sequence[float] = 0.0,
    ) -> None:
        super().__init__()
        self.fs = float(fs)
        self.time_constants_s = np.asarray(time_constants_s, dtype=float)
        if self.time_constants_s.ndim != 1 or np.any(self.time_constants_s <= 0):
            raise ValueError(f"time constants must be positive, got {time_constants_s}")
        self.poles = np.exp(-1.0 / (self.fs * self.time_constants_s))  # float64, fixed
        n = len(self.time_constants_s)
        self.weights = nn.Parameter(torch.tensor(as_float_array(weights, n)))

    def forward(self, x: Tensor) -> Tensor:
        """``x`` (B, T) -> (B, T)."""
        out = x
        for i, pole in enumerate(self.poles):
            b = torch.tensor([1.0 - pole], dtype=torch.float64)
            a = torch.tensor([1.0, -pole], dtype=torch.float64)
            out = out + self.weights[i].to(x.dtype) * iir_filter(x, b, a)
        return out

    def state_names(self) -> list[str]:
        return [f"creep_{tau:g}s" for tau in self.time_constants_s]

    def step(self, x: Tensor, state: StepState) -> Tensor:
        """One sample (B,) -> (B,) (`hysteresis_lab.blocks.step`)."""
        out = x
        for i, pole in enumerate(self.poles):
            b = torch.tensor([1.0 - pole], dtype=torch.float64)
            a = torch.tensor([1.0, -pole], dtype=torch.float64)
            out = out + frozen(self.weights[i])[0] * tdf2_step(b, a, x, state)
        return out

    def export(self) -> dict[str, Any]:
        return {
            "fs": self.fs,
            "time_constants_s": self.time_constants_s.copy(),
            "weights": self.weights.detach().double().cpu().numpy().copy(),
        }


class SecondOrderMode(nn.Module):
    """Unit-DC-gain second-order resonance(s), learnable frequency and damping.

    ``frequency = fmin + (fmax - fmin) sigmoid(raw)`` with ``fmax = 0.45 fs`` by default (below
    Nyquist, so the prewarped bilinear filter exists) and ``damping = 1e-4 + 4 sigmoid(raw)``
    (> 0, and bounded so that no pole rounds onto z = 1): stable for any raw value. With
    ``n_modes > 1`` the modes act in parallel on the same input, ``y = sum_m w_m mode_m(x)``
    with ``w_1 = 1 - sum_{m>1} w_m`` (unit DC gain; the others free,
    default 0.05 each); a scalar ``frequency_hz`` places mode m at ``frequency * 3^(m-1)``
    (clipped below ``fmax``). ``feedthrough``: a share ``w_0`` of the input passed on
    directly, ``y = w_0 x + sum_m w_m mode_m(x)`` with ``w_1 = 1 - w_0 - sum_{m>1} w_m`` (the
    residual stiffness of the modes above the modelled ones, as `ModalDynamics`'
    feedthrough), learnable from 0.
    """

    def __init__(
        self,
        fs: float,
        frequency_hz: float | Sequence[float],
        damping: float | Sequence[float],
        n_modes: int = 1,
        *,
        weights: Sequence[float] | None = None,
        fmin: float = 1.0,
        fmax: float | None = None,
        feedthrough: bool = False,
    ) -> None:
        super().__init__()
        self.fs = float(fs)
        self.n_modes = int(n_modes)
        self.fmin = float(fmin)
        self.fmax = float(fmax) if fmax is not None else 0.45 * self.fs
        if not 0 < self.fmin < self.fmax < 0.5 * self.fs or self.n_modes < 1:
            raise ValueError(f"need 0 < fmin < fmax < fs/2 and n_modes >= 1 (fs={fs}, "
                             f"fmin={fmin}, fmax={self.fmax}, n_modes={n_modes})")
        freqs = np.asarray(frequency_hz, dtype=float).reshape(-1)
        if freqs.size == 1 and self.n_modes > 1:
            freqs = freqs[0] * 3.0 ** np.arange(self.n_modes)
        freqs = np.clip(as_float_array(freqs, self.n_modes), None, 0.98 * self.fmax)
        damp = as_float_array(damping, self.n_modes)
        if np.any(freqs <= self.fmin) or np.any(damp <= DAMPING_EPS) or \
                np.any(damp >= DAMPING_EPS + DAMPING_MAX):
            raise ValueError(f"frequencies must exceed fmin={self.fmin} Hz and damping lie in "
                             f"({DAMPING_EPS}, {DAMPING_MAX}) (got {freqs}, {damp})")
        frac = (freqs - self.fmin) / (self.fmax - self.fmin)
        raw_f = [logit(p) for p in frac]
        self.raw_frequency = nn.Parameter(torch.tensor(raw_f, dtype=torch.float64))
        raw_d = [logit(z) for z in (damp - DAMPING_EPS) / DAMPING_MAX]
        self.raw_damping = nn.Parameter(torch.tensor(raw_d, dtype=torch.float64))
        extra = np.full(self.n_modes - 1, 0.05) if weights is None else \
            np.asarray(weights, dtype=float).reshape(-1)[1:]
        if weights is not None and len(weights) != self.n_modes:
            raise ValueError(f"weights needs {self.n_modes} values, got {len(weights)}")
        self.raw_weights = nn.Parameter(torch.tensor(extra, dtype=torch.float64))
        #: the share passed on directly (`feedthrough_share`); None: no feedthrough
        self.raw_feedthrough = nn.Parameter(torch.zeros(1, dtype=torch.float64)) \
            if feedthrough else None

    def _load_from_state_dict(self, state_dict: dict[str, Any], prefix: str,
                              *args: Any, **kwargs: Any) -> None:
        """A state saved without a feedthrough passes nothing on directly (share 0)."""
        key = prefix + "raw_feedthrough"
        if self.raw_feedthrough is not None and key not in state_dict:
            state_dict[key] = torch.zeros_like(self.raw_feedthrough)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    @property
    def feedthrough_share(self) -> Tensor:
        """The input's share passed on directly, ``w_0`` (0 without a feedthrough)."""
        if self.raw_feedthrough is None:
            return torch.zeros((), dtype=torch.float64)
        return self.raw_feedthrough.double()[0]

    @property
    def frequency_hz(self) -> Tensor:
        return self.fmin + (self.fmax - self.fmin) * torch.sigmoid(self.raw_frequency.double())

    @property
    def damping(self) -> Tensor:
        return DAMPING_EPS + DAMPING_MAX * torch.sigmoid(self.raw_damping.double())

    @property
    def weights(self) -> Tensor:
        extra = self.raw_weights.double()
        first = 1.0 - extra.sum() - self.feedthrough_share.to(extra.device)
        return torch.cat([first.reshape(1), extra])

    def forward(self, x: Tensor) -> Tensor:
        """``x`` (B, T) -> (B, T)."""
        freqs, damp = self.frequency_hz, self.damping
        if self.n_modes == 1 and self.raw_feedthrough is None:
            return iir_filter(x, *mode_coefficients(freqs[0], damp[0], self.fs))
        w = self.weights.to(device=x.device, dtype=x.dtype)
        out = 0.0
        for m in range(self.n_modes):
            y = iir_filter(x, *mode_coefficients(freqs[m], damp[m], self.fs))
            out = out + w[m] * y
        if self.raw_feedthrough is not None:
            out = out + self.feedthrough_share.to(device=x.device, dtype=x.dtype) * x
        return out

    def state_names(self) -> list[str]:
        return [f"mode{m}_z{i}" for m in range(self.n_modes) for i in (1, 2)]

    def step(self, x: Tensor, state: StepState) -> Tensor:
        """One sample (B,) -> (B,) (`hysteresis_lab.blocks.step`)."""
        freqs, damp = self.frequency_hz, self.damping
        if self.n_modes == 1 and self.raw_feedthrough is None:
            return tdf2_step(*frozen(*mode_coefficients(freqs[0], damp[0], self.fs)), x, state)
        w, share = frozen(self.weights, self.feedthrough_share)
        out = share * x
        for m in range(self.n_modes):
            y = tdf2_step(*frozen(*mode_coefficients(freqs[m], damp[m], self.fs)), x, state)
            out = out + w[m] * y
        return out

    def export(self) -> dict[str, Any]:
        with torch.no_grad():
            return {
                "fs": self.fs,
                "frequency_hz": self.frequency_hz.cpu().numpy().copy(),
                "damping": self.damping.cpu().numpy().copy(),
                "weights": self.weights.cpu().numpy().copy(),
                "feedthrough": float(self.feedthrough_share),
            }


class Delay(nn.Module):
    """Fixed integer delay of ``samples`` along time (dim 1), zeros shifted in at the start."""

    def __init__(self, samples: int = 1) -> None:
        super().__init__()
        if samples < 0:
            raise ValueError(f"delay must be >= 0 samples, got {samples}")
        self.samples = int(samples)

    def forward(self, x: Tensor) -> Tensor:
        """``x`` (B, T, ...) -> same shape, ``out[:, k] = x[:, k - samples]``."""
        n = self.samples
        if n == 0:
            return x
        if n >= x.shape[1]:
            return torch.zeros_like(x)
        pad = torch.zeros_like(x[:, :n])
        return torch.cat([pad, x[:, :-n]], dim=1)

    @property
    def delay_samples(self) -> float:
        """The delay in samples (as `LearnedDelay.delay_samples`)."""
        return float(self.samples)

    def state_names(self) -> list[str]:
        return [f"delay_{i}" for i in range(self.samples)]

    def step(self, x: Tensor, state: StepState) -> Tensor:
        """One sample (B,) -> (B,): the buffer of the last ``samples`` inputs, oldest first."""
        return delay_step(self.samples, x, state)

    def export(self) -> dict[str, Any]:
        return {"samples": self.samples}
