"""The loop's default refit (``loop.refit=new_inputs``): after the warm start only the added
effect's input weights train; every weight the last round fitted stays exactly as it was."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.loop.driver import LoopSettings
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from narx import CONFIGS, TRAINER


def grown_model(name, splits, trained, effect_path="network", **hparams):
    """``name`` with a creep channel added, warm-started from the fitted network."""
    fitted, dm = trained[name]
    augmented, ctx = augment_splits(splits, ["creep"])
    dm_aug = WindowDataModule(augmented, layout=dm.layout, scaling="standard", batch_size=64)
    cfg = {**CONFIGS[name], "effects": ["creep"], "effect_path": effect_path, **hparams}
    model = build_model(cfg, dm_aug, feature_context=context_to_dict(ctx),
                        n_base_inputs=splits.nu)
    model.warm_start_from(fitted)
    return model, fitted, augmented, dm_aug


def old_entries(model, fitted) -> dict[str, torch.Tensor]:
    """Every parameter entry of ``model`` that ``fitted`` has too, in ``fitted``'s shape."""
    positions = torch.as_tensor(model._old_regressor_positions(fitted.nu))
    fitted_names = dict(fitted.named_parameters())
    out = {}
    for name, value in model.named_parameters():
        if name not in fitted_names:
            continue
        same = value.shape == fitted_names[name].shape
        out[name] = value.detach().clone() if same else value.detach()[:, positions].clone()
    return out


@pytest.mark.parametrize(
    ("name", "effect_path", "fine_tune"),
    [
        ("ffnn", "network", False),
        ("ffnn", "network", True),
        ("lstm", "network", False),
        ("cnn", "network", False),
        ("ffnn", "linear", True),
    ],
)
def test_refit_trains_only_the_new_inputs(name, effect_path, fine_tune, splits, trained,
                                          tmp_path):
    lr = CONFIGS[name].get("lr", 1e-3)  # a short test: refit at the full rate
    model, fitted, augmented, dm_aug = grown_model(name, splits, trained, effect_path, refit_lr=lr)
    if fine_tune:
        model.hparams.update(objective="simulation", horizon=40, simulation_epochs=2)
    model.train_new_inputs_only()
    assert model.new_inputs_only
    refit = fit(model, dm_aug, TRAINER, tmp_path, one_step=not fine_tune).model
    for key, value in old_entries(refit, fitted).items():
        torch.testing.assert_close(value, dict(fitted.named_parameters())[key].detach(),
                                   rtol=0, atol=0, msg=f"{key} moved")
    new = [p.detach()[mask] for n, p in refit.named_parameters()
           if (mask := refit.new_entries.get(n)) is not None]
    assert max(float(v.abs().max()) for v in new) > 1e-4  # the new inputs were learned
    with torch.no_grad():  # without the new weights the refit is the fitted network again
        for n, p in refit.named_parameters():
            if (mask := refit.new_entries.get(n)) is not None:
                p[mask] = 0.0
    for a, b in zip(free_run(refit, augmented.test, refit.window),
                    free_run(fitted, splits.test, refit.window), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-5)


def test_weight_decay_does_not_move_the_old_weights(splits, trained, tmp_path):
    model, fitted, _, dm_aug = grown_model("ffnn", splits, trained, weight_decay=0.1)
    model.train_new_inputs_only()
    refit = fit(model, dm_aug, TRAINER, tmp_path).model
    for key, value in old_entries(refit, fitted).items():
        torch.testing.assert_close(value, dict(fitted.named_parameters())[key].detach(),
                                   rtol=0, atol=0, msg=f"{key} moved")


def test_new_inputs_only_needs_a_warm_start_that_added_inputs(splits, trained):
    fitted, dm = trained["ffnn"]
    with pytest.raises(ConfigError, match="warm start"):
        build_model(CONFIGS["ffnn"], dm).train_new_inputs_only()
    same = build_model(CONFIGS["ffnn"], dm)
    same.warm_start_from(fitted)
    with pytest.raises(ConfigError, match="no new input weights"):
        same.train_new_inputs_only()


def test_unknown_refit_is_a_config_error():
    with pytest.raises(ConfigError, match="loop.refit=one of"):
        LoopSettings(refit="everything")


@pytest.mark.parametrize(("refit_lr", "expected"), [(None, 1e-4), (3e-5, 3e-5)])
def test_a_refit_fine_tunes_at_the_refit_learning_rate(refit_lr, expected, splits, trained):
    """A refit starts from a fitted network: Adam at the full training rate throws it off its
    minimum in the first steps, so it trains at ``refit_lr`` (default lr / 10)."""
    from hysteresis_lab.fitting import stage_lr

    model, *_ = grown_model("ffnn", splits, trained, lr=1e-3, lr_schedule="none",
                            refit_lr=refit_lr)
    assert stage_lr(model, "one_step") == pytest.approx(expected)
    assert stage_lr(model, "fine_tune") == pytest.approx(0.1 * expected)  # simulation_lr unset
    model.stage_lr = stage_lr(model, "one_step")  # what training sets before each stage
    assert model.configure_optimizers().param_groups[0]["lr"] == pytest.approx(expected)
    fresh = build_model({**CONFIGS["ffnn"], "lr": 1e-3, "lr_schedule": "none"}, trained["ffnn"][1])
    assert stage_lr(fresh, "one_step") == pytest.approx(1e-3)
    assert fresh.configure_optimizers().param_groups[0]["lr"] == pytest.approx(1e-3)


def test_bad_refit_learning_rate_is_a_config_error(trained):
    with pytest.raises(ConfigError, match="training.refit_lr"):
        build_model({**CONFIGS["ffnn"], "refit_lr": -1.0}, trained["ffnn"][1])
