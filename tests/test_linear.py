"""The linear model: stable dynamics from a least-squares ARX start, fitted on the free-run
error; the effect catalogue's blocks grow it and start where they change nothing."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch
from scipy import signal

from hysteresis_lab.blocks.sections import StableSections, arx_least_squares
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from hysteresis_lab.sim.default_dataset import make_default_dataset

TRAINER = TrainerSettings(max_epochs=5, accelerator="cpu", enable_progress_bar=False,
                          enable_model_summary=False)
NOISE_UM = 0.01


def test_arx_start_reproduces_a_linear_system_and_stays_stable():
    rng = np.random.default_rng(0)
    u = rng.normal(size=4000)
    b_true, a_true = [0.0, 0.1, 0.05], [1.0, -1.5, 0.7]
    y = signal.lfilter(b_true, a_true, u)
    b, a = arx_least_squares(u, y + 1e-3 * rng.normal(size=len(u)), na=4, nb=4, nk=1)
    sections = StableSections(order=4)
    sections.set_transfer_function(b, a)
    with torch.no_grad():
        simulated = sections(torch.as_tensor(u[None]))[0].numpy()
    assert np.sqrt(np.mean((simulated - y) ** 2)) < 1e-3 * np.std(y)
    sections.set_transfer_function(np.array([0.0, 1.0]), np.array([1.0, -1.2]))  # unstable
    poles = np.roots(sections.denominators()[0].detach().numpy())
    assert np.all(np.abs(poles) < 1.0)


def test_any_raw_parameters_give_stable_dynamics():
    sections = StableSections(order=6)
    with torch.no_grad():
        sections.raw_denominators.copy_(torch.randn(3, 2, dtype=torch.float64) * 30)
    for row in sections.denominators().detach().numpy():
        assert np.all(np.abs(np.roots(row)) < 1.0)


def positioner(effects: dict) -> tuple:
    data = make_default_dataset(effects=effects, n_train=8000, test_frequencies=(10.0, 100.0),
                                max_test_samples=3000, val_samples=4000)
    return data, WindowDataModule(data, scaling="paper")


def test_a_linear_positioner_is_identified_to_the_noise_floor(tmp_path):
    """Amplifier, delay and mode with the hysteresis and creep switched off: a linear
    system, which the linear model simulates at the sensor noise."""
    data, dm = positioner({"hysteresis": {"enabled": False}, "creep": {"enabled": False}})
    L.seed_everything(0)
    model = build_model({"name": "linear"}, dm, trained_on={"fs": data.fs})
    fitted = fit(model, dm, TRAINER, tmp_path).model
    ft = dm.window.first_target
    for predicted, rec in zip(free_run(fitted, data.test, dm.window), data.test, strict=True):
        assert np.sqrt(np.mean((predicted[ft:] - rec.y[ft:]) ** 2)) < 5 * NOISE_UM


def test_an_added_effect_block_starts_where_it_changes_nothing(tmp_path):
    """The loop grows a fitted linear model by an effect: the grown model simulates exactly
    what the fitted one did until its new block is trained."""
    data, dm = positioner({})
    L.seed_everything(0)
    plain = fit(build_model({"name": "linear"}, dm, trained_on={"fs": data.fs}), dm,
                TRAINER.with_changes(max_epochs=1), tmp_path).model
    effects = ["saturation", "dead_zone", "backlash", "hysteresis", "rate", "creep",
               "resonance", "nonlinear_feedback", "overflow"]
    augmented, context = augment_splits(data, effects)
    dm_grown = WindowDataModule(augmented, scaling="paper")
    grown = build_model({"name": "linear", "effects": effects}, dm_grown,
                        trained_on={"fs": data.fs}, feature_context=context_to_dict(context),
                        n_base_inputs=1)
    grown.warm_start_from(plain)
    for a, b in zip(free_run(plain, data.test, dm.window),
                    free_run(grown, augmented.test, dm.window), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)
    assert set(grown._new_entries) >= {"creep.0.weights", "input_blocks.0.hysteresis.weight",
                                       "input_blocks.0.hysteresis.rate_gain"}
    before = free_run(grown, augmented.test, dm.window)
    for name in ("saturation", "dead_zone", "backlash", "hysteresis"):  # each block is in the
        with torch.no_grad():                                          # chain: weighted, it acts
            grown.input_blocks[0][name].weight.fill_(0.5)
        after = free_run(grown, augmented.test, dm.window)
        assert max(np.max(np.abs(a - b)) for a, b in zip(after, before, strict=True)) > 1e-3, name
        with torch.no_grad():
            grown.input_blocks[0][name].weight.zero_()
    cell = grown.input_blocks[0]["hysteresis"]
    with torch.no_grad():  # the rate gain widens the weighted cell's loop on fast inputs
        cell.weight.fill_(0.5)
        weighted = free_run(grown, augmented.test, dm.window)
        cell.rate_gain.fill_(2.0)
    after = free_run(grown, augmented.test, dm.window)
    assert max(np.max(np.abs(a - b)) for a, b in zip(after, weighted, strict=True)) > 1e-3
    with torch.no_grad():
        cell.weight.zero_()
        cell.rate_gain.zero_()
    with torch.no_grad():  # the static feedback closes a loop around the (resonant) dynamics
        grown.static_feedback[0][0].weights.fill_(1e-5)
    after = free_run(grown, augmented.test, dm.window)
    change = max(np.max(np.abs(a - b)) for a, b in zip(after, before, strict=True))
    assert 1e-6 < change < 1.0
    with torch.no_grad():
        grown.static_feedback[0][0].weights.zero_()
    with torch.no_grad():  # the output block acts after the dynamics: levels inside the range
        grown.overflow[0].levels.copy_(torch.tensor([-0.1, 0.1]))
        grown.overflow[0].weights.fill_(1.0)
    clipped = free_run(grown, augmented.test, dm.window)
    scale = float(grown.y_scale[0])
    for rec, y in zip(augmented.test, clipped, strict=True):
        assert np.max(y[dm.window.first_target:]) == pytest.approx(0.1 * scale)  # the level
        assert np.max(rec.y) > 0.2 * scale


def test_effects_without_a_block_are_refused():
    data, dm = positioner({})
    with pytest.raises(ConfigError, match=r"effects \['drift'\]"):
        build_model({"name": "linear", "effects": ["drift"]}, dm, feature_context={})


def mimo_recordings(n_rec: int, n: int, seed: int) -> list:
    """A stable 2-input, 2-output linear system (a distinct second-order transfer function
    per pair, a rest offset per output), driven by white noise from rest."""
    from hysteresis_lab.data.recording import Recording

    systems = [[([0.0, 0.2, 0.1], [1.0, -1.2, 0.5]), ([0.0, -0.3], [1.0, -0.7])],
               [([0.0, 0.1], [1.0, -0.9]), ([0.0, 0.4, -0.2], [1.0, -0.5, 0.3])]]
    rng = np.random.default_rng(seed)
    out = []
    for r in range(n_rec):
        u = rng.normal(size=(n, 2))
        y = np.stack([sum(signal.lfilter(b, a, u[:, j]) for j, (b, a) in enumerate(row))
                      for row in systems], axis=1) + np.array([1.0, -2.0])
        out.append(Recording(u=u, y=y, fs=1000.0, name=f"r{seed}_{r}"))
    return out


def test_mimo_data_are_identified_per_output_and_input(tmp_path):
    """Two inputs, two outputs: each output a sum over inputs of its own dynamics; the ARX
    start on every recording (one denominator per output: 3 poles) and the free-run fit
    simulate a new recording exactly."""
    from hysteresis_lab.data.splits import DatasetSplits

    splits = DatasetSplits("mimo", train=mimo_recordings(3, 800, 0),
                           test=mimo_recordings(1, 800, 1))
    dm = WindowDataModule(splits, scaling="standard")
    L.seed_everything(0)
    model = build_model({"name": "linear", "order": 3}, dm, trained_on={"fs": 1000.0})
    fitted = fit(model, dm, TRAINER.with_changes(max_epochs=1), tmp_path).model
    assert len(fitted.dynamics) == 2 and len(fitted.dynamics[0]) == 2
    predicted = free_run(fitted, splits.test, dm.window)[0]
    y = splits.test[0].y
    ft = dm.window.first_target
    assert np.sqrt(np.mean((predicted[ft:] - y[ft:]) ** 2, axis=0)).max() < 1e-3 * y.std()


def test_a_model_saved_in_the_single_channel_layout_loads():
    """The one-input layout before MIMO (``input_blocks.<effect>``, ``dynamics.<parameter>``,
    a scalar offset) loads into the per-channel one unchanged."""
    data, dm = positioner({})
    model = build_model({"name": "linear"}, dm, trained_on={"fs": data.fs})
    with torch.no_grad():
        model.offset.fill_(0.25)
    old = {key.replace("dynamics.0.0.", "dynamics."): value
           for key, value in model.state_dict().items()}
    old["offset"] = old["offset"].reshape(())
    fresh = build_model({"name": "linear"}, dm, trained_on={"fs": data.fs})
    fresh.load_state_dict(old)
    assert float(fresh.offset[0]) == 0.25
    torch.testing.assert_close(fresh.dynamics[0][0].numerators, model.dynamics[0][0].numerators)


def test_a_single_sine_starts_from_an_arx_order_it_identifies():
    """P-885's one 1 Hz sine does not identify an order-6 ARX (its free run from rest lay at
    74 um on a ±22 um record): the start falls back to the order that simulates best, and
    its free run stays within the output's spread."""
    from hysteresis_lab.data.benchmarks import piezo_p885

    data = piezo_p885()
    dm = WindowDataModule(data, scaling="standard")
    dm.setup()
    model = build_model({"name": "linear", "order": 6}, dm, trained_on={"fs": data.fs})
    train = data.train[0]
    model.initialise_from_data(train.u[:, 0], train.y[:, 0], train.fs)
    predicted = free_run(model, data.test, dm.window)[0]
    ft = dm.window.first_target
    rmse = np.sqrt(np.mean((predicted[ft:] - data.test[0].y[ft:]) ** 2))
    assert rmse < 0.5 * np.std(data.test[0].y)
