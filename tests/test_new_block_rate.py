"""A whole refit of a grown physical-chain model trains its added block's new parameters at
`new_block_lr_factor` times the rate and the fitted ones at the rate."""

from __future__ import annotations

import pytest

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.fitting import build_model
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from hysteresis_lab.models.linear import LinearModel
from hysteresis_lab.sim.default_dataset import make_default_dataset


def _grown(effect: str) -> LinearModel:
    """A linear model with ``effect`` added, warm-started from one without (no training)."""
    data = make_default_dataset(effects={}, n_train=2000, test_frequencies=(10.0,),
                                max_test_samples=500, val_samples=0)
    plain = build_model({"name": "linear"}, WindowDataModule(data, scaling="paper"),
                        trained_on={"fs": data.fs})
    augmented, context = augment_splits(data, [effect])
    grown = build_model({"name": "linear", "effects": [effect]},
                        WindowDataModule(augmented, scaling="paper"), trained_on={"fs": data.fs},
                        feature_context=context_to_dict(context), n_base_inputs=1)
    grown.warm_start_from(plain)
    return grown


def test_a_whole_refit_trains_the_new_block_faster():
    """The dead zone starts at weight 0 and must reach about 1; the fitted dynamics only
    adjust. At one rate for both the weight stopped at 0.56 on the simulator."""
    grown = _grown("dead_zone")
    groups = grown._parameter_groups(0.002)
    rates = {id(p): g["lr"] for g in groups for p in g["params"]}
    block = grown.input_blocks[0]["dead_zone"]
    assert grown.new_block_lr_factor > 1.0
    assert rates[id(block.weight)] == pytest.approx(0.002 * grown.new_block_lr_factor)
    assert rates[id(grown.dynamics[0][0].numerators)] == pytest.approx(0.002)


def test_a_new_inputs_refit_and_a_first_fit_train_at_one_rate():
    """Training only the new block (the rest frozen) or a model without a warm start: one
    group at the rate."""
    grown = _grown("creep")
    grown.train_new_inputs_only()
    assert [g["lr"] for g in grown._parameter_groups(0.002)] == [0.002]
    data = make_default_dataset(effects={}, n_train=2000, test_frequencies=(10.0,),
                                max_test_samples=500, val_samples=0)
    fresh = build_model({"name": "linear"}, WindowDataModule(data, scaling="paper"),
                        trained_on={"fs": data.fs})
    assert [g["lr"] for g in fresh._parameter_groups(0.002)] == [0.002]
