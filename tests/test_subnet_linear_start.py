"""SUBNET's linear start: before any training the model free-runs (and predicts one step) as
well as a least-squares linear model, on linear and on MIMO data, and it stays stable."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch
from scipy import signal

from hysteresis_lab.blocks.sections import arx_least_squares
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.evaluation.predict import free_run, one_step
from hysteresis_lab.fitting import _initialise_from_data, build_model
from hysteresis_lab.models.subnet_init import stabilise
from narx import datamodule_for, narx_data

SUBNET = {"name": "subnet", "nx": 4, "neurons": 16, "encoder_neurons": 16}
B, A = [0.0, 0.2, 0.1], [1.0, -1.2, 0.5]  # a resonant second-order system, one sample delay
NOISE = 0.01


def linear_data(seed: int = 0) -> DatasetSplits:
    """The linear system above (output offset 0.3, sensor noise) on noise; sine tests."""
    rng = np.random.default_rng(seed)

    def record(u: np.ndarray, name: str) -> Recording:
        y = signal.lfilter(B, A, u) + 0.3 + NOISE * rng.standard_normal(len(u))
        return Recording(u=u[:, None], y=y[:, None], fs=100.0, name=name)

    t = np.arange(400) / 100.0
    return DatasetSplits("linear", train=[record(rng.uniform(-1, 1, 2000), "train")],
                         test=[record(np.sin(2 * np.pi * f * t), f"sine{f}") for f in (1.0, 5.0)])


def initialised(splits: DatasetSplits, **cfg) -> tuple:
    dm = datamodule_for("subnet", splits)
    L.seed_everything(0)
    model = build_model({**SUBNET, **cfg}, dm).eval()
    return model, dm


def rmse(predictions, recordings, start: int) -> float:
    return float(np.sqrt(np.mean(np.concatenate(
        [(p[start:] - r.y[start:]) ** 2 for p, r in zip(predictions, recordings, strict=True)]))))


def arx_free_run_rmse(splits: DatasetSplits, order: int, start: int) -> float:
    """Free-run RMSE on the tests of a least-squares ARX model of the training recording."""
    rec = splits.train[0]
    b, a = arx_least_squares(rec.u[:, 0], rec.y[:, 0], order, order, 1)
    offset = np.mean(rec.y[:, 0] - signal.lfilter(b, a, rec.u[:, 0]))
    runs = [(signal.lfilter(b, a, r.u[:, 0]) + offset)[:, None] for r in splits.test]
    return rmse(runs, splits.test, start)


def test_untrained_subnet_identifies_a_linear_system():
    """The linear start alone finds a linear system to its noise level: free run and one
    step as good as the least-squares ARX model of the system's own order."""
    splits = linear_data()
    model, dm = initialised(splits)
    ft = dm.window.first_target
    random_start = rmse(free_run(model, splits.test, dm.window), splits.test, ft)
    _initialise_from_data(model, dm)
    free = rmse(free_run(model, splits.test, dm.window), splits.test, ft)
    step = rmse(one_step(model, splits.test, dm.window), splits.test, ft)
    arx = arx_free_run_rmse(splits, 2, ft)
    assert free < 3 * NOISE and step < 3 * NOISE  # the noise level: the system itself
    assert free < 1.5 * arx
    assert random_start > 10 * free  # the random start is far off: the start did the work


def test_linear_start_matches_arx_on_a_nonlinear_system():
    """On the NARX system with play-operator memory the untrained model free-runs about as
    well as a least-squares ARX model (the networks start at zero: a linear model)."""
    splits = narx_data()
    model, dm = initialised(splits)
    _initialise_from_data(model, dm)
    ft = dm.window.first_target
    free = rmse(free_run(model, splits.test, dm.window), splits.test, ft)
    assert free < 1.3 * arx_free_run_rmse(splits, 2, ft)


def test_linear_start_of_a_mimo_system():
    """Two inputs, two outputs (the FSM's case): the start reproduces the linear system."""
    rng = np.random.default_rng(1)

    def record(u: np.ndarray, name: str) -> Recording:
        y = np.column_stack([signal.lfilter(B, A, u[:, 0]) + 0.5 * signal.lfilter(B, A, u[:, 1]),
                             signal.lfilter([0.0, 0.3], [1.0, -0.7], u[:, 1])])
        return Recording(u=u, y=y + NOISE * rng.standard_normal(y.shape), fs=100.0, name=name)

    splits = DatasetSplits("mimo", train=[record(rng.uniform(-1, 1, (3000, 2)), "train")],
                           test=[record(rng.uniform(-1, 1, (500, 2)), "test")])
    model, dm = initialised(splits, nx=3)
    _initialise_from_data(model, dm)
    ft = dm.window.first_target
    assert rmse(free_run(model, splits.test, dm.window), splits.test, ft) < 3 * NOISE


def test_linear_start_can_be_switched_off():
    splits = linear_data()
    model, dm = initialised(splits, linear_start=False)
    before = model.A.weight.detach().clone()
    _initialise_from_data(model, dm)
    assert model.A.weight.detach().equal(before)


@pytest.mark.parametrize("eigenvalues", [[1.2, 0.5], [1.0005, -0.3]])
def test_stabilise_moves_every_pole_inside(eigenvalues):
    rng = np.random.default_rng(0)
    basis = rng.standard_normal((2, 2))
    a = basis @ np.diag(eigenvalues) @ np.linalg.inv(basis)
    assert np.abs(np.linalg.eigvals(stabilise(a))).max() < 1.0
    stable = basis @ np.diag([0.9, 0.5]) @ np.linalg.inv(basis)
    np.testing.assert_array_equal(stabilise(stable), stable)  # a stable model is kept


def test_a_subnet_saved_before_the_encoders_linear_map_loads_and_simulates_alike():
    """Checkpoints from before the linear start have no ``encoder_linear``: they load with
    it at zero (what the model without it computed), so their free run is unchanged."""
    splits = linear_data()
    old, dm = initialised(splits, linear_start=False)  # its encoder's linear map is zero
    state = {k: v for k, v in old.state_dict().items() if not k.startswith("encoder_linear.")}
    fresh, _ = initialised(splits, linear_start=False)
    with torch.no_grad():
        fresh.encoder_linear.weight.fill_(1.0)  # overwritten by the load
    fresh.load_state_dict(state)
    assert not fresh.encoder_linear.weight.any()
    expected = free_run(old, splits.test, dm.window)
    for a, b in zip(free_run(fresh.eval(), splits.test, dm.window), expected, strict=True):
        np.testing.assert_array_equal(a, b)
