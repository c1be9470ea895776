"""Free-run (simulation-error) fine-tuning and warm starts: the differentiable free run, the
training stage, nested refits."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.segments import SegmentDataModule
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.predict import free_run, one_step
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from narx import CONFIGS, TRAINER, datamodule_for


@pytest.mark.parametrize("name", ["ffnn", "lstm", "cnn"])
def test_differentiable_free_run_equals_the_simulator(name, trained):
    """`simulate_scaled` (used for training) is the same free run as the evaluation's."""
    model, dm = trained[name]
    rec = dm.splits.test[0]
    s = dm.scaler
    u = torch.tensor((rec.u - s.u_offset) / s.u_scale, dtype=torch.float32)[None]
    y = torch.tensor((rec.y - s.y_offset) / s.y_scale, dtype=torch.float32)[None]
    with torch.no_grad():
        scaled = model.simulate_scaled(u, y[:, : dm.window.first_target])[0].double().numpy()
    physical = scaled * s.y_scale + s.y_offset
    reference = free_run(model, [rec], dm.window)[0][dm.window.first_target :]
    np.testing.assert_allclose(physical, reference, atol=1e-4)


def segment_loss(model, segments: SegmentDataModule) -> float:
    """Mean free-run MSE (scaled) over the validation segments."""
    u, y = segments.val_dataloader().dataset.tensors
    start = model.window.first_target
    with torch.no_grad():
        return float(torch.mean((model.simulate_scaled(u, y) - y[:, start:]) ** 2))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fine_tuning_lowers_the_free_run_error(seed, splits, tmp_path):
    """After the one-step fit, the free-run stage lowers the held-out free-run loss."""
    dm = datamodule_for("ffnn", splits)
    L.seed_everything(seed)
    one_step = fit(build_model(CONFIGS["ffnn"], dm), dm, TRAINER, tmp_path / "one_step").model
    segments = SegmentDataModule(dm, steps=50)
    before = segment_loss(one_step, segments)
    cfg = {**CONFIGS["ffnn"], "objective": "simulation", "horizon": 50, "simulation_epochs": 8,
           "simulation_lr": 3e-3}
    L.seed_everything(seed)  # the same one-step fit, then the free-run stage
    tuned = fit(build_model(cfg, dm), dm, TRAINER, tmp_path / "free_run")
    after = segment_loss(tuned.model, segments)
    assert after < 0.8 * before
    assert tuned.checkpoint is not None and tuned.checkpoint.parent.name == "checkpoints_free_run"
    assert not tuned.model.simulation_mode  # back to one-step batches for later use


def test_segments_are_scaled_consecutive_samples(splits):
    dm = datamodule_for("ffnn", splits)
    segments = SegmentDataModule(dm, steps=40)
    u, y = segments.train_dataloader().dataset.tensors
    assert u.shape[1] == y.shape[1] == dm.window.first_target + 40
    rec = splits.train[0]
    s = dm.scaler
    scaled_y = (rec.y - s.y_offset) / s.y_scale
    # every segment is a contiguous stretch of the (only) training recording
    for row in y[:5, :, 0].numpy():
        start = int(np.argmin(np.abs(scaled_y[:-1, 0] - row[0]) + np.abs(scaled_y[1:, 0] - row[1])))
        np.testing.assert_allclose(scaled_y[start : start + len(row), 0], row, atol=1e-6)


def test_bad_fine_tuning_settings_are_config_errors(splits):
    dm = datamodule_for("ffnn", splits)
    with pytest.raises(ConfigError, match=r"horizon=-1 \(a whole number >= 1\)"):
        build_model({**CONFIGS["ffnn"], "objective": "simulation", "horizon": -1}, dm)
    with pytest.raises(ConfigError, match="unknown training.objective 'free'"):
        build_model({**CONFIGS["ffnn"], "objective": "free"}, dm)
    with pytest.raises(ConfigError, match="training.horizon="):
        SegmentDataModule(dm, steps=10_000).setup()


@pytest.mark.parametrize("name", ["ffnn", "lstm", "cnn"])
def test_warm_start_adds_inputs_without_changing_the_model(name, splits, trained):
    """A network warm-started with an extra effect input predicts exactly what the fitted one
    did (the new input weights start at zero): the loop's refits are nested models."""
    fitted, dm = trained[name]
    augmented, ctx = augment_splits(splits, ["creep"])
    dm_aug = WindowDataModule(augmented, layout=dm.layout, scaling="standard", batch_size=64)
    grown = build_model({**CONFIGS[name], "effects": ["creep"]}, dm_aug,
                        feature_context=context_to_dict(ctx))
    assert grown.nu == fitted.nu + 1
    before = one_step(grown, augmented.test, dm.window)
    grown.warm_start_from(fitted)
    after = one_step(grown, augmented.test, dm.window)
    reference = one_step(fitted, splits.test, dm.window)
    for a, b, r in zip(before, after, reference, strict=True):
        np.testing.assert_allclose(b, r, atol=1e-5)
        assert np.max(np.abs(a - r)) > 1e-3  # an untrained network would not match


def test_warm_start_rejects_another_architecture(trained):
    with pytest.raises(ConfigError, match="cannot warm-start"):
        trained["lstm"][0].warm_start_from(trained["ffnn"][0])


def test_fine_tuning_that_does_not_help_keeps_the_starting_weights(splits, tmp_path):
    """A diverging fine-tuning (absurd learning rate) must not replace a good one-step fit."""
    dm = datamodule_for("ffnn", splits)
    L.seed_everything(0)
    plain = fit(build_model(CONFIGS["ffnn"], dm), dm, TRAINER, tmp_path / "plain").model
    cfg = {**CONFIGS["ffnn"], "objective": "simulation", "horizon": 50, "simulation_epochs": 2,
           "simulation_lr": 1e3}
    L.seed_everything(0)
    guarded = fit(build_model(cfg, dm), dm, TRAINER, tmp_path / "guarded")
    assert guarded.checkpoint is not None and guarded.checkpoint.parent.name == "checkpoints"
    for a, b in zip(free_run(plain, splits.test, dm.window),
                    free_run(guarded.model, splits.test, dm.window), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6)


def test_a_fine_tuning_that_diverges_keeps_finite_weights_when_the_last_epoch_is_asked_for(
        splits, tmp_path):
    """``keep_last`` (the loop's whole-record refit) keeps the last epoch's weights, but not
    those of a fine-tuning that diverged: its free run stays finite."""
    dm = datamodule_for("ffnn", splits)
    cfg = {**CONFIGS["ffnn"], "objective": "simulation", "horizon": 50, "simulation_epochs": 2,
           "simulation_lr": 1e3}
    L.seed_everything(0)
    kept = fit(build_model(cfg, dm), dm, TRAINER, tmp_path / "last", keep_last=True)
    assert kept.epochs["one_step"] == TRAINER.max_epochs
    for y in free_run(kept.model, splits.test, dm.window):
        assert np.all(np.isfinite(y))
