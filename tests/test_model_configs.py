"""The networks' shared settings live once, in ``conf/model/_network.yaml``."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

REPO = Path(__file__).resolve().parents[1]
CONF = REPO / "src" / "hysteresis_lab" / "conf"
GRU_CONF = REPO / "plugins" / "hysteresis_lab_gru" / "src" / "hysteresis_lab_gru" / "conf"
SHARED = OmegaConf.to_container(OmegaConf.load(CONF / "model" / "_network.yaml"))


def composed_model(model: str, *overrides: str) -> dict:
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose("train", [f"model={model}", *overrides])
    return OmegaConf.to_container(cfg.model)


@pytest.mark.parametrize(("model", "own"), [
    ("ffnn", {}), ("lstm", {}), ("cnn", {}), ("subnet", {}),
])
def test_every_network_gets_the_shared_settings_and_keeps_its_own(model, own):
    cfg = composed_model(model)
    assert cfg["name"] == model
    assert {k: cfg[k] for k in SHARED} == {**SHARED, **own}


def test_the_example_plugin_takes_the_shared_settings_too():
    cfg = composed_model("gru", f"hydra.searchpath=[file://{GRU_CONF}]")
    assert cfg["name"] == "gru" and cfg["units"] == 64
    assert {k: cfg[k] for k in SHARED} == SHARED


def test_a_network_config_sets_no_shared_setting_itself_unless_it_differs():
    for model in ("ffnn", "lstm", "cnn"):
        own = OmegaConf.load(CONF / "model" / f"{model}.yaml")
        assert not set(own) & set(SHARED), model


def test_training_settings_are_their_own_group_not_the_models():
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose("train", ["model=greybox"])
    assert "lr" not in cfg.model and "objective" not in cfg.model
    # unset: each model's own defaults (its class states them)
    assert set(OmegaConf.to_container(cfg.training).values()) == {None}
