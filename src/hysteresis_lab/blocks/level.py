"""`WeightedLaw`: a static input law ``v + w g(v, c)`` whose weight starts at zero (the
input blocks of ``model=linear``: saturation, dead zone, backlash)."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from hysteresis_lab.blocks.step import StepState, frozen


class WeightedLaw(nn.Module):
    """A weighted input nonlinearity ``v + w g(v, c)`` with ``w`` from zero and a level
    ``c > 0`` (in the input's scaled units) from ``level``."""

    def __init__(self, level: float) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.raw_level = nn.Parameter(torch.tensor(float(np.log(level)), dtype=torch.float64))

    @property
    def level(self) -> torch.Tensor:
        return self.raw_level.exp()

    def state_names(self) -> list[str]:
        return []

    def step(self, v: torch.Tensor, state: StepState) -> torch.Tensor:
        """One sample (B,) -> (B,); a static block has no state."""
        return self.apply_with(v, *frozen(self.weight, self.level))

    def forward(self, v: torch.Tensor) -> torch.Tensor:
        return self.apply_with(v, self.weight, self.level)

    def apply_with(
        self, v: torch.Tensor, weight: torch.Tensor, level: torch.Tensor
    ) -> torch.Tensor:
        """The block with weight ``weight`` and level ``level``."""
        raise NotImplementedError
