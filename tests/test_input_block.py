"""The input block: effects ahead of the dynamics (saturation) correct the measured input the
network sees (``u + W @ operators``), in training, one-step prediction and free run."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
import torch

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.evaluation.predict import free_run, one_step
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from narx import CONFIGS, TRAINER


def with_effects(name, splits, trained, effects=("creep", "saturation")):
    """``name`` with ``effects`` added, warm-started from the fitted network."""
    fitted, dm = trained[name]
    augmented, ctx = augment_splits(splits, list(effects))
    dm_aug = WindowDataModule(augmented, layout=dm.layout, scaling="standard", batch_size=64)
    model = build_model({**CONFIGS[name], "effects": list(effects)}, dm_aug,
                        feature_context=context_to_dict(ctx), n_base_inputs=splits.nu)
    model.warm_start_from(fitted)
    return model, fitted, augmented, dm_aug, ctx


def test_saturation_enters_through_the_input_block(splits, trained):
    model, *_ = with_effects("ffnn", splits, trained)
    assert get_effect("saturation").block == "input"
    assert model.input_weight is not None and model.input_weight.shape == (1, 4)
    assert model.effect_weight is None  # creep stays a network input
    n_creep = model.nu - 1 - 4
    channels = model.away_channels.tolist()
    assert channels == [False] + [False] * n_creep + [True] * 4


@pytest.mark.parametrize("name", ["ffnn", "lstm", "cnn"])
def test_input_block_with_gain_minus_one_is_a_clipped_input(name, splits, trained):
    """``u - 1 * excess over c`` is ``clip(u, c)``: the grown model with that gain predicts
    what the fitted network predicts on the clipped input, one step ahead and in free run
    (compiled kernels and the torch loop)."""
    model, fitted, augmented, _, ctx = with_effects(name, splits, trained)
    limit = 0.9 * float(ctx.u_amplitude[0])
    channel = 1 + model.nu - 1 - 4 + 2  # the excess over 90 % of the range
    position = int((model.input_channels == channel).nonzero())
    with torch.no_grad():
        model.u_offset[channel] = 0.0  # gain -1 in volts needs the excess unshifted
        model.input_weight[0, position] = -model.u_scale[channel] / model.u_scale[0]
    clipped = [dataclasses.replace(r, u=np.clip(r.u, -limit, limit)) for r in splits.test]
    assert max(np.abs(r.u).max() for r in splits.test) > limit  # the test input does clip
    for a, b in zip(one_step(model, augmented.test, model.window),
                    one_step(fitted, clipped, model.window), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-4)
    reference = free_run(fitted, clipped, model.window)
    for fast in (True, False):
        for a, b in zip(free_run(model, augmented.test, model.window, fast=fast), reference,
                        strict=True):
            np.testing.assert_allclose(a, b, atol=1e-4)
    unclipped = free_run(fitted, splits.test, model.window)
    assert max(np.max(np.abs(a - b)) for a, b in zip(reference, unclipped, strict=True)) > 1e-3


def test_input_block_trains_and_warm_starts_grow_it(splits, trained, tmp_path):
    model, fitted, augmented, dm_aug, _ = with_effects("ffnn", splits, trained, ["saturation"])
    model.train_new_inputs_only()
    refit = fit(model, dm_aug, TRAINER, tmp_path).model
    assert refit.input_weight.detach().abs().max() > 1e-5
    grown, *_ = with_effects("ffnn", splits, trained, ["saturation", "creep"])
    grown.warm_start_from(refit)
    torch.testing.assert_close(grown.input_weight, refit.input_weight, rtol=0, atol=0)
    assert "input_weight" not in grown.new_entries  # same shape: copied, not new


def test_refit_keeps_its_start_unless_it_beats_it(splits, trained, tmp_path):
    """A warm-started refit that only makes validation worse returns the starting model."""
    fitted, dm = trained["ffnn"]
    diverging = copy.deepcopy(fitted)
    diverging.hparams["lr"] = 50.0
    kept = fit(diverging, dm, TRAINER, tmp_path / "kept", keep_start_unless_beaten=True).model
    for a, b in zip(free_run(kept, splits.test, dm.window),
                    free_run(fitted, splits.test, dm.window), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6)
    fresh = build_model(CONFIGS["ffnn"], dm)
    start = [p.detach().clone() for p in fresh.parameters()]
    learned = fit(fresh, dm, TRAINER, tmp_path / "learned", keep_start_unless_beaten=True).model
    assert any(not torch.equal(a, b.detach()) for a, b in zip(start, learned.parameters(),
                                                                  strict=True))
