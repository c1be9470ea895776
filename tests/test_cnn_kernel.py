"""The compiled CNN free run (`_CNNKernel.run_all`) against the NumPy step and torch."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.models.cnn import CNNNet, _CNNKernel

# (window, nu, ny, num_layers, conv_layers, kernel_size): default lags, the study's two conv
# layers; masked lags, delay 2, two inputs, one conv layer, a hidden dense layer; no output
# lags, three conv layers; no delay, two outputs; masked lags with two outputs, kernel 3;
# an even kernel (torch pads one more sample on the right)
SETUPS = [
    (WindowSpec(), 1, 1, 3, 2, 5),
    (WindowSpec(na=3, nb=6, nk=2), 2, 1, 3, 1, 5),
    (WindowSpec(na=0, nb=5, nk=1), 1, 1, 4, 3, 3),
    (WindowSpec(na=4, nb=4, nk=0), 1, 2, 3, 1, 3),
    (WindowSpec(na=5, nb=3, nk=1), 1, 2, 3, 2, 3),
    (WindowSpec(na=2, nb=7, nk=1), 1, 1, 3, 2, 4),
]
IDS = ["default", "masked_1conv", "na0_3conv_k3", "nk0_mimo_k3", "masked_mimo_k3", "even_k4"]


def random_model(window: WindowSpec, nu: int, ny: int, num_layers: int, conv_layers: int,
                 kernel_size: int, seed: int = 0) -> CNNNet:
    torch.manual_seed(seed)
    return CNNNet(nu=nu, ny=ny, na=window.na, nb=window.nb, nk=window.nk,
                  num_layers=num_layers, conv_layers=conv_layers, units=12,
                  kernel_size=kernel_size).eval()


def recordings(nu: int, ny: int, lengths: tuple[int, ...] = (160, 90, 90, 40)) -> list[Recording]:
    rng = np.random.default_rng(1)
    recs = []
    for i, n in enumerate(lengths):
        t = np.arange(n) / 100.0
        u = np.sin(2 * np.pi * (1.0 + i) * t)[:, None] + 0.3 * rng.standard_normal((n, nu))
        recs.append(Recording(u=u, y=rng.standard_normal((n, ny)), fs=100.0, name=f"r{i}"))
    return recs


def step_loop(kernel: _CNNKernel, y: np.ndarray, active: np.ndarray,
              first_target: int, term: np.ndarray | None = None) -> np.ndarray:
    """The NumPy reference: one `step` per sample (what the simulator did before run_all)."""
    for k in range(first_target, y.shape[1]):
        n = int(active[k])
        y[:n, k] = kernel.step(k, n, y) + (term[:n, k] if term is not None else 0.0)
    return y


@pytest.mark.parametrize("setup", SETUPS, ids=IDS)
def test_run_all_equals_the_step_kernel_and_torch(setup, monkeypatch):
    window, nu, ny = setup[:3]
    model = random_model(window, nu, ny, *setup[3:])
    recs = recordings(nu, ny)
    reference = free_run(model, recs, window, fast=False)  # torch loop

    def no_step(*args, **kwargs):
        raise AssertionError("free_run should use run_all, not step")

    with monkeypatch.context() as patch:
        patch.setattr(_CNNKernel, "step", no_step)
        compiled = free_run(model, recs, window)
    for rec, a, b in zip(recs, compiled, reference, strict=True):
        assert a.shape == rec.y.shape
        np.testing.assert_array_equal(a[: window.first_target], rec.y[: window.first_target])
        np.testing.assert_allclose(a, b, atol=2e-5)
        assert b[window.first_target :].std() > 0.01  # the output moves: not a trivial check

    # the same rows directly, against the NumPy step kernel, with an input-only output term
    n = max(r.n_samples for r in recs)
    lengths = np.array([r.n_samples for r in recs])
    u = np.zeros((len(recs), n, nu))
    y = np.zeros((len(recs), n, ny))
    for b, rec in enumerate(recs):
        u[b, : rec.n_samples], y[b, : rec.n_samples] = rec.u, rec.y
    active = np.searchsorted(-lengths, -np.arange(n), side="left")
    term = np.random.default_rng(2).standard_normal(y.shape) * 0.1
    ft = window.first_target
    for extra in (None, term):
        fast = model.free_run_kernel(u, window).run_all(y.copy(), active, ft, term=extra)
        slow = step_loop(model.free_run_kernel(u, window), y.copy(), active, ft, extra)
        np.testing.assert_allclose(fast, slow, atol=1e-5)
        np.testing.assert_array_equal(fast[:, :ft], y[:, :ft])
        for b, length in enumerate(lengths):  # rows past their end keep the padding
            np.testing.assert_array_equal(fast[b, length:], y[b, length:])


def test_run_all_is_independent_of_the_batch():
    window = WindowSpec()
    model = random_model(window, 1, 1, 3, 2, 5)
    recs = recordings(1, 1)
    batched = free_run(model, recs, window)
    for rec, a in zip(recs, batched, strict=True):
        np.testing.assert_array_equal(a, free_run(model, [rec], window)[0])
