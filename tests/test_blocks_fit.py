"""The blocks' gradients are usable: a perturbed chain fits data of the true chain."""

from __future__ import annotations

import pytest
import torch

from hysteresis_lab.blocks import (
    BlockChain,
    BoucWen,
    CreepBank,
    Delay,
    FirstOrderLag,
    SecondOrderMode,
)
from hysteresis_lab.signals import multisine

FS = 20_000.0


def _chain(lag: float, d: float, alpha: float, beta: float, gamma: float, creep: float,
           f: float, zeta: float) -> BlockChain:
    """The simulator's default chain in scaled units, each parameter times a factor."""
    return BlockChain(
        FirstOrderLag(FS, 5000.0 * lag),
        Delay(1),
        BoucWen(1.15 * d, 0.32 * alpha, 2.0 * beta, 0.6 * gamma),
        CreepBank(FS, (0.1, 1.0, 10.0, 100.0), weights=0.015 * creep),
        SecondOrderMode(FS, 900.0 * f, 0.03 * zeta),
    )


@pytest.mark.parametrize("f_factor", [1.2, 0.8])
def test_adam_recovers_perturbed_chain(f_factor: float) -> None:
    """0.2 s of data (B = 1), every parameter ±20 %, 200 Adam steps in float32 training mode."""
    u = torch.tensor(multisine(4000, fs=FS, n_components=400, f_max=2000.0, amplitude=1.0,
                               seed=0), dtype=torch.float32)[None]
    with torch.no_grad():
        y = _chain(1, 1, 1, 1, 1, 1, 1, 1).float()(u)
    model = _chain(0.8, 1.2, 0.8, 1.2, 0.8, 0.8, f_factor, 1.2).float()
    opt = torch.optim.Adam(model.parameters(), lr=0.02)
    losses = []
    for _ in range(200):
        opt.zero_grad()
        loss = torch.mean((model(u) - y) ** 2)
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < losses[0] / 10
    assert float(model.mode.frequency_hz.detach()) == pytest.approx(900.0, rel=0.02)
