"""Excitation signals: the study's multisine (Eq. 1) and sines. Deterministic for a seed."""

from __future__ import annotations

import numpy as np

from hysteresis_lab.errors import ConfigError


def _positive(**values: float) -> None:
    for name, value in values.items():
        if not np.isfinite(value) or value <= 0:
            raise ConfigError(f"signal {name}={value!r} must be a positive number.")


def _integer(**values: float) -> None:
    for name, value in values.items():
        if float(value) != int(value):
            raise ConfigError(f"signal {name}={value!r} must be a whole number.")


def multisine(
    n_samples: int,
    fs: float = 20_000.0,
    n_components: int = 500,
    f_max: float = 500.0,
    amplitude: float = 100.0,
    seed: int = 0,
) -> np.ndarray:
    """Sum of ``n_components`` cosines at ``f_k = k * f_max / n_components`` (k = 1..n_f).

    Phases are uniform in [0, 2π) from ``seed``; the sum is scaled so that
    ``max|x| == amplitude`` exactly (the study's Eq. (1), ±100 V).
    """
    _positive(n_samples=n_samples, fs=fs, n_components=n_components, f_max=f_max,
              amplitude=amplitude)
    _integer(n_samples=n_samples, n_components=n_components)
    if f_max >= fs / 2:
        raise ConfigError(f"multisine f_max={f_max} Hz must lie below fs/2 = {fs / 2} Hz.")
    n_components = int(n_components)
    rng = np.random.default_rng(seed)
    phases = rng.uniform(0.0, 2.0 * np.pi, n_components)
    freqs = np.arange(1, n_components + 1) * (f_max / n_components)
    n = int(n_samples)
    bins = freqs * n / fs
    if np.allclose(bins, np.round(bins)):  # every line on an FFT bin: one inverse FFT
        spectrum = np.zeros(n // 2 + 1, dtype=complex)
        spectrum[np.round(bins).astype(int)] = np.exp(1j * phases)
        x = np.fft.irfft(spectrum, n)
    else:
        t = np.arange(n) / fs
        x = np.zeros(n)
        for f, phi in zip(freqs, phases, strict=True):
            x += np.cos(2.0 * np.pi * f * t + phi)
    return x * (amplitude / np.max(np.abs(x)))


def sine(
    frequency: float,
    fs: float = 20_000.0,
    amplitude: float = 100.0,
    n_periods: float = 2.0,
    n_samples: int | None = None,
    phase: float = 0.0,
) -> np.ndarray:
    """``amplitude * sin(2π f t + phase)``, ``n_periods`` periods long unless ``n_samples``."""
    _positive(frequency=frequency, fs=fs, amplitude=amplitude)
    if frequency >= fs / 2:
        raise ConfigError(f"sine frequency {frequency} Hz must lie below fs/2 = {fs / 2} Hz.")
    if n_samples is None:
        _positive(n_periods=n_periods)
        n_samples = int(round(n_periods * fs / frequency))
    _positive(n_samples=n_samples)
    _integer(n_samples=n_samples)
    t = np.arange(int(n_samples)) / fs
    return amplitude * np.sin(2.0 * np.pi * frequency * t + phase)
