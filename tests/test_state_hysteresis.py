"""The linear model's state-side hysteresis: its dynamics in a closed loop with a Bouc–Wen
restoring force of their output (the Bouc–Wen oscillator), exact gradients, and a refit that
learns a simulated oscillator's hysteresis."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch
from scipy import signal

from hysteresis_lab.blocks.feedback import closed_loop
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.loop.driver import _refit_mode
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from hysteresis_lab.models.linear import LinearModel
from hysteresis_lab.signals import multisine

FS = 100.0
STIFFNESS = (2 * np.pi * 3.0) ** 2  # k = alpha: a 3 Hz mode whose spring is half hysteretic


def _parameters(lag: int) -> tuple[torch.Tensor, ...]:
    double = {"dtype": torch.float64, "requires_grad": True}
    b = torch.tensor([0.0 if lag == 0 else 0.3, 0.5, 0.2, -0.1], **double)
    return (b, torch.tensor([1.0, -1.2, 0.5], **double), torch.tensor(0.3, **double),
            torch.tensor(-0.2, **double), torch.tensor([1.0, 0.5], **double),
            torch.tensor([0.8, 1.5], **double), torch.tensor([1.2, 0.4], **double))


def test_the_closed_loop_has_exact_gradients_and_is_the_dynamics_without_force():
    x = torch.randn(2, 50, dtype=torch.float64, generator=torch.Generator().manual_seed(0),
                    requires_grad=True)
    for lag in (0, 1):  # a delayed numerator feeds back at once, else a sample later
        b, a, wh, wy, ba, r1, r2 = _parameters(lag)
        lead = b[:1].detach()  # b_0 = 0 is structural at lag 0: not a parameter

        def loop(x, b_rest, a, wh, wy, ba, r1, r2, lag=lag, lead=lead):
            return closed_loop(x, torch.cat([lead, b_rest]), a, wh, wy, ba, r1, r2, lag)

        assert torch.autograd.gradcheck(loop, (x, b[1:], a, wh, wy, ba, r1, r2), eps=1e-7,
                                        atol=1e-5)
        zero = torch.zeros((), dtype=torch.float64)
        y = closed_loop(x, b, a, zero, zero, ba, r1, r2, lag).detach().numpy()
        expected = signal.lfilter(b.detach().numpy(), a.detach().numpy(), x.detach().numpy())
        np.testing.assert_allclose(y, expected, atol=1e-12)
        y_force = closed_loop(x, b, a, wh, wy, ba, r1, r2, lag).detach().numpy()
        assert np.max(np.abs(y_force - expected)) > 1e-2


def oscillator(n: int, seed: int, name: str) -> Recording:
    """``y'' + c y' + k y + z = u``, ``z' = k y' - |y'| z + 0.5 y' |z|`` (the
    Bouc–Wen benchmark's equations, bounded), integrated at 20 times the sampling rate
    (semi-implicit Euler) from rest under a multisine."""
    u = multisine(n, fs=FS, n_components=20, f_max=10.0, seed=seed)
    u = 2.0 * STIFFNESS * u / np.std(u)
    sub, damping = 20, 0.1 * np.sqrt(2.0 * STIFFNESS)
    dt = 1.0 / (FS * sub)
    y = v = z = 0.0
    out = np.empty(n)
    for i in range(n):
        for _ in range(sub):
            v += dt * (u[i] - damping * v - STIFFNESS * y - z)
            z += dt * (STIFFNESS * v - abs(v) * z + 0.5 * v * abs(z))
            y += dt * v
        out[i] = y
    return Recording(u=u, y=out, fs=FS, name=name)


def test_the_feedback_refit_learns_a_bouc_wen_oscillator(tmp_path):
    """The loop's step on a simulated Bouc–Wen oscillator: a fitted linear model grown by
    `hysteresis` starts where it was and, refitted whole, cuts the test free-run error well
    below the linear model's."""
    splits = DatasetSplits("oscillator", train=[oscillator(2000, 1, "train")],
                           val=[oscillator(600, 2, "val")], test=[oscillator(600, 3, "test")])
    trainer = TrainerSettings(max_epochs=80, accelerator="cpu", enable_progress_bar=False,
                              enable_model_summary=False)
    settings = {"name": "linear", "order": 2, "lr": 0.01}
    dm = WindowDataModule(splits, scaling="standard")
    L.seed_everything(0)
    linear = fit(build_model(settings, dm, trained_on={"fs": FS}), dm, trainer,
                 tmp_path / "linear").model
    augmented, context = augment_splits(splits, ["hysteresis"])
    dm_grown = WindowDataModule(augmented, scaling="standard")
    grown = build_model({**settings, "effects": ["hysteresis"]}, dm_grown,
                        trained_on={"fs": FS}, feature_context=context_to_dict(context),
                        n_base_inputs=1)
    grown.warm_start_from(linear)
    assert _refit_mode("new_inputs", "hysteresis", LinearModel) == "full"
    ft = dm.window.first_target
    y = splits.test[0].y[ft:]

    def rmse(model, test) -> float:
        return float(np.sqrt(np.mean((free_run(model, test, dm.window)[0][ft:] - y) ** 2)))

    before = rmse(linear, splits.test)
    assert rmse(grown, augmented.test) == pytest.approx(before, rel=1e-9)  # no force yet
    grown = fit(grown, dm_grown, trainer, tmp_path / "grown").model
    assert rmse(grown, augmented.test) < 0.5 * before
    assert grown.physical_parameters()["state_hysteresis"][0][0]["weight"] != 0.0


def test_a_model_saved_with_the_former_feedback_hysteresis_is_refused_with_a_fix():
    from hysteresis_lab.errors import ConfigError

    splits = DatasetSplits("oscillator", train=[oscillator(300, 1, "train")],
                           test=[oscillator(200, 3, "test")])
    augmented, context = augment_splits(splits, ["hysteresis"])
    model = build_model({"name": "linear", "order": 2, "effects": ["hysteresis"]},
                        WindowDataModule(augmented, scaling="standard"), trained_on={"fs": FS},
                        feature_context=context_to_dict(context), n_base_inputs=1)
    old = {k: v for k, v in model.state_dict().items() if "state_hysteresis" not in k}
    old["state_hysteresis.0.0.weights"] = torch.zeros(5, dtype=torch.float64)
    with pytest.raises(ConfigError, match="train it again"):
        model.load_state_dict(old)
