"""The compiled SVM free run (`SVMKernel.run_all`) against the NumPy step and the generic
``predict_scaled`` loop."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.models.fast import FlatKernel
from hysteresis_lab.training import build_model, fit
from narx import TRAINER, datamodule_for, narx_data

SETTINGS = [
    {"kernel": "rbf", "gamma": 0.05, "strategy": "nystroem", "n_components": 60},
    {"kernel": "sigmoid", "gamma": 0.01, "coef0": 0.1, "strategy": "nystroem",
     "n_components": 60},
    {"kernel": "poly", "gamma": 0.05, "degree": 2, "strategy": "subsample", "max_samples": 300},
    {"kernel": "rbf", "gamma": 0.05, "strategy": "subsample", "max_samples": 300},
]


@pytest.mark.parametrize("settings", SETTINGS, ids=["rbf", "sigmoid", "poly", "rbf_exact"])
@pytest.mark.parametrize("ny", [1, 2])
def test_run_all_equals_the_numpy_step_and_predict_scaled(settings, ny, tmp_path, monkeypatch):
    splits = narx_data(n=800, ny=ny)
    # recordings of different lengths: rows drop out of the batch as they finish
    short = dataclasses.replace(splits.test[1], u=splits.test[1].u[:150],
                                y=splits.test[1].y[:150], name="short")
    recs = [splits.test[0], short]
    dm = datamodule_for("svm", splits)
    model = fit(build_model({"name": "svm", "C": 1.0, **settings}, dm), dm, TRAINER,
                tmp_path).model
    reference = free_run(model, recs, dm.window, fast=False)  # predict_scaled per step
    numpy_steps = free_run(model, recs, dm.window)  # first call: the NumPy step

    def no_step(*args, **kwargs):
        raise AssertionError("free_run should use run_all, not step")

    kernel = type(model.free_run_kernel(np.zeros((1, 30, 1)), dm.window))
    assert kernel is not FlatKernel and hasattr(kernel, "run_all")
    with monkeypatch.context() as patch:
        patch.setattr(kernel, "step", no_step)
        compiled = free_run(model, recs, dm.window)
    for rec, a, b, c in zip(recs, compiled, reference, numpy_steps, strict=True):
        assert a.shape == rec.y.shape
        np.testing.assert_allclose(a, c, atol=1e-9)  # the same algebra as the NumPy step
        np.testing.assert_allclose(a, b, atol=1e-8)  # sklearn's own kernel evaluation
        assert b[dm.window.first_target :].std() > 0.01  # the output moves
