"""``training.optimizer=lbfgs``: full-batch L-BFGS for the physical models (one step over every
training recording, a line search instead of a learning rate), refused for the networks."""

from __future__ import annotations

import dataclasses
import math

import lightning as L
import numpy as np
import pytest
import torch

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.segments import RecordingDataModule
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.base import batches_of
from hysteresis_lab.models.full_batch import lbfgs_closure, make_lbfgs
from hysteresis_lab.models.settings import TrainingSettings
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.sim.default_dataset import make_default_dataset
from hysteresis_lab.workflows.grow import REFIT_LR_FACTORS, refit_rates

MAX_EPOCHS = 300


@pytest.fixture(scope="module")
def linear_positioner():
    """Amplifier, delay and mode, the hysteresis and creep switched off: a linear plant."""
    data = make_default_dataset(effects={"hysteresis": {"enabled": False},
                                         "creep": {"enabled": False}},
                                n_train=6000, test_frequencies=(10.0, 100.0),
                                max_test_samples=2000, val_samples=3000)
    return data, WindowDataModule(data, scaling="paper")


def _fit(optimizer: str, epochs: int, data, dm, folder):
    L.seed_everything(0)
    training = ModelSpec.from_config({"name": "linear"}).training_settings()
    model = build_model({"name": "linear"}, dm, training.with_changes(optimizer=optimizer),
                        trained_on={"fs": data.fs})
    settings = TrainerSettings(max_epochs=epochs, accelerator="cpu",
                               enable_progress_bar=False, enable_model_summary=False)
    return fit(model, dm, settings, folder)


def _free_run_mse(model, data, dm) -> float:
    first = dm.window.first_target
    errors = [predicted[first:] - rec.y[first:]
              for predicted, rec in zip(free_run(model, data.val, dm.window), data.val,
                                        strict=True)]
    return float(np.mean(np.square(np.concatenate(errors))))


def test_lbfgs_fits_the_linear_model_at_least_as_well_as_adam_and_stops_when_converged(
        linear_positioner, tmp_path):
    data, dm = linear_positioner
    adam = _fit("adam", 3, data, dm, tmp_path / "adam")
    lbfgs = _fit("lbfgs", MAX_EPOCHS, data, dm, tmp_path / "lbfgs")
    assert lbfgs.model.training_settings.optimizer == "lbfgs"
    assert _free_run_mse(lbfgs.model, data, dm) <= _free_run_mse(adam.model, data, dm)
    # converged: the stage ended on its own, before its epochs ran out
    assert lbfgs.model.trainer.current_epoch < MAX_EPOCHS - 1


def test_lbfgs_steps_read_every_training_recording_at_once(linear_positioner):
    data, dm = linear_positioner
    twice = WindowDataModule(dataclasses.replace(data, train=[*data.train, *data.train]),
                             scaling="paper")
    one_by_one = list(RecordingDataModule(twice, repeats=3).train_dataloader())
    together = list(RecordingDataModule(twice, repeats=1, together=True).train_dataloader())
    assert len(one_by_one) == 6
    assert len(together) == 1 and len(together[0]) == 2


def test_a_trial_point_whose_free_run_is_not_finite_makes_the_line_search_step_back():
    weight = torch.nn.Parameter(torch.ones(3))
    optimizer = torch.optim.LBFGS([weight])
    closure = lbfgs_closure(optimizer, lambda: (weight * math.nan).sum(), lambda x: x.backward())
    loss = closure()
    assert loss == math.inf
    assert torch.equal(weight.grad, torch.zeros(3))


def test_a_step_past_the_finite_region_steps_back_and_still_descends():
    """A loss finite only near the start (a free run stable only there): the first trial
    step leaves that region, the line search steps back and the step still lowers the loss
    (an infinite trial loss left the step where it began)."""
    weight = torch.nn.Parameter(torch.zeros(2))
    target = torch.tensor([3.0, -2.0])

    def loss_of() -> torch.Tensor:
        loss = ((weight - target) ** 2).sum()
        return loss if float(weight.detach().abs().max()) < 0.05 else loss * math.nan

    optimizer = make_lbfgs([weight], iterations=10)
    start = float(loss_of())
    closure = lbfgs_closure(optimizer, loss_of, lambda loss: loss.backward())
    assert float(optimizer.step(closure)) == start  # the step's start
    assert torch.isfinite(weight).all() and float(weight.abs().max()) < 0.05
    assert float(loss_of()) < start - 0.1


def test_the_free_run_loss_of_float32_batches_resolves_a_step_of_1e_8(linear_positioner):
    """The line search compares the losses of nearby parameters: the physical chain's loss
    of a float32 batch (as the data modules give) must change along a step as its gradient
    says. In float32 a central difference over 1e-8 misses the gradient by ~14 %."""
    data, dm = linear_positioner
    training = ModelSpec.from_config({"name": "linear"}).training_settings()
    model = build_model({"name": "linear"}, dm, training.with_changes(optimizer="lbfgs"),
                        trained_on={"fs": data.fs})
    model.simulation_mode = True
    batch = next(iter(RecordingDataModule(dm, repeats=1, together=True).train_dataloader()))
    part = batches_of(batch)[0]
    assert part[0].dtype == torch.float32
    loss = model._loss(part)
    loss.backward()
    params = [p for p in model.parameters() if p.requires_grad]
    grads = [p.grad.detach().clone() for p in params]
    slope = float(torch.sqrt(sum((g ** 2).sum() for g in grads)))
    step = 1e-8

    def loss_moved(by: float) -> float:
        with torch.no_grad():
            for p, g in zip(params, grads, strict=True):
                p.add_(g, alpha=by / slope)
            value = float(model._loss(part))
            for p, g in zip(params, grads, strict=True):
                p.add_(g, alpha=-by / slope)
        return value

    difference = (loss_moved(step) - loss_moved(-step)) / (2 * step)
    assert difference == pytest.approx(slope, rel=1e-4)


def test_lbfgs_refits_at_one_rate_adam_at_each_factor():
    assert refit_rates(TrainingSettings(optimizer="lbfgs", lr=0.02)) == [0.02]
    assert len(refit_rates(TrainingSettings(lr=0.02))) == len(REFIT_LR_FACTORS)


def test_an_unknown_optimizer_and_lbfgs_for_a_network_are_refused(linear_positioner):
    with pytest.raises(ConfigError, match="training.optimizer=one of"):
        TrainingSettings(optimizer="sgd")
    _, dm = linear_positioner
    training = ModelSpec.from_config({"name": "ffnn"}).training_settings()
    with pytest.raises(ConfigError, match="training.optimizer=adam"):
        build_model({"name": "ffnn"}, dm, training.with_changes(optimizer="lbfgs"))
