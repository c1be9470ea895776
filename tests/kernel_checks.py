"""Shared checks of a compiled free-run kernel (`run_all`) against the torch loop and the
kernel's own NumPy `step` (used by the LSTM and CNN kernel tests)."""

from __future__ import annotations

import numpy as np
import pytest

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.evaluation.predict import free_run


def recordings(nu: int, ny: int, lengths: tuple[int, ...] = (160, 90, 90, 40)) -> list[Recording]:
    """Noisy sines of different lengths (rows drop out of the batch as they finish)."""
    rng = np.random.default_rng(1)
    recs = []
    for i, n in enumerate(lengths):
        t = np.arange(n) / 100.0
        u = np.sin(2 * np.pi * (1.0 + i) * t)[:, None] + 0.3 * rng.standard_normal((n, nu))
        recs.append(Recording(u=u, y=rng.standard_normal((n, ny)), fs=100.0, name=f"r{i}"))
    return recs


def step_loop(kernel, y: np.ndarray, active: np.ndarray, first_target: int,
              term: np.ndarray | None = None) -> np.ndarray:
    """The NumPy reference: one `step` per sample (what the simulator did before run_all)."""
    for k in range(first_target, y.shape[1]):
        n = int(active[k])
        y[:n, k] = kernel.step(k, n, y) + (term[:n, k] if term is not None else 0.0)
    return y


def check_run_all(model, kernel_class: type, window: WindowSpec, nu: int, ny: int,
                  monkeypatch: pytest.MonkeyPatch) -> None:
    """``free_run`` takes the compiled path and equals the torch loop; ``run_all`` equals the
    step kernel with and without an output term and leaves initial conditions and padding."""
    recs = recordings(nu, ny)
    reference = free_run(model, recs, window, fast=False)  # torch loop

    def no_step(*args, **kwargs):
        raise AssertionError("free_run should use run_all, not step")

    with monkeypatch.context() as patch:
        patch.setattr(kernel_class, "step", no_step)
        compiled = free_run(model, recs, window)
    for rec, a, b in zip(recs, compiled, reference, strict=True):
        assert a.shape == rec.y.shape
        np.testing.assert_array_equal(a[: window.first_target], rec.y[: window.first_target])
        np.testing.assert_allclose(a, b, atol=2e-5)
        assert b[window.first_target :].std() > 0.01  # the output moves: not a trivial check

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


def check_batch_independence(model, window: WindowSpec) -> None:
    """Each recording simulates the same alone as in the batch."""
    recs = recordings(1, 1)
    batched = free_run(model, recs, window)
    for rec, a in zip(recs, batched, strict=True):
        np.testing.assert_array_equal(a, free_run(model, [rec], window)[0])
