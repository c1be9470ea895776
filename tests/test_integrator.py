"""`model=linear model.integrator=true`: the output integrates the dynamics' output (a
position from a force), for plants that do not settle at a held input (EMPS)."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch

from cart import FS, cart_data
from hysteresis_lab.api import compose, train
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.augment import augment_splits, context_to_dict, feature_context
from hysteresis_lab.models.linear import LinearModel

TRAINER = TrainerSettings(max_epochs=20, accelerator="cpu", enable_progress_bar=False,
                          enable_model_summary=False)



def _fitted(data: DatasetSplits, config: dict, tmp_path) -> tuple[LinearModel, float]:
    """The model fitted on ``data`` and its free-run RMSE on the test recording."""
    augmented, context = augment_splits(data, config.get("effects", []))
    dm = WindowDataModule(augmented, scaling="standard")
    L.seed_everything(0)
    model = build_model({"name": "linear", **config}, dm, trained_on={"fs": FS},
                        feature_context=context_to_dict(context), n_base_inputs=1)
    fitted = fit(model, dm, TRAINER, tmp_path).model
    ft = dm.window.first_target
    test = augmented.test[0]
    predicted = free_run(fitted, [test], dm.window)[0]
    return fitted, float(np.sqrt(np.mean((predicted[ft:] - test.y[ft:]) ** 2)))


def test_an_integrating_plant_is_simulated_with_an_integrator_and_not_without(tmp_path):
    """A cart's position: stable dynamics alone cannot follow it; with the integrator the
    linear model simulates it to a small share of its range."""
    data = cart_data()
    spread = float(np.std(data.test[0].y))
    with_integrator, error = _fitted(data, {"integrator": True}, tmp_path / "integrator")
    _, without = _fitted(data, {}, tmp_path / "plain")
    assert error < 0.05 * spread
    assert error < 0.2 * without
    assert with_integrator.physical_parameters()["integrator"] is True


def test_a_law_in_the_feedback_of_an_integrator_reads_the_integrand():
    """Friction is a law of the velocity, the integrand: the nonlinear feedback's knots
    spread over the output's steps in the integrand's unit (around zero, not over the
    output's levels) and read no output offset; weighted, the law changes the free run."""
    data = cart_data()
    augmented, context = augment_splits(data, ["nonlinear_feedback"])
    dm = WindowDataModule(augmented, scaling="standard")
    model = build_model({"name": "linear", "integrator": True, "effects": ["nonlinear_feedback"],
                         "feedback_knots": 3}, dm, trained_on={"fs": FS},
                        feature_context=context_to_dict(context), n_base_inputs=1)
    rec = augmented.train[0]
    model.initialise_from_data(rec.u[:, 0], rec.y[:, 0], FS)
    low, high = model._step_extremes(0)
    size = max(abs(low), abs(high))
    law = model.static_feedback[0][0]
    expected = (low + np.array([0.1, 0.475, 0.85]) * (high - low)) / size
    np.testing.assert_allclose(law.levels.numpy(), expected)
    assert low < 0.0 < high and float(model.step_scale[0]) == pytest.approx(size)
    assert abs(float(model.offset.detach()[0])) > 0.0
    np.testing.assert_allclose(law.knots(model._forced_offset(model.offset[0])).detach().numpy(),
                               expected)
    test = augmented.test[0]
    before = free_run(model, [test], dm.window)[0]
    with torch.no_grad():
        law.weights.fill_(0.3)
    after = free_run(model, [test], dm.window)[0]
    assert np.max(np.abs(after - before)) > 0.01 * np.std(test.y)


def test_the_integrand_unit_is_the_largest_step_of_the_training_output():
    """Built as the pipeline builds a model without effects (no feature context), the
    integrand's unit comes from the training recording at the start: its largest step."""
    data = cart_data()
    dm = WindowDataModule(data, scaling="standard")
    model = build_model({"name": "linear", "integrator": True}, dm, trained_on={"fs": FS})
    rec = data.train[0]
    model.initialise_from_data(rec.u[:, 0], rec.y[:, 0], FS)
    largest = np.max(np.abs(np.diff(rec.y[:, 0]))) / float(model.y_scale[0])
    assert float(model.step_scale[0]) == pytest.approx(largest)


def test_a_grown_integrator_model_starts_where_the_fitted_one_ended(tmp_path):
    """The loop grows a fitted model by an effect: the grown model keeps the integrand's unit
    of the fitted one (here its context spans other recordings, whose steps are larger) and
    simulates exactly what the fitted one did."""
    data = cart_data()
    fitted, _ = _fitted(data, {"integrator": True}, tmp_path)
    wider = DatasetSplits("cart", train=[*data.train, *data.test], val=data.val, test=data.test)
    augmented, context = augment_splits(wider, ["nonlinear_feedback"])
    dm = WindowDataModule(augmented, scaling="standard")
    grown = build_model({"name": "linear", "integrator": True, "effects": ["nonlinear_feedback"]},
                        dm, trained_on={"fs": FS}, feature_context=context_to_dict(context),
                        n_base_inputs=1)
    assert float(grown.step_scale[0]) != pytest.approx(float(fitted.step_scale[0]))
    grown.y_scale.copy_(fitted.y_scale)  # the same scaler, as in the loop
    grown.y_offset.copy_(fitted.y_offset)
    grown.u_scale.copy_(fitted.u_scale)
    grown.u_offset.copy_(fitted.u_offset)
    grown.warm_start_from(fitted)
    before = free_run(fitted, data.test, dm.window)[0]
    after = free_run(grown, augmented.test, dm.window)[0]
    np.testing.assert_allclose(after, before, atol=1e-9 * np.max(np.abs(before)))


def test_the_steps_of_the_output_are_kept_with_the_model():
    """The feature context records the output's smallest and largest step per sample,
    through its saved form too."""
    y = np.array([0.0, 1.0, 3.0, 2.5])
    ctx = feature_context([Recording(u=np.zeros((4, 1)), y=y[:, None], fs=1.0, name="r")])
    assert ctx.dy_low.tolist() == [-0.5] and ctx.dy_high.tolist() == [2.0]
    assert context_to_dict(ctx)["dy_high"] == [2.0]


@pytest.mark.parametrize(("settings", "message"), [
    ({"integrator": "yes"}, "model.integrator='yes'"),
    ({"integrator": True, "feedback_on": "output_stage"}, "feedback_on=output_stage"),
])
def test_bad_integrator_settings_are_refused(settings, message):
    data = cart_data()
    dm = WindowDataModule(data, scaling="standard")
    with pytest.raises(ConfigError, match=message):
        build_model({"name": "linear", **settings}, dm, trained_on={"fs": FS})


def test_an_integrator_is_refused_where_recordings_share_an_unknown_start():
    data = cart_data()
    dm = WindowDataModule(data, scaling="standard")
    with pytest.raises(ConfigError, match="never settles"):
        build_model({"name": "linear", "integrator": True}, dm,
                    trained_on={"fs": FS, "shared_initial_state": True})


def test_the_loop_keeps_the_forces_on_the_integrand():
    """A loop refit that adds a storage's law to a fitted model tries the output stage too,
    but not with an integrator: its forces read the integrand."""
    data = cart_data()
    dm = WindowDataModule(data, scaling="standard")
    for integrator, places in ((False, ["dynamics", "output_stage"]), (True, ["dynamics"])):
        previous = build_model({"name": "linear", "integrator": integrator}, dm,
                               trained_on={"fs": FS})
        variants = LinearModel.refit_variants({"integrator": integrator, "order": 6}, previous,
                                              "nonlinear_feedback")
        assert [v["feedback_on"] for v in variants] == places


def test_on_emps_the_data_set_says_its_output_integrates_and_the_model_follows(tmp_path):
    """Measured data (EMPS, a force moving a cart): by default the linear model carries the
    integrator the data set declares, and the same short training simulates the pulses test
    record several times closer than the stable model (``model.integrator=false``)."""
    rmse, models = {}, {}
    for name, overrides in (("default", []), ("stable", ["model.integrator=false"])):
        cfg = compose("model=linear", "data=emps", *overrides, "trainer.max_epochs=30",
                      "logger=none", "trainer.enable_progress_bar=false")
        L.seed_everything(0)
        result = train(cfg, tmp_path / name)
        rmse[name] = result.evaluation.metrics["emps_test_pulses"]["rmse_free_run"]
        models[name] = result.model
    assert models["default"].integrator and not models["stable"].integrator
    assert rmse["default"] < 0.25 * rmse["stable"]


def test_other_data_keep_the_stable_model_by_default():
    data = cart_data()
    assert not data.output_integrates
    dm = WindowDataModule(data, scaling="standard")
    assert not build_model({"name": "linear"}, dm, trained_on={"fs": FS}).integrator
