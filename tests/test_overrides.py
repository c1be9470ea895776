"""Overrides must keep the type of the packaged value they replace (`cli._overrides`)."""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf

from hysteresis_lab.cli._overrides import type_mismatches

PACKAGED = OmegaConf.create({
    "seed": 0,
    "n_step": None,
    "plots": True,
    "model": {"lr": 1e-3, "effects": [], "lr_schedule": "cosine", "num_layers": 4},
    "trainer": {"devices": 1},
    "data": {"effects": {"creep": {"enabled": True}}},
})


def overridden(**values) -> DictConfig:
    cfg = OmegaConf.create(OmegaConf.to_container(PACKAGED))
    for key, value in values.items():
        OmegaConf.update(cfg, key.replace("__", "."), value, merge=False)
    return cfg


def test_values_of_the_packaged_type_pass():
    cfg = overridden(seed=3, training__lr=5, n_step=100, plots=False, model__effects=["creep"],
                     training__lr_schedule="plateau", trainer__devices="auto",
                     model__num_layers=3)
    keys = ["seed", "training.lr", "n_step", "plots", "model.effects", "training.lr_schedule",
            "trainer.devices", "model.num_layers"]
    assert type_mismatches(cfg, PACKAGED, keys) == []


def test_each_changed_type_is_named_with_its_fix():
    cfg = overridden(seed="abc", training__lr=True, n_step="x", plots="maybe",
                     model__effects="creep", data__effects__creep=True)
    problems = type_mismatches(
        cfg, PACKAGED, ["seed", "training.lr", "n_step", "plots", "model.effects",
                        "data.effects.creep"],
    )
    assert problems == [
        "seed='abc' must be a whole number. Fix: seed=0",
        "training.lr=True must be a number or null. Fix: e.g. training.lr=0.001",
        "n_step='x' must be a whole number or null. Fix: e.g. n_step=null",
        "plots='maybe' must be true or false. Fix: plots=true (true or false)",
        "model.effects='creep' must be a list. Fix: model.effects=[a,b] (brackets even for one "
        "item: model.effects=[a])",
        "data.effects.creep=True must be a group of settings. Fix: set one of its settings, e.g. "
        "data.effects.creep.enabled=...",
    ]


def test_only_the_overridden_keys_are_checked():
    cfg = overridden(seed="abc")
    assert type_mismatches(cfg, PACKAGED, ["training.lr"]) == []


def test_a_count_takes_only_whole_numbers():
    cfg = overridden(model__num_layers=2.5, seed=1.0, n_step=2.5)
    assert type_mismatches(cfg, PACKAGED, ["model.num_layers", "seed", "n_step"]) == [
        "model.num_layers=2.5 must be a whole number. Fix: model.num_layers=4",
        "seed=1.0 must be a whole number. Fix: seed=0",
        "n_step=2.5 must be a whole number or null. Fix: e.g. n_step=null",
    ]


def test_a_training_setting_under_its_old_name_is_renamed_with_a_warning(caplog):
    from hysteresis_lab.cli._overrides import renamed_overrides

    with caplog.at_level("WARNING"):
        renamed = renamed_overrides(["model.lr=0.01", "+model.horizon=50", "model.units=8",
                                     "~model.patience", "model=lstm"])
    assert renamed == ["training.lr=0.01", "training.horizon=50", "model.units=8",
                       "~training.patience", "model=lstm"]
    assert sum("is deprecated" in r.getMessage() for r in caplog.records) == 3
