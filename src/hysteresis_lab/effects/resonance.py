"""Resonance: unmodelled structural dynamics (a mode the model does not hold).

Faces: resonant filters of the input on a log frequency grid as operators and evidence;
``model=linear``'s second-order section in parallel with the dynamics; one more mode of the
grey-box. The simulator's modes are plant blocks (`hysteresis_lab.sim.blocks`)."""

from __future__ import annotations

import numpy as np
import torch

from hysteresis_lab.blocks.sections import StableSections
from hysteresis_lab.effects._shared import per_input
from hysteresis_lab.effects.base import (
    Effect,
    FeatureContext,
    GreyBoxPart,
    LinearBlock,
    LinearContext,
)
from hysteresis_lab.physics.filters import resonator_bank


class Resonance(Effect):
    """Unmodelled structural dynamics: resonant filters of the input on a log frequency grid."""

    name = "resonance"
    description = "resonance / unmodelled dynamics (band-pass filters of the input)"
    place = "dynamics"
    rank = 30

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        grid = np.geomspace(0.01 * ctx.fs, 0.4 * ctx.fs, 12)
        return per_input(u, lambda x, i: resonator_bank(x, ctx.fs, grid))

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        """A second-order section in parallel with the dynamics of every output and input."""
        return [LinearBlock("parallel", lambda c, pair: resonance_section(),
                            attribute="resonance")]

    def greybox_part(self) -> GreyBoxPart:
        """One more mode of the structure."""
        return GreyBoxPart(extra_modes=1)


def resonance_section() -> StableSections:
    """A lightly damped pair at zero weight (numerator zero)."""
    section = StableSections(2)
    with torch.no_grad():
        section.numerators.zero_()
        section.raw_denominators[:, 1] = 2.0
    return section

