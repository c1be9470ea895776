"""Play operators start spread over the range the training input sweeps, whatever its scaling:
the grey-box's Prandtl–Ishlinskii cell, the data test that chooses the cell and the play
stand-in that checks the delay (`spread_thresholds`). Thresholds fixed in scaled units
opened only on the input's largest excursions under ``scaling=standard`` (the CSV path),
so zoo plant 11 (plays up to 89 V of a ±100 V drive) read one sample of delay it does not
have and left the cell to a second fit."""

from __future__ import annotations

import numpy as np
import pytest

from hysteresis_lab.blocks import PlayOperators
from hysteresis_lab.blocks.estimate import select_chain_structure
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.fitting import build_model
from hysteresis_lab.models.augment import trained_on
from hysteresis_lab.models.greybox import GreyBox
from hysteresis_lab.physics.play import spread_thresholds
from hysteresis_lab.sim.default_dataset import make_default_dataset
from hysteresis_lab.sim.zoo import draw_effects

#: a Prandtl–Ishlinskii zoo plant with plays across the drive, an amplifier at 2.2 kHz and
#: no input delay
WIDE_PLAYS_PLANT = 11


@pytest.fixture(scope="module")
def wide_plays() -> DatasetSplits:
    return make_default_dataset(draw_effects(WIDE_PLAYS_PLANT), seed=0, val_samples=20_000,
                                max_test_samples=1000)


def test_spread_thresholds_open_evenly_within_the_amplitude():
    np.testing.assert_allclose(spread_thresholds(9.0, 8), np.arange(1.0, 9.0))
    with pytest.raises(ValueError, match="amplitude > 0"):
        spread_thresholds(0.0, 8)


def test_the_plant_has_plays_across_the_drive_and_no_delay():
    effects = draw_effects(WIDE_PLAYS_PLANT)
    assert effects["hysteresis"]["cell"] == "prandtl_ishlinskii"
    assert max(effects["hysteresis"]["thresholds_v"]) > 80.0
    assert effects["input_delay"]["samples"] == 0
    assert effects["amplifier"]["cutoff_hz"] == pytest.approx(2200.0, rel=0.01)


def test_the_greybox_play_cell_starts_spread_over_the_training_input(wide_plays):
    datamodule = WindowDataModule(wide_plays, scaling="standard")
    model = build_model({"name": "greybox", "hysteresis": "prandtl_ishlinskii", "effects": []},
                        datamodule, trained_on=trained_on(wide_plays))
    assert isinstance(model.hysteresis, PlayOperators)
    amplitude = np.max(np.abs(wide_plays.train[0].u)) / float(model.u_scale[0])
    assert amplitude > 3.0  # a ±100 V multisine over its standard deviation
    thresholds = model.hysteresis.thresholds.detach().numpy()
    np.testing.assert_allclose(thresholds, spread_thresholds(amplitude, 8), rtol=1e-9)


def test_the_delay_check_reads_no_delay_behind_a_slow_amplifier(wide_plays):
    train = wide_plays.train[0]
    structure = select_chain_structure(train.u[:, 0], train.y[:, 0], train.fs)
    assert structure.delay == 0, structure.misfits
    assert structure.amplifier_hz == pytest.approx(2200.0, rel=0.2)


def test_the_data_test_tells_wide_plays_from_bouc_wen(wide_plays):
    candidates, found = GreyBox.settings_from_data(
        {"hysteresis": "auto", "delay": "auto", "n_modes": "auto"}, wide_plays)
    assert [c["hysteresis"] for c in candidates] == ["prandtl_ishlinskii"], found
    assert found["hysteresis"]["by"] == "data test"
