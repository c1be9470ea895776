"""The grey-box model: fitted on the simulation error of a simulated positioner it reaches
the noise floor, extrapolates in amplitude, and refuses what it cannot model."""

from __future__ import annotations

import dataclasses

import lightning as L
import numpy as np
import pytest

from conftest import optional_dependency
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.predict import free_run, one_step
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.io import load_model, save_model
from hysteresis_lab.sim.default_dataset import make_default_dataset

TRAINER = TrainerSettings(max_epochs=6, accelerator="cpu", enable_progress_bar=False,
                          enable_model_summary=False)
NOISE_UM = 0.01  # the simulator's sensor noise (conf/sim/positioner.yaml)


def small_positioner(amplitude: float = 100.0, test_amplitude: float | None = None):
    """0.4 s of multisine (creep off: too slow to show in 0.4 s) and two short sine tests."""
    effects = {"creep": {"enabled": False}}
    data = make_default_dataset(effects=effects, n_train=8000, amplitude=amplitude,
                                test_frequencies=(10.0, 100.0), max_test_samples=3000,
                                val_samples=4000)
    if test_amplitude is not None:  # the tests at another amplitude than the training
        tests = make_default_dataset(effects=effects, n_train=100, amplitude=test_amplitude,
                                     test_frequencies=(10.0, 100.0), max_test_samples=3000).test
        data = dataclasses.replace(data, test=tests)
    return data


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    data = small_positioner(amplitude=50.0, test_amplitude=100.0)
    dm = WindowDataModule(data, scaling="paper")
    L.seed_everything(0)
    model = build_model({"name": "greybox"}, dm, trained_on={"fs": data.fs})
    result = fit(model, dm, TRAINER.with_changes(max_epochs=15), tmp_path_factory.mktemp("greybox"))
    return result.model, dm


def rmse(predicted, recordings, start):
    return [float(np.sqrt(np.mean((p[start:] - r.y[start:]) ** 2)))
            for p, r in zip(predicted, recordings, strict=True)]


def test_fitted_on_half_amplitude_it_simulates_full_amplitude_at_the_noise_floor(fitted):
    """Trained on a ±50 V multisine, scored on ±100 V sines: the physics extrapolates."""
    model, dm = fitted
    errors = rmse(free_run(model, dm.splits.test, dm.window), dm.splits.test,
                  dm.window.first_target)
    assert max(errors) < 5 * NOISE_UM, errors
    mode = model.physical_parameters()["mode"]["frequency_hz"][0]
    assert mode == pytest.approx(900.0, rel=0.02)  # the simulator's first mode


def test_its_one_step_prediction_is_its_free_run(fitted):
    model, dm = fitted
    for a, b in zip(one_step(model, dm.splits.test, dm.window),
                    free_run(model, dm.splits.test, dm.window), strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_saved_greybox_loads_and_simulates_the_same(fitted, tmp_path):
    model, dm = fitted
    loaded = load_model(save_model(model, tmp_path / "model"))
    for a, b in zip(free_run(model, dm.splits.test, dm.window),
                    free_run(loaded, dm.splits.test, dm.window), strict=True):
        np.testing.assert_array_equal(a, b)


def test_settings_it_cannot_model_are_refused():
    data = small_positioner()
    dm = WindowDataModule(data, scaling="paper")
    with pytest.raises(ConfigError, match=r"model.hysteresis='preisach'"):
        build_model({"name": "greybox", "hysteresis": "preisach"}, dm)
    with pytest.raises(ConfigError, match=r"objective='one_step'"):
        build_model({"name": "greybox", "objective": "one_step"}, dm)


def test_the_residual_network_learns_what_the_physics_lacks(tmp_path):
    """An asymmetric stroke (v² term) is outside the chain's structure: the residual network
    takes most of the error the physical model leaves; without it nothing changes."""
    data = make_default_dataset(
        effects={"creep": {"enabled": False}, "asymmetry": {"enabled": True}}, n_train=8000,
        test_frequencies=(10.0, 100.0), max_test_samples=3000, val_samples=4000)
    dm = WindowDataModule(data, scaling="paper")
    errors = {}
    for neurons in (0, 16):
        L.seed_everything(0)
        model = build_model({"name": "greybox", "residual_neurons": neurons}, dm,
                            trained_on={"fs": data.fs})
        fitted = fit(model, dm, TRAINER.with_changes(max_epochs=10), tmp_path / str(neurons)).model
        errors[neurons] = np.mean(rmse(free_run(fitted, data.test, dm.window), data.test,
                                       dm.window.first_target))
    assert errors[16] < 0.7 * errors[0], errors


def test_the_fitted_greybox_steps_in_onnx_as_it_simulates(fitted, tmp_path):
    """The exported simulation step, from the state at rest, reproduces the fitted model's
    free run of a test recording."""
    ort = optional_dependency("onnxruntime")
    from hysteresis_lab.models.export import export_onnx

    model, dm = fitted
    session = ort.InferenceSession(str(export_onnx(model, tmp_path / "greybox.onnx")))
    rec = dm.splits.test[0]
    state = np.zeros((1, len(model.state_names())))
    produced = np.empty_like(rec.y)
    for k, u in enumerate(rec.u):
        produced[k], state = session.run(None, {"state": state, "u": u[None]})
    expected = free_run(model, [rec], dm.window)[0]
    ft = dm.window.first_target
    np.testing.assert_allclose(produced[ft:], expected[ft:], rtol=0,
                               atol=1e-9 * np.max(np.abs(expected)))


def test_it_builds_for_slow_data():
    """Cascaded tanks sample at 0.25 Hz: the blocks' frequency floors follow fs (they were a
    fixed 1 Hz, above the tanks' Nyquist frequency, and the model could not be built)."""
    from hysteresis_lab.data.benchmarks import load_benchmark

    data = load_benchmark("cascaded_tanks")
    dm = WindowDataModule(data, scaling="standard")
    model = build_model({"name": "greybox"}, dm, trained_on={"fs": data.fs})
    model.initialise_from_data(data.train[0].u[:, 0], data.train[0].y[:, 0], data.fs)
    assert float(model.amplifier.cutoff_hz) < 0.5 * data.fs
