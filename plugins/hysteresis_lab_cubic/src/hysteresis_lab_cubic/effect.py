"""A cubic law of the drive ahead of the dynamics (a stiffening drive stage, an
electrostrictive actuator's curved gain): ``v + c v_ref (v / v_ref)^3``.

The whole effect is this file: its evidence for the diagnosis (`CubicInput.features`), its
simulator block (`CubicInput.simulate`, parameters `CubicInputConfig` under
``data.effects.cubic``) and its ``model=linear`` block (`CubicBlock`), placed on the input
after a backlash and before the input delay (``place``, ``rank``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.effects.base import (
    Effect,
    FeatureContext,
    LinearBlock,
    LinearContext,
    PlantSignals,
)


@dataclass
class CubicInputConfig:
    """``v + coefficient * v_ref * (v / v_ref)^3`` on the drive."""

    enabled: bool = False
    coefficient: float = 0.1
    v_ref: float = 100.0


class CubicBlock(nn.Module):
    """``v + w v^3`` on an input over its scale, ``w`` from zero (no effect at the start)."""

    def __init__(self) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.zeros((), dtype=torch.float64))

    def forward(self, v: torch.Tensor) -> torch.Tensor:
        return v + self.weight * v**3

    def state_names(self) -> list[str]:
        return []

    def step(self, v: torch.Tensor, state: StepState) -> torch.Tensor:
        """One sample (B,) -> (B,); a static block has no state."""
        (weight,) = frozen(self.weight)
        return v + weight * v**3

    def export(self) -> dict[str, Any]:
        return {"weight": float(self.weight.detach())}


class CubicInput(Effect):
    """A cubic law of the drive: the input's cube (over its amplitude) as evidence."""

    name = "cubic"
    description = "cubic law of the drive (stiffening input stage)"
    place = "input"
    rank = 45
    sim_config = CubicInputConfig

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        amplitude = np.maximum(np.asarray(ctx.u_amplitude, dtype=float), 1e-12)
        return (u / amplitude) ** 3

    def simulate(self, plant: PlantSignals, cfg: CubicInputConfig) -> None:
        plant.v = plant.v + cfg.coefficient * cfg.v_ref * (plant.v / cfg.v_ref) ** 3

    def validate(self, cfg: CubicInputConfig, key: str) -> list[str]:
        return [] if cfg.v_ref > 0 else [f"{key}.v_ref={cfg.v_ref!r} must be positive."]

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        return [LinearBlock("series", lambda c, j: CubicBlock())]
