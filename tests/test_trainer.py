"""The trainer factory: `TrainerSettings` from the ``trainer`` config, `build_trainer`."""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path

import lightning as L
import pytest
from lightning.pytorch.callbacks import TQDMProgressBar
from omegaconf import OmegaConf

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.fitting import check_trainer_settings
from hysteresis_lab.lightning_trainer import (
    PROGRESS_BAR_REFRESH_BATCHES,
    TrainerSettings,
    build_trainer,
)

PACKAGED = Path(__file__).resolve().parents[1] / "src/hysteresis_lab/conf/trainer/default.yaml"
QUIET = {"logger": False, "enable_checkpointing": False}


def test_a_setting_left_out_behaves_as_lightning_decides():
    lightning_defaults = inspect.signature(L.Trainer).parameters
    for f in dataclasses.fields(TrainerSettings):
        if f.name not in {"extra", "configured"}:
            assert f.default == lightning_defaults[f.name].default, f.name


def test_the_packaged_config_becomes_settings_and_other_arguments_pass_through():
    cfg = {**OmegaConf.to_container(OmegaConf.load(PACKAGED)), "num_sanity_val_steps": 0}
    settings = TrainerSettings.from_config(cfg)
    assert settings.max_epochs == 100 and settings.precision == "32-true"
    assert settings.extra == {"num_sanity_val_steps": 0}
    assert settings.trainer_arguments() == cfg
    trainer = build_trainer(settings.with_changes(max_epochs=3), **QUIET)
    assert trainer.max_epochs == 3 and trainer.num_sanity_val_steps == 0


def test_settings_give_back_the_config_they_came_from_and_nothing_more():
    """`to_config` is what fit records fingerprint: exactly the config, no defaults added."""
    cfg = {**OmegaConf.to_container(OmegaConf.load(PACKAGED)), "num_sanity_val_steps": 0}
    settings = TrainerSettings.from_config(OmegaConf.create(cfg))
    assert settings == TrainerSettings.from_config(cfg) and settings.to_config() == cfg
    assert TrainerSettings.from_config(settings.to_config()) == settings
    short = TrainerSettings.from_config({"max_epochs": 3})
    assert short.accelerator == "auto" and short.to_config() == {"max_epochs": 3}
    changed = short.with_changes(devices=1, num_sanity_val_steps=0)
    assert changed.to_config() == {"max_epochs": 3, "devices": 1, "num_sanity_val_steps": 0}
    assert TrainerSettings(max_epochs=3).to_config()["accelerator"] == "auto"  # made in code


def test_the_progress_bar_refreshes_every_few_batches_unless_it_is_off():
    bars = [c for c in build_trainer(TrainerSettings(max_epochs=1), **QUIET).callbacks
            if isinstance(c, TQDMProgressBar)]
    assert [bar.refresh_rate for bar in bars] == [PROGRESS_BAR_REFRESH_BATCHES]
    quiet = build_trainer(TrainerSettings(max_epochs=1, enable_progress_bar=False), **QUIET)
    assert not any(isinstance(c, TQDMProgressBar) for c in quiet.callbacks)


def test_an_argument_lightning_does_not_know_is_refused_with_a_fix():
    with pytest.raises(ConfigError, match="Lightning refused the trainer settings.*Fix"):
        check_trainer_settings(TrainerSettings.from_config({"max_epochs": 1, "max_epoch": 2}))
