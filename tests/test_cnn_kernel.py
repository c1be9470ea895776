"""The compiled CNN free run (`_CNNKernel.run_all`) against the NumPy step and torch."""

from __future__ import annotations

import pytest
import torch

from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.models.cnn import CNNNet, _CNNKernel
from kernel_checks import check_batch_independence, check_run_all

# (window, nu, ny, num_layers, conv_layers, kernel_size): default lags, the study's two conv
# layers; masked lags, delay 2, two inputs, one conv layer, a hidden dense layer; no output
# lags, three conv layers; no delay, two outputs; masked lags with two outputs, kernel 3;
# an even kernel (torch pads one more sample on the right)
SETUPS = [
    (WindowSpec(), 1, 1, 3, 2, 5),
    (WindowSpec(na=3, nb=6, nk=2), 2, 1, 3, 1, 5),
    (WindowSpec(na=0, nb=5, nk=1), 1, 1, 4, 3, 3),
    (WindowSpec(na=4, nb=4, nk=0), 1, 2, 3, 1, 3),
    (WindowSpec(na=5, nb=3, nk=1), 1, 2, 3, 2, 3),
    (WindowSpec(na=2, nb=7, nk=1), 1, 1, 3, 2, 4),
]
IDS = ["default", "masked_1conv", "na0_3conv_k3", "nk0_mimo_k3", "masked_mimo_k3", "even_k4"]


def random_model(window: WindowSpec, nu: int, ny: int, num_layers: int, conv_layers: int,
                 kernel_size: int, seed: int = 0, units: int = 12) -> CNNNet:
    torch.manual_seed(seed)
    return CNNNet(nu=nu, ny=ny, na=window.na, nb=window.nb, nk=window.nk,
                  num_layers=num_layers, conv_layers=conv_layers, units=units,
                  kernel_size=kernel_size).eval()


@pytest.mark.parametrize("setup", SETUPS, ids=IDS)
def test_run_all_equals_the_step_kernel_and_torch(setup, monkeypatch):
    window, nu, ny = setup[:3]
    model = random_model(window, nu, ny, *setup[3:])
    check_run_all(model, _CNNKernel, window, nu, ny, monkeypatch)


@pytest.mark.parametrize("setup", [SETUPS[0], SETUPS[1], SETUPS[5]], ids=[IDS[0], IDS[1], IDS[5]])
def test_wide_layers_take_the_blas_path_to_the_same_numbers(setup, monkeypatch):
    """The study's width (83 units): the layers wide enough for the BLAS products and the
    reused rows of the sliding window."""
    window, nu, ny = setup[:3]
    model = random_model(window, nu, ny, *setup[3:], units=83)
    check_run_all(model, _CNNKernel, window, nu, ny, monkeypatch)


def test_run_all_is_independent_of_the_batch():
    window = WindowSpec()
    check_batch_independence(random_model(window, 1, 1, 3, 2, 5), window)

