"""The positioner's physical blocks as functions of sampled signals (linear ones via scipy)."""

from __future__ import annotations

import numpy as np

from hysteresis_lab.physics.bouc_wen import bouc_wen_state
from hysteresis_lab.physics.filters import first_order_lowpass
from hysteresis_lab.physics.filters import mode_filter as physics_mode_filter
from hysteresis_lab.physics.play import play_operators
from hysteresis_lab.physics.static import dead_zone as physics_dead_zone
from hysteresis_lab.sim.config import (
    Amplifier,
    Asymmetry,
    Backlash,
    Creep,
    DeadZone,
    Drift,
    Hysteresis,
    Mode,
    Noise,
    Quantisation,
    RateDependence,
    Saturation,
)


def amplifier(v: np.ndarray, fs: float, cfg: Amplifier) -> np.ndarray:
    return first_order_lowpass(v, fs, 1.0 / (2.0 * np.pi * cfg.cutoff_hz))


def saturation(v: np.ndarray, cfg: Saturation) -> np.ndarray:
    return np.clip(v, -cfg.limit_v, cfg.limit_v)


def dead_zone(v: np.ndarray, cfg: DeadZone) -> np.ndarray:
    """``v`` with the band ``±width_v`` around zero removed."""
    return physics_dead_zone(v, cfg.width_v)


def backlash(v: np.ndarray, cfg: Backlash) -> np.ndarray:
    """A play operator of half-width ``width_v``, starting at rest."""
    x = np.ascontiguousarray(v, dtype=float)
    return play_operators(x, np.array([cfg.width_v]))[:, 0]


def delay(x: np.ndarray, samples: int) -> np.ndarray:
    if samples <= 0:
        return x
    return np.concatenate([np.zeros(samples), x[:-samples]])[: len(x)]


def hysteresis(
    v: np.ndarray, fs: float, cfg: Hysteresis, rate: RateDependence | None = None
) -> np.ndarray:
    """Bouc–Wen displacement ``d v - h`` (µm); ``alpha`` rate-dependent when ``rate`` is on."""
    alpha = np.full(len(v), cfg.alpha)
    if rate is not None and rate.enabled:
        dv_dt = np.abs(np.diff(v, prepend=v[0])) * fs
        alpha = alpha * (1.0 + rate.gain * dv_dt / rate.rate_ref_v_per_s)
    h = bouc_wen_state(np.ascontiguousarray(v, dtype=float), cfg.d_um_per_v, alpha, cfg.beta,
                       cfg.gamma)
    return cfg.d_um_per_v * v - h


def asymmetry(x: np.ndarray, v: np.ndarray, cfg: Asymmetry, stroke_um: float) -> np.ndarray:
    return x + cfg.coefficient * stroke_um * (v / cfg.v_ref) ** 2


def creep(x: np.ndarray, fs: float, cfg: Creep) -> np.ndarray:
    """``x + w * sum_i lowpass_tau_i(x)``: each decade of time adds about ``w`` of the step."""
    out = np.array(x, dtype=float)
    for tau in cfg.time_constants_s:
        out += cfg.weight_per_decade * first_order_lowpass(x, fs, tau)
    return out


def mode_filter(x: np.ndarray, fs: float, cfg: Mode) -> np.ndarray:
    """Second-order resonance ``wn^2 / (s^2 + 2 zeta wn s + wn^2)``; bilinear, prewarped at wn."""
    return physics_mode_filter(x, fs, cfg.frequency_hz, cfg.damping)


def drift(n: int, fs: float, cfg: Drift, rng: np.random.Generator) -> np.ndarray:
    """Ramp plus a slow oscillation of random phase (thermal expansion, sensor drift)."""
    t = np.arange(n) / fs
    phase = rng.uniform(0.0, 2.0 * np.pi)
    wave = np.sin(2.0 * np.pi * t / cfg.period_s + phase) - np.sin(phase)
    return cfg.rate_um_per_s * t + cfg.amplitude_um * wave


def noise(n: int, cfg: Noise, rng: np.random.Generator) -> np.ndarray:
    return rng.normal(0.0, cfg.rms_um, n)


def quantise(y: np.ndarray, cfg: Quantisation) -> np.ndarray:
    return np.round(y / cfg.step_um) * cfg.step_um
