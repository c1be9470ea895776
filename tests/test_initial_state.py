"""``evaluation.initial_state=estimate``: each test recording's output offset from its first
``n_init`` samples, which are then not scored (a sensor zeroed elsewhere on another day)."""

from __future__ import annotations

import dataclasses
import json

import lightning as L
import numpy as np
import pytest

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.evaluate import evaluate_model
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.sim.default_dataset import make_default_dataset
from hysteresis_lab.workflows.pipeline import RunConfig, run_model

TRAINER = TrainerSettings(max_epochs=3, accelerator="cpu", enable_progress_bar=False,
                          enable_model_summary=False)
OFFSET_UM = 0.7
N_INIT = 200


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    data = make_default_dataset(effects={"creep": {"enabled": False}}, n_train=6000,
                                test_frequencies=(10.0, 100.0), max_test_samples=2000,
                                val_samples=3000)
    dm = WindowDataModule(data, scaling="paper")
    L.seed_everything(0)
    model = build_model({"name": "linear"}, dm, trained_on={"fs": data.train[0].fs})
    return fit(model, dm, TRAINER, tmp_path_factory.mktemp("fit")).model, dm, data


def _shifted(data):
    return [dataclasses.replace(rec, y=rec.y + OFFSET_UM, name=rec.name) for rec in data.test]


def test_an_estimated_initial_state_removes_a_known_output_offset(fitted):
    model, dm, data = fitted
    rest = {label: evaluate_model(model, recordings, dm.window, n_init=N_INIT)
            for label, recordings in (("plain", data.test), ("shifted", _shifted(data)))}
    estimated = {label: evaluate_model(model, recordings, dm.window, n_init=N_INIT,
                                       initial_state="estimate")
                 for label, recordings in (("plain", data.test), ("shifted", _shifted(data)))}
    for name in rest["plain"].metrics:
        # from rest, the sensor's offset is an error of its size on every sample ...
        assert rest["shifted"].metrics[name]["rmse_free_run"] > (
            rest["plain"].metrics[name]["rmse_free_run"] + 0.1 * OFFSET_UM)
        # ... estimated from the first samples, it is gone: the same scores as without it
        assert estimated["shifted"].metrics[name]["rmse_free_run"] == pytest.approx(
            estimated["plain"].metrics[name]["rmse_free_run"], rel=1e-9)
        shift = (estimated["shifted"].predictions[name]["free_run"]
                 - rest["shifted"].predictions[name]["free_run"])
        plain_shift = (estimated["plain"].predictions[name]["free_run"]
                       - rest["plain"].predictions[name]["free_run"])
        np.testing.assert_allclose(shift - plain_shift, OFFSET_UM, atol=1e-9)
        # one-step prediction reads the measured outputs: the offset is no news to it
        assert estimated["shifted"].metrics[name]["rmse_one_step"] == pytest.approx(
            rest["shifted"].metrics[name]["rmse_one_step"])


def test_estimating_needs_initial_samples_and_a_known_mode(fitted):
    model, dm, data = fitted
    with pytest.raises(ConfigError, match="data.n_init"):
        evaluate_model(model, data.test, dm.window, n_init=0, initial_state="estimate")
    with pytest.raises(ConfigError, match="initial_state"):
        evaluate_model(model, data.test, dm.window, n_init=N_INIT, initial_state="guess")


def test_the_mode_is_named_in_metrics_json(tmp_path):
    data = make_default_dataset(effects={"creep": {"enabled": False}}, n_train=4000,
                                test_frequencies=(10.0,), max_test_samples=2000, val_samples=2000)
    data = dataclasses.replace(data, n_init=N_INIT)
    run_model(RunConfig.build({"name": "linear"}, {"name": "default"}, TRAINER, tmp_path,
                              use_tensorboard=False, plots=False, initial_state="estimate"),
              splits=data)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["initial_state"] == "estimate"
    assert np.isfinite(metrics["mean"]["rmse_free_run"])
