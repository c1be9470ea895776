"""Asymmetry: a loop that is not point-symmetric about zero drive, its branches bent by a
square law of the drive (a poled piezo stretches more one way than the other).

Faces: the input's square (over its amplitude) as operator and evidence; ``model=linear``'s
hysteresis cell with a square law of its input, weighted from zero (`HysteresisCell`). The
simulator's asymmetry is a plant block (`hysteresis_lab.sim.blocks.AsymmetryBlock`,
``data.effects.asymmetry``: ``c * 40 µm * (v / v_ref)^2`` added to the displacement)."""

from __future__ import annotations

import numpy as np

from hysteresis_lab.effects._shared import per_input
from hysteresis_lab.effects.base import Effect, FeatureContext, LinearBlock, LinearContext
from hysteresis_lab.effects.hysteresis import hysteresis_cell


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
