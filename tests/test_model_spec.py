"""`ModelSpec`: a model config as an object, its class looked up once."""

from __future__ import annotations

import pytest

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.lstm import LSTMNet
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.models.svm import SVMModel
from hysteresis_lab.workflows.pipeline import RunConfig


def test_a_spec_knows_its_class_layout_kind_and_effects():
    lstm = ModelSpec.from_config({"name": "lstm", "effects": ["creep"], "lr": 1e-3})
    assert lstm.cls is LSTMNet and lstm.layout == "sequence" and lstm.is_network
    assert lstm.effects == ["creep"] and lstm.settings == {"effects": ["creep"], "lr": 1e-3}
    assert lstm.to_config() == {"name": "lstm", "effects": ["creep"], "lr": 1e-3}
    svm = ModelSpec.from_config({"name": "svm"})
    assert svm.cls is SVMModel and svm.layout == "flat" and not svm.is_network
    assert svm.effects == [] and ModelSpec.from_config(svm) is svm


def test_a_run_config_holds_a_spec_built_from_its_model_config(tmp_path):
    config = RunConfig({"name": "ffnn", "lr": 1e-3}, {}, {}, tmp_path)
    assert isinstance(config.model, ModelSpec) and config.model_name == "ffnn"


@pytest.mark.parametrize(("config", "says"), [({}, "no 'name'"), ({"name": "nope"}, "nope")])
def test_a_bad_model_config_is_refused_where_the_spec_is_built(config, says):
    with pytest.raises(ConfigError, match=says):
        ModelSpec.from_config(config)
