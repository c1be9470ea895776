"""The blocks with the simulator's parameters reproduce the simulator; the numba chain the
torch chain; the mode estimate finds the simulator's resonance."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import signal

from hysteresis_lab.blocks import (
    BlockChain,
    BoucWen,
    CreepBank,
    Delay,
    FirstOrderLag,
    SecondOrderMode,
    bouc_wen_scaled_params,
    estimate_mode,
    estimate_static_gain,
    simulate_chain,
)
from hysteresis_lab.sim.default_dataset import make_default_dataset
from hysteresis_lab.sim.positioner import Positioner
from hysteresis_lab.sim.reference_chain import chain_from_positioner

FS = 20_000.0
U_SCALE, Y_SCALE = 100.0, 20.0
QUIET = {"noise": {"enabled": False}, "quantisation": {"enabled": False}}


def _random_input(n: int, seed: int = 0, band_hz: float = 2000.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    u = signal.lfilter(*signal.butter(2, band_hz / (FS / 2)), rng.normal(size=n))
    return 100.0 * u / np.abs(u).max()


def _manual_chain() -> BlockChain:
    """The simulator's default blocks, built by hand in scaled units."""
    bw = bouc_wen_scaled_params(0.23, 0.32, 0.02, 0.006, U_SCALE, Y_SCALE)
    return BlockChain(
        FirstOrderLag(FS, 5000.0),
        Delay(1),
        BoucWen(**bw),
        CreepBank(FS, (0.1, 1.0, 10.0, 100.0), weights=0.015),
        SecondOrderMode(FS, 900.0, 0.03),
    ).double()


def test_bouc_wen_scaling_rule() -> None:
    p = bouc_wen_scaled_params(0.23, 0.32, 0.02, 0.006, U_SCALE, Y_SCALE)
    assert p == pytest.approx({"d": 1.15, "alpha": 0.32, "beta": 2.0, "gamma": 0.6})


def test_torch_chain_reproduces_simulator() -> None:
    u = _random_input(int(0.5 * FS))
    y_sim = Positioner(QUIET).simulate(u, FS)
    chain = _manual_chain()
    y = chain(torch.tensor(u[None] / U_SCALE))[0].detach().numpy() * Y_SCALE
    rel = np.max(np.abs(y - y_sim)) / np.max(np.abs(y_sim))
    assert rel < 1e-6
    y2 = chain_from_positioner(QUIET, FS, U_SCALE, Y_SCALE).double()(
        torch.tensor(u[None] / U_SCALE))[0].detach().numpy() * Y_SCALE
    assert np.max(np.abs(y2 - y_sim)) / np.max(np.abs(y_sim)) < 1e-6


def test_two_modes_reproduce_simulator() -> None:
    cfg = {**QUIET, "mode2": {"enabled": True}}
    u = _random_input(4000, seed=1)
    y_sim = Positioner(cfg).simulate(u, FS)
    chain = chain_from_positioner(cfg, FS, U_SCALE, Y_SCALE).double()
    y = chain(torch.tensor(u[None] / U_SCALE))[0].detach().numpy() * Y_SCALE
    assert np.max(np.abs(y - y_sim)) / np.max(np.abs(y_sim)) < 1e-6
    y_numba = simulate_chain(u[None] / U_SCALE, chain.export())[0] * Y_SCALE
    assert np.max(np.abs(y_numba - y_sim)) / np.max(np.abs(y_sim)) < 1e-6


def test_simulate_chain_equals_torch_chain_after_perturbation() -> None:
    chain = _manual_chain()
    with torch.no_grad():  # move every learnable parameter away from its initial value
        for p in chain.parameters():
            p.add_(0.1 * torch.randn_like(p))
    u = _random_input(3000, seed=2)[None].repeat(3, axis=0) * np.array([[1.0], [0.5], [-0.8]])
    u = u / U_SCALE
    y_torch = chain(torch.tensor(u)).detach().numpy()
    y_numba = simulate_chain(u, chain.export())
    np.testing.assert_allclose(y_numba, y_torch, rtol=0, atol=1e-5 * np.abs(y_torch).max())
    multi = BlockChain(bouc_wen=BoucWen(1.15, 0.32, 2.0, 0.6, n_channels=3),
                       mode=SecondOrderMode(FS, 900.0, 0.03, n_modes=2)).double()
    y_torch = multi(torch.tensor(u)).detach().numpy()
    np.testing.assert_allclose(simulate_chain(u, multi.export()), y_torch, rtol=0,
                               atol=1e-5 * np.abs(y_torch).max())


@pytest.fixture(scope="module")
def multisine_recording():
    splits = make_default_dataset(test_frequencies=(10,), max_test_samples=100)
    return splits.train[0]


def test_estimate_mode_finds_simulated_resonance(multisine_recording) -> None:
    rec = multisine_recording
    f, zeta = estimate_mode(rec.u[:, 0], rec.y[:, 0], rec.fs)
    assert f == pytest.approx(900.0, rel=0.05)
    assert 0.005 <= zeta <= 0.5
    assert zeta == pytest.approx(0.03, rel=0.3)
    gain = estimate_static_gain(rec.u[:, 0], rec.y[:, 0])
    assert 0.15 < gain < 0.3  # µm/V: d (0.23) less the hysteresis, plus creep


def test_estimate_mode_in_band_peak() -> None:
    """Broadband input: the resonance lies inside the excited band, found from the BLA peak."""
    u = np.random.default_rng(5).normal(size=40_000)
    y = signal.lfilter(*signal.bilinear([1.0], [1 / (2 * np.pi * 700) ** 2,
                                                 2 * 0.05 / (2 * np.pi * 700), 1.0], FS), u)
    f, zeta = estimate_mode(u, y, FS)
    assert f == pytest.approx(700.0, rel=0.02)
    assert zeta == pytest.approx(0.05, rel=0.2)
