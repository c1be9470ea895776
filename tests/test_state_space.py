"""SUBNET, the neural state-space model: its free runs agree with each other, it trains on the
simulation error, and it is saved, loaded and scored like every model."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch

from conftest import optional_dependency
from hysteresis_lab.data.segments import SegmentDataModule
from hysteresis_lab.evaluation.predict import free_run, n_step, one_step
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.models.io import load_model, save_model
from narx import TRAINER, datamodule_for

SUBNET = {"name": "subnet", "nx": 4, "neurons": 16, "encoder_neurons": 16, "horizon": 40,
          "lr": 3e-3}


@pytest.fixture(scope="module")
def untrained(splits):
    dm = datamodule_for("subnet", splits)
    L.seed_everything(0)
    return build_model(SUBNET, dm).eval(), dm


def scaled(rec, scaler):
    u = torch.tensor((rec.u - scaler.u_offset) / scaler.u_scale, dtype=torch.float32)[None]
    y = torch.tensor((rec.y - scaler.y_offset) / scaler.y_scale, dtype=torch.float32)[None]
    return u, y


def test_compiled_free_run_equals_the_torch_free_run(untrained):
    """The numba kernel that evaluation uses is the differentiable free run of training."""
    model, dm = untrained
    rec = dm.splits.test[0]
    u, y = scaled(rec, dm.scaler)
    ft = dm.window.first_target
    with torch.no_grad():
        reference = model.simulate_scaled(u, y[:, :ft])[0].double().numpy()
    compiled = free_run(model, [rec], dm.window)[0][ft:]
    s = dm.scaler
    np.testing.assert_allclose(compiled, reference * s.y_scale + s.y_offset, atol=1e-4)
    assert np.std(reference) > 1e-3  # a model that outputs a constant would match trivially


def test_one_step_is_the_output_of_the_encoded_state(untrained):
    """n-step prediction with n=1 re-encodes the state at every sample: the one-step
    prediction; a long horizon is the free run."""
    model, dm = untrained
    recs = dm.splits.test
    for a, b in zip(n_step(model, recs, dm.window, 1), one_step(model, recs, dm.window),
                    strict=True):
        np.testing.assert_allclose(a, b, atol=1e-4)
    for a, b in zip(n_step(model, recs, dm.window, 10_000), free_run(model, recs, dm.window),
                    strict=True):
        np.testing.assert_allclose(a, b, atol=1e-4)


def test_training_on_the_simulation_error_lowers_it(splits, tmp_path):
    dm = datamodule_for("subnet", splits)
    L.seed_everything(0)
    model = build_model(SUBNET, dm)
    segments = SegmentDataModule(dm, 40)
    u, y = segments.val_dataloader().dataset.tensors
    ft = dm.window.first_target

    def loss() -> float:
        with torch.no_grad():
            return float(torch.mean((model.simulate_scaled(u, y[:, :ft]) - y[:, ft:]) ** 2))

    before = loss()
    result = fit(model, dm, TRAINER.with_changes(max_epochs=40), tmp_path)
    assert loss() < 0.5 * before
    assert result.val_mse == pytest.approx(loss(), rel=1e-3)  # selection on the free run
    assert result.checkpoint is not None and result.checkpoint.parent.name == "checkpoints"


def test_a_saved_subnet_loads_and_predicts_the_same(untrained, tmp_path):
    model, dm = untrained
    loaded = load_model(save_model(model, tmp_path / "model"))
    for a, b in zip(free_run(model, dm.splits.test, dm.window),
                    free_run(loaded, dm.splits.test, dm.window), strict=True):
        np.testing.assert_array_equal(a, b)


def test_warm_start_with_an_effect_channel_keeps_the_free_run():
    """The loop's refit grows a fitted SUBNET by effect channels; their weights start at
    zero, so the grown model simulates exactly what the fitted one did (nested models)."""
    torch.manual_seed(0)
    cfg = {k: v for k, v in SUBNET.items() if k not in ("name", "horizon", "lr")}
    fitted = build_model_class("subnet")(nu=1, ny=1, **cfg)
    grown = build_model_class("subnet")(nu=3, ny=1, **cfg)
    u = torch.randn(2, 60, 1)
    u_grown = torch.cat([u, torch.randn(2, 60, 2)], -1)
    y = torch.randn(2, 10, 1)
    with torch.no_grad():
        assert not torch.allclose(fitted.simulate_scaled(u, y), grown.simulate_scaled(u_grown, y))
        grown.warm_start_from(fitted)
        np.testing.assert_allclose(grown.simulate_scaled(u_grown, y),
                                   fitted.simulate_scaled(u, y), atol=1e-5)


def build_model_class(name: str):
    from hysteresis_lab.models.registry import get_model_class

    return get_model_class(name)


def test_onnx_step_simulates_like_the_model(untrained, tmp_path):
    """The exported step file, fed its own state, reproduces the model's free run."""
    ort = optional_dependency("onnxruntime")
    from hysteresis_lab.models.export import export_onnx

    model, dm = untrained
    path = export_onnx(model, tmp_path / "subnet.onnx")
    step = ort.InferenceSession(str(path.with_name("subnet_step.onnx")))
    rec = dm.splits.test[0]
    u, y = scaled(rec, dm.scaler)
    ft = dm.window.first_target
    with torch.no_grad():
        state = model.encode(model._regressor_at(u, y[:, :ft], ft)).numpy()
    expected = free_run(model, [rec], dm.window)[0][ft : ft + 50]
    produced = []
    for k in range(ft, ft + 50):
        y_k, state = step.run(None, {"state": state,
                                     "u": rec.u[k - dm.window.nk + 1][None].astype(np.float32)})
        produced.append(y_k[0])
    np.testing.assert_allclose(np.array(produced), expected, atol=1e-3)
