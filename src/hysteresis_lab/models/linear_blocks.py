"""The effect catalogue's blocks on `model=linear` (`hysteresis_lab.models.linear`): the
input nonlinearities (saturation, dead zone, backlash, the hysteresis cell with its optional
rate dependence), the output's overflow, and the forces in the dynamics' feedback (the
Bouc–Wen restoring force `StateHysteresis` and the static law `StaticFeedback`, simulated
in one closed loop by `hysteresis_lab.blocks.feedback`). Each starts where it changes
nothing (its weight at zero), so a model that declares it starts as the model without it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.blocks import BoucWen, bouc_wen_scaled_params, play
from hysteresis_lab.blocks.feedback import closed_loop
from hysteresis_lab.blocks.sections import StableSections
from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.physics.bouc_wen import bouc_wen_advance
from hysteresis_lab.physics.play import play_step


class _Level(nn.Module):
    """A weighted input nonlinearity ``v + w g(v, c)`` with ``w`` from zero and a level
    ``c > 0`` (in the input's scaled units) from ``level``."""

    def __init__(self, level: float) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.raw_level = nn.Parameter(torch.tensor(float(np.log(level)), dtype=torch.float64))

    @property
    def level(self) -> torch.Tensor:
        return self.raw_level.exp()

    def state_names(self) -> list[str]:
        return []

    def step(self, v: torch.Tensor, state: StepState) -> torch.Tensor:
        """One sample (B,) -> (B,); a static block has no state."""
        return self.apply_with(v, *frozen(self.weight, self.level))

    def forward(self, v: torch.Tensor) -> torch.Tensor:
        return self.apply_with(v, self.weight, self.level)

    def apply_with(
        self, v: torch.Tensor, weight: torch.Tensor, level: torch.Tensor
    ) -> torch.Tensor:
        """The block with weight ``weight`` and level ``level``."""
        raise NotImplementedError


class Saturation(_Level):
    def apply_with(self, v: torch.Tensor, weight: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        return v - weight * (v - torch.maximum(torch.minimum(v, c), -c))


class DeadZone(_Level):
    def apply_with(self, v: torch.Tensor, weight: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        return v - weight * torch.maximum(torch.minimum(v, c), -c)


class Backlash(_Level):
    def forward(self, v: torch.Tensor) -> torch.Tensor:
        return v + self.weight * (play(v, self.level.reshape(1))[..., 0] - v)

    def state_names(self) -> list[str]:
        return ["play"]

    def step(self, v: torch.Tensor, state: StepState) -> torch.Tensor:
        """One sample (B,) -> (B,); state: the play operator's output."""
        weight, level = frozen(self.weight, self.level)
        return v + weight * (play_step(v, level.reshape(1), state)[:, 0] - v)


class HysteresisCell(nn.Module):
    """``v - w h(v)``: the Bouc–Wen state ``h`` (`hysteresis_lab.blocks.BoucWen`) subtracted
    with a weight from zero.

    With ``rate_step`` (effect ``rate``) the hysteresis is rate-dependent: the step into each
    sample runs with ``alpha * max(1 + k |dv| / rate_step, 0)`` (``dv`` the input step, the
    simulator's ``alpha (1 + gain |dv/dt| / rate_ref)`` per sample), so loops widen with the
    input's rate. ``k`` is learnable and starts at 0 (the plain cell); ``rate_step`` is fixed
    from the training input's scale: the steepest step of a sine of the training input's
    amplitude with 200 samples per period (at the simulator's 20 kHz and ±100 V: its
    ``rate_ref``, 62,832 V/s, a 100 Hz sine)."""

    def __init__(self, rate_step: float | None = None) -> None:
        super().__init__()
        self.bouc_wen = BoucWen(**bouc_wen_scaled_params(1.0, 0.32, 0.02, 0.006, 100.0, 100.0))
        self.weight = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.rate_gain: nn.Parameter | None = None
        if rate_step is not None:
            if not rate_step > 0:
                raise ValueError(f"rate_step must be > 0 (got {rate_step})")
            self.rate_gain = nn.Parameter(torch.zeros((), dtype=torch.float64))
            self.register_buffer("rate_step", torch.tensor(float(rate_step), dtype=torch.float64))

    @staticmethod
    def rate_step_for(amplitude: float) -> float:
        """``rate_step`` for an input of ``amplitude`` (scaled units): ``2 pi amplitude / 200``."""
        return 2.0 * np.pi * amplitude / 200.0

    @staticmethod
    def _alpha_factor(dv: torch.Tensor, gain: torch.Tensor,
                      rate_step: torch.Tensor) -> torch.Tensor:
        """The factor of ``alpha`` for input steps ``dv`` (never below zero)."""
        return torch.clamp(1.0 + gain * dv.abs() / rate_step, min=0.0)

    def forward(self, v: torch.Tensor) -> torch.Tensor:
        factor = None
        if self.rate_gain is not None:
            v64 = v.double()
            dv = torch.diff(v64, dim=-1, prepend=torch.zeros_like(v64[..., :1]))
            factor = self._alpha_factor(dv, self.rate_gain, self.rate_step)
        x, _ = self.bouc_wen(v, alpha_factor=factor)
        h = self.bouc_wen.d * v - x
        return v - self.weight * h

    def state_names(self) -> list[str]:
        return self.bouc_wen.state_names()

    def step(self, v: torch.Tensor, state: StepState) -> torch.Tensor:
        """One sample (B,) -> (B,); state: the Bouc–Wen cell's."""
        d, weight = frozen(self.bouc_wen.d, self.weight)
        factor = None
        if self.rate_gain is not None:
            gain, rate_step = frozen(self.rate_gain, self.rate_step)

            def factor(dv: torch.Tensor) -> torch.Tensor:
                return self._alpha_factor(dv, gain, rate_step)

        return v - weight * (d * v - self.bouc_wen.step(v, state, factor))


class Overflow(nn.Module):
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


class StateHysteresis(nn.Module):
    """Hysteresis in the dynamics' feedback: a Bouc–Wen restoring force of the output fed
    back into the dynamics' input, ``e = x - w (d y - h(y))``, ``y = dynamics(e)`` — the
    Bouc–Wen oscillator ``m y'' + c y' + k y + z(y) = u`` — simulated as the closed loop
    (`hysteresis_lab.blocks.feedback`). ``w`` starts at zero (the dynamics alone). The
    force is the Bouc–Wen cell's output (`hysteresis_lab.blocks.BoucWen`): its states ``h``
    start with the slope ``d`` of the spring ``d y``, so the force starts with none for small
    motions (the fitted dynamics hold the linear stiffness) and grows as the states saturate,
    over about ``width`` (the output over its scale)."""

    n_channels = 2

    def __init__(self, width: float) -> None:
        super().__init__()
        self.bouc_wen = BoucWen(d=1.0, alpha=1.0, beta=2.0 / max(width, 1e-6), gamma=0.0,
                                n_channels=self.n_channels)
        self.weight = nn.Parameter(torch.zeros((), dtype=torch.float64))

    def _coefficients(self, dynamics: StableSections) -> tuple[torch.Tensor, ...]:
        """``b, a`` of the dynamics (delay included) and the Bouc–Wen ``a, r1, r2``."""
        b, a = dynamics.polynomials()
        bw = self.bouc_wen
        beta, gamma = bw.beta, bw.gamma
        return b, a, bw.alpha * bw.d, beta - gamma, beta + gamma

    def forward(self, dynamics: StableSections, x: torch.Tensor,
                static: StaticFeedback | None = None, offset: torch.Tensor | None = None,
                ) -> torch.Tensor:
        """The closed loop's output (B, T) for the dynamics' input ``x`` (B, T); ``static``:
        a static feedback in the same loop (its knots set by the output ``offset``)."""
        b, a, ba, r1, r2 = self._coefficients(dynamics)
        w, knots = ((None, None) if static is None
                    else (static.loop_weights(dynamics), static.knots(offset)))
        return closed_loop(x.double(), b, a, -self.weight, self.weight * self.bouc_wen.d, ba, r1,
                           r2, _lag(dynamics), w, knots)

    def state_names(self, dynamics: StableSections) -> list[str]:
        """The step's state: past dynamics' inputs ``e`` and outputs ``y``, Bouc–Wen ``h``."""
        return _loop_state_names(dynamics) + [f"h{c}" for c in range(self.n_channels)]

    def step(self, dynamics: StableSections, x: torch.Tensor, state: StepState,
             static: StaticFeedback | None = None, offset: torch.Tensor | None = None,
             ) -> torch.Tensor:
        """One sample of `forward`: ``x`` (B,) -> ``y`` (B,); state: the past dynamics'
        inputs and outputs (newest first) and the Bouc–Wen states."""
        b, a, ba, r1, r2, weight, d = frozen(*self._coefficients(dynamics), self.weight,
                                             self.bouc_wen.d)
        phi = _no_feedback if static is None else static.function(dynamics, offset)

        def force(y: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
            return weight * (d * y - h.sum(dim=1)) + phi(y)

        def advance(h: torch.Tensor, dy: torch.Tensor) -> torch.Tensor:
            return bouc_wen_advance(h, dy[:, None], ba[None], r1[None], r2[None])

        return _loop_step(b, a, _lag(dynamics), x, state, force, self.n_channels, advance)

    def export(self) -> dict[str, Any]:
        """The weight and the Bouc–Wen parameters."""
        return {"weight": float(self.weight.detach()), **{
            k: np.asarray(v).tolist() for k, v in self.bouc_wen.export().items()}}


def knot_fractions(n_knots: int) -> np.ndarray:
    """Where `StaticFeedback`'s knots sit in the output's range: ``n_knots`` evenly from 10 %
    to 85 % (one knot: the middle)."""
    return np.linspace(0.1, 0.85, n_knots) if n_knots > 1 else np.array([0.5])


def _lag(dynamics: StableSections) -> int:
    """0 when the dynamics delay their input (a closed loop is causal as it is), else 1."""
    return 0 if int(dynamics.delay) > 0 else 1


def _no_feedback(y: torch.Tensor) -> torch.Tensor:
    return torch.zeros_like(y)


def _loop_state_names(dynamics: StableSections) -> list[str]:
    """A closed loop's step state: past dynamics' inputs ``e`` and outputs ``y``."""
    b, a = dynamics.polynomials()
    return [f"e{i}" for i in range(1, b.shape[0])] + [f"y{i}" for i in range(1, a.shape[0])]


def _loop_step(
    b: torch.Tensor, a: torch.Tensor, lag: int, x: torch.Tensor, state: StepState,
    force: Callable[[torch.Tensor, torch.Tensor | None], torch.Tensor],
    n_hidden: int = 0,
    advance: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
) -> torch.Tensor:
    """One sample of the dynamics ``b, a`` in a closed loop, ``e = x - force(y_fed, h)``,
    ``x`` (B,) -> ``y`` (B,); state: the past ``e`` and ``y`` (newest first), then
    ``n_hidden`` states ``h`` of the force that ``advance(h, y - y_prev)`` moves on."""
    past_e = state.take(b.shape[0] - 1)
    past_y = state.take(a.shape[0] - 1)
    h = state.take(n_hidden) if n_hidden else None
    e = x - force(past_y[:, 0], h) if lag else torch.zeros_like(x)
    y = b[0] * e + past_e @ b[1:] - past_y @ a[1:]
    if advance is not None:
        h = advance(h, y - past_y[:, 0])
    if not lag:
        e = x - force(y, h)
    if b.shape[0] > 1:  # a numerator of one term (`StagePole`) keeps no past input
        state.put(torch.cat([e[:, None], past_e[:, :-1]], dim=1))
    state.put(torch.cat([y[:, None], past_y[:, :-1]], dim=1))
    if h is not None:
        state.put(h)
    return y


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
        return closed_loop(x.double(), b, a, zero, zero, none, none, none, _lag(dynamics),
                           self.loop_weights(dynamics), self.knots(offset))

    @staticmethod
    def state_names(dynamics: StableSections) -> list[str]:
        """The step's state: past dynamics' inputs ``e`` and outputs ``y``."""
        return _loop_state_names(dynamics)

    def step(self, dynamics: StableSections, x: torch.Tensor, state: StepState,
             offset: torch.Tensor) -> torch.Tensor:
        """One sample of `forward`: ``x`` (B,) -> ``y`` (B,); state: the past dynamics'
        inputs and outputs (newest first)."""
        b, a = frozen(*dynamics.polynomials())
        phi = self.function(dynamics, offset)
        return _loop_step(b, a, _lag(dynamics), x, state, lambda y, _h: phi(y))

    def export(self) -> dict[str, Any]:
        """The weights and the levels of the knots (the output over its scale)."""
        return {"weights": self.weights.detach().cpu().numpy().tolist(),
                "levels": self.levels.cpu().numpy().tolist()}
