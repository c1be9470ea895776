"""The compiled SVM free run (`SVMKernel.run_all`) against the NumPy step and the generic
``predict_scaled`` loop."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.kernels.svm import SVMKernel
from kernel_checks import step_loop
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
    kernel = type(model.free_run_kernel(np.zeros((1, 30, 1)), dm.window))
    assert kernel is SVMKernel
    reference = free_run(model, recs, dm.window, fast=False)  # predict_scaled per step

    steps = []
    numpy_step = SVMKernel.step

    def counted_step(self, k, n, y):
        steps.append(k)
        return numpy_step(self, k, n, y)

    with monkeypatch.context() as patch:  # without run_all the simulator loops over step
        patch.delattr(SVMKernel, "run_all")
        patch.setattr(SVMKernel, "step", counted_step)
        numpy_steps = free_run(model, recs, dm.window)
    assert len(steps) == recs[0].n_samples - dm.window.first_target  # the NumPy step ran

    def no_step(*args, **kwargs):
        raise AssertionError("free_run should use run_all, not step")

    with monkeypatch.context() as patch:
        patch.setattr(SVMKernel, "step", no_step)
        compiled = free_run(model, recs, dm.window)
    for rec, a, b, c in zip(recs, compiled, reference, numpy_steps, strict=True):
        assert a.shape == rec.y.shape
        np.testing.assert_allclose(a, c, atol=1e-9)  # the same algebra as the NumPy step
        np.testing.assert_allclose(a, b, atol=1e-8)  # sklearn's own kernel evaluation
        assert b[dm.window.first_target :].std() > 0.01  # the output moves

    # run_all with an output term (the linear effect path) equals the step loop with it
    u = np.stack([r.u[:150] for r in recs])
    y = np.stack([r.y[:150] for r in recs]).astype(float)
    active = np.full(150, len(recs))
    term = np.random.default_rng(2).standard_normal(y.shape) * 0.1
    ft = dm.window.first_target
    fast = model.free_run_kernel(u, dm.window).run_all(y.copy(), active, ft, term=term)
    slow = step_loop(model.free_run_kernel(u, dm.window), y.copy(), active, ft, term)
    np.testing.assert_allclose(fast, slow, atol=1e-9)
    assert not np.allclose(fast, model.free_run_kernel(u, dm.window).run_all(
        y.copy(), active, ft))  # the term mattered
