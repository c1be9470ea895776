"""Nonlinear feedback: a static law of the output inside the dynamics (a Lur'e system): a
tank's outflow through an orifice, a hardening or softening spring.

Faces: powers of the model's own free-run output, fed back and smoothed, as evidence;
``model=linear``'s piecewise-linear law in the dynamics' feedback (`StaticFeedback`),
simulated in one closed loop with a hysteretic force where both are declared
(`hysteresis_lab.blocks.feedback`). The simulated positioner has none."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from scipy import signal
from torch import nn

from hysteresis_lab.blocks.feedback import closed_loop, loop_lag, loop_state_names, loop_step
from hysteresis_lab.blocks.sections import StableSections
from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.effects._shared import ReadFromModelOutput
from hysteresis_lab.effects.base import LinearBlock, LinearContext


def knot_fractions(n_knots: int) -> np.ndarray:
    """Where `StaticFeedback`'s knots sit in the output's range: ``n_knots`` evenly from 10 %
    to 85 % (one knot: the middle)."""
    return np.linspace(0.1, 0.85, n_knots) if n_knots > 1 else np.array([0.5])


class StaticFeedback(nn.Module):
    """A static nonlinearity in the dynamics' feedback (a Lur'e system): the dynamics in a
    closed loop with a function of their own output level, ``e = x - phi(y + offset)``,
    ``y = dynamics(e)`` — an outflow that grows with the level as no linear law does
    (Torricelli's ``sqrt``), a hardening or softening spring. ``phi`` is piecewise linear,
    ``sum_k w_k relu(level - c_k)`` less its value at rest, over the dynamics' static gain
    (so ``w`` is in the output's own units: a slope ``s`` of ``phi`` lowers the static gain
    by ``1 + s``, whatever the data's units), with knots ``c_k`` spread over the training
    output's range (`knot_fractions` of it, the output over its scale) and the weights ``w``
    from zero, so the block starts as the dynamics alone; the linear part of the law is the
    dynamics' own. Simulated with the hysteretic force, if any, in one loop
    (`hysteresis_lab.blocks.feedback`)."""

    def __init__(self, low: float, high: float, n_knots: int = 6) -> None:
        super().__init__()
        levels = [low + f * (high - low) for f in knot_fractions(n_knots)]
        self.weights = nn.Parameter(torch.zeros(len(levels), dtype=torch.float64))
        self.register_buffer("levels", torch.tensor(levels, dtype=torch.float64))

    def knots(self, offset: torch.Tensor) -> torch.Tensor:
        """The knots on the dynamics' output (the levels less the output ``offset``)."""
        return self.levels - offset

    def loop_weights(self, dynamics: StableSections) -> torch.Tensor:
        """The weights over the dynamics' static gain ``b(1) / a(1)`` (kept at least
        ``1e-6`` in size): what the loop feeds back into the dynamics' input."""
        b, a = dynamics.polynomials()
        gain = b.sum() / a.sum()
        sign = torch.where(gain < 0, -1.0, 1.0).to(gain)
        return self.weights / (sign * torch.clamp(gain.abs(), min=1e-6))

    def function(self, dynamics: StableSections, offset: torch.Tensor) -> Any:
        """``phi`` on the dynamics' output as the loop feeds it back, (B,) -> (B,), zero at
        rest."""
        weights, knots = frozen(self.loop_weights(dynamics), self.knots(offset))

        def phi(y: torch.Tensor) -> torch.Tensor:
            hinges = torch.relu(y[:, None] - knots) - torch.relu(-knots)
            return hinges @ weights

        return phi

    def forward(self, dynamics: StableSections, x: torch.Tensor,
                offset: torch.Tensor) -> torch.Tensor:
        """The closed loop's output (B, T) for the dynamics' input ``x`` (B, T)."""
        b, a = dynamics.polynomials()
        none = torch.zeros(0, dtype=torch.float64, device=x.device)
        zero = torch.zeros((), dtype=torch.float64, device=x.device)
        return closed_loop(x.double(), b, a, zero, zero, none, none, none, loop_lag(dynamics),
                           self.loop_weights(dynamics), self.knots(offset))

    @staticmethod
    def state_names(dynamics: StableSections) -> list[str]:
        """The step's state: past dynamics' inputs ``e`` and outputs ``y``."""
        return loop_state_names(dynamics)

    def step(self, dynamics: StableSections, x: torch.Tensor, state: StepState,
             offset: torch.Tensor) -> torch.Tensor:
        """One sample of `forward`: ``x`` (B,) -> ``y`` (B,); state: the past dynamics'
        inputs and outputs (newest first)."""
        b, a = frozen(*dynamics.polynomials())
        phi = self.function(dynamics, offset)
        return loop_step(b, a, loop_lag(dynamics), x, state, lambda y, _h: phi(y))

    def export(self) -> dict[str, Any]:
        """The weights and the levels of the knots (the output over its scale)."""
        return {"weights": self.weights.detach().cpu().numpy().tolist(),
                "levels": self.levels.cpu().numpy().tolist()}


class NonlinearFeedback(ReadFromModelOutput):
    """A static nonlinearity in the dynamics' feedback (a Lur'e system): what leaves or
    restores the system depends on its own output level as no linear law does — a tank's
    outflow through an orifice (Torricelli, ``sqrt`` of the level), a hardening or softening
    spring.

    It has no input operators: a model carries it as the dynamics in a closed loop with a
    function of their output (``model=linear``: piecewise linear, weights from zero, knots
    ``model.feedback_knots``). Its evidence is the model's own free-run output's distance
    from the middle of its range, squared and cubed (a linear law fitted to a curved one
    leaves a residual that follows the curvature, over the whole range), a sample late and
    smoothed by first-order filters (time constants of about 2 and 10 samples): what is fed
    back reaches the output through the dynamics. A clip at the output (`Overflow`) bends
    the output sharply at one level and at once; these smooth curves do not. Where the two
    overlap the clip is the simpler explanation: this effect is significant only where it is
    also significant beyond the overflow's signals (`beyond`).
    """

    name = "nonlinear_feedback"
    description = ("nonlinear feedback / level-dependent outflow (a static law of the "
                   "model's own output inside its dynamics)")
    block = "feedback"
    place = "feedback"
    rank = 10
    #: a static law closes a loop around the dynamics: the loop refits the whole model, and
    #: tries the law on the whole dynamics and on the output stage's own level
    linear_whole_refit = True
    linear_tries_output_stage = True
    #: a clip at the output is the simpler explanation of a bent output: this effect is
    #: significant only beyond it too
    beyond = ("overflow",)
    #: powers of the output's distance from the middle of its range
    powers = (2, 3)
    #: first-order smoothing of the law (time constants of about 2 and 10 samples)
    poles = (0.6, 0.9)

    def output_evidence(self, y_model: np.ndarray, span: tuple[float, float]) -> np.ndarray:
        y, low, width = self._on_range(y_model, span)
        level = (y - low) / width
        law = (level - 0.5)[:, None] ** np.asarray(self.powers)
        law = np.vstack([np.zeros((1, law.shape[1])), law[:-1]])  # fed back: a sample late
        smoothed = [signal.lfilter([1.0 - p], [1.0, -p], law, axis=0) for p in self.poles]
        return np.nan_to_num(np.column_stack(smoothed))

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        """A piecewise-linear law of the output (``model.feedback_knots`` knots over the range
        the loop forces read) in the dynamics' feedback, weights from zero."""
        return [LinearBlock("law", lambda c, pair: StaticFeedback(
            *c.forced_extremes[pair[0]], c.settings["feedback_knots"]),
            attribute="static_feedback")]

