"""The compiled LSTM free run (`_LSTMKernel.run_all`) against the NumPy step and torch."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.kernels.lstm import _tanh_rows
from hysteresis_lab.models.lstm import LSTMNet, _LSTMKernel
from kernel_checks import check_batch_independence, check_run_all

# (window, nu, ny, num_layers, lstm_layers): default lags; masked lags, delay 2, two inputs,
# a hidden dense layer; no output lags; no delay, two outputs, three LSTM layers; masked
# lags with two outputs (the torch loop's output mask spans every output)
SETUPS = [
    (WindowSpec(), 1, 1, 3, 2),
    (WindowSpec(na=3, nb=6, nk=2), 2, 1, 3, 1),
    (WindowSpec(na=0, nb=5, nk=1), 1, 1, 2, 1),
    (WindowSpec(na=4, nb=4, nk=0), 1, 2, 4, 3),
    (WindowSpec(na=5, nb=3, nk=1), 1, 2, 3, 2),
]


def random_model(window: WindowSpec, nu: int, ny: int, num_layers: int, lstm_layers: int,
                 seed: int = 0) -> LSTMNet:
    torch.manual_seed(seed)
    model = LSTMNet(nu=nu, ny=ny, na=window.na, nb=window.nb, nk=window.nk,
                    num_layers=num_layers, lstm_layers=lstm_layers, units=12)
    with torch.no_grad():  # larger weights than the default init: saturating gates
        for p in model.net.parameters():
            p.mul_(2.0)
    return model.eval()


@pytest.mark.parametrize("setup", SETUPS,
                         ids=["default", "masked", "na0", "nk0_mimo", "masked_mimo"])
def test_run_all_equals_the_step_kernel_and_torch(setup, monkeypatch):
    window, nu, ny, num_layers, lstm_layers = setup
    model = random_model(window, nu, ny, num_layers, lstm_layers)
    check_run_all(model, _LSTMKernel, window, nu, ny, monkeypatch)


def test_run_all_is_independent_of_the_batch():
    window = WindowSpec()
    check_batch_independence(random_model(window, 1, 1, 3, 2), window)


def test_compiled_tanh_is_correctly_rounded():
    rng = np.random.default_rng(0)
    x = np.concatenate([
        rng.standard_normal(20_000) * 3, rng.standard_normal(20_000) * 1e-3,
        np.linspace(-12.0, 12.0, 20_001), [0.0, 1e-45, -1e-45, 9.0, 9.5, 3e38, -3e38],
    ]).astype(np.float32)
    out = x.copy()[None]
    _tanh_rows(out, 1, 0, x.size)
    exact = np.tanh(x.astype(np.float64))
    ulp = np.spacing(np.abs(exact).astype(np.float32)).astype(np.float64)
    assert np.max(np.abs(out[0] - exact) / ulp) <= 0.5001
    special = np.array([[np.nan, np.inf, -np.inf, -0.0]], np.float32)
    _tanh_rows(special, 1, 0, 4)
    assert np.isnan(special[0, 0]) and special[0, 1] == 1.0 and special[0, 2] == -1.0
    assert special[0, 3] == 0.0 and np.signbit(special[0, 3])
    rows = np.full((3, 4), 0.5, np.float32)
    _tanh_rows(rows, 2, 1, 3)  # only rows < 2, columns 1..2
    np.testing.assert_array_equal(rows[2], 0.5)
    np.testing.assert_array_equal(rows[:2, [0, 3]], 0.5)
    np.testing.assert_allclose(rows[:2, 1:3], np.tanh(np.float32(0.5)), rtol=1e-7)
