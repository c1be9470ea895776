"""Architectures, registry, training and save/load."""

from __future__ import annotations

import logging
import re

import lightning as L
import numpy as np
import pytest
import torch

from hysteresis_lab.errors import ConfigError, DataError
from hysteresis_lab.evaluation.predict import free_run, one_step
from hysteresis_lab.fitting import build_model, check_trainer_settings, fit
from hysteresis_lab.models.io import load_model, save_model
from hysteresis_lab.models.registry import available_models, get_model_class
from narx import CONFIGS, TRAINER, datamodule_for, narx_data


def test_builtin_models_register_through_entry_points():
    assert {"ffnn", "lstm", "cnn", "svm"} <= set(available_models())
    with pytest.raises(ConfigError, match=r"unknown model 'gpt'.*'cnn', 'ffnn'"):
        get_model_class("gpt")


def test_unknown_model_parameter_lists_valid_ones(splits):
    with pytest.raises(ConfigError, match="neuronz.*Valid:.*neurons"):
        build_model({"name": "ffnn", "neuronz": 3}, datamodule_for("ffnn", splits))


@pytest.mark.parametrize("name", ["ffnn", "lstm", "cnn", "svm"])
def test_training_lowers_the_loss(name, splits, trained):
    dm = datamodule_for(name, splits)
    dm.setup()
    x, target = dm.scale_windows(dm.val_windows)
    untrained = build_model(CONFIGS[name], dm)
    model = trained[name][0]

    def mse(m) -> float:
        if isinstance(m, torch.nn.Module):
            with torch.no_grad():
                return float(torch.mean((m(torch.from_numpy(x)) - torch.from_numpy(target)) ** 2))
        return float(np.mean((m.predict_scaled(x) - target) ** 2))

    before = mse(untrained) if name != "svm" else float(np.mean(target**2))
    assert mse(model) < 0.7 * before


class _StepLosses(L.Callback):
    """Records every training step's loss and batch size, per epoch."""

    def __init__(self) -> None:
        self.epochs: list[list[tuple[float, int]]] = []

    def on_train_epoch_start(self, trainer, pl_module) -> None:
        self.epochs.append([])

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        self.epochs[-1].append((float(outputs["loss"]), len(batch[0])))


def test_logged_training_loss_is_the_last_epochs_weighted_mean(splits):
    dm = datamodule_for("ffnn", splits)
    dm.batches_per_step = 1  # a Lightning step per batch: the callback sees every batch
    steps = _StepLosses()
    trainer = L.Trainer(**TRAINER.with_changes(max_epochs=2).trainer_arguments(), logger=False,
                        enable_checkpointing=False, callbacks=[steps])
    trainer.fit(build_model(CONFIGS["ffnn"], dm), datamodule=dm)

    def weighted_mean(rows: list[tuple[float, int]]) -> float:
        return sum(loss * size for loss, size in rows) / sum(size for _, size in rows)

    sizes = {size for _, size in steps.epochs[-1]}
    assert len(sizes) == 2  # a short last batch: an unweighted mean would differ
    logged = float(trainer.callback_metrics["train_loss"])
    assert logged == pytest.approx(weighted_mean(steps.epochs[-1]), rel=1e-5)
    assert logged != pytest.approx(weighted_mean(steps.epochs[0] + steps.epochs[1]), rel=1e-3)


def test_study_architectures_have_the_published_structure():
    ffnn = get_model_class("ffnn")(nu=1, ny=1)  # the study's optimum: 4 layers x 100
    linears = [m for m in ffnn.net if isinstance(m, torch.nn.Linear)]
    assert [m.out_features for m in linears] == [100, 100, 100, 1]
    assert linears[0].in_features == 20
    lstm = get_model_class("lstm")(nu=1, ny=1)
    assert lstm.net.lstm.num_layers == 2 and lstm.net.lstm.hidden_size == 66
    cnn = get_model_class("cnn")(nu=1, ny=1)
    convs = [m for m in cnn.net.conv if isinstance(m, torch.nn.Conv1d)]
    assert len(convs) == 2 and convs[0].kernel_size == (5,) and convs[0].out_channels == 83
    assert cnn(torch.zeros(3, 10, 2)).shape == (3, 1)


@pytest.mark.parametrize("name", ["ffnn", "lstm", "cnn", "svm"])
def test_save_and_load_round_trip(name, splits, trained, tmp_path):
    model, dm = trained[name]
    path = save_model(model, tmp_path / "model")
    loaded = load_model(path)
    np.testing.assert_allclose(
        one_step(loaded, splits.test, dm.window)[1],
        one_step(model, splits.test, dm.window)[1],
        atol=1e-6,
    )


def test_missing_and_corrupt_checkpoints(tmp_path):
    with pytest.raises(DataError, match="no checkpoint"):
        load_model(tmp_path / "absent.ckpt")
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(b"\x00garbage" * 50)
    with pytest.raises(DataError, match="corrupt"):
        load_model(bad)
    bad_svm = tmp_path / "bad.skops"
    bad_svm.write_bytes(b"not a zip")
    with pytest.raises(DataError, match="corrupt"):
        load_model(bad_svm)


def test_mimo_model_trains_and_simulates(tmp_path):
    splits = narx_data(n=800, nu=2, ny=1)
    dm = datamodule_for("lstm", splits)
    model = build_model(CONFIGS["lstm"], dm)
    result = fit(model, dm, TRAINER.with_changes(max_epochs=1), tmp_path)
    (y,) = free_run(result.model, splits.test[:1], dm.window)
    assert y.shape == splits.test[0].y.shape and np.all(np.isfinite(y))


def test_invalid_hyperparameters_are_config_errors():
    with pytest.raises(ConfigError, match="lr_schedule"):
        get_model_class("ffnn")(nu=1, ny=1, lr_schedule="step")
    with pytest.raises(ConfigError, match="num_layers > lstm_layers"):
        get_model_class("lstm")(nu=1, ny=1, num_layers=2, lstm_layers=2)
    with pytest.raises(ConfigError, match="kernel"):
        get_model_class("svm")(nu=1, ny=1, kernel="laplace")


@pytest.mark.parametrize(
    ("name", "bad", "fix"),
    [
        ("ffnn", {"neurons": 0}, "model.neurons=100"),
        ("lstm", {"units": 0}, "model.units=66"),
        ("cnn", {"units": 0}, "model.units=83"),
        ("svm", {"C": 0.0}, "model.C=10"),
    ],
)
def test_a_bad_model_size_names_the_setting_and_a_fix(name, bad, fix):
    setting = next(iter(bad))
    with pytest.raises(ConfigError, match=rf"{setting}=0.*Fix: .*{re.escape(fix)}"):
        get_model_class(name)(nu=1, ny=1, **bad)


def test_checking_trainer_settings_logs_no_lightning_lines():
    """The check builds a Trainer only to validate it: the device lines come from the fit.

    Lightning's logger does not propagate to the root logger (so not to caplog): a handler
    on it collects what it would print."""
    records: list[logging.LogRecord] = []
    handler = logging.Handler(logging.INFO)
    handler.emit = records.append
    lightning_log = logging.getLogger("lightning.pytorch")
    lightning_log.addHandler(handler)
    try:
        check_trainer_settings(TRAINER.with_changes(max_epochs=1))
        assert not records
        # the same Trainer built for real does log them
        L.Trainer(logger=False, enable_checkpointing=False, enable_progress_bar=False)
        assert any("GPU available" in r.getMessage() for r in records)
    finally:
        lightning_log.removeHandler(handler)
