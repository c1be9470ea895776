"""The declared model interface, checked when the registry loads an entry point."""

from __future__ import annotations

import textwrap
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
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
from hysteresis_lab.models.settings import TrainingSettings
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


GRU_SRC = Path(__file__).resolve().parents[1] / "plugins" / "hysteresis_lab_gru" / "src"


def test_a_plain_third_party_network_gets_every_capability_of_the_contract_by_default(
    monkeypatch,
):
    monkeypatch.syspath_prepend(str(GRU_SRC))
    from hysteresis_lab_gru.model import GRUNet

    # what the loop, growing and training read off the class
    assert GRUNet.is_network and GRUNet.warm_starts and not GRUNet.simulation_trained
    assert GRUNet.carried_effects is None and GRUNet.whole_refit_effects == ()
    assert GRUNet.predicts_from_outputs and not GRUNet.whole_recordings
    assert GRUNet.built_in_effects({"effects": ["creep"]}) == ()
    assert GRUNet.refit_variants({"name": "gru"}, None, "creep") == [{}]
    assert GRUNet.growth_stages({"effects": ["creep"]}) == [
        ("declared", {"effects": ["creep"]}, None)]
    assert GRUNet.training_defaults() == TrainingSettings().to_dict()
    assert {"units", "gru_layers", "lr", "effects", "na"} <= GRUNet.settings_keys()
    # what the evaluation and the warm start read off a model
    model = GRUNet(nu=1, ny=1, na=2, nb=2, units=4)
    u = np.zeros((1, 12, 1))
    assert model.free_run_kernel(u, model.window) is None and not model.simulates_recordings
    assert model.free_run_split(u)[1] is None and model.baseline is None
    assert model.new_entries is None and not model.warm_started
    assert model.hparams["lr"] == 1e-3 and model.hparams["units"] == 4
    grown = GRUNet(nu=1, ny=1, na=2, nb=2, units=4)
    grown.warm_start_from(model)
    assert grown.new_entries == {} and grown.warm_started


def test_an_estimator_refuses_what_it_cannot_do_with_the_fix():
    svm = SVMModel(nu=1, ny=1)
    assert not svm.is_network and not svm.warm_starts and svm.new_entries is None
    with pytest.raises(ConfigError, match="loop.warm_start=false"):
        svm.warm_start_from(svm)
    with pytest.raises(ConfigError, match="cannot be exported"):
        svm.export_onnx("unused.onnx")


def test_a_complete_class_outside_the_contract_is_refused(tmp_path, monkeypatch):
    install_plugin(tmp_path, monkeypatch, "bare_models", """
        class BareEstimator:
            layout = "flat"

            def fit(self, x, target):
                return self

            def predict_scaled(self, x):
                return x[:, :1]

            def predict_physical(self, u_past, y_past):
                return y_past[:, -1]
    """, {"bare": "BareEstimator"})
    with pytest.raises(ConfigError, match=r"does not subclass .*ModelContract.*Fix: subclass"):
        get_model_class("bare")
