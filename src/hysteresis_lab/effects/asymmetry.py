"""Asymmetry: a loop that is not point-symmetric about zero drive, its branches bent by a
square law of the drive (a poled piezo stretches more one way than the other).

Faces: the input's square (over its amplitude) as operator and evidence; ``model=linear``'s
hysteresis cell with a square law of its input, weighted from zero (`HysteresisCell`), and
the same law added to ``model=greybox``'s cell (`SquareLaw`, from zero weight). The
simulator's asymmetry is a plant block (`hysteresis_lab.sim.blocks.AsymmetryBlock`,
``data.effects.asymmetry``: ``c * 40 µm * (v / v_ref)^2`` added to the displacement)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.effects._shared import per_input
from hysteresis_lab.effects.base import (
    Effect,
    FeatureContext,
    GreyBoxPart,
    LinearBlock,
    LinearContext,
)
from hysteresis_lab.effects.hysteresis import HysteresisCell, hysteresis_cell


class SquareLaw(nn.Module):
    """The asymmetric term a hysteresis cell adds, ``q A (v / A)^2`` of the cell's input
    ``v`` of amplitude ``A``: the law of ``model=linear``'s cell (`HysteresisCell`), the
    weight ``q`` from zero (the symmetric cell)."""

    def __init__(self, amplitude: float) -> None:
        super().__init__()
        if not amplitude > 0:
            raise ValueError(f"amplitude must be > 0 (got {amplitude})")
        self.weight = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.register_buffer("amplitude", torch.tensor(float(amplitude), dtype=torch.float64))

    def forward(self, v: torch.Tensor) -> torch.Tensor:
        return HysteresisCell._square_law(v, self.weight, self.amplitude)

    def step(self, v: torch.Tensor, state: StepState) -> torch.Tensor:
        """One sample (B,) -> (B,); no state."""
        return HysteresisCell._square_law(v, *frozen(self.weight, self.amplitude))

    def export(self) -> dict[str, Any]:
        """``q`` (``weight``) and ``A`` (``amplitude``, the cell input's scale)."""
        return {"weight": float(self.weight.detach()), "amplitude": float(self.amplitude)}


class Asymmetry(Effect):
    """An asymmetric loop: the square of the input over its amplitude."""

    name = "asymmetry"
    description = "asymmetric loop (square law of the drive)"
    # where the simulator adds it: to the displacement, ahead of creep and the modes
    place = "dynamics"
    rank = 10
    #: the hysteresis cell of ``model=linear`` takes a square law of its input where declared
    makes_cell_asymmetric = True
    #: the square law moves the input path's mean and gain the dynamics were fitted to: the
    #: loop refits the whole model
    linear_whole_refit = True

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        return per_input(u, lambda x, i: (x / max(ctx.u_amplitude[i], 1e-12))[:, None] ** 2)

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        """The hysteresis cell (shared with ``hysteresis`` where both are declared) with a
        square law of its input from zero; declared alone it brings the cell, weight from
        zero."""
        return [LinearBlock("series", hysteresis_cell, key="hysteresis")]

    def greybox_part(self) -> GreyBoxPart:
        """The square law added to the grey-box's hysteresis cell, weight from zero."""
        return GreyBoxPart(cell_term=SquareLaw, attribute="asymmetry",
                           attribute_mimo="asymmetries")
