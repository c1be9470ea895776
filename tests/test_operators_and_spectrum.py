"""The resonance, rate, dead-zone and backlash operators against analytically known responses,
and the residual spectrum's marked peaks."""

from __future__ import annotations

import numpy as np
import pytest

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.loop.diagnosis.residuals import diagnostics_figure, residual_analysis
from hysteresis_lab.loop.diagnosis.spectrum import residual_spectrum
from hysteresis_lab.physics.filters import resonator_bank
from hysteresis_lab.physics.static import dead_zone, rate

FS = 2000.0
CTX = FeatureContext(FS, np.array([100.0]), 10.0)


def steady_amplitude(x: np.ndarray, n_last: int) -> float:
    return float(np.max(np.abs(x[-n_last:])))


def test_resonator_passes_its_own_frequency_at_unit_gain_and_damps_others():
    """A band-pass of quality q: gain 1 at its centre, 1/sqrt(1 + q^2 (r - 1/r)^2) at r times
    the centre, r measured on the bilinear transform's warped axis tan(pi f / fs)."""
    t = np.arange(int(4 * FS)) / FS
    centre = 100.0
    for ratio in (1.0, 0.5, 2.0, 4.0):
        u = np.sin(2 * np.pi * ratio * centre * t)
        out = resonator_bank(u, FS, np.array([centre]), q=5.0)[:, 0]
        r = np.tan(np.pi * ratio * centre / FS) / np.tan(np.pi * centre / FS)
        expected = 1.0 / np.sqrt(1.0 + 25.0 * (r - 1.0 / r) ** 2)
        assert steady_amplitude(out, int(FS)) == pytest.approx(expected, rel=0.03), ratio
    # frequencies at or above 0.45 fs get no filter
    assert resonator_bank(u, FS, np.array([100.0, 0.45 * FS, 950.0])).shape == (len(u), 1)


def test_resonance_effect_responds_most_in_the_filter_at_the_input_frequency():
    effect = get_effect("resonance")
    grid = np.geomspace(0.01 * FS, 0.4 * FS, 12)
    t = np.arange(int(4 * FS)) / FS
    for j in (2, 6, 10):
        u = 100.0 * np.sin(2 * np.pi * grid[j] * t)
        features = effect.features(u[:, None], CTX)
        assert features.shape == (len(u), 12)
        amplitudes = np.abs(features[-int(FS):]).max(axis=0)
        assert np.argmax(amplitudes) == j
        assert amplitudes[j] == pytest.approx(100.0, rel=0.02)


def test_rate_of_a_ramp_is_its_slope():
    t = np.arange(200) / FS
    u = 3.0 + 50.0 * t  # 50 V/s
    r = rate(u, FS)
    assert r[0] == 0.0  # at rest before the first sample
    np.testing.assert_allclose(r[1:], 50.0, rtol=1e-9)
    features = get_effect("rate").features(u[:, None], CTX)
    scale = 2 * np.pi * 100.0 * 100.0  # a 100 Hz sine at the training amplitude: rate 1
    np.testing.assert_allclose(features[1:, 0], 50.0 / scale, rtol=1e-9)
    np.testing.assert_allclose(features[1:, 1], 50.0 / scale * u[1:] / 100.0, rtol=1e-9)
    # a sine's rate is its derivative, 2 pi f A cos (to the backward difference's error)
    s = 100.0 * np.sin(2 * np.pi * 5.0 * t)
    np.testing.assert_allclose(rate(s, FS)[1:], 2 * np.pi * 5.0 * 100.0 *
                               np.cos(2 * np.pi * 5.0 * (t[1:] - 0.5 / FS)), rtol=1e-3)


def test_dead_zone_removes_the_band_around_zero():
    u = np.array([-10.0, -3.0, -2.0, -1.0, 0.0, 1.5, 2.0, 2.5, 10.0])
    expected = [-8.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, 8.0]
    np.testing.assert_array_equal(dead_zone(u, 2.0), expected)
    features = get_effect("dead_zone").features(u[:, None] * 10.0, CTX)  # widths 2, 5, 10, 20 V
    assert features.shape == (len(u), 4)
    for column, width in enumerate((2.0, 5.0, 10.0, 20.0)):
        x = u * 10.0
        expected = np.where(np.abs(x) > width, x - np.sign(x) * width, 0.0)
        np.testing.assert_allclose(features[:, column], expected)


def test_backlash_follows_the_input_with_its_play():
    """A triangle 0 -> 100 -> -100 V through plays of half-width 5, 10 and 15 V: the output
    lags the rising input by r, holds for 2r after the turn, then lags the falling input by r."""
    u = np.concatenate([np.linspace(0, 100, 101), np.linspace(99, -100, 200)])
    features = get_effect("backlash").features(u[:, None], CTX)
    assert features.shape == (len(u), 3)
    for column, r in enumerate((5.0, 10.0, 15.0)):
        rising, falling = u[:101], u[101:]
        np.testing.assert_allclose(features[:101, column], np.maximum(rising - r, 0.0))
        np.testing.assert_allclose(features[101:, column], np.minimum(100.0 - r, falling + r))


def test_a_sine_in_the_residual_is_a_marked_peak_at_its_frequency():
    fs, f = 1000.0, 37.0
    rng = np.random.default_rng(0)
    t = np.arange(8000) / fs
    noise = 0.01 * rng.standard_normal(len(t))
    freqs, psd, peaks = residual_spectrum(noise + 0.5 * np.sin(2 * np.pi * f * t), fs)
    resolution = freqs[1] - freqs[0]
    assert peaks and abs(peaks[0]["frequency_hz"] - f) <= resolution
    assert peaks[0]["above_median"] > 1000
    assert freqs[np.argmax(psd)] == peaks[0]["frequency_hz"]
    assert residual_spectrum(noise, fs)[2] == []  # white: nothing marked

    # the residual analysis lists it, the diagnostics figure draws it
    u = 10.0 * np.sin(2 * np.pi * 3.0 * t)
    rec = Recording(u=u, y=0.5 * np.sin(2 * np.pi * f * t) + noise, fs=fs, name="r")
    predictions = {"r": {"free_run": np.zeros((len(t), 1)), "one_step": rec.y - noise[:, None]}}
    analysis = residual_analysis([rec], predictions, n_skip=0)
    marked = analysis["r"]["free_run"]["spectrum_peaks"]
    assert abs(marked[0]["frequency_hz"] - f) <= resolution
    assert analysis["r"]["one_step"]["spectrum_peaks"] == []
    figure = diagnostics_figure([rec], predictions, n_skip=0)
    spectrum_axis = figure.axes[2]
    drawn = [line.get_xdata()[0] for line in spectrum_axis.get_lines()[1:]]
    assert marked[0]["frequency_hz"] in drawn
