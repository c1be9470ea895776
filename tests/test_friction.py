"""`friction`: Coulomb friction as a law of the velocity in the feedback of an integrating
``model=linear`` (EMPS), and its evidence in the diagnosis."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch

from cart import FS, cart_data
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.effects.friction import FrictionLaw
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.loop.diagnosis.ranking import diagnose
from hysteresis_lab.models.augment import augment_splits, context_to_dict, feature_context

TRAINER = TrainerSettings(max_epochs=20, accelerator="cpu", enable_progress_bar=False,
                          enable_model_summary=False)
COULOMB = 1.0  # the friction force, against forces of 1-3



def _fitted(data: DatasetSplits, effects: list[str], tmp_path):
    """``model=linear model.integrator=true`` with ``effects`` fitted on ``data``; the
    model and its free-run RMSE on the test recording."""
    augmented, context = augment_splits(data, effects)
    dm = WindowDataModule(augmented, scaling="standard")
    L.seed_everything(0)
    model = build_model({"name": "linear", "integrator": True, "effects": effects}, dm,
                        trained_on={"fs": FS}, feature_context=context_to_dict(context),
                        n_base_inputs=1)
    fitted = fit(model, dm, TRAINER, tmp_path).model
    test = augmented.test[0]
    ft = dm.window.first_target
    predicted = free_run(fitted, [test], dm.window)[0]
    return fitted, float(np.sqrt(np.mean((predicted[ft:] - test.y[ft:]) ** 2)))


def test_the_friction_law_is_a_tied_hinge_pair_against_the_motion():
    """One level: ``level clip(v / eps)``, zero at rest, odd, flat beyond ``±eps``."""
    law = FrictionLaw(0.1)
    assert [name for name, _ in law.named_parameters()] == ["level"]
    with torch.no_grad():
        law.level.fill_(0.5)
    knots = law.knots(torch.zeros((), dtype=torch.float64))
    v = torch.tensor([-1.0, -0.1, -0.05, 0.0, 0.05, 0.1, 1.0], dtype=torch.float64)
    hinges = torch.relu(v[:, None] - knots) - torch.relu(-knots)
    np.testing.assert_allclose((hinges @ law.weights).detach().numpy(),
                               [-0.5, -0.5, -0.25, 0.0, 0.25, 0.5, 0.5], atol=1e-12)


@pytest.mark.slow
def test_friction_is_named_on_a_coulomb_cart_and_its_law_fits_it(tmp_path):
    """On a cart with Coulomb friction the integrating linear model coasts where the cart
    stops: its free-run residual names friction (the direction of its own motion explains
    it), and with the friction law it learns a level against the motion and simulates the
    test record better."""
    data = cart_data(COULOMB, smallest_push=0.5)
    plain, without = _fitted(data, [], tmp_path / "plain")
    recordings = [data.val[0], data.test[0]]
    window = WindowDataModule(data, scaling="standard").window
    predictions = free_run(plain, recordings, window)
    residuals = [rec.y - p for rec, p in zip(recordings, predictions, strict=True)]
    ranked = {d.effect: d for d in diagnose(
        recordings, residuals, feature_context(data.train), declared=[], lags=(0, 2, 5, 10, 20),
        predictions=predictions, through_dynamics=True)}
    assert ranked["friction"].significant and ranked["friction"].score > 0.2
    model, error = _fitted(data, ["friction"], tmp_path / "friction")
    assert float(model.friction[0][0].level.detach()) > 0.05
    assert error < 0.8 * without


def test_model_linear_has_no_friction_block_without_an_integrator():
    """A law of the output's level is no friction: without an integrator the model is
    built without it (and the loop does not add it, `loop.driver._not_carried`)."""
    data = cart_data(COULOMB, smallest_push=0.5)
    augmented, context = augment_splits(data, ["friction"])
    dm = WindowDataModule(augmented, scaling="standard")
    model = build_model({"name": "linear", "integrator": False, "effects": ["friction"]}, dm,
                        trained_on={"fs": FS}, feature_context=context_to_dict(context),
                        n_base_inputs=1)
    assert not hasattr(model, "friction")
