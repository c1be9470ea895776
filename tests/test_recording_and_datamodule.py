"""Recording validation, scaling and the DataModules' split sizes and shapes."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from conftest import make_recording
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.factory import build_datamodule
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.scaling import PAPER_U_SCALE, PAPER_Y_SCALE, Scaler, ScalingSettings
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.data.windows import WindowSpec, make_windows
from hysteresis_lab.errors import ConfigError, DataError


@pytest.mark.parametrize(
    ("u", "y", "fs", "message"),
    [
        (np.r_[0.0, np.nan, 1.0], np.zeros(3), 1.0, "NaN/inf .* row 2 \\(1-based\\)"),
        (np.r_[0.0, np.inf, 1.0], np.zeros(3), 1.0, "NaN/inf"),
        (np.zeros(4), np.zeros(3), 1.0, "u has 4 samples but y has 3"),
        (np.zeros((2, 2, 2)), np.zeros(2), 1.0, "shape"),
        (np.zeros(0), np.zeros(0), 1.0, "no samples"),
        (np.zeros(3), np.zeros(3), -5.0, "sampling rate"),
        (["a", "b"], np.zeros(2), 1.0, "not numeric"),
    ],
)
def test_recording_rejects_bad_input(u, y, fs, message):
    with pytest.raises(DataError, match=message) as info:
        Recording(u=u, y=y, fs=fs, name="bad")
    assert "recording 'bad'" in str(info.value)
    assert "Fix:" in str(info.value)


def test_recording_keeps_callers_array_writable():
    u = np.zeros(5)
    Recording(u=u, y=np.zeros(5), fs=1.0)
    u[0] = 1.0  # would raise if the recording froze the caller's array


def test_different_sampling_rates_are_rejected():
    a = make_recording(50, "a", fs=1000.0)
    b = make_recording(50, "b", fs=500.0)
    with pytest.raises(
        DataError, match="recording 'b'.*500 Hz differs from 1000 Hz of recording 'a'"
    ):
        DatasetSplits("mixed", train=[a], test=[b])


def test_paper_and_standard_scaling():
    rec = Recording(u=np.linspace(-100, 100, 11), y=np.linspace(-20, 20, 11) + 3.0, fs=1.0)
    paper = Scaler.fit([rec], "paper")
    assert paper.u_scale[0] == 100.0 and paper.y_scale[0] == 20.0 and paper.y_offset[0] == 0.0
    standard = Scaler.fit([rec], "standard")
    assert standard.y_offset[0] == pytest.approx(3.0)
    assert standard.y_scale[0] == pytest.approx(rec.y.std())
    restored = Scaler.from_dict(standard.to_dict())
    for name in ("u_offset", "u_scale", "y_offset", "y_scale"):
        np.testing.assert_allclose(getattr(restored, name), getattr(standard, name))
    with pytest.raises(ConfigError, match="unknown scaling mode"):
        Scaler.fit([rec], "minmax")


def test_the_scaling_defaults_are_set_once():
    """The packaged config states the code's constants; a config without them gets them."""
    window_yaml = Path(__file__).resolve().parents[1] / "src/hysteresis_lab/conf/data/_window.yaml"
    packaged = ScalingSettings.from_config(OmegaConf.load(window_yaml).scaling)
    assert packaged == ScalingSettings() == ScalingSettings("paper", PAPER_U_SCALE, PAPER_Y_SCALE)
    assert ScalingSettings.from_config({"mode": "none"}) == ScalingSettings(mode="none")
    rec = Recording(u=np.linspace(-1, 1, 40), y=np.linspace(0, 2, 40), fs=1.0)
    splits = DatasetSplits(name="d", train=[rec], val=[], test=[])
    scaler = build_datamodule(DataSpec.from_config({}), "flat", splits=splits).scaler
    assert (scaler.u_scale[0], scaler.y_scale[0]) == (PAPER_U_SCALE, PAPER_Y_SCALE)


def test_random_90_10_split_of_windows():
    train = make_recording(1010, "train")
    splits = DatasetSplits("d", train=[train], test=[make_recording(100, "t")])
    dm = WindowDataModule(splits, WindowSpec(), layout="flat", val_fraction=0.1, seed=3)
    dm.setup()
    n_windows = 1010 - 10
    assert len(dm.val_windows) == 100 and len(dm.train_windows) == n_windows - 100
    # disjoint and together all windows
    together = np.concatenate([dm.train_windows.index, dm.val_windows.index])
    assert sorted(together.tolist()) == list(range(10, 1010))
    # random, not the last 10 %: validation targets spread over the recording
    assert dm.val_windows.index.min() < 300 and dm.val_windows.index.max() > 700
    x, target = next(iter(dm.train_dataloader()))[0]  # a block's first batch
    assert x.shape == (128, 20) and target.shape == (128, 1) and x.dtype == torch.float32
    # paper scaling: u = k / 100 V, y = -k / 20 um
    assert torch.allclose(x[:, 9] * 100.0, -target[:, 0] * 20.0 - 1.0)


def test_sequence_layout_batches_and_explicit_validation_recordings():
    splits = DatasetSplits(
        "d",
        train=[make_recording(300, "tr", nu=2)],
        val=[make_recording(60, "va", nu=2)],
        test=[make_recording(80, "te", nu=2)],
    )
    dm = WindowDataModule(splits, WindowSpec(), layout="sequence", batch_size=16)
    dm.setup()
    assert len(dm.val_windows) == 50 and len(dm.train_windows) == 290
    x, target = next(iter(dm.val_dataloader()))[0]  # a block's first batch
    assert x.shape == (16, 10, 3) and target.shape == (16, 1)
    (test_loader,) = dm.test_dataloader()
    assert len(test_loader.dataset) == 70


def test_validation_mse_scores_a_predictor_on_the_scaled_validation_windows():
    splits = DatasetSplits("d", train=[make_recording(400, "tr")], val=[make_recording(90, "va")],
                           test=[make_recording(80, "te")])
    dm = WindowDataModule(splits, WindowSpec(), layout="flat", scaling="standard")
    x, target = dm.scale_windows(make_windows(splits.val, dm.window))  # what it scores on
    assert dm.validation_mse(lambda x: np.zeros((len(x), 1))) == pytest.approx(
        float(np.mean(target**2)))
    assert dm.validation_mse(lambda x: np.asarray(target)) == 0.0
    assert len(x) == len(dm.val_windows) == 80  # set up by the call


def test_bad_datamodule_settings():
    splits = DatasetSplits("d", train=[make_recording(100, "tr")], test=[make_recording(50, "t")])
    with pytest.raises(ConfigError, match="val_fraction"):
        WindowDataModule(splits, val_fraction=1.5)
    with pytest.raises(ConfigError, match="layout"):
        WindowDataModule(splits, layout="image")


def test_recordings_without_validation_are_said_once_per_data_set(caplog):
    from hysteresis_lab.data.segments import RecordingDataModule
    from hysteresis_lab.sim.default_dataset import make_default_dataset

    data = make_default_dataset(effects={"creep": {"enabled": False}}, n_train=3000,
                                test_frequencies=(10.0,), max_test_samples=1000, val_samples=0)
    assert not data.val
    data = dataclasses.replace(data, name="told-once")  # not one an earlier test warned of
    windows = WindowDataModule(data, scaling="paper")
    with caplog.at_level("WARNING", logger="hysteresis_lab.data.segments"):
        for _ in range(3):  # a grown model's stages, the selection loss: modules per fit
            RecordingDataModule(windows).setup()
    told = [r for r in caplog.records if "no validation recordings" in r.getMessage()]
    assert len(told) == 1
