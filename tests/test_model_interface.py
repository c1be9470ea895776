"""The declared model interface, checked when the registry loads an entry point."""

from __future__ import annotations

import textwrap
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.base import NarxModule
from hysteresis_lab.models.interface import (
    EstimatorModel,
    NetworkModel,
    class_members,
    missing_members,
)
from hysteresis_lab.models.registry import available_models, get_model_class
from hysteresis_lab.models.svm import SVMModel


def install_plugin(root: Path, monkeypatch, module: str, source: str, entries: dict) -> None:
    """A plugin distribution on ``sys.path``: ``module`` and its model entry points, found
    by the standard entry-point discovery the registry uses."""
    (root / f"{module}.py").write_text(textwrap.dedent(source))
    dist = root / f"{module}-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {module}\nVersion: 0.1\n")
    lines = "".join(f"{name} = {module}:{cls}\n" for name, cls in entries.items())
    (dist / "entry_points.txt").write_text("[hysteresis_lab.models]\n" + lines)
    monkeypatch.syspath_prepend(str(root))


def test_the_built_in_models_declare_the_interface_they_implement():
    # explicit: the classes name their interface (protocols with attributes refuse issubclass)
    assert EstimatorModel in SVMModel.__mro__ and NetworkModel in NarxModule.__mro__
    assert missing_members(SVMModel, EstimatorModel) == []
    assert missing_members(NarxModule, NetworkModel) == []
    assert {"fit", "predict_scaled", "predict_physical", "layout"} <= class_members(EstimatorModel)
    assert {"warm_start_from", "simulation_horizon"} <= class_members(NetworkModel)
    built_in = [ep.name for ep in entry_points(group="hysteresis_lab.models")
                if ep.dist is not None and ep.dist.name == "hysteresis-lab"]
    assert set(built_in) <= set(available_models()) and "linear" in built_in
    for name in built_in:  # plugins installed on the machine are not this package's to check
        get_model_class(name)  # each passes the check


def test_a_plugin_model_lacking_methods_is_refused_naming_them_and_its_entry_point(
    tmp_path, monkeypatch
):
    install_plugin(tmp_path, monkeypatch, "half_models", """
        import lightning as L

        class HalfEstimator:
            layout = "flat"

            def fit(self, x, target):
                return self

        class HalfNetwork(L.LightningModule):
            layout = "sequence"
            simulation_trained = False

            def predict_physical(self, u_past, y_past):
                return y_past[:, -1]
    """, {"half_svr": "HalfEstimator", "half_net": "HalfNetwork"})
    with pytest.raises(ConfigError, match=(
        r"model 'half_svr' \(half_models.HalfEstimator, registered by 'half_models' \(entry "
        r"point half_svr = half_models:HalfEstimator\)\) does not implement .*EstimatorModel "
        r"interface: it lacks predict_physical, predict_scaled\. Fix: add them"
    )):
        get_model_class("half_svr")
    with pytest.raises(ConfigError, match=(
        r"model 'half_net' .*NetworkModel interface: it lacks simulation_horizon, "
        r"train_new_inputs_only, training_settings, warm_start_from\. Fix:.*NarxModule"
    )):
        get_model_class("half_net")


def test_a_plugin_network_built_on_narx_module_passes(tmp_path, monkeypatch):
    install_plugin(tmp_path, monkeypatch, "whole_models", """
        from hysteresis_lab.models.ffnn import FFNN

        class Wide(FFNN):
            pass
    """, {"wide": "Wide"})
    cls = get_model_class("wide")
    assert cls.__name__ == "Wide" and cls.registry_name == "wide"
