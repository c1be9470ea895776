"""A plugin effect (one file, one entry point: plugins/hysteresis_lab_cubic) works in the
simulator, the diagnosis and ``model=linear``.

The plugin is installed as a real distribution: a ``*.dist-info`` with ``entry_points.txt``
beside the plugin's source on ``sys.path`` (and ``PYTHONPATH`` for the console app), found by
the standard entry-point discovery.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import REPO, data_overrides, run_app, small_dataset
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.effects.registry import available_effects
from hysteresis_lab.loop.diagnosis.ranking import diagnose
from hysteresis_lab.models.io import load_model
from hysteresis_lab.models.linear import LinearModel
from hysteresis_lab.signals import multisine
from hysteresis_lab.sim import Positioner

PLUGIN_SRC = REPO / "plugins" / "hysteresis_lab_cubic" / "src"
FS = 2000.0
QUIET = {"creep": {"enabled": False}, "noise": {"enabled": False},
         "quantisation": {"enabled": False}, "mode1": {"frequency_hz": 300.0}}


def install_plugin(root: Path) -> Path:
    """The distribution ``hysteresis-lab-cubic`` (its metadata in ``root``, its code in the
    repository's plugins/ folder)."""
    dist = root / "hysteresis_lab_cubic-0.1.0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: hysteresis-lab-cubic\n"
                                   "Version: 0.1.0\n")
    (dist / "entry_points.txt").write_text(
        "[hysteresis_lab.effects]\ncubic = hysteresis_lab_cubic.effect:CubicInput\n")
    return root


@pytest.fixture
def plugin(tmp_path, monkeypatch) -> Path:
    root = install_plugin(tmp_path / "site")
    monkeypatch.syspath_prepend(str(PLUGIN_SRC))
    monkeypatch.syspath_prepend(str(root))
    return root


def test_the_simulator_runs_the_plugin_block(plugin):
    u = 90.0 * np.sin(2 * np.pi * 2.0 * np.arange(4000) / FS)
    plain = Positioner(QUIET).simulate(u, FS)
    cubic = Positioner({**QUIET, "cubic": {"enabled": True, "coefficient": 0.2}}).simulate(u, FS)
    assert Positioner({**QUIET, "cubic": {"enabled": False}}).simulate(u, FS) == \
        pytest.approx(plain, abs=0)
    # the drive's cube adds most at the peaks: 0.2 * 100 V * 0.9^3 of drive, ~0.23 um/V
    assert np.max(np.abs(cubic)) - np.max(np.abs(plain)) > 0.5 * 0.2 * 100 * 0.9**3 * 0.23
    assert "cubic" in Positioner({**QUIET, "cubic": {"enabled": True}}).config.enabled_blocks()


def test_the_diagnosis_scores_the_plugin_effect(plugin):
    assert "cubic" in available_effects()
    u = multisine(8000, fs=FS, n_components=40, f_max=20.0, seed=3)
    u = 90.0 * u / np.max(np.abs(u))
    config = {**QUIET, "hysteresis": {"enabled": False}, "mode1": {"enabled": False},
              "amplifier": {"enabled": False}, "input_delay": {"enabled": False}}
    plain = Positioner(config).simulate(u, FS)
    cubic = Positioner({**config, "cubic": {"enabled": True, "coefficient": 0.3}}).simulate(u, FS)
    rec = Recording(u=u, y=cubic, fs=FS, name="cubic")
    context = FeatureContext(FS, np.array([90.0]), len(u) / FS)
    ranked = diagnose([rec], [(cubic - plain)[:, None]], context, declared=[],
                      candidates=["cubic", "drift", "dead_zone"])
    scores = {r.effect: r for r in ranked}
    # the cube beyond what the baseline (linear in the input) explains of it
    assert scores["cubic"].significant and scores["cubic"].score > 0.2
    assert ranked[0].effect == "cubic"


def test_model_linear_carries_and_trains_the_plugin_block(plugin, tmp_path):
    assert "cubic" in LinearModel.carried_effects
    train, tests = small_dataset(tmp_path, effects={"creep": {"enabled": False},
                                                    "cubic": {"enabled": True,
                                                              "coefficient": 0.3}})
    env = {"PYTHONPATH": os.pathsep.join([str(plugin), str(PLUGIN_SRC),
                                          os.environ.get("PYTHONPATH", "")])}
    result = run_app("train", "model=linear", "model.effects=[cubic]", "model.grow=false",
                     *data_overrides(train, tests), "trainer.max_epochs=3", "logger=none",
                     f"hydra.run.dir={tmp_path / 'run'}", env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    model = load_model(tmp_path / "run" / "model.ckpt")
    network = model.network if hasattr(model, "network") else model
    block = network.input_blocks[0]["cubic"]
    assert float(block.weight.detach()) != 0.0  # trained from zero
    v = torch.linspace(-2.0, 2.0, 200, dtype=torch.float64)[None, :, None]
    with torch.no_grad():
        trained = network.simulate_full(v)
        block.weight.zero_()
        assert not torch.allclose(network.simulate_full(v), trained)  # it is in the chain
