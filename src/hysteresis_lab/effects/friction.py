"""Friction: Coulomb friction, a force of constant size against the direction of motion (a
cart on its guide, a lead screw, a bearing), inside the dynamics.

Faces: the direction of the model's own motion (Dahl's presliding), lagged and integrated as
a position is, as evidence; ``model=linear``'s friction law in the feedback of the
dynamics' integrand (`FrictionLaw`), where the model's output integrates (a position from
a force). The simulated positioner has none."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import torch
from scipy import signal
from torch import nn

from hysteresis_lab.effects._shared import ReadFromModelOutput
from hysteresis_lab.effects.base import LinearBlock, LinearContext
from hysteresis_lab.effects.nonlinear_feedback import StaticFeedback
from hysteresis_lab.physics.play import play_operators

log = logging.getLogger(__name__)


class FrictionLaw(StaticFeedback):
    """Coulomb friction in the dynamics' feedback: ``phi(v) = level clip(v / eps, -1, 1)``,
    the tied hinge pair ``level / eps (relu(v + eps) - relu(v - eps)) - level`` of the
    velocity ``v`` (the integrand of a model whose output integrates), a force of size
    ``level`` against the motion, smoothed over ``±eps`` (the velocity over its scale) so
    its gradient exists. One parameter, ``level`` (in the velocity's units, as
    `StaticFeedback`'s weights: the drop in steady velocity the friction causes), from zero:
    the block starts as the dynamics alone. Simulated by the closed loop of
    `StaticFeedback` (its two hinge weights tied)."""

    def __init__(self, eps: float) -> None:
        nn.Module.__init__(self)
        eps = max(float(eps), 1e-9)
        self.level = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.register_buffer("levels", torch.tensor([-eps, eps], dtype=torch.float64))

    @property
    def weights(self) -> torch.Tensor:  # type: ignore[override]
        """The two hinges' weights, tied to one level: ``(level / eps, -level / eps)``."""
        eps = self.levels[1]
        return torch.stack([self.level / eps, -self.level / eps])

    def export(self) -> dict[str, Any]:
        """The friction level and its smoothing width (the velocity over its scale)."""
        return {"level": float(self.level.detach()), "eps": float(self.levels[1])}


class Friction(ReadFromModelOutput):
    """Coulomb friction: a force of constant size against the direction of motion.

    It acts inside the dynamics on the velocity, so it has no input operators; a model
    carries it as a law of its own velocity in the dynamics' feedback (``model=linear`` with
    an integrating output, ``model.integrator``: `FrictionLaw` on the integrand). Its
    evidence is the direction of the model's own last motion (its free-run output less a
    play operator of it over a small presliding width, as in Dahl's friction model), passed
    through first-order lags (the mass that the force accelerates) and summed as the
    position sums the velocity: a model without friction coasts on where the system stops,
    and its residual follows those signals.
    """

    name = "friction"
    description = "Coulomb friction (the direction of the model's own motion, fed back)"
    block = "feedback"
    place = "feedback"
    rank = 20
    #: a force in the loop reshapes what the fitted dynamics were fitted to
    linear_whole_refit = True
    #: ``model=linear`` reads the velocity as the integrand: without an integrator it has
    #: no friction block, and the loop does not add it (`hysteresis_lab.loop.driver`)
    linear_needs_integrator = True
    #: presliding widths of the direction of motion (Dahl), as shares of the output's span
    widths = (0.001, 0.005, 0.02)
    #: first-order lags of the force's effect on the velocity (per sample)
    poles = (0.9, 0.99, 0.999)
    #: the law's smoothing width, as a share of the largest velocity
    law_width = 0.02

    def output_evidence(self, y_model: np.ndarray, span: tuple[float, float]) -> np.ndarray:
        """The direction of the model's last motion, ``(y - play_r(y)) / r`` for presliding
        widths ``r`` (Dahl's friction: the force turns over a small displacement after a
        reversal), a sample late, through the lags `poles` and summed as a position sums
        the velocity."""
        y = np.ascontiguousarray(np.nan_to_num(np.asarray(y_model, dtype=float).reshape(-1)))
        widths = np.asarray(self.widths) * max(span[1] - span[0], 1e-12)
        direction = (y[:, None] - play_operators(y, widths)) / widths
        direction = np.vstack([np.zeros((1, len(widths))), direction[:-1]])  # fed back
        lagged = [signal.lfilter([1.0 - p], [1.0, -p], direction, axis=0) for p in self.poles]
        summed = [np.cumsum(x, axis=0) / max(len(y), 1) for x in (direction, *lagged)]
        return np.nan_to_num(np.column_stack([direction, *lagged, *summed]))

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        """Where the output integrates: the friction law of the integrand (the velocity),
        its width `law_width` of the range the loop forces read, level from zero. Otherwise
        none (a law of the output's level is no friction): the model stays as it is."""
        if not ctx.settings.get("integrator"):
            log.warning("model=linear carries friction only where its output integrates a "
                        "velocity (model.integrator=true): no friction block added")
            return []
        return [LinearBlock("law", lambda c, pair: FrictionLaw(
            self.law_width * max(abs(v) for v in c.forced_extremes[pair[0]])),
            attribute="friction")]
