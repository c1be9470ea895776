"""``evaluation.initial_state=estimate``: each test recording's start (a physical model's held
input level, and the output offset) from its first ``n_init`` samples, which are then not
scored (a sensor zeroed elsewhere on another day, an actuator left at a level)."""

from __future__ import annotations

import dataclasses
import json

import lightning as L
import numpy as np
import pytest
import torch

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.evaluate import evaluate_model
from hysteresis_lab.evaluation.predict import free_run, one_step
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from hysteresis_lab.models.physical_chain import BURN_IN_DEFAULT
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
            estimated["plain"].metrics[name]["rmse_free_run"], rel=1e-6)
        shift = (estimated["shifted"].predictions[name]["free_run"]
                 - rest["shifted"].predictions[name]["free_run"])
        plain_shift = (estimated["plain"].predictions[name]["free_run"]
                       - rest["plain"].predictions[name]["free_run"])
        ft = dm.window.first_target  # the window's measured samples stay as measured
        np.testing.assert_allclose((shift - plain_shift)[ft:], OFFSET_UM, atol=1e-5)
        # one-step prediction reads the measured outputs: the offset is no news to it
        assert estimated["shifted"].metrics[name]["rmse_one_step"] == pytest.approx(
            rest["shifted"].metrics[name]["rmse_one_step"])


def test_a_physical_model_estimates_the_level_it_was_held_at_before_the_record():
    """A record that starts where the actuator was left (held at a level before it, its
    hysteresis remembering that level) is fitted from its first samples: the free run from
    the estimated start matches it, the one from rest (offset estimated) does not."""
    data = make_default_dataset(effects={"creep": {"enabled": False}}, n_train=4000,
                                test_frequencies=(10.0,), max_test_samples=3000,
                                val_samples=2000)
    augmented, context = augment_splits(data, ["hysteresis"])
    dm = WindowDataModule(augmented, scaling="paper")
    model = build_model({"name": "linear", "effects": ["hysteresis"]}, dm,
                        trained_on={"fs": data.train[0].fs},
                        feature_context=context_to_dict(context), n_base_inputs=data.nu)
    with torch.no_grad():
        model.input_blocks[0].hysteresis.weight.fill_(0.5)  # a loop with memory
    test = augmented.test[0]
    small = dataclasses.replace(test, u=test.u * 0.3)  # a sine inside the held level's loop
    held = np.repeat(small.u[:1] * 0 + 80.0, max(BURN_IN_DEFAULT, small.n_samples), axis=0)
    history = dataclasses.replace(small, u=np.concatenate([held, small.u]),
                                  y=np.zeros((len(held) + small.n_samples, 1)))
    truth = free_run(model, [history], dm.window)[0][len(held):] + OFFSET_UM
    record = dataclasses.replace(small, y=truth)
    scores = {mode: evaluate_model(model, [record], dm.window, n_init=N_INIT,
                                   initial_state=mode).metrics[record.name]["rmse_free_run"]
              for mode in ("rest", "estimate")}
    no_offset = evaluate_model(model, [dataclasses.replace(record, y=truth - OFFSET_UM)],
                               dm.window, n_init=N_INIT)
    assert scores["rest"] > 0.05  # from rest, the remembered level is an error ...
    assert no_offset.metrics[record.name]["rmse_free_run"] > 0.05  # ... beside the offset
    assert scores["estimate"] < 0.01 * scores["rest"]


def test_a_narx_network_restarts_from_the_measured_samples_less_their_offset(fitted, tmp_path):
    """A network reads its state from measured outputs: estimated, it restarts at the first
    scored sample from the samples before it, less the offset its free run shows, so a
    sensor offset costs it about nothing; from rest it drifts off by the offset."""
    _, dm, data = fitted
    L.seed_everything(0)
    network = fit(build_model({"name": "ffnn"}, dm, trained_on={"fs": data.train[0].fs}), dm,
                  dataclasses.replace(TRAINER, max_epochs=1), tmp_path).model
    scores = {(label, mode): evaluate_model(network, recordings, dm.window, n_init=N_INIT,
                                            initial_state=mode).metrics
              for label, recordings in (("plain", data.test), ("shifted", _shifted(data)))
              for mode in ("rest", "estimate")}
    for name in scores["plain", "rest"]:
        plain = scores["plain", "estimate"][name]["rmse_free_run"]
        assert scores["shifted", "rest"][name]["rmse_free_run"] > (
            scores["plain", "rest"][name]["rmse_free_run"] + 0.1 * OFFSET_UM)
        assert scores["shifted", "estimate"][name]["rmse_free_run"] < plain + 0.02 * OFFSET_UM
    # the first scored sample is the one-step prediction from the measured samples before it
    rec = _shifted(data)[0]
    rest = evaluate_model(network, [rec], dm.window, n_init=N_INIT).predictions[rec.name]
    estimated = evaluate_model(network, [rec], dm.window, n_init=N_INIT,
                               initial_state="estimate").predictions[rec.name]
    offset = np.mean((rec.y - rest["free_run"])[dm.window.first_target:N_INIT], axis=0)
    level = dataclasses.replace(rec, y=rec.y - offset)
    first_step = one_step(network, [level], dm.window)[0][N_INIT] + offset
    np.testing.assert_allclose(estimated["free_run"][N_INIT], first_step, rtol=1e-6)


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
