"""Prandtl–Ishlinskii hysteresis: learnable play operators on the physics floor's play
recursion (`hysteresis_lab.physics.play`, with its adjoint)."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from hysteresis_lab.blocks._util import inv_softplus
from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.physics.play import play, play_step


class PlayOperators(nn.Module):
    """Prandtl–Ishlinskii operator ``w0 v + sum_i w_i play_{r_i}(v)``.

    Thresholds ``r_i = cumsum(softplus(raw))`` (positive, sorted), weights ``w0, w_i =
    softplus(raw)`` (non-negative). Initial thresholds evenly spaced up to ``max_threshold``
    (in the input's scaled units), initial weights ``w0`` and ``weight``.
    """

    def __init__(
        self,
        n_operators: int = 8,
        max_threshold: float = 0.8,
        w0: float = 1.0,
        weight: float = 0.05,
    ) -> None:
        super().__init__()
        if n_operators < 1 or max_threshold <= 0 or w0 <= 0 or weight <= 0:
            raise ValueError("need n_operators >= 1 and max_threshold, w0, weight > 0")
        step = max_threshold / n_operators
        self.raw_increments = nn.Parameter(torch.full((n_operators,), inv_softplus(step),
                                                      dtype=torch.float64))
        self.raw_w0 = nn.Parameter(torch.tensor(inv_softplus(w0), dtype=torch.float64))
        self.raw_weights = nn.Parameter(torch.full((n_operators,), inv_softplus(weight),
                                                   dtype=torch.float64))

    @property
    def thresholds(self) -> Tensor:
        return torch.cumsum(F.softplus(self.raw_increments), dim=0)

    @property
    def weights(self) -> Tensor:
        return F.softplus(self.raw_weights)

    @property
    def w0(self) -> Tensor:
        return F.softplus(self.raw_w0)

    def forward(self, v: Tensor) -> Tensor:
        """``v`` (B, T) -> (B, T)."""
        p = play(v, self.thresholds)
        return self.w0.to(v.dtype) * v + p @ self.weights.to(v.dtype)

    def state_names(self) -> list[str]:
        return [f"play{i}" for i in range(self.raw_weights.shape[0])]

    def step(self, v: Tensor, state: StepState) -> Tensor:
        """One sample (B,) -> (B,); state: the operators' outputs."""
        thresholds, w0, weights = frozen(self.thresholds, self.w0, self.weights)
        p = play_step(v, thresholds, state)
        return w0 * v + p @ weights

    def export(self) -> dict[str, Any]:
        with torch.no_grad():
            return {
                "w0": float(self.w0),
                "thresholds": self.thresholds.double().cpu().numpy().copy(),
                "weights": self.weights.double().cpu().numpy().copy(),
            }
