"""`ModelSpec`: a model config as an object, its class looked up once; training settings
apart from it (the ``training`` group), the old ``model.*`` keys still taking effect."""

from __future__ import annotations

import logging

import pytest

import hysteresis_lab as hl
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.lstm import LSTMNet
from hysteresis_lab.models.settings import TrainingSettings
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.models.svm import SVMModel
from hysteresis_lab.workflows.pipeline import RunConfig


def test_a_spec_knows_its_class_layout_kind_and_effects():
    lstm = ModelSpec.from_config({"name": "lstm", "effects": ["creep"], "units": 8})
    assert lstm.cls is LSTMNet and lstm.layout == "sequence" and lstm.is_network
    assert lstm.effects == ["creep"] and lstm.settings == {"effects": ["creep"], "units": 8}
    assert lstm.to_config() == {"name": "lstm", "effects": ["creep"], "units": 8}
    svm = ModelSpec.from_config({"name": "svm"})
    assert svm.cls is SVMModel and svm.layout == "flat" and not svm.is_network
    assert svm.effects == []


def test_a_run_config_holds_a_spec_built_from_its_model_config(tmp_path):
    config = RunConfig.build({"name": "ffnn"}, {}, {}, tmp_path, {"lr": 3e-4})
    assert isinstance(config.model, ModelSpec) and config.model_name == "ffnn"
    assert config.training == TrainingSettings(lr=3e-4)
    # made from objects, unset training settings are the model's own too
    greybox = RunConfig(ModelSpec.from_config({"name": "greybox"}), config.data,
                        config.trainer, tmp_path)
    assert greybox.training.lr == 0.02 and greybox.training.objective == "simulation"


def test_unset_training_settings_are_the_models_own():
    # the class states its defaults; the training group's nulls leave them
    greybox = ModelSpec.from_config({"name": "greybox"}).training_settings({"lr": None})
    assert greybox.lr == 0.02 and greybox.objective == "simulation"
    ffnn = ModelSpec.from_config({"name": "ffnn"}).training_settings({"horizon": 50})
    assert ffnn == TrainingSettings(horizon=50)
    with pytest.raises(ConfigError, match=r"unknown training setting\(s\) \['lrr'\]"):
        ModelSpec.from_config({"name": "ffnn"}).training_settings({"lrr": 1.0})


def test_a_training_setting_under_model_still_takes_effect_and_warns(caplog):
    with caplog.at_level(logging.WARNING):
        spec = ModelSpec.from_config({"name": "ffnn", "lr": 0.005, "objective": "simulation"})
    assert "lr" not in spec.settings and spec.training_settings({"lr": 0.1}).lr == 0.005
    assert spec.training_settings().objective == "simulation"
    said = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("model.lr is deprecated" in m and "training.lr=0.005" in m for m in said)


def test_the_old_model_lr_override_still_takes_effect_and_warns(caplog, tmp_path):
    with caplog.at_level(logging.WARNING):
        cfg = hl.compose("model=greybox", "model.lr=0.05")
    assert cfg.training.lr == 0.05 and "lr" not in cfg.model
    assert RunConfig.from_config(cfg, tmp_path).training.lr == 0.05
    said = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("model.lr is deprecated" in m and "training.lr=0.05" in m for m in said)


@pytest.mark.parametrize(("config", "says"), [({}, "no 'name'"), ({"name": "nope"}, "nope")])
def test_a_bad_model_config_is_refused_where_the_spec_is_built(config, says):
    with pytest.raises(ConfigError, match=says):
        ModelSpec.from_config(config)


def test_a_spec_travels_to_another_process_by_its_registered_name():
    import pickle

    spec = ModelSpec.from_config({"name": "lstm", "units": 8})
    LSTMNet.registry_name = ""  # a fresh process: the class not yet named by the registry
    again = pickle.loads(pickle.dumps(spec))
    assert again == spec and again.cls.registry_name == "lstm"
