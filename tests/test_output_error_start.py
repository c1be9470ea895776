"""The linear model's start: ARX refined by Steiglitz–McBride towards the output-error fit."""

from __future__ import annotations

import numpy as np
from scipy import signal

from hysteresis_lab.blocks.sections import arx_least_squares, output_error_start
from hysteresis_lab.signals import multisine, sine

FS = 20_000.0


def _mode(frequency_hz: float, damping: float) -> tuple[np.ndarray, np.ndarray]:
    """A unit-DC-gain second-order resonance, discretised as the simulator does."""
    wn = 2.0 * np.pi * frequency_hz
    warped = 2.0 * FS * np.tan(wn / (2.0 * FS))
    return signal.bilinear([warped**2], [1.0, 2.0 * damping * warped, warped**2], FS)


def _two_modes() -> tuple[np.ndarray, np.ndarray]:
    """0.85 of a 900 Hz mode plus 0.15 of a 2.8 kHz one, one sample of delay (the simulated
    positioner with its second mode on, amplifier left out)."""
    b1, a1 = _mode(900.0, 0.03)
    b2, a2 = _mode(2800.0, 0.02)
    b = 0.85 * np.convolve(b1, a2) + 0.15 * np.convolve(b2, a1)
    return np.concatenate([[0.0], b]), np.convolve(a1, a2)


def _free_run_rmse(b: np.ndarray, a: np.ndarray, u: np.ndarray, y: np.ndarray) -> float:
    return float(np.sqrt(np.mean((y - signal.lfilter(b, a, u)) ** 2)))


def test_the_start_holds_a_mode_above_the_input_band():
    """A 0-500 Hz multisine shows the 2.8 kHz mode only in its start transient. Plain ARX
    (equation error) misplaces it and a sine started from rest rings wrongly; the
    Steiglitz–McBride start finds the system the order can hold."""
    b_true, a_true = _two_modes()
    u = multisine(20_000, fs=FS, amplitude=1.0, seed=0)
    y = signal.lfilter(b_true, a_true, u) + 1e-4 * np.random.default_rng(0).normal(size=len(u))
    check = sine(500.0, fs=FS, amplitude=1.0, n_periods=1.0)  # one period from rest, as the tests
    y_check = signal.lfilter(b_true, a_true, check)
    arx = _free_run_rmse(*arx_least_squares(u, y, na=4, nb=4, nk=1), check, y_check)
    start = _free_run_rmse(*output_error_start(u, y, na=4, nb=4, nk=1), check, y_check)
    size = float(np.sqrt(np.mean(y_check**2)))
    assert start < 0.015 * size < arx, (start, arx, size)


def test_the_start_is_never_worse_than_arx_in_free_run():
    """On data ARX already fits (broadband input, low order) the start keeps a fit at least
    as good in free run, for several inputs (MISO) and recordings."""
    rng = np.random.default_rng(1)
    b_true = np.array([[0.0, 0.5, 0.2], [0.0, -0.3, 0.1]])
    a_true = np.array([1.0, -0.6, 0.1])
    us = [rng.normal(size=(3000, 2)) for _ in range(2)]
    ys = [sum(signal.lfilter(b_true[j], a_true, u[:, j]) for j in range(2))
          + 0.05 * rng.normal(size=len(u)) for u in us]

    def error(b: np.ndarray, a: np.ndarray) -> float:
        return float(np.var(np.concatenate([
            y - sum(signal.lfilter(b[j], a, u[:, j]) for j in range(2))
            for u, y in zip(us, ys, strict=True)])))

    b, a = output_error_start(us, ys, na=2, nb=2, nk=1)
    assert b.shape == (2, 3) and a.shape == (3,)
    assert error(b, a) <= error(*arx_least_squares(us, ys, na=2, nb=2, nk=1)) + 1e-12
    np.testing.assert_allclose(a, a_true, atol=0.05)
