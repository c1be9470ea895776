"""Excitation signals: the multisine's spectrum, scaling and seeding; sines; validation."""

from __future__ import annotations

import numpy as np
import pytest

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.signals import multisine, sine

FS = 20_000.0
N = 80_000  # 4 s: the 1 Hz lines fall on every 4th FFT bin


def test_multisine_has_exactly_the_500_lines():
    x = multisine(N, fs=FS, n_components=500, f_max=500.0, amplitude=100.0, seed=0)
    power = np.abs(np.fft.rfft(x)) ** 2
    freqs = np.fft.rfftfreq(N, 1.0 / FS)
    lines = np.isin(np.round(freqs, 6), np.arange(1, 501, dtype=float))
    assert lines.sum() == 500
    assert power[~lines].sum() < 1e-12 * power[lines].sum()
    # flat amplitude spectrum: every line carries the same energy
    assert power[lines].min() > 0.999 * power[lines].max()
    assert power[0] < 1e-12 * power[lines].max()  # no DC


def test_multisine_phases_are_uniform_random():
    x = multisine(N, seed=3)
    phases = np.angle(np.fft.rfft(x)[4 : 4 * 501 : 4])
    # a uniform phase distribution: about a quarter in each quadrant
    counts = np.histogram(phases, bins=4, range=(-np.pi, np.pi))[0]
    assert counts.min() > 90


def test_multisine_peak_is_exactly_the_amplitude():
    for amplitude in (100.0, 3.5):
        x = multisine(N, amplitude=amplitude, seed=1)
        assert np.max(np.abs(x)) == pytest.approx(amplitude, rel=1e-12)


def test_multisine_is_deterministic_by_seed():
    np.testing.assert_array_equal(multisine(N, seed=7), multisine(N, seed=7))
    assert np.max(np.abs(multisine(N, seed=7) - multisine(N, seed=8))) > 10.0


@pytest.mark.parametrize("n", [20_000, 30_001])  # lines on FFT bins (inverse FFT) / off them
def test_multisine_matches_eq1(n):
    x = multisine(n, n_components=20, f_max=200.0, seed=2)
    t = np.arange(n) / FS
    freqs = np.arange(1, 21) * 10.0
    phases = np.random.default_rng(2).uniform(0.0, 2.0 * np.pi, 20)
    direct = np.cos(2 * np.pi * freqs[None, :] * t[:, None] + phases).sum(axis=1)
    np.testing.assert_allclose(x, direct * 100.0 / np.max(np.abs(direct)), atol=1e-8)


def test_sine_starts_at_zero_and_lasts_n_periods():
    x = sine(50.0, fs=FS, amplitude=100.0, n_periods=2.0)
    assert len(x) == 800
    assert x[0] == 0.0
    assert np.max(x) == pytest.approx(100.0, rel=1e-6)
    assert len(sine(0.1, n_periods=1.0)) == 200_000
    assert len(sine(10.0, n_samples=123)) == 123
    assert sine(1.0, phase=np.pi / 2, n_samples=1)[0] == pytest.approx(100.0)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: multisine(1000, f_max=10_000.0),
         r"multisine f_max=10000.0 Hz must lie below fs/2 = 10000.0 Hz"),
        (lambda: multisine(0), r"signal n_samples=0 must be a positive number"),
        (lambda: multisine(1000, amplitude=-1.0), r"signal amplitude=-1.0 must be a positive"),
        (lambda: multisine(1000, n_components=2.5),
         r"signal n_components=2.5 must be a whole number"),
        (lambda: sine(10_000.0), r"sine frequency 10000.0 Hz must lie below fs/2 = 10000.0 Hz"),
        (lambda: sine(-1.0), r"signal frequency=-1.0 must be a positive number"),
        (lambda: sine(1.0, n_periods=0.0), r"signal n_periods=0.0 must be a positive number"),
    ],
)
def test_invalid_signal_arguments_raise_config_error(call, message):
    with pytest.raises(ConfigError, match=message):
        call()
