"""Declared effects are grown the way the loop grows a model: the linear dynamics first, then
each declared block from no effect on the warm model (`hysteresis_lab.workflows.grow`)."""

from __future__ import annotations

import json

import lightning as L
import numpy as np
import pytest
import torch

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from hysteresis_lab.models.greybox import GreyBox
from hysteresis_lab.models.linear import LinearModel
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.sim.default_dataset import make_default_dataset
from hysteresis_lab.workflows.grow import growth_stages
from hysteresis_lab.workflows.pipeline import RunConfig, run_model

TRAINER = TrainerSettings(max_epochs=3, accelerator="cpu", enable_progress_bar=False,
                          enable_model_summary=False)


def test_declared_effects_grow_one_at_a_time_in_the_physics_order():
    settings = {"effects": ["creep", "hysteresis", "saturation"], "lr": 0.002}
    stages = growth_stages(ModelSpec("linear", LinearModel, settings))
    assert [s.label for s in stages] == ["linear", "saturation", "hysteresis", "creep"]
    assert [list(s.settings["effects"]) for s in stages] == [
        [], ["saturation"], ["saturation", "hysteresis"], ["creep", "hysteresis", "saturation"]]
    assert [s.added for s in stages] == [None, "saturation", "hysteresis", "creep"]
    assert stages[-1].settings == settings  # the last stage is the model as declared
    off = growth_stages(ModelSpec("linear", LinearModel, {**settings, "grow": False}))
    assert [s.label for s in off] == ["declared"]


def test_the_grey_box_grows_its_hysteresis_cell_on_the_chain_without_one():
    stages = growth_stages(ModelSpec("greybox", GreyBox, {"effects": ["creep"]}))
    assert [s.label for s in stages] == ["linear", "hysteresis", "creep"]
    assert stages[0].settings["hysteresis"] == "none"
    assert stages[1].settings.get("hysteresis", "bouc_wen") == "bouc_wen"
    assert list(stages[1].settings["effects"]) == []
    none = growth_stages(ModelSpec("greybox", GreyBox, {"hysteresis": "none"}))
    assert len(none) == 1  # nothing declared to grow


def _positioner() -> tuple:
    data = make_default_dataset(effects={"creep": {"enabled": False}}, n_train=6000,
                                test_frequencies=(10.0, 100.0), max_test_samples=2000,
                                val_samples=3000)
    return data, WindowDataModule(data, scaling="paper")


def test_a_grown_grey_box_cell_starts_where_it_changes_nothing():
    data, dm = _positioner()
    L.seed_everything(0)
    linear = build_model({"name": "greybox", "hysteresis": "none"}, dm,
                         trained_on={"fs": data.train[0].fs})
    linear.initialise_from_recordings(data.train)
    cell = build_model({"name": "greybox"}, dm, trained_on={"fs": data.train[0].fs})
    cell.warm_start_from(linear)
    v = torch.as_tensor(data.test[0].u[None] / 100.0, dtype=torch.float64)  # over its scale
    with torch.no_grad():
        before, after = linear.chain(v), cell.chain(v)
    assert float(cell.hysteresis.alpha.detach()) < 2e-3
    assert torch.allclose(before, after, atol=5e-3 * float(before.abs().max()))


def test_a_declared_model_is_grown_from_its_fitted_linear_start(tmp_path):
    data, _ = _positioner()
    result = run_model(RunConfig.build(
        {"name": "linear", "effects": ["hysteresis"], "grow": True}, {"name": "default"},
        TRAINER, tmp_path, {"lr": 0.002}, use_tensorboard=False, plots=False), splits=data)
    stages = sorted(p.name for p in (tmp_path / "grow").iterdir())
    assert stages == ["0_linear", "1_hysteresis"]
    rates = sorted(p.name for p in (tmp_path / "grow" / "1_hysteresis").iterdir())
    assert rates == ["refit_lr_0.0002", "refit_lr_0.002"]
    assert list(result.model.hparams["effects"]) == ["hysteresis"]
    # the hysteresis stage starts from the fitted linear model: its starting validation loss
    # is that model's best (the new block at no effect changes nothing)
    (best,) = (tmp_path / "grow" / "0_linear" / "checkpoints").glob("best-*.ckpt")
    linear_loss = float(best.stem.split("val_loss=")[1])
    losses = result.refit_validation
    assert losses is not None and losses["start"] == pytest.approx(linear_loss, rel=1e-3)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert np.isfinite(metrics["mean"]["rmse_free_run"])


def test_each_stage_is_polished_before_the_next_block_is_added(tmp_path):
    """With ``model.polish`` a stage before the last ends with its own L-BFGS polish, and the
    next block grows on the polished model, as the loop adds it."""
    data, _ = _positioner()
    result = run_model(RunConfig.build(
        {"name": "linear", "effects": ["hysteresis"], "grow": True, "polish": True},
        {"name": "default"}, TRAINER, tmp_path, {"lr": 0.002}, use_tensorboard=False,
        plots=False), splits=data)
    linear = tmp_path / "grow" / "0_linear"
    adam, polished = _best_loss(linear / "checkpoints"), _best_loss(linear / "polish")
    assert polished < adam
    assert result.refit_validation is not None
    assert result.refit_validation["start"] == pytest.approx(polished, rel=1e-3)


def _best_loss(folder) -> float:
    """The lowest validation loss of the checkpoints kept under ``folder``."""
    return min(float(p.stem.split("val_loss=")[1]) for p in folder.rglob("best-*.ckpt"))


def test_by_default_the_grown_and_the_at_once_fit_compete_on_validation(tmp_path):
    """``model.grow=best`` (the default) grows the declared model and trains it at once too,
    and keeps the one with the lower validation free-run loss."""
    data, _ = _positioner()
    run_model(RunConfig.build(
        {"name": "linear", "effects": ["hysteresis"]}, {"name": "default"}, TRAINER, tmp_path,
        {"lr": 0.002}, use_tensorboard=False, plots=False), splits=data)
    grow = tmp_path / "grow"
    assert sorted(p.name for p in grow.iterdir()) == ["0_linear", "1_hysteresis", "at_once"]
    grown, at_once = _best_loss(grow / "1_hysteresis"), _best_loss(grow / "at_once")
    assert grown != pytest.approx(at_once, rel=1e-3)  # two different fits to choose from
    kept = json.loads((tmp_path / "metrics.json").read_text())["val_mse_scaled"]
    assert kept == pytest.approx(min(grown, at_once), rel=1e-3)


def test_a_step_that_leaves_the_stable_region_is_taken_back(tmp_path):
    """A feedback force at a huge rate pushes the closed loop past stability within a step:
    the step is taken back and the rate halved, where it used to end the fit diverged."""
    data, _ = _positioner()
    augmented, context = augment_splits(data, ["hysteresis"])
    dm = WindowDataModule(augmented, scaling="paper")
    L.seed_everything(0)
    model = build_model({"name": "linear", "effects": ["hysteresis"], "lr": 5.0}, dm,
                        feature_context=context_to_dict(context),
                        n_base_inputs=augmented.metadata["n_base_inputs"],
                        trained_on={"fs": data.train[0].fs})
    result = fit(model, dm, TRAINER, tmp_path)
    assert model._step_backs > 0
    assert np.isfinite(result.val_mse)


@pytest.mark.parametrize("grow", [True, False, "best"])
def test_grow_is_a_model_setting_of_the_physical_models(grow, tmp_path):
    data, dm = _positioner()
    model = build_model({"name": "linear", "grow": grow}, dm, trained_on={"fs": 20_000.0})
    assert model.hparams["grow"] is grow
