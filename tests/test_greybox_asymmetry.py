"""``model=greybox model.effects=[asymmetry]``: the asymmetry effect's square law on the
grey-box's hysteresis cell, from zero weight. It starts as the grey-box without it, fits an
asymmetric loop the symmetric cell cannot, and its simulation step exports exactly."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch

from conftest import optional_dependency
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.effects.asymmetry import SquareLaw
from hysteresis_lab.effects.hysteresis import HysteresisCell
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from hysteresis_lab.models.greybox import GreyBox
from hysteresis_lab.sim.default_dataset import make_default_dataset
from hysteresis_lab.workflows.grow import refit_mode
from narx import datamodule_for, narx_data

TRAINER = TrainerSettings(max_epochs=10, accelerator="cpu", enable_progress_bar=False,
                          enable_model_summary=False)


def _greybox(splits, effects: list[str], **settings):
    """A grey-box built as the pipeline builds it (the effects' context beside the data)."""
    nu = splits.train[0].u.shape[1]
    augmented, context = augment_splits(splits, effects)
    dm = datamodule_for("greybox", augmented)
    model = build_model({"name": "greybox", "effects": effects, **settings}, dm,
                        trained_on={"fs": splits.train[0].fs},
                        feature_context=context_to_dict(context), n_base_inputs=nu)
    return model, dm


def _initialised(model, splits):
    model.initialise_from_recordings(splits.train)
    return model


@pytest.mark.parametrize("channels", [1, 2])
def test_it_starts_exactly_as_the_greybox_without_it(channels):
    """Built from the data (the fit at once) or warm-started from the symmetric grey-box
    (the grown path), the square law starts at zero weight and the free run is the same to
    the bit; moved off zero, it changes it by the square law."""
    splits = narx_data(n=600, nu=channels, ny=channels)
    symmetric, dm = _greybox(splits, [])
    symmetric = _initialised(symmetric, splits)
    asymmetric, dm_asym = _greybox(splits, ["asymmetry"])
    asymmetric = _initialised(asymmetric, splits)
    rec, rec_asym = dm.splits.test[0], dm_asym.splits.test[0]  # the latter with its channels
    np.testing.assert_array_equal(free_run(asymmetric, [rec_asym], dm_asym.window)[0],
                                  free_run(symmetric, [rec], dm.window)[0])
    with torch.no_grad():
        for p in symmetric.parameters():  # off the start: a fitted model
            p.add_(0.05)
    asymmetric.warm_start_from(symmetric)
    terms = [m for m in asymmetric.modules() if isinstance(m, SquareLaw)]
    assert len(terms) == channels
    assert all(float(t.weight.detach()) == 0.0 for t in terms)
    assert all(any(t.weight is p for t in terms) for name, p in asymmetric.named_parameters()
               if name in asymmetric._new_entries)
    before = free_run(symmetric, [rec], dm.window)[0]
    np.testing.assert_array_equal(free_run(asymmetric, [rec_asym], dm_asym.window)[0], before)
    with torch.no_grad():
        terms[0].weight.fill_(0.1)
    assert not np.allclose(free_run(asymmetric, [rec_asym], dm_asym.window)[0], before)


def test_the_grown_square_law_refits_the_whole_chain():
    """Added to a fitted grey-box (the loop, or ``grow``), the square law moves the mean
    and gain the chain was fitted to: the whole model refits."""
    assert "asymmetry" in GreyBox.carried_effects
    assert "asymmetry" not in GreyBox.built_in_effects({})  # not held without declaring it
    assert refit_mode("asymmetry", GreyBox) == "full"


def test_the_law_is_the_linear_models_cell_law():
    """One law: the grey-box's term is `HysteresisCell`'s square law."""
    v = torch.linspace(-2.0, 2.0, 9, dtype=torch.float64)
    term, cell = SquareLaw(1.5), HysteresisCell(square_amplitude=1.5)
    with torch.no_grad():
        term.weight.fill_(0.3)
        cell.square_weight.fill_(0.3)
        cell.weight.fill_(0.0)
        np.testing.assert_allclose((cell(v[None]) - v[None]).numpy()[0], term(v).numpy(),
                                   rtol=0, atol=1e-15)


def test_on_an_asymmetric_plant_it_fits_better_than_the_symmetric_greybox(tmp_path):
    """A simulated positioner with an asymmetric loop (the square law 3.5 % of the stroke at
    ±100 V): trained alike, the grey-box with the square law fits the test sines far better,
    its weight of the plant's sign."""
    coefficient = 0.02
    data = make_default_dataset(
        effects={"creep": {"enabled": False},
                 "asymmetry": {"enabled": True, "coefficient": coefficient}},
        n_train=8000, test_frequencies=(10.0, 100.0), max_test_samples=3000, val_samples=4000)
    errors, weights = {}, {}
    for effects in ([], ["asymmetry"]):
        augmented, context = augment_splits(data, effects)
        dm = WindowDataModule(augmented, scaling="paper")
        L.seed_everything(0)
        model = build_model({"name": "greybox", "effects": effects}, dm,
                            trained_on={"fs": data.fs}, feature_context=context_to_dict(context),
                            n_base_inputs=1)
        fitted = fit(model, dm, TRAINER, tmp_path / "_".join(effects or ["none"])).model
        predicted = free_run(fitted, dm.splits.test, dm.window)
        ft = dm.window.first_target
        errors[bool(effects)] = np.mean([np.sqrt(np.mean((p[ft:] - r.y[ft:]) ** 2))
                                         for p, r in zip(predicted, dm.splits.test,
                                                         strict=True)])
        weights[bool(effects)] = fitted.physical_parameters().get("asymmetry", {}).get("weight")
    assert errors[True] < 0.2 * errors[False], errors
    assert np.sign(weights[True]) == np.sign(coefficient), weights


@pytest.mark.parametrize("channels", [1, 2])
def test_its_simulation_step_exports_exactly(channels, tmp_path):
    """The exported step, stepped from rest over a recording with the square law at work,
    reproduces the torch free run (to rounding, far inside 1e-5)."""
    ort = optional_dependency("onnxruntime")
    from hysteresis_lab.models.export import export_onnx

    splits = narx_data(n=600, nu=channels, ny=channels)
    model, dm = _greybox(splits, ["asymmetry"])
    model = _initialised(model, splits)
    with torch.no_grad():
        for term in (m for m in model.modules() if isinstance(m, SquareLaw)):
            term.weight.fill_(0.2)
    model = model.eval()
    rec = dm.splits.test[0]
    expected = free_run(model, [rec], dm.window)[0]
    session = ort.InferenceSession(str(export_onnx(model, tmp_path / "greybox.onnx")))
    state = np.zeros((1, len(model.state_names())))
    produced = np.empty_like(rec.y)
    for k, u in enumerate(rec.u[:, :channels]):  # the measured inputs alone
        produced[k], state = session.run(None, {"state": state, "u": u[None]})
    ft = dm.window.first_target
    square = sum(float(m.weight.detach()) for m in model.modules()
                 if isinstance(m, SquareLaw))
    assert square != 0.0  # the law was at work in the file
    np.testing.assert_allclose(produced[ft:], expected[ft:], rtol=0,
                               atol=1e-9 * np.max(np.abs(expected)))
