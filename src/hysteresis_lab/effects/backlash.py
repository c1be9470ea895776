"""Backlash: mechanical play (a gear or clamp with play): the drive is followed only once it
has moved the play's width the other way.

Faces: wide play operators as operators and evidence; the simulator's play operator
(``data.effects.backlash``); ``model=linear``'s weighted play ahead of the dynamics."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from hysteresis_lab.blocks.level import WeightedLaw
from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.effects._shared import per_input
from hysteresis_lab.effects.base import (
    Effect,
    FeatureContext,
    LinearBlock,
    LinearContext,
    PlantSignals,
)
from hysteresis_lab.physics.play import play, play_operators, play_step


@dataclass
class BacklashConfig:
    """Backlash (mechanical play) of ``±width_v`` ahead of the actuator: a play operator that
    follows the command only once it has moved ``width_v`` the other way (a gear or clamp
    with play)."""

    enabled: bool = False
    width_v: float = 5.0


class BacklashBlock(WeightedLaw):
    """``v + w (play_c(v) - v)``: a play operator, weighted from zero."""

    def forward(self, v: torch.Tensor) -> torch.Tensor:
        return v + self.weight * (play(v, self.level.reshape(1))[..., 0] - v)

    def state_names(self) -> list[str]:
        return ["play"]

    def step(self, v: torch.Tensor, state: StepState) -> torch.Tensor:
        """One sample (B,) -> (B,); state: the play operator's output."""
        weight, level = frozen(self.weight, self.level)
        return v + weight * (play_step(v, level.reshape(1), state)[:, 0] - v)


class Backlash(Effect):
    """Backlash: single wide play operators (gear/clamp play, 5-15 % of the range)."""

    name = "backlash"
    description = "backlash (wide play operators)"
    place = "input"
    rank = 40
    sim_config = BacklashConfig
    fractions = np.array([0.05, 0.1, 0.15])
    #: a backlash takes its play off every reversal; a linear fit meets it with a lag, which a
    #: block-only refit cannot give back
    linear_whole_refit = True

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        return per_input(
            u,
            lambda x, i: play_operators(
                np.ascontiguousarray(x), self.fractions * ctx.u_amplitude[i]
            ),
        )

    def simulate(self, plant: PlantSignals, cfg: BacklashConfig) -> None:
        """A play operator of half-width ``width_v``, starting at rest."""
        x = np.ascontiguousarray(plant.v, dtype=float)
        plant.v = play_operators(x, np.array([cfg.width_v]))[:, 0]

    def validate(self, cfg: BacklashConfig, key: str) -> list[str]:
        return [] if cfg.width_v > 0 else [f"{key}.width_v={cfg.width_v!r} must be positive."]

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        """A play of 5 % of the input's amplitude, weight from zero."""
        return [LinearBlock("series", lambda c, j: BacklashBlock(0.05 * c.input_amplitude(j)))]
