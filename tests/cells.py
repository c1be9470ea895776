"""Test helpers for hysteresis cells: a random-walk drive, a run sample by sample through a
block's ``step``, and a least-squares fit of a block's parameters with L-BFGS."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import nn

from hysteresis_lab.blocks.step import StepState


def walk(n: int, seed: int, batch: int = 2, step: float = 0.3) -> torch.Tensor:
    """``batch`` random walks of ``n`` samples (float64)."""
    rng = np.random.default_rng(seed)
    return torch.tensor(np.cumsum(rng.normal(0, step, (batch, n)), axis=1), dtype=torch.float64)


def stepped(block: nn.Module, v: torch.Tensor) -> torch.Tensor:
    """``block`` run one sample at a time through its ``step`` from a zero state over the
    drive ``v`` (batch, samples); its outputs stacked like the whole run's."""
    with torch.no_grad():
        state = torch.zeros(v.shape[0], len(block.state_names()), dtype=torch.float64)
        steps = []
        for k in range(v.shape[1]):
            stepper = StepState(state)
            steps.append(block.step(v[:, k], stepper))
            state = stepper.next_state()
    return torch.stack(steps, dim=1)


def fit_lbfgs(module: nn.Module, predict: Callable[[], torch.Tensor], target: torch.Tensor,
              max_iter: int = 100) -> float:
    """Fit ``module``'s parameters so that ``predict()`` matches ``target`` in mean square
    (L-BFGS, strong Wolfe line search); the mean-square error left."""
    optimiser = torch.optim.LBFGS(module.parameters(), lr=0.5, max_iter=max_iter,
                                  line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        optimiser.zero_grad()
        loss = torch.mean((predict() - target) ** 2)
        loss.backward()
        return loss

    optimiser.step(closure)
    with torch.no_grad():
        return float(torch.mean((predict() - target) ** 2))
