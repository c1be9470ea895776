"""Gradients of the blocks' custom autograd functions (float64 gradcheck) and shared kernels."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hysteresis_lab.blocks import (
    BoucWen,
    CreepBank,
    Delay,
    FirstOrderLag,
    PlayOperators,
    SecondOrderMode,
    bouc_wen_free_run,
    iir_filter,
    mode_coefficients,
    play,
)
from hysteresis_lab.physics.bouc_wen import BoucWenStates, bouc_wen_state
from hysteresis_lab.physics.filters import first_order_lowpass
from hysteresis_lab.physics.play import play_operators
from hysteresis_lab.sim import blocks as sim_blocks
from hysteresis_lab.sim.config import Mode


def _signal(n: int, seed: int, batch: int = 2) -> torch.Tensor:
    rng = np.random.default_rng(seed)
    return torch.tensor(np.cumsum(rng.normal(0, 0.3, (batch, n)), axis=1), dtype=torch.float64)


def test_iir_filter_gradcheck() -> None:
    x = _signal(30, 0).requires_grad_()
    b = torch.tensor([0.2, 0.3, 0.1], dtype=torch.float64, requires_grad=True)
    a = torch.tensor([1.0, -0.9, 0.3], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(iir_filter, (x, b, a))


def test_bouc_wen_gradcheck_includes_zero_crossings() -> None:
    v = _signal(40, 1)  # random walk: direction changes, h changes sign inside steps
    v0 = torch.tensor([0.1, -0.2], dtype=torch.float64, requires_grad=True)
    h0 = torch.tensor([[0.05, -0.1], [-0.2, 0.02]], dtype=torch.float64, requires_grad=True)
    a = torch.tensor([0.37, 0.2], dtype=torch.float64, requires_grad=True)
    r1 = torch.tensor([1.4, 0.5], dtype=torch.float64, requires_grad=True)
    r2 = torch.tensor([2.6, 1.5], dtype=torch.float64, requires_grad=True)
    v.requires_grad_()
    assert torch.autograd.gradcheck(BoucWenStates.apply, (v, v0, h0, a, r1, r2))
    hs = BoucWenStates.apply(v, v0, h0, a, r1, r2).detach().numpy()
    signs = np.sign(hs[:, 1:, :]) * np.sign(hs[:, :-1, :])
    assert (signs < 0).sum() >= 2  # the crossing branch was exercised


def test_bouc_wen_module_gradients_reach_every_parameter() -> None:
    bw = BoucWen(d=1.15, alpha=0.32, beta=2.0, gamma=0.6, n_channels=2)
    x, h_last = bw(_signal(50, 2).float())
    assert x.dtype == torch.float32 and x.shape == (2, 50) and h_last.shape == (2, 2)
    (x.square().sum() + h_last.sum()).backward()
    for p in bw.parameters():
        assert p.grad is not None and torch.all(torch.isfinite(p.grad)) and p.grad.abs().sum() > 0


def test_bouc_wen_matches_simulator_kernel_and_free_run() -> None:
    rng = np.random.default_rng(3)
    v = 60.0 * np.sin(np.linspace(0, 12, 400)) + rng.normal(0, 2, 400)
    d, alpha, beta, gamma = 0.23, 0.32, 0.02, 0.006
    x_sim = d * v - bouc_wen_state(v, d, np.full(len(v), alpha), beta, gamma)
    x_free = bouc_wen_free_run(v[None], d, alpha, beta, gamma)[0]
    np.testing.assert_allclose(x_free, x_sim, rtol=0, atol=1e-12)
    bw = BoucWen(d, alpha, beta, gamma)
    x_torch, _ = bw(torch.tensor(v[None]))
    np.testing.assert_allclose(x_torch.detach().numpy()[0], x_sim, rtol=0, atol=1e-10)
    np.testing.assert_allclose(bw.numpy_kernel()(v[None])[0], x_sim, atol=1e-10)


def test_bouc_wen_rejects_unbounded_parameters() -> None:
    with pytest.raises(ValueError):
        BoucWen(beta=0.01, gamma=0.02)


def test_play_gradcheck_and_shared_recursion() -> None:
    v = _signal(40, 4).requires_grad_()
    r = torch.tensor([0.05, 0.2, 0.5], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(play, (v, r))
    ref = play_operators(v.detach().numpy()[0].copy(), r.detach().numpy())
    np.testing.assert_array_equal(play(v, r).detach().numpy()[0], ref)


def test_play_operators_module() -> None:
    pi = PlayOperators(n_operators=4, max_threshold=0.8)
    r = pi.thresholds.detach().numpy()
    assert np.all(r > 0) and np.all(np.diff(r) > 0)
    y = pi(_signal(60, 5))
    y.square().sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in pi.parameters())
    assert set(pi.export()) == {"w0", "thresholds", "weights"}


def test_mode_coefficients_equal_simulator_filter() -> None:
    fs, f, zeta = 20_000.0, 900.0, 0.03
    x = np.random.default_rng(6).normal(size=500)
    ref = sim_blocks.mode_filter(x, fs, Mode(frequency_hz=f, damping=zeta))
    mode = SecondOrderMode(fs, f, zeta).double()
    np.testing.assert_allclose(mode(torch.tensor(x[None]))[0].detach().numpy(), ref, atol=1e-10)
    b, a = mode_coefficients(torch.tensor(f, dtype=torch.float64),
                             torch.tensor(zeta, dtype=torch.float64), fs)
    assert float(b.sum() / a.sum()) == pytest.approx(1.0)  # unit DC gain


@pytest.mark.parametrize("raw", [-50.0, -5.0, 0.0, 5.0, 50.0])
def test_linear_blocks_stable_for_any_raw_parameter(raw: float) -> None:
    mode = SecondOrderMode(20_000.0, 900.0, 0.03, n_modes=2)
    lag = FirstOrderLag(20_000.0, 5000.0)
    with torch.no_grad():
        mode.raw_frequency.fill_(raw)
        mode.raw_damping.fill_(raw)
        lag.raw_cutoff.fill_(min(raw, 30.0))
    for m in range(2):
        _, a = mode_coefficients(mode.frequency_hz[m], mode.damping[m], mode.fs)
        a1, a2 = a.detach().numpy()[1:]
        assert abs(a2) < 1.0 and abs(a1) < 1.0 + a2  # stability triangle
    _, a = lag.coefficients()
    assert 0.0 <= -float(a[1]) < 1.0


def test_mode_weights_sum_to_one_and_gradients() -> None:
    mode = SecondOrderMode(20_000.0, [900.0, 2800.0], [0.03, 0.02], n_modes=2,
                           weights=[0.85, 0.15])
    assert float(mode.weights.detach().sum()) == pytest.approx(1.0)
    assert mode.weights.detach().numpy() == pytest.approx([0.85, 0.15])
    y = mode(_signal(200, 7).float())
    y.square().sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in mode.parameters())


def test_creep_and_delay() -> None:
    fs = 1000.0
    x = np.random.default_rng(8).normal(size=300)
    creep = CreepBank(fs, (0.01, 0.1), weights=0.05).double()
    ref = x + 0.05 * (first_order_lowpass(x, fs, 0.01)
                      + first_order_lowpass(x, fs, 0.1))
    np.testing.assert_allclose(creep(torch.tensor(x[None]))[0].detach().numpy(), ref,
                               atol=1e-12)
    assert CreepBank(fs).weights.detach().abs().sum() == 0.0  # initialised off
    out = Delay(2)(torch.tensor(x[None]))[0].numpy()
    np.testing.assert_array_equal(out, sim_blocks.delay(x, 2))
