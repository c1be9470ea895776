"""Overflow: the output cannot pass a level (a tank overflows, a sensor or an amplifier stage
clips), after the dynamics.

Faces: the model's own free-run output beyond its range's extremes as evidence; a clip on
``model=linear``'s output (`OverflowBlock`) and, with the loop forces on the output stage, a
rim on its upstream storage. The simulated positioner has no overflow."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from scipy import signal
from torch import nn

from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.effects._shared import ReadFromModelOutput
from hysteresis_lab.effects.base import LinearBlock, LinearContext
from hysteresis_lab.effects.nonlinear_feedback import knot_fractions


class OverflowBlock(nn.Module):
    """Output saturation after the dynamics: ``y - w_hi relu(y - c_hi) + w_lo relu(c_lo - y)``
    (``w = 1``: a hard clip at ``c``), the weights from zero, the levels from ``low`` and
    ``high`` (the output over its scale)."""

    def __init__(self, low: float, high: float) -> None:
        super().__init__()
        self.weights = nn.Parameter(torch.zeros(2, dtype=torch.float64))  # (low, high)
        self.levels = nn.Parameter(torch.tensor([low, high], dtype=torch.float64))

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.apply_with(y, self.weights, self.levels)

    def step(self, y: torch.Tensor, state: StepState) -> torch.Tensor:
        """One sample (B,) -> (B,); a static block has no state."""
        return self.apply_with(y, *frozen(self.weights, self.levels))

    @staticmethod
    def apply_with(y: torch.Tensor, weights: torch.Tensor, levels: torch.Tensor) -> torch.Tensor:
        return y - weights[1] * torch.relu(y - levels[1]) + weights[0] * torch.relu(levels[0] - y)

    def export(self) -> dict[str, Any]:
        """The weights (low, high) and the levels (the output over its scale)."""
        with torch.no_grad():
            return {k: v.detach().cpu().numpy().tolist() for k, v in self.named_parameters()}



class Overflow(ReadFromModelOutput):
    """Output saturation / overflow: the output cannot pass a level (a tank overflows, a
    sensor or an amplifier stage clips), after the dynamics.

    It has no input operators: a model carries it as an output block (``model=linear``:
    ``y - w_hi relu(y - c_hi) + w_lo relu(c_lo - y)``). Its evidence is the model's own
    free-run output beyond 70-95 % of its range on either side: a model that does not clip
    overshoots where the system clips, so its residual follows those excesses.
    """

    name = "overflow"
    description = "output saturation / overflow (the model's own output clipped near its extremes)"
    block = "output"
    place = "output"
    rank = 10
    #: a refit that adds it tries the clip on the output and a rim on the output stage's
    #: upstream storage (`hysteresis_lab.models.linear.FEEDBACK_PLACES`)
    linear_tries_output_stage = True
    fractions = np.array([0.7, 0.8, 0.9, 0.95])
    #: an upstream storage held at its rim: the excesses through a first-order storage
    poles = (0.9,)

    def output_evidence(self, y_model: np.ndarray, span: tuple[float, float]) -> np.ndarray:
        y, low, width = self._on_range(y_model, span)
        high = low + width
        upper = [np.maximum(y - (low + f * width), 0.0) for f in self.fractions]
        lower = [np.minimum(y - (high - f * width), 0.0) for f in self.fractions]
        clips = np.column_stack(upper + lower)
        stored = [signal.lfilter([1.0 - p], [1.0, -p], clips, axis=0) for p in self.poles]
        return np.nan_to_num(np.column_stack([clips, *stored]))

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        """A clip on each output at its training extremes, weights from zero."""
        return [LinearBlock("output", lambda c, o: OverflowBlock(*c.output_extremes[o]),
                            attribute="overflow")]

    def linear_storage_rim(self, low: float, high: float) -> float | None:
        """With the loop forces on the output stage: the rim of the upstream storage, near
        the top of the output's range ``low``-``high``."""
        return low + knot_fractions(2)[-1] * (high - low)

