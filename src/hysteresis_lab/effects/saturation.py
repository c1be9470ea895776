"""Saturation: the drive clipped at a level (an amplifier rated below the command).

Faces: the clipped-off excess as operators and evidence; the simulator's clip of the drive
(``data.effects.saturation``); ``model=linear``'s weighted clip ahead of the dynamics."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from hysteresis_lab.blocks.level import WeightedLaw
from hysteresis_lab.effects._shared import per_input
from hysteresis_lab.effects.base import (
    Effect,
    FeatureContext,
    LinearBlock,
    LinearContext,
    PlantSignals,
)


@dataclass
class SaturationConfig:
    """Amplifier output clipping at ``±limit_v`` (e.g. an amplifier rated below the command)."""

    enabled: bool = False
    limit_v: float = 90.0


class SaturationBlock(WeightedLaw):
    """``v - w (v - clip(v, ±c))``: the clip, weighted from zero."""

    def apply_with(self, v: torch.Tensor, weight: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        return v - weight * (v - torch.maximum(torch.minimum(v, c), -c))


class Saturation(Effect):
    """Saturation: the clipped-off excess of the input over 70-95 % of its range.

    Amplifier clipping happens ahead of the actuator's dynamics, so a network takes it in
    through the input block: ``u - 1 * excess`` is the clipped input.
    """

    name = "saturation"
    description = "saturation (clipped-input features)"
    block = "input"
    place = "input"
    rank = 20
    sim_config = SaturationConfig
    fractions = np.array([0.7, 0.8, 0.9, 0.95])

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        def make(x: np.ndarray, i: int) -> np.ndarray:
            limits = self.fractions * ctx.u_amplitude[i]
            return np.column_stack([x - np.clip(x, -c, c) for c in limits])

        return per_input(u, make)

    def simulate(self, plant: PlantSignals, cfg: SaturationConfig) -> None:
        plant.v = np.clip(plant.v, -cfg.limit_v, cfg.limit_v)

    def validate(self, cfg: SaturationConfig, key: str) -> list[str]:
        return [] if cfg.limit_v > 0 else [f"{key}.limit_v={cfg.limit_v!r} must be positive."]

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        """A clip at 90 % of the input's amplitude, weight from zero."""
        return [LinearBlock("series", lambda c, j: SaturationBlock(0.9 * c.input_amplitude(j)))]
