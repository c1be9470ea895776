"""One-step, free-run and n-step prediction: honest feedback, batching, fast paths."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError, DataError
from hysteresis_lab.evaluation.predict import free_run, n_step, one_step
from hysteresis_lab.fitting import build_model
from narx import CONFIGS

NAMES = ["ffnn", "lstm", "cnn", "svm"]


def naive_free_run(model, rec: Recording, w: WindowSpec) -> np.ndarray:
    """Reference: one recording, one ``predict_physical`` call per sample."""
    y = rec.y.copy()
    for k in range(w.first_target, rec.n_samples):
        u_past = rec.u[k - w.nk - w.nb + 1 : k - w.nk + 1][None]
        y_past = y[k - w.na : k][None]
        if isinstance(model, torch.nn.Module):
            with torch.no_grad():
                y[k] = model.predict_physical(
                    torch.tensor(u_past, dtype=torch.float32),
                    torch.tensor(y_past, dtype=torch.float32),
                )[0].numpy()
        else:
            y[k] = model.predict_physical(u_past, y_past)[0]
    return y


@pytest.mark.parametrize("name", NAMES)
def test_free_run_feeds_back_its_own_predictions(name, splits, trained):
    model, dm = trained[name]
    rec = splits.test[0]
    ft = dm.window.first_target
    corrupted_y = rec.y.copy()
    corrupted_y[ft:] += 100.0  # measured outputs after the initial window must not matter
    corrupted = Recording(u=rec.u, y=corrupted_y, fs=rec.fs, name=rec.name)
    clean, bad = free_run(model, [rec], dm.window)[0], free_run(model, [corrupted], dm.window)[0]
    np.testing.assert_allclose(clean[ft:], bad[ft:], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(clean[:ft], rec.y[:ft])  # measured initial conditions
    clean_one = one_step(model, [rec], dm.window)[0]
    bad_one = one_step(model, [corrupted], dm.window)[0]
    assert np.abs(clean_one - bad_one)[ft:].max() > 0.1  # one-step does read the measurement


@pytest.mark.parametrize("name", NAMES)
def test_batched_free_run_matches_a_naive_loop_and_single_runs(name, splits, trained):
    model, dm = trained[name]
    recs = [splits.test[0].slice(0, 150, name="short"), splits.test[1].slice(0, 260)]
    batched = free_run(model, recs, dm.window)
    for rec, fast in zip(recs, batched, strict=True):
        assert fast.shape == rec.y.shape
        np.testing.assert_allclose(fast, naive_free_run(model, rec, dm.window), atol=2e-4)
        np.testing.assert_allclose(fast, free_run(model, [rec], dm.window)[0], atol=1e-6)


@pytest.mark.parametrize("name", NAMES)
def test_fast_kernel_equals_the_generic_path(name, splits, trained):
    model, dm = trained[name]
    recs = [splits.test[1], splits.test[0].slice(0, 120)]
    fast = free_run(model, recs, dm.window)
    generic = free_run(model, recs, dm.window, fast=False)
    for a, b in zip(fast, generic, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-4)


@pytest.mark.parametrize("name", ["ffnn", "lstm"])
def test_n_step_between_one_step_and_free_run(name, splits, trained):
    model, dm = trained[name]
    recs = splits.test
    for a, b in zip(n_step(model, recs, dm.window, 1), one_step(model, recs, dm.window),
                    strict=True):
        np.testing.assert_allclose(a, b, atol=1e-4)
    for a, b in zip(n_step(model, recs, dm.window, 10_000), free_run(model, recs, dm.window),
                    strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6)
    five = n_step(model, recs, dm.window, 5)[0]
    ft = dm.window.first_target
    corrupted_y = recs[0].y.copy()
    corrupted_y[ft + 7] += 100.0  # read at the restart at ft + 10, not before
    corrupted = Recording(u=recs[0].u, y=corrupted_y, fs=recs[0].fs, name="c")
    bad = n_step(model, [corrupted], dm.window, 5)[0]
    np.testing.assert_allclose(bad[: ft + 10], five[: ft + 10], atol=1e-9)
    assert np.abs(bad[ft + 10 :] - five[ft + 10 :]).max() > 1e-4
    for bad_horizon in (0, 2.5, True):
        with pytest.raises(DataError, match="must be a whole number >= 1"):
            n_step(model, recs, dm.window, bad_horizon)


def test_data_with_other_channels_than_the_model(trained):
    model, dm = trained["ffnn"]
    two_inputs = Recording(u=np.zeros((100, 2)), y=np.zeros(100), fs=100.0, name="mimo")
    for predict in (free_run, one_step):
        with pytest.raises(DataError, match="2 input.*expects 1"):
            predict(model, [two_inputs], dm.window)
    with pytest.raises(DataError, match="2 input.*expects 1"):
        free_run(trained["svm"][0], [two_inputs], dm.window)


def test_window_other_than_the_models_is_a_config_error(splits, trained):
    model, _ = trained["cnn"]
    with pytest.raises(ConfigError, match="na=10.*na=5"):
        free_run(model, splits.test, WindowSpec(na=5, nb=10, nk=1))


@pytest.mark.parametrize("name", ["ffnn", "cnn", "lstm"])
def test_unequal_lags_and_delay(name, splits, tmp_path):
    """na != nb and nk = 2: masked sequence steps, padding, warm-up before first_target."""
    from hysteresis_lab.data.datamodules import WindowDataModule
    from hysteresis_lab.models.registry import get_model_class

    window = WindowSpec(na=3, nb=6, nk=2)
    dm = WindowDataModule(splits, window=window, layout=get_model_class(name).layout,
                          scaling="standard", batch_size=64)
    model = build_model(CONFIGS[name], dm).eval()
    recs = [splits.test[0].slice(0, 90), splits.test[1].slice(0, 60)]
    fast = free_run(model, recs, window)
    generic = free_run(model, recs, window, fast=False)
    for rec, a, b in zip(recs, fast, generic, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-4)
        np.testing.assert_allclose(a, naive_free_run(model, rec, window), atol=1e-4)
