"""A network's settings, grouped and checked once (`hysteresis_lab.models.settings`)."""

from __future__ import annotations

import pytest

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.ffnn import FFNN
from hysteresis_lab.models.settings import EffectSettings, TrainingSettings


def test_each_stage_learning_rate_is_decided_by_the_settings():
    plain = TrainingSettings(lr=2e-3)
    assert plain.stage_lr("one_step") == plain.stage_lr("simulation") == 2e-3
    assert plain.stage_lr("fine_tune") == pytest.approx(2e-4)  # simulation_lr unset: lr / 10
    assert plain.stage_lr("one_step", refit=True) == pytest.approx(2e-4)  # refit_lr unset
    assert plain.stage_lr("fine_tune", refit=True) == pytest.approx(2e-5)
    chosen = TrainingSettings(lr=2e-3, refit_lr=5e-4, simulation_lr=3e-4)
    assert chosen.stage_lr("one_step", refit=True) == 5e-4
    assert chosen.stage_lr("fine_tune", refit=True) == 3e-4


def test_a_model_keeps_the_settings_its_hparams_save():
    model = FFNN(nu=1, ny=1, lr=4e-4, objective="simulation", horizon=50, patience=3)
    assert model.training_settings == TrainingSettings.from_hparams(model.hparams)
    assert model.simulation_horizon == 50
    assert FFNN(nu=1, ny=1, horizon=50).simulation_horizon == 0  # one-step objective


@pytest.mark.parametrize(
    ("settings", "names"),
    [
        ({"lr": 0.0}, "training.lr"),
        ({"lr_schedule": "linear"}, "lr_schedule"),
        ({"objective": "free_run"}, "training.objective"),
        ({"objective": "simulation", "horizon": 0}, "horizon=0"),
        ({"patience": 0}, "training.patience"),
        ({"refit_lr": -1.0}, "training.refit_lr"),
    ],
)
def test_bad_training_settings_are_refused_naming_the_setting(settings, names):
    with pytest.raises(ConfigError, match=names.replace(".", r"\.")):
        TrainingSettings(**settings)


def test_effect_settings_are_checked_against_the_inputs():
    with pytest.raises(ConfigError, match="feature_context"):
        EffectSettings(("creep",)).checked(nu=2)
    with pytest.raises(ConfigError, match="effect_path"):
        EffectSettings(effect_path="side").checked(nu=1)
    with pytest.raises(ConfigError, match="n_base_inputs=3"):
        EffectSettings(n_base_inputs=3).checked(nu=2)
