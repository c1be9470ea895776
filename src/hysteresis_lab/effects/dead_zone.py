"""Dead zone: a band around zero the drive does not pass (a drive stage that does not respond
to small commands, stiction of a clamp).

Faces: the input with the band removed as operators and evidence; the simulator's dead zone
(``data.effects.dead_zone``); ``model=linear``'s weighted dead zone ahead of the dynamics."""

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
from hysteresis_lab.physics.static import dead_zone


@dataclass
class DeadZoneConfig:
    """Dead zone of ``±width_v`` ahead of the actuator: ``sign(v) max(|v| - width_v, 0)`` (a
    drive stage that does not respond to small commands, stiction of a clamp)."""

    enabled: bool = False
    width_v: float = 10.0


class DeadZoneBlock(WeightedLaw):
    """``v - w clip(v, ±c)``: the dead zone, weighted from zero."""

    def apply_with(self, v: torch.Tensor, weight: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        return v - weight * torch.maximum(torch.minimum(v, c), -c)


class DeadZone(Effect):
    """Dead zone: the input with a band around zero removed (2-20 % of its range)."""

    name = "dead_zone"
    description = "dead zone (input with a band around zero removed)"
    place = "input"
    rank = 30
    sim_config = DeadZoneConfig
    fractions = np.array([0.02, 0.05, 0.1, 0.2])
    #: a dead zone takes a band off every input; a linear fit meets the lost output with a
    #: lower gain, which a block-only refit cannot give back
    linear_whole_refit = True

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        return per_input(
            u,
            lambda x, i: np.column_stack(
                [dead_zone(x, f * ctx.u_amplitude[i]) for f in self.fractions]
            ),
        )

    def simulate(self, plant: PlantSignals, cfg: DeadZoneConfig) -> None:
        """``v`` with the band ``±width_v`` around zero removed."""
        plant.v = dead_zone(plant.v, cfg.width_v)

    def validate(self, cfg: DeadZoneConfig, key: str) -> list[str]:
        return [] if cfg.width_v > 0 else [f"{key}.width_v={cfg.width_v!r} must be positive."]

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        """A dead zone of 5 % of the input's amplitude, weight from zero."""
        return [LinearBlock("series", lambda c, j: DeadZoneBlock(0.05 * c.input_amplitude(j)))]
