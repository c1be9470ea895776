"""The linear model's start: ARX, or a Steiglitz–McBride fit where its free run is far
closer to the training recordings (a mode above the input band that ARX misplaces) and it
needs no slower mode than ARX's (slow effects such as creep stay out of the start), or clearly
closer, with ARX's slow dynamics, where ARX's gain at Nyquist is above its static gain and the
output-error fit's is not."""

from __future__ import annotations

import numpy as np
import torch
from scipy import signal

from hysteresis_lab.blocks.sections import (
    arx_least_squares,
    free_run_error,
    nyquist_share,
    stable_denominator,
    steiglitz_mcbride,
)
from hysteresis_lab.models.linear import (
    NYQUIST_GAIN_SHARE,
    OUTPUT_ERROR_REPLACES_AT,
    LinearModel,
)
from hysteresis_lab.signals import multisine, sine
from hysteresis_lab.sim.default_dataset import make_default_dataset

FS = 20_000.0


def _mode(frequency_hz: float, damping: float) -> tuple[np.ndarray, np.ndarray]:
    """A unit-DC-gain second-order resonance, discretised by the bilinear transform."""
    wn = 2.0 * np.pi * frequency_hz
    warped = 2.0 * FS * np.tan(wn / (2.0 * FS))
    return signal.bilinear([warped**2], [1.0, 2.0 * damping * warped, warped**2], FS)


def _two_modes() -> tuple[np.ndarray, np.ndarray]:
    """0.85 of a 900 Hz mode plus 0.15 of a lightly damped 2.8 kHz one, one sample of delay
    (the simulated positioner with its second mode on)."""
    b1, a1 = _mode(900.0, 0.03)
    b2, a2 = _mode(2800.0, 0.02)
    b = 0.85 * np.convolve(b1, a2) + 0.15 * np.convolve(b2, a1)
    return np.concatenate([[0.0], b]), np.convolve(a1, a2)


def _started(u: np.ndarray, y: np.ndarray, order: int) -> LinearModel:
    model = LinearModel(nu=1, ny=1, order=order, delay=1, fs=FS)
    model.initialise_from_data(u, y, FS)
    return model


def _free_run(model: LinearModel, u: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return (model.chain(torch.as_tensor(u[None, :, None]))[0, :, 0]
                + model.offset[0]).numpy()


def test_the_start_holds_a_mode_above_the_input_band():
    """A 0-500 Hz multisine shows the 2.8 kHz mode only in start transients: ARX's equation
    error misplaces it and a 500 Hz sine from rest rings wrongly in its free run; the start
    (Steiglitz–McBride, chosen by its free run on the training data) holds the system."""
    b_true, a_true = _two_modes()
    u = multisine(20_000, fs=FS, amplitude=1.0, seed=0)
    y = signal.lfilter(b_true, a_true, u) + 1e-4 * np.random.default_rng(0).normal(size=len(u))
    check = sine(500.0, fs=FS, amplitude=1.0, n_periods=1.0)
    y_check = signal.lfilter(b_true, a_true, check)
    size = float(np.sqrt(np.mean(y_check**2)))

    b_arx, a_arx = arx_least_squares(u, y, na=4, nb=4, nk=1)
    arx = np.sqrt(np.mean((signal.lfilter(b_arx, stable_denominator(a_arx), check)
                           - y_check) ** 2))
    start = np.sqrt(np.mean((_free_run(_started(u, y, order=4), check) - y_check) ** 2))
    assert start < 0.01 * size < arx, (start, arx, size)


def test_the_arx_start_stays_where_it_holds_the_data():
    """On broadband data ARX already fits, the output-error fit gains little in free run:
    the ARX fit itself starts (same poles), for several inputs and recordings."""
    rng = np.random.default_rng(1)
    b_true = np.array([[0.0, 0.5, 0.2], [0.0, -0.3, 0.1]])
    a_true = np.array([1.0, -0.6, 0.1])
    us = [rng.normal(size=(3000, 2)) for _ in range(2)]
    ys = [sum(signal.lfilter(b_true[j], a_true, u[:, j]) for j in range(2))
          + 0.05 * rng.normal(size=len(u)) for u in us]
    b_arx, a_arx = arx_least_squares(us, ys, na=2, nb=2, nk=1)
    b_sm, a_sm = steiglitz_mcbride(us, ys, na=2, nb=2, nk=1)
    assert b_sm.shape == b_arx.shape and a_sm.shape == a_arx.shape
    assert free_run_error(us, ys, b_sm, a_sm) <= free_run_error(us, ys, b_arx, a_arx)

    model = LinearModel(nu=2, ny=1, order=2, delay=1, fs=FS)
    model._initialise_from_arrays(us, ys)
    _, a_start = model.dynamics[0][0].polynomials()
    np.testing.assert_allclose(a_start.detach().numpy(), a_arx, atol=1e-9)


def test_a_slow_effect_stays_out_of_the_start():
    """A creep-like slow part (first order, 0.1 s) beside the 900 Hz mode: the
    Steiglitz–McBride fit holds it far better in free run than ARX, but with a mode far
    slower than ARX's; the ARX fit starts (the loop's creep block is there for it)."""
    b1, a1 = _mode(900.0, 0.03)
    pole = np.exp(-1.0 / (0.1 * FS))
    u = multisine(20_000, fs=FS, amplitude=1.0, seed=0)
    y = (0.9 * signal.lfilter(np.concatenate([[0.0], b1]), a1, u)
         + 0.1 * signal.lfilter([0.0, 1.0 - pole], [1.0, -pole], u)
         + 1e-4 * np.random.default_rng(0).normal(size=len(u)))
    b_arx, a_arx = arx_least_squares(u, y, na=4, nb=4, nk=1)
    b_sm, a_sm = steiglitz_mcbride(u, y, na=4, nb=4, nk=1)
    assert (free_run_error([u], [y], b_sm, stable_denominator(a_sm))
            < OUTPUT_ERROR_REPLACES_AT * free_run_error([u], [y], b_arx, stable_denominator(a_arx)))

    _, a_start = _started(u, y, order=4).dynamics[0][0].polynomials()
    np.testing.assert_allclose(a_start.detach().numpy(), a_arx, atol=1e-9)


def test_nyquist_share_is_the_gain_at_nyquist_over_the_static_gain():
    """Two inputs: the larger gain at Nyquist over the larger static gain (scipy's freqz)."""
    b = np.array([[0.0, 0.2, 0.1], [0.0, 0.05, -0.3]])
    a = np.array([1.0, -0.5, 0.2])
    gains = [np.abs(signal.freqz(row, a, worN=[0.0, np.pi])[1]) for row in b]
    expected = max(g[1] for g in gains) / max(g[0] for g in gains)
    assert np.isclose(nyquist_share(b, a), expected)


def test_a_clipped_positioner_starts_without_arx_gain_at_nyquist():
    """The simulated positioner clipping at 90 V on a 0-500 Hz multisine with sensor noise:
    ARX's equation error puts poles near Nyquist (gain there far above the static gain, which
    no training on the band moves and a clipped input's corners reach); the output-error fit
    simulates the record better without them, and starts."""
    data = make_default_dataset(
        effects={"hysteresis": {"enabled": False}, "creep": {"enabled": False},
                 "saturation": {"enabled": True}},
        n_train=8000, test_frequencies=(10.0,), max_test_samples=100)
    rec = data.train[0]
    u, y = rec.u[:, 0] / 100.0, rec.y[:, 0] / 20.0
    b_arx, a_arx = arx_least_squares(u, y, na=6, nb=6, nk=1)
    assert nyquist_share(b_arx, a_arx) > 10.0
    start = _started(u, y, order=6)
    b, a = (p.detach().numpy() for p in start.dynamics[0][0].polynomials())
    assert nyquist_share(b, a) < NYQUIST_GAIN_SHARE
    assert (free_run_error([u], [y], b, a)
            < free_run_error([u], [y], b_arx, stable_denominator(a_arx)))
