"""The linear effect path (``model.effect_path=linear``): effect channels bypass the network and
enter through a linear map of their lags, in training, one-step prediction and free run."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.predict import free_run, one_step
from hysteresis_lab.fitting import build_model
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from narx import CONFIGS


def linear_path_model(name, splits, trained, effects=("creep", "hysteresis"), warm=True):
    """A linear-path model with ``effects``, warm-started from the fitted network (path at
    zero) or, with ``warm=False``, freshly initialised (random network weights on every input)."""
    fitted, dm = trained[name]
    augmented, ctx = augment_splits(splits, list(effects))
    dm_aug = WindowDataModule(augmented, layout=dm.layout, scaling="standard", batch_size=64)
    model = build_model({**CONFIGS[name], "effects": list(effects), "effect_path": "linear"},
                        dm_aug, feature_context=context_to_dict(ctx), n_base_inputs=splits.nu)
    if warm:
        model.warm_start_from(fitted)
    return model, fitted, augmented, dm_aug


@pytest.mark.parametrize("name", ["ffnn", "lstm", "cnn"])
def test_linear_path_starts_at_the_fitted_network(name, splits, trained):
    model, fitted, augmented, _ = linear_path_model(name, splits, trained)
    assert model.effect_weight is not None and not model.effect_weight.any()
    for a, b in zip(free_run(model, augmented.test, model.window),
                    free_run(fitted, splits.test, model.window), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-5)


@pytest.mark.parametrize("name", ["ffnn", "lstm", "cnn"])
def test_free_run_with_linear_path_equals_the_differentiable_free_run(name, splits, trained):
    """The free run's precomputed effect term is the same model as ``forward``."""
    model, _, augmented, _ = linear_path_model(name, splits, trained)
    torch.manual_seed(1)
    with torch.no_grad():
        model.effect_weight.normal_(0.0, 0.05)
    rec = augmented.test[0]
    u_off, u_sc = model.u_offset.numpy(), model.u_scale.numpy()
    y_off, y_sc = model.y_offset.numpy(), model.y_scale.numpy()
    u = torch.tensor((rec.u - u_off) / u_sc, dtype=torch.float32)[None]
    y = torch.tensor((rec.y - y_off) / y_sc, dtype=torch.float32)[None]
    with torch.no_grad():
        scaled = model.simulate_scaled(u, y[:, : model.window.first_target])[0].double().numpy()
    reference = scaled * y_sc + y_off
    for fast in (True, False):
        simulated = free_run(model, [rec], model.window, fast=fast)[0]
        np.testing.assert_allclose(simulated[model.window.first_target :], reference, atol=1e-4)
    plain = free_run(trained[name][0], [splits.test[0]], model.window)[0]
    assert np.max(np.abs(plain - reference[0])) > 1e-3  # the effect path changed the output


@pytest.mark.parametrize("name", ["ffnn", "lstm"])
def test_effect_channels_enter_only_linearly(name, splits, trained):
    """Scaling the effect channels' deviation scales the output change by the same factor, and
    with the path at zero they change nothing (the network does not see them)."""
    model, _, augmented, _ = linear_path_model(name, splits, trained, warm=False)
    rec = augmented.test[0]
    base = splits.nu

    def with_effects_scaled(factor: float):
        u = rec.u.copy()
        u[:, base:] = model.u_offset.numpy()[base:] + factor * (
            u[:, base:] - model.u_offset.numpy()[base:])
        return one_step(model, [dataclasses.replace(rec, u=u)], model.window)[0]

    np.testing.assert_allclose(with_effects_scaled(3.0), with_effects_scaled(1.0), atol=1e-5)
    torch.manual_seed(2)
    with torch.no_grad():
        model.effect_weight.normal_(0.0, 0.05)
    zero, one, three = (with_effects_scaled(f) for f in (0.0, 1.0, 3.0))
    np.testing.assert_allclose(three - zero, 3.0 * (one - zero), atol=1e-4)
    assert np.max(np.abs(one - zero)) > 1e-3


def test_unknown_effect_path_is_a_config_error(splits, trained):
    _, dm = trained["ffnn"]
    with pytest.raises(ConfigError, match="model.effect_path=one of"):
        build_model({**CONFIGS["ffnn"], "effect_path": "sideways"}, dm)
