"""``model.baseline``: a network reads a fitted model's free run as an extra input, keeps it
in its saved model, and the wrong uses are refused with a fix."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import hysteresis_lab as hl
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.errors import ConfigError, DataError
from hysteresis_lab.loop.driver import LoopSettings, run_loop
from hysteresis_lab.models.augment import for_model
from hysteresis_lab.models.io import load_baseline, load_model
from hysteresis_lab.workflows.pipeline import (
    RunConfig,
    _fit_record_key,
    run_model,
)
from narx import TRAINER, narx_data

DATA = DataSpec.from_config({"window": {"na": 4, "nb": 4, "nk": 1},
                             "scaling": {"mode": "standard"}})
SUBNET = {"name": "subnet", "nx": 4, "neurons": 16, "hidden_layers": 1, "encoder_neurons": 16,
          "encoder_layers": 1}
SUBNET_TRAINING = {"horizon": 50, "lr": 1e-3}


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """The NARX data set, a linear baseline fitted on it, and SUBNET augmenting it."""
    root = tmp_path_factory.mktemp("baseline")
    splits = narx_data(800)
    base = run_model(RunConfig.build({"name": "linear", "effects": []}, DATA,
                                     TRAINER.with_changes(max_epochs=2), root / "linear",
                                     {"lr": 0.02}, use_tensorboard=False, plots=False),
                     splits=splits)
    augmented = run_model(RunConfig.build({**SUBNET, "baseline": str(root / "linear")}, DATA,
                                          TRAINER.with_changes(max_epochs=2),
                                          root / "augmented", SUBNET_TRAINING,
                                          use_tensorboard=False, plots=False), splits=splits)
    return splits, base, augmented, root


def test_the_network_reads_the_baseline_free_run_and_keeps_it_in_its_file(fitted):
    splits, base, augmented, root = fitted
    model = augmented.model
    assert model.nu == splits.nu + splits.ny
    assert model.baseline.source == str(root / "linear" / "model.ckpt")
    expected = hl.simulate(base.model, splits.test)
    seen = [rec.u[:, -1] for rec in for_model(model, splits.test)]
    for y_base, channel in zip(expected, seen, strict=True):
        np.testing.assert_allclose(channel, y_base[:, 0], rtol=1e-12, atol=1e-12)

    # the saved file carries the baseline: a loaded model scores as the run did, on the
    # measured recordings alone, with the baseline's run folder gone
    (root / "linear" / "model.ckpt").rename(root / "linear" / "moved.ckpt")
    try:
        loaded = load_model(root / "augmented" / "model.ckpt")
    finally:
        (root / "linear" / "moved.ckpt").rename(root / "linear" / "model.ckpt")
    assert loaded.baseline is not None and loaded.baseline.digest == model.baseline.digest
    scores = hl.evaluate(loaded, splits.test).metrics
    written = json.loads((root / "augmented" / "metrics.json").read_text())["tests"]
    for name, metrics in scores.items():
        assert metrics["rmse_free_run"] == pytest.approx(written[name]["rmse_free_run"],
                                                         rel=1e-6)


def test_wrong_uses_of_a_baseline_are_refused_with_a_fix(fitted, tmp_path):
    splits, _, _, root = fitted
    with pytest.raises(ConfigError, match="no fitted model there.*Fix: train the baseline"):
        run_model(RunConfig.build({**SUBNET, "baseline": str(tmp_path / "nothing")}, DATA,
                                  TRAINER, tmp_path / "run", use_tensorboard=False),
                  splits=splits)
    with pytest.raises(ConfigError, match="is for the networks.*Fix"):
        run_model(RunConfig.build({"name": "linear", "baseline": str(root / "linear")}, DATA,
                                  TRAINER, tmp_path / "run", use_tensorboard=False),
                  splits=splits)
    with pytest.raises(ConfigError, match="the loop grows a model.*Fix"):
        run_loop({**SUBNET, "effects": [], "baseline": str(root / "linear")}, DATA, TRAINER,
                 splits, tmp_path / "loop", LoopSettings(max_rounds=0), use_tensorboard=False,
                 plots=False)
    two_inputs = Recording(u=np.zeros((100, 2)), y=np.zeros((100, 1)), fs=100.0, name="two")
    with pytest.raises(DataError, match="has 2 measured input.*reads 1"):
        load_baseline(root / "linear").channels_for([two_inputs])


def test_declared_effects_and_a_baseline_each_get_their_own_channels(fitted, tmp_path):
    """Effect operators come after the measured input and the baseline's free run last: on
    the linear effect path only the operators' lags get the linear map, the baseline's
    channel goes to the network."""
    splits, _, _, root = fitted
    ffnn = {"name": "ffnn", "num_layers": 3, "neurons": 16, "effects": ["hysteresis"],
            "effect_path": "linear", "baseline": str(root / "linear")}
    model = run_model(RunConfig.build(ffnn, DATA, TRAINER.with_changes(max_epochs=1),
                                      tmp_path / "ffnn", use_tensorboard=False, plots=False),
                      splits=splits).model
    operators = model.nu - 2
    assert operators == 8 and model.n_base_inputs == 1
    nb = DATA.window.nb
    assert int(model.effect_mask.sum()) == operators * nb  # the operators' lags only
    baseline_columns = [lag * model.nu + model.nu - 1 for lag in range(nb)]
    assert model.net_mask[baseline_columns].tolist() == [1.0] * nb
    loaded = load_model(tmp_path / "ffnn" / "model.ckpt")
    assert [r.u.shape[1] for r in for_model(loaded, splits.test)] == [model.nu] * 2


def test_a_finished_fit_is_reused_only_with_the_same_baseline(fitted):
    splits, _, _, root = fitted
    config = RunConfig.build({**SUBNET, "baseline": str(root / "linear")}, DATA, TRAINER,
                             root / "unused", SUBNET_TRAINING, reuse=True)
    baseline = load_baseline(root / "linear")
    refitted = dataclasses.replace(baseline, payload=baseline.payload + b"another fit")
    key = _fit_record_key(config, splits, None, baseline)
    assert key == _fit_record_key(config, splits, None, load_baseline(root / "linear"))
    assert key != _fit_record_key(config, splits, None, refitted)
