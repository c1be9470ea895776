"""The compiled free runs against the torch step: FFNN (`FFNNKernel.run_all`) and SUBNET
(`subnet_free_run`), to 1e-6."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch

from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model
from hysteresis_lab.kernels.ffnn import FFNNKernel
from hysteresis_lab.models.ffnn import FFNN
from kernel_checks import check_batch_independence, check_run_all, recordings
from narx import datamodule_for

# (window, nu, ny, num_layers): the study's lags and depth; masked lags with a delay and two
# inputs; no output lags; two outputs without delay
SETUPS = [
    (WindowSpec(), 1, 1, 4),
    (WindowSpec(na=3, nb=6, nk=2), 2, 1, 3),
    (WindowSpec(na=0, nb=5, nk=1), 1, 1, 3),
    (WindowSpec(na=4, nb=4, nk=0), 1, 2, 2),
]
IDS = ["study", "masked_delay2_two_inputs", "na0", "nk0_mimo"]


def random_ffnn(window: WindowSpec, nu: int, ny: int, num_layers: int) -> FFNN:
    torch.manual_seed(0)
    return FFNN(nu=nu, ny=ny, na=window.na, nb=window.nb, nk=window.nk,
                num_layers=num_layers, neurons=24).eval()


@pytest.mark.parametrize("setup", SETUPS, ids=IDS)
def test_run_all_equals_the_step_kernel_and_torch(setup, monkeypatch):
    window, nu, ny, layers = setup
    model = random_ffnn(window, nu, ny, layers)
    check_run_all(model, FFNNKernel, window, nu, ny, monkeypatch)
    recs = recordings(nu, ny)
    compiled = free_run(model, recs, window)
    torch_step = free_run(model, recs, window, fast=False)
    for a, b in zip(compiled, torch_step, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)


def test_run_all_is_independent_of_the_batch():
    window = WindowSpec()
    check_batch_independence(random_ffnn(window, 1, 1, 4), window)


def test_subnet_compiled_free_run_equals_its_torch_loop(splits, monkeypatch):
    dm = datamodule_for("subnet", splits)
    L.seed_everything(0)
    model = build_model({"name": "subnet", "nx": 4, "neurons": 16, "encoder_neurons": 16},
                        dm).eval()
    model.initialise_from_recordings(dm.splits.train)
    recs = dm.splits.test
    compiled = free_run(model, recs, dm.window)
    monkeypatch.setattr(model, "compiled_free_run", lambda *args, **kwargs: None)
    torch_loop = free_run(model, recs, dm.window)
    for a, b in zip(compiled, torch_loop, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
        assert b[dm.window.first_target :].std() > 1e-3  # the output moves
