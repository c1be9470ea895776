"""`linear`: stable linear dynamics from the inputs to the outputs, grown into a physical model
by the effect catalogue.

    u_j -> [saturation] -> [dead zone] -> [backlash] -> [hysteresis] -> [creep] -> x_j
    y_o = [overflow_o](sum_j dynamics_oj(x_j) (+ [resonance_oj](x_j) in parallel) + offset_o)
    dynamics_oj in a closed loop with [hysteresis] / [nonlinear_feedback] of its output

Every input channel ``j`` has its own input blocks, every output ``o`` is a sum over the
inputs of stable linear dynamics (one transfer function per input and output, so MIMO data
such as the FSM mirror's 3x3 run as they are). The dynamics are an output-error model of
``model.order`` poles per pair, stable for any parameter value
(`hysteresis_lab.blocks.StableSections`), started from a least-squares ARX fit per output
(all inputs, one denominator, on every training recording; a Steiglitz–McBride fit instead
where its free run is far closer to the recordings) and refined on the free-run error
of whole recordings. Each declared effect (``model.effects``)
puts its block where the physics puts it, and every block starts where it changes nothing
(its weight at zero), so ``effects=[hysteresis]`` starts as the linear model and a loop
refit that adds an effect starts exactly from the model it grows:

* ``saturation``: ``v - w (v - clip(v, ±c))``, amplifier clipping ahead of the actuator;
* ``dead_zone``: ``v - w clip(v, ±c)``; ``backlash``: ``v + w (play_c(v) - v)``;
* ``hysteresis``: ``v - w h(v)``, ``h`` the Bouc–Wen state (the grey-box's cell), and
  inside the dynamics' feedback: the dynamics in a closed loop with a Bouc–Wen restoring
  force of their output, weighted from zero (`StateHysteresis`; per output and input pair,
  each on its own part of the output). The loop refits the whole model when it adds it
  (``whole_refit_effects``, as for the dead zone);
* ``rate``: the input's hysteresis cell rate-dependent, its Bouc–Wen ``alpha`` per sample
  ``alpha (1 + k |dv| / rate_step)`` with ``k`` from zero (`HysteresisCell`; declared
  without ``hysteresis`` it brings the cell, weight from zero, and no feedback force). The
  loop refits the whole model when it adds it;
* ``nonlinear_feedback``: the dynamics in a closed loop with a static function of their
  output level (a Lur'e system: a level-dependent outflow, a nonlinear spring;
  `StaticFeedback`), piecewise linear with weights from zero; per output and input pair,
  in the same loop as the hysteretic force when both are declared. The loop refits the
  whole model when it adds it;
* ``creep``: a first-order filter bank (the grey-box's block), weights from zero;
* ``resonance``: a second-order section in parallel with the dynamics, numerator from zero;
* ``overflow``: ``y - w_hi relu(y - c_hi) + w_lo relu(c_lo - y)`` on each output, after the
  dynamics (a tank that overflows, a sensor that clips), levels from the training output's
  extremes; with the output stage also a rim on the upstream storage.

``model.feedback_on`` says where the loop forces act: ``dynamics`` (around the whole
dynamics) or ``output_stage``: the dynamics as a `StorageCascade` (an upstream part, an
upstream storage, the output stage) with the forces on the output stage's own level, as a
tank's outflow law reads its own level (`LinearModel.refit_variants`: the loop tries both).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.blocks import BoucWen, CreepBank, bouc_wen_scaled_params, play
from hysteresis_lab.blocks.feedback import closed_loop
from hysteresis_lab.blocks.linear import iir_filter
from hysteresis_lab.blocks.sections import (
    MAX_RADIUS,
    StableSections,
    _polymul,
    arx_least_squares,
    held_poles,
    nyquist_share,
    slowest_rate,
    steiglitz_mcbride,
)
from hysteresis_lab.blocks.step import StepState, bouc_wen_advance, frozen, play_step, tdf2_step
from hysteresis_lab.blocks.storage import rim_step, rim_storage
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.augment import context_from_dict
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.physical_chain import PhysicalChainModule

log = logging.getLogger(__name__)

#: the Steiglitz–McBride fit replaces the ARX start only below this share of its free-run
#: error variance on the training recordings: a gross gain says ARX misplaced poles; a
#: modest one is what fitting the free run of these same recordings gives anyway (near the
#: unit circle on the cascaded tanks, under half of ARX's error there, a worse start on
#: the test)
OUTPUT_ERROR_REPLACES_AT = 0.01
#: ... and only where its slowest mode is at least this share of the ARX fit's slowest
#: (`slowest_rate`): slower dynamics are slow effects (creep, drift) read into the start,
#: which the loop names itself (the creep block carries creep); from a start holding them the
#: loop's creep refit did worse (simulator creep diagnosed on a 1 Hz sine: its 0.1 Hz test
#: 0.121 instead of 0.053 um after the refit)
SLOWEST_MODE_SHARE = 0.5
#: ... or where the ARX start's gain at Nyquist exceeds this share of its static gain while
#: the Steiglitz–McBride fit's does not: a sampled physical low-pass system has far less
#: there; ARX's equation error, whitening the sensor noise above the input's band, puts poles
#: near Nyquist that no training on that band moves (simulated positioner, 0-500 Hz
#: multisine: order-6 ARX 1.02 um/V at 4.5 kHz and 7.96 at 9 kHz where it has 0.005 and
#: 0.0001, 39x its static gain; an input clipped by the loop's saturation block rang in it:
#: the refit left 1.00 um on the 100 Hz sine and 0.76-1.02 on 400-500 Hz, from the
#: output-error start 0.08 and 0.32-0.41; experiments/saturation_refit.py) ...
NYQUIST_GAIN_SHARE = 1.0
#: ... where, too, the output-error fit simulates clearly better (below this share of the ARX
#: start's error variance) and keeps ARX's slow dynamics (its slowest mode at least this share
#: of ARX's): it is there to take out the poles near Nyquist, not to read another mode into
#: the start (an 8000-sample dead-zone record: output-error fit 0.97 of ARX's error with a
#: pole at the radius limit, the round-0 held-out loss 0.29 instead of 0.18 and the loop's
#: dead-zone refit no longer cut it; the simulator's default data, hysteresis and creep on:
#: 0.41 with its slowest mode at 0.68, a plain linear fit 6 % worse on the test sines)
NYQUIST_CLEAR_SHARE = 0.9

#: where the loop forces (hysteresis in the feedback, nonlinear_feedback) act: around the whole
#: dynamics, or on the output stage's own level (`StorageCascade`)
FEEDBACK_PLACES = ("dynamics", "output_stage")
#: effects whose refit in the loop tries both places (the held-out loss chooses)
PLACED_EFFECTS = ("hysteresis", "nonlinear_feedback", "overflow")

#: catalogue effects the linear model carries as blocks, in physical order
LINEAR_EFFECTS = ("saturation", "dead_zone", "backlash", "hysteresis", "rate", "creep",
                  "resonance", "nonlinear_feedback", "overflow")


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


class StagePole(nn.Module):
    """One real pole ``p = MAX_RADIUS tanh(raw)`` with unit static gain,
    ``(1 - p) / (1 - p z^-1)``: a first-order storage, stable for any parameter value. It has
    `StableSections`' ``polynomials`` and ``delay`` (none), so the closed loops
    (`StaticFeedback`, `StateHysteresis`) run around it as they do around the dynamics."""

    def __init__(self) -> None:
        super().__init__()
        self.raw_pole = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.register_buffer("delay", torch.zeros((), dtype=torch.long))

    @property
    def pole(self) -> torch.Tensor:
        return MAX_RADIUS * torch.tanh(self.raw_pole)

    def set_pole(self, pole: float) -> None:
        """Start at ``pole`` (kept within ``MAX_RADIUS``)."""
        held = float(np.clip(pole / MAX_RADIUS, -0.999999, 0.999999))
        with torch.no_grad():
            self.raw_pole.fill_(float(np.arctanh(held)))

    def polynomials(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``b = [1 - p]``, ``a = [1, -p]``."""
        p = self.pole
        return (1.0 - p).reshape(1), torch.stack([torch.ones_like(p), -p])


class StorageCascade(nn.Module):
    """The dynamics as storages in a row (``model.feedback_on=output_stage``): an upstream
    part (`StableSections`: the gain, delay and the other poles, open loop), then an
    upstream storage (one real pole, `StagePole`'s rate, optionally with a rim:
    `hysteresis_lab.blocks.storage`, its level held there and a share of the spill passed
    on), then the output stage (one real pole) whose own level the loop forces
    (`StaticFeedback`, `StateHysteresis`) act on — a tank whose outflow law reads its own
    level, fed by an upper tank that overflows. Both storages have unit static gain, so the
    cascade's static gain is the upstream part's."""

    def __init__(self, order: int, rim_level: float | None = None) -> None:
        super().__init__()
        #: room for ``order`` poles upstream (sections the start leaves empty may train)
        self.upstream = StableSections(order)
        self.storage = StagePole()
        self.stage = StagePole()
        self.rim_weight: nn.Parameter | None = None
        if rim_level is not None:  # effect overflow: the rim, spill weight and share from zero
            self.rim_weight = nn.Parameter(torch.zeros((), dtype=torch.float64))
            self.rim_level = nn.Parameter(torch.tensor(float(rim_level), dtype=torch.float64))
            self.spill_share = nn.Parameter(torch.zeros((), dtype=torch.float64))

    def _rim(self, offset: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The rim on the storage's level (the output's units less its ``offset``), the
        spill's weight and its share passed on (zeros without a rim)."""
        if self.rim_weight is None:
            zero = torch.zeros((), dtype=torch.float64, device=offset.device)
            return zero, zero, zero
        return self.rim_level - offset, self.rim_weight, self.spill_share

    def storage_output(self, x: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
        """What fills the output stage (B, T): the upstream storage's level plus its share of
        the spill (over the output stage's rate: ``share = 1`` passes all of it into the
        stage's level), for the cascade's input ``x`` (B, T)."""
        rim, weight, share = self._rim(offset)
        level, spill = rim_storage(self.upstream(x), 1.0 - self.storage.pole, rim, weight)
        return level + share * spill / (1.0 - self.stage.pole)

    def storage_step(self, x: torch.Tensor, state: StepState,
                     offset: torch.Tensor) -> torch.Tensor:
        """One sample of `storage_output`; state: the upstream part's, the storage's level."""
        v = self.upstream.step(x, state)
        alpha, rim, weight, share, stage = frozen(1.0 - self.storage.pole, *self._rim(offset),
                                                  1.0 - self.stage.pole)
        level, spill = rim_step(v, state.take(1)[:, 0], alpha, rim, weight)
        state.put(level[:, None])
        return level + share * spill / stage

    def storage_state_names(self) -> list[str]:
        return [f"upstream.{name}" for name in self.upstream.state_names()] + ["storage"]

    def set_transfer_function(self, b: np.ndarray, a: np.ndarray) -> None:
        """Start from ``b(z^-1) / a(z^-1)``: its two slowest real poles become the storages
        (the slowest the upstream storage, the other the output stage), the other poles the
        upstream part with ``b``'s delay and the static gain but no zeros (the inflow: the
        exact numerator over two slow storages amplifies high frequencies a thousandfold on
        the cascaded tanks, where the rim then acts). Where ``a`` has fewer real poles, its
        slowest complex pair gives two real poles of its radius. So the start keeps the
        poles, the delay and the static gain, not the zeros."""
        poles = list(held_poles(a))
        chosen = []
        for _ in range(2):
            real = [i for i, p in enumerate(poles) if abs(p.imag) <= 1e-9]
            if not real and poles:
                i = max(range(len(poles)), key=lambda k: abs(poles[k]))
                radius = abs(poles[i])
                pair = [k for k in range(len(poles)) if k != i
                        and abs(poles[k] - np.conj(poles[i])) < 1e-9][:1]
                poles = [p for k, p in enumerate(poles) if k not in (i, *pair)]
                poles += [complex(radius)] * (1 + len(pair))
                log.info("output stage start: no real pole left, a pole pair of radius %.4f "
                         "made real", radius)
                real = [len(poles) - 1]
            if not real:
                chosen.append(0.0)
                continue
            i = max(real, key=lambda k: poles[k].real)
            chosen.append(float(poles.pop(i).real))
        rest = np.atleast_1d(np.real(np.poly(poles)))
        b = np.asarray(b, dtype=float)
        static_gain = b.sum() / np.sum(np.real(np.poly(held_poles(a))))
        lead = int(np.flatnonzero(b)[0]) if np.any(b) else 0
        upstream = np.zeros(lead + 1)
        upstream[lead] = static_gain * rest.sum()  # the inflow: no zeros, the static gain kept
        self.upstream.set_transfer_function(upstream, rest)
        self.storage.set_pole(chosen[0])
        self.stage.set_pole(chosen[1])

    def polynomials(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The cascade below the rim as one transfer function (upstream, storage, stage)."""
        b, a = self.upstream.polynomials()
        for part in (self.storage, self.stage):
            bp, ap = part.polynomials()
            b, a = _polymul(b, bp), _polymul(a, ap)
        return b, a

    def export(self) -> dict[str, Any]:
        with torch.no_grad():
            out = {"upstream": self.upstream.export(),
                   "storage_pole": float(self.storage.pole), "stage_pole": float(self.stage.pole)}
            if self.rim_weight is not None:
                out.update(rim_level=float(self.rim_level), rim_weight=float(self.rim_weight),
                           spill_share=float(self.spill_share))
        return out


def _pairs(n_out: int, n_in: int, make: Any) -> nn.ModuleList:
    """``[output][input]`` blocks from ``make()``."""
    return nn.ModuleList(nn.ModuleList(make() for _ in range(n_in)) for _ in range(n_out))


class LinearModel(PhysicalChainModule):
    """Stable linear dynamics with the declared effects' blocks (see the module docstring)."""

    carried_effects = LINEAR_EFFECTS
    #: a dead zone takes a band off every input and a backlash its play off every reversal (a
    #: linear fit meets the lost output with a lower gain and a lag, which a block-only refit
    #: cannot give back); hysteresis closes a restoring force around the dynamics, a
    #: nonlinear feedback a static law; a rate-dependent loop shares out the loop width the
    #: cell's ``alpha`` was fitted to at the training input's rates (``alpha`` must fall as
    #: the rate gain grows): the loop refits the whole model when it adds any of them
    whole_refit_effects = ("dead_zone", "backlash", "hysteresis", "rate", "nonlinear_feedback")

    def __init__(
        self,
        nu: int,
        ny: int,
        order: int = 6,
        delay: int = 1,
        fs: float = 20_000.0,
        creep_time_constants_s: Sequence[float] = (0.1, 1.0, 10.0, 100.0),
        recording_repeats: int = 10,
        feedback_knots: int = 6,
        feedback_on: str = "dynamics",
        objective: str = "simulation",
        lr: float = 0.002,
        **kwargs: Any,
    ) -> None:
        super().__init__(nu=nu, ny=ny, objective=objective, lr=lr, **kwargs)
        fs = float((kwargs.get("trained_on") or {}).get("fs") or fs)
        effects = list(self.hparams.get("effects") or [])
        problems = []
        unknown = [e for e in effects if e not in LINEAR_EFFECTS]
        if unknown:
            problems.append(f"effects {unknown} (its blocks: {list(LINEAR_EFFECTS)})")
        if not (isinstance(order, int) and order >= 1):
            problems.append(f"model.order={order!r} (poles, >= 1)")
        if not (isinstance(delay, int) and delay >= 0):
            problems.append(f"model.delay={delay!r} (whole samples >= 0)")
        if not (isinstance(feedback_knots, int) and not isinstance(feedback_knots, bool)
                and 1 <= feedback_knots <= 50):
            problems.append(f"model.feedback_knots={feedback_knots!r} (knots of the "
                            "nonlinear feedback's law, a whole number from 1 to 50)")
        if feedback_on not in FEEDBACK_PLACES:
            problems.append(f"model.feedback_on={feedback_on!r} (where the loop forces act: "
                            f"one of {list(FEEDBACK_PLACES)})")
        elif feedback_on == "output_stage" and isinstance(order, int) and order < 2:
            problems.append(f"model.feedback_on=output_stage with model.order={order} (the "
                            "output stage and the upstream storage take a pole each: order >= 2)")
        if objective != "simulation":
            problems.append(f"model.objective='{objective}' (it is fitted on the simulation "
                            "error only)")
        if problems:
            raise ConfigError(
                "model=linear cannot take " + "; ".join(problems) + ". Fix: change those "
                "settings (hysteresis_lab/conf/model/linear.yaml has the defaults)."
            )
        n_in = self.n_base_inputs
        self.input_blocks = nn.ModuleList(
            self._input_blocks(effects, self._input_amplitude(j)) for j in range(n_in))
        self.creep = nn.ModuleList(CreepBank(fs, creep_time_constants_s) for _ in range(n_in)) \
            if "creep" in effects else None
        extremes = [self._output_extremes(o) for o in range(ny)]
        #: the loop forces act on the output stage's own level (`StorageCascade`)
        self.output_stage = feedback_on == "output_stage"
        if self.output_stage:
            rim = "overflow" in effects
            self.dynamics = nn.ModuleList(
                nn.ModuleList(StorageCascade(order, low + knot_fractions(2)[-1] * (high - low)
                                             if rim else None) for _ in range(n_in))
                for low, high in extremes)
        else:
            self.dynamics = _pairs(ny, n_in, lambda: StableSections(order))
        self.resonance: nn.ModuleList | None = None
        if "resonance" in effects:
            self.resonance = _pairs(ny, n_in, self._resonance_section)
        self.offset = nn.Parameter(torch.zeros(ny, dtype=torch.float64))
        self.overflow: nn.ModuleList | None = None
        if "overflow" in effects:
            self.overflow = nn.ModuleList(Overflow(low, high) for low, high in extremes)
        self.state_hysteresis: nn.ModuleList | None = None
        if "hysteresis" in effects:
            self.state_hysteresis = nn.ModuleList(
                nn.ModuleList(StateHysteresis(high - low) for _ in range(n_in))
                for low, high in extremes)
        self.static_feedback: nn.ModuleList | None = None
        if "nonlinear_feedback" in effects:
            self.static_feedback = nn.ModuleList(
                nn.ModuleList(StaticFeedback(low, high, feedback_knots) for _ in range(n_in))
                for low, high in extremes)

    def _output_extremes(self, channel: int) -> tuple[float, float]:
        """An output's lowest and highest training value over its scale (the overflow
        block's starting levels; the scaled output's ±3 without a record of them)."""
        context = self.hparams.get("feature_context")
        ctx = context_from_dict(context) if context is not None else None
        scale, offset = float(self.y_scale[channel]), float(self.y_offset[channel])
        if ctx is None or ctx.y_low is None or ctx.y_high is None or scale <= 0:
            return (offset - 3.0 * scale) / scale, (offset + 3.0 * scale) / scale
        return float(ctx.y_low[channel]) / scale, float(ctx.y_high[channel]) / scale

    @staticmethod
    def _input_blocks(effects: Sequence[str], amplitude: float) -> nn.ModuleDict:
        """One input channel's blocks, in physical order (``rate``: the hysteresis cell
        rate-dependent)."""
        blocks = nn.ModuleDict()
        rate_step = HysteresisCell.rate_step_for(amplitude) if "rate" in effects else None
        for name, block in (("saturation", lambda: Saturation(0.9 * amplitude)),
                            ("dead_zone", lambda: DeadZone(0.05 * amplitude)),
                            ("backlash", lambda: Backlash(0.05 * amplitude)),
                            ("hysteresis", lambda: HysteresisCell(rate_step))):
            if name in effects or (name == "hysteresis" and rate_step is not None):
                blocks[name] = block()
        return blocks

    @staticmethod
    def _resonance_section() -> StableSections:
        """A lightly damped pair at zero weight (numerator zero)."""
        section = StableSections(2)
        with torch.no_grad():
            section.numerators.zero_()
            section.raw_denominators[:, 1] = 2.0
        return section

    def _input_amplitude(self, channel: int) -> float:
        """A measured input's amplitude over its scale (for the levels of input blocks)."""
        context = self.hparams.get("feature_context")
        if context is None:
            return 1.0
        amplitude = float(context_from_dict(context).u_amplitude[channel])
        scale = float(self.u_scale[channel])
        return max(amplitude / scale, 1e-6) if scale > 0 else 1.0

    # ------------------------------------------------------------------ the model
    def _input_path(self, v: torch.Tensor, j: int) -> torch.Tensor:
        """Input ``j``'s blocks (B, T) -> (B, T)."""
        x = v
        for block in self.input_blocks[j].values():
            x = block(x)
        if self.creep is not None:
            x = self.creep[j](x)
        return x

    def chain(self, v: torch.Tensor) -> torch.Tensor:
        xs = [self._input_path(v[..., j], j) for j in range(self.n_base_inputs)]
        outputs = []
        for o in range(self.ny):
            y = sum(self._dynamics_path(o, j, x) for j, x in enumerate(xs))
            if self.resonance is not None:
                y = y + sum(self.resonance[o][j](x) for j, x in enumerate(xs))
            if self.overflow is not None:  # on the output itself, offset included
                y = self.overflow[o](y + self.offset[o]) - self.offset[o]
            outputs.append(y)
        return torch.stack(outputs, dim=-1)

    def _dynamics_path(self, o: int, j: int, x: torch.Tensor) -> torch.Tensor:
        """The dynamics of pair ``(o, j)`` on ``x`` (B, T), in a closed loop with the
        hysteretic force and/or the static feedback where declared (with
        ``feedback_on=output_stage``: the loop around the output stage, fed by the upstream
        part and storage)."""
        dynamics = self.dynamics[o][j]
        if self.output_stage:
            x = dynamics.storage_output(x, self.offset[o])
            dynamics = dynamics.stage
        static = None if self.static_feedback is None else self.static_feedback[o][j]
        if self.state_hysteresis is not None:
            return self.state_hysteresis[o][j](dynamics, x, static, self.offset[o])
        if static is not None:
            return static(dynamics, x, self.offset[o])
        if self.output_stage:
            return iir_filter(x, *dynamics.polynomials())
        return dynamics(x)

    def _dynamics_step(self, o: int, j: int, x: torch.Tensor, state: StepState) -> torch.Tensor:
        """One sample of `_dynamics_path`."""
        dynamics = self.dynamics[o][j]
        offset = frozen(self.offset)[0][o]
        if self.output_stage:
            x = dynamics.storage_step(x, state, offset)
            dynamics = dynamics.stage
        static = None if self.static_feedback is None else self.static_feedback[o][j]
        if self.state_hysteresis is not None:
            return self.state_hysteresis[o][j].step(dynamics, x, state, static, offset)
        if static is not None:
            return static.step(dynamics, x, state, offset)
        if self.output_stage:
            return tdf2_step(*frozen(*dynamics.polynomials()), x, state)
        return dynamics.step(x, state)

    def _dynamics_state_names(self, o: int, j: int) -> list[str]:
        """The state of `_dynamics_step` for pair ``(o, j)``."""
        dynamics = self.dynamics[o][j]
        names = []
        if self.output_stage:
            names = [f"dynamics{o}{j}.{part}" for part in dynamics.storage_state_names()]
            dynamics = dynamics.stage
        if self.state_hysteresis is not None:
            return names + [f"state_hysteresis{o}{j}.{part}"
                            for part in self.state_hysteresis[o][j].state_names(dynamics)]
        if self.static_feedback is not None:
            return names + [f"static_feedback{o}{j}.{part}"
                            for part in StaticFeedback.state_names(dynamics)]
        if self.output_stage:
            return names + [f"dynamics{o}{j}.stage"]
        return [f"dynamics{o}{j}.{part}" for part in dynamics.state_names()]

    def state_names(self) -> list[str]:
        """Per input: its blocks' states (backlash: the play output; hysteresis: previous
        input and Bouc–Wen state) and creep filters; then per output and input: the
        dynamics' delay buffer and second-order section states, and the resonance's."""
        names = []
        for j, blocks in enumerate(self.input_blocks):
            for name, block in blocks.items():
                names += [f"input{j}.{name}.{part}" for part in block.state_names()]
            if self.creep is not None:
                names += [f"input{j}.creep.{part}" for part in self.creep[j].state_names()]
        for o in range(self.ny):
            n_in = self.n_base_inputs
            names += [name for j in range(n_in) for name in self._dynamics_state_names(o, j)]
            if self.resonance is not None:
                names += [f"resonance{o}{j}.{part}" for j in range(n_in)
                          for part in self.resonance[o][j].state_names()]
        return names

    def chain_step(self, v: torch.Tensor, state: StepState) -> torch.Tensor:
        xs = []
        for j, blocks in enumerate(self.input_blocks):
            x = v[:, j]
            for block in blocks.values():
                x = block.step(x, state)
            if self.creep is not None:
                x = self.creep[j].step(x, state)
            xs.append(x)
        outputs = []
        for o in range(self.ny):  # the blocks in the order of `state_names`
            y = sum(self._dynamics_step(o, j, x, state) for j, x in enumerate(xs))
            if self.resonance is not None:
                y = y + sum(self.resonance[o][j].step(x, state) for j, x in enumerate(xs))
            if self.overflow is not None:
                offset = frozen(self.offset)[0][o]
                y = self.overflow[o].step(y + offset, state) - offset
            outputs.append(y)
        return torch.stack(outputs, dim=-1)

    # ------------------------------------------------------------------ the loop's refits
    @classmethod
    def refit_variants(cls, model_cfg: dict[str, Any], previous: Any | None,
                       added: str | None) -> list[dict[str, Any]]:
        """The model settings a loop round fits (each a candidate; the held-out loss chooses):
        a refit that adds a loop force or the overflow (`PLACED_EFFECTS`) to a model whose
        forces still act on the whole dynamics tries both places (`FEEDBACK_PLACES`), the
        physics deciding where a law sits: the tanks' outflow law reads the output stage's
        own level, a spring's force the whole oscillator's. Otherwise the place the last
        model was fitted with (``model.feedback_on`` at the start)."""
        place = (previous.hparams.get("feedback_on") if previous is not None
                 else None) or model_cfg.get("feedback_on", "dynamics")
        order = model_cfg.get("order", 6)
        if (added in PLACED_EFFECTS and place == "dynamics" and previous is not None
                and isinstance(order, int) and order >= 2):
            return [{"feedback_on": p} for p in FEEDBACK_PLACES]
        return [{"feedback_on": place}]

    def warm_start_from(self, previous: Any) -> None:
        """`PhysicalChainModule.warm_start_from`; from a model whose forces act on the whole
        dynamics into one with an output stage, the fitted dynamics are factored into the
        `StorageCascade` (`StorageCascade.set_transfer_function`: its poles, delay and static
        gain; the loop forces' weights carry over onto the output stage), and only the
        blocks new to the model (the rim) count as new."""
        super().warm_start_from(previous)
        if not self.output_stage or getattr(previous, "output_stage", False):
            return
        for o in range(self.ny):
            for j in range(self.n_base_inputs):
                with torch.no_grad():
                    b, a = previous.dynamics[o][j].polynomials()
                self.dynamics[o][j].set_transfer_function(b.cpu().numpy(), a.cpu().numpy())
        self._new_entries = {name: new for name, new in self._new_entries.items()
                             if not re.match(r"^dynamics\.\d+\.\d+\.(upstream|storage|stage)\.",
                                             name)}
        log.info("output stage: the fitted dynamics factored into upstream part, storage and "
                 "output stage")

    # ------------------------------------------------------------------ initial values
    def initialise_from_data(self, u: np.ndarray, y: np.ndarray, fs: float) -> None:
        """`initialise_from_recordings` on one training recording's arrays (physical units;
        1-D for one channel, else (T, channels))."""
        self._initialise_from_arrays([u], [y])

    def initialise_from_recordings(self, recordings: Sequence[Recording]) -> None:
        """The dynamics from a least-squares ARX fit per output (``order`` poles, one
        denominator for all inputs, ``delay``) on the training ``recordings`` (only their
        measured inputs are read), and the output offsets.

        ``order`` starts unless its free run from rest is further from the recordings than
        their mean; then every order from 1 up is fitted and the one that simulates best
        starts: on data that excite few frequencies (a single sine) a high-order ARX is not
        identified and its free run can be far off.

        A Steiglitz–McBride fit of ``order`` (`steiglitz_mcbride`: ARX on data prefiltered
        by the last denominator, towards the output-error fit) starts instead where its free
        run has less than `OUTPUT_ERROR_REPLACES_AT` of the ARX start's error variance and
        its slowest mode is no slower than `SLOWEST_MODE_SHARE` of the ARX start's: ARX's
        equation error can misplace a lightly damped mode above the input band (seen only in
        start transients), which training on the free run does not recover; slow effects
        (creep, drift) stay out of the start, for the loop's creep block. It also starts
        where the ARX start's gain at Nyquist is above `NYQUIST_GAIN_SHARE` of its static gain
        while its own is not (`nyquist_share`), its free run below `NYQUIST_CLEAR_SHARE` of
        ARX's error variance and its slowest mode at least that share of ARX's: ARX's poles
        near Nyquist, fitted to sensor noise above the input's band, leave a gain there that
        no training on that band moves and that a clipped input's corners reach."""
        self._initialise_from_arrays([rec.u for rec in recordings], [rec.y for rec in recordings])

    def _initialise_from_arrays(
        self, us: Sequence[np.ndarray], ys: Sequence[np.ndarray]
    ) -> None:
        """`initialise_from_recordings` on arrays (physical units, (T, channels) or 1-D)."""
        n_in = self.n_base_inputs
        vs = [np.asarray(u, float).reshape(len(u), -1)[:, :n_in] / self.u_scale[:n_in].numpy()
              for u in us]
        ys_s = [np.asarray(y, float).reshape(len(y), -1) / self.y_scale.numpy() for y in ys]
        radius, orders, fits = 0.0, [], []
        for o in range(self.ny):
            order, a, fit = self._start_output(o, vs, [y[:, o] for y in ys_s])
            orders.append(order)
            fits.append(fit)
            radius = max(radius, float(np.max(np.abs(np.roots(a)))) if len(a) > 1 else 0.0)
        with torch.no_grad():
            residuals = [y - self.chain(torch.as_tensor(v[None]))[0].numpy()
                         for v, y in zip(vs, ys_s, strict=True)]
            self.offset.copy_(torch.as_tensor(np.concatenate(residuals).mean(axis=0)))
        log.info("linear start: %s per output on %d recording(s), orders %s (model.order=%d), "
                 "delay %d, poles |p| <= %.4f", fits, len(vs), orders, self.hparams.order,
                 self.hparams.delay, radius)

    def _start_output(
        self, o: int, vs: Sequence[np.ndarray], ys: Sequence[np.ndarray]
    ) -> tuple[int, np.ndarray, str]:
        """Set output ``o``'s dynamics to the start described in
        `initialise_from_recordings`; returns the order, the denominator and the fit
        chosen (``"ARX"`` or ``"Steiglitz-McBride"``)."""
        arx = self._arx_start(o, vs, ys)
        order = self.hparams.order
        b, a = steiglitz_mcbride(vs, ys, na=order, nb=self._nb(order), nk=self.hparams.delay)
        output_error = self._set_start(o, vs, ys, b, a)
        rings = (nyquist_share(arx[2], arx[3]), nyquist_share(b, a))
        slowest = slowest_rate(a) / slowest_rate(arx[3])
        clean = (rings[0] > NYQUIST_GAIN_SHARE >= rings[1] and slowest >= NYQUIST_CLEAR_SHARE
                 and output_error < NYQUIST_CLEAR_SHARE * arx[0])
        if output_error < OUTPUT_ERROR_REPLACES_AT * arx[0] or clean:
            replaces = slowest >= SLOWEST_MODE_SHARE
            log.info("linear start, output %d: Steiglitz-McBride (order %d) in free run %.3g "
                     "of the ARX fit's error variance (order %d), its slowest mode at %.3g of "
                     "ARX's, gain at Nyquist %.3g of its static gain (ARX: %.3g): %s", o, order,
                     output_error / arx[0], arx[1], slowest, rings[1], rings[0],
                     "it starts" if replaces else "too slow, ARX starts")
            if replaces:
                return order, a, "Steiglitz-McBride"
        self._set_dynamics(o, *arx[2:])  # set it again: the last fit tried is in place
        return arx[1], arx[3], "ARX"

    def _nb(self, order: int) -> int:
        """Numerator terms of an ARX fit of ``order`` poles after the delay."""
        return max(1, order - max(self.hparams.delay, 1) + 1)

    def _set_start(
        self, o: int, vs: Sequence[np.ndarray], ys: Sequence[np.ndarray], b: np.ndarray,
        a: np.ndarray,
    ) -> float:
        """Set output ``o``'s dynamics to ``b / a``; the variance of its free-run error from
        rest on the recordings (the offset comes after), ``inf`` where not finite."""
        self._set_dynamics(o, b, a)
        with torch.no_grad():
            errors = np.concatenate([
                y - self.chain(torch.as_tensor(v[None]))[0, :, o].numpy()
                for v, y in zip(vs, ys, strict=True)])
        error = float(np.var(errors))
        return error if np.isfinite(error) else np.inf

    def _set_dynamics(self, o: int, b: np.ndarray, a: np.ndarray) -> None:
        """Output ``o``'s dynamics from every input: ``b[j] / a``."""
        for j in range(self.n_base_inputs):
            self.dynamics[o][j].set_transfer_function(b[j], a)

    def _arx_start(
        self, o: int, vs: Sequence[np.ndarray], ys: Sequence[np.ndarray]
    ) -> tuple[float, int, np.ndarray, np.ndarray]:
        """The ARX fit of `initialise_from_recordings` (``model.order``, else the order
        that simulates best): its free-run error variance, order, ``b`` and ``a``."""
        delay = self.hparams.delay
        spread = float(np.var(np.concatenate(ys)))

        def fit(order: int) -> tuple[float, int, np.ndarray, np.ndarray]:
            b, a = arx_least_squares(vs, ys, na=order, nb=self._nb(order), nk=delay)
            return self._set_start(o, vs, ys, b, a), order, b, a

        full = fit(self.hparams.order)
        if full[0] < spread:
            return full
        candidates = [fit(order) for order in range(1, self.hparams.order)] + [full]
        return min(candidates, key=lambda c: c[0])

    def load_state_dict(self, state_dict: Any, strict: bool = True, assign: bool = False) -> Any:
        """Also reads a one-input, one-output model saved before the MIMO layout; refuses,
        with what to do, one whose feedback hysteresis is the former play operators."""
        state_dict = _mimo_keys(state_dict)
        if any(re.match(r"^state_hysteresis\.\d+\.\d+\.weights$", key) for key in state_dict):
            raise ConfigError(
                "this linear model was saved with the former feedback hysteresis (play "
                "operators of the linear response); the block is now the closed loop with a "
                "Bouc–Wen restoring force and those weights do not carry over. Fix: train it "
                "again (hysteresis-lab-train model=linear model.effects=[hysteresis,...])."
            )
        return super().load_state_dict(state_dict, strict=strict, assign=assign)

    def physical_parameters(self) -> dict[str, Any]:
        """Every block's current parameters (for reports); per output and input pair
        ``dynamics[o][j]``, per input ``inputs[j]``."""
        with torch.no_grad():
            out: dict[str, Any] = {
                "dynamics": [[block.export() for block in row] for row in self.dynamics],
                "offset": self.offset.cpu().numpy().tolist(),
                "inputs": [{name: {k: v.detach().cpu().numpy().tolist()
                                   for k, v in block.named_parameters()}
                            for name, block in blocks.items()} for blocks in self.input_blocks],
            }
            if self.creep is not None:
                out["creep"] = [block.export() for block in self.creep]
            if self.resonance is not None:
                out["resonance"] = [[block.export() for block in row] for row in self.resonance]
            if self.state_hysteresis is not None:
                out["state_hysteresis"] = [[block.export() for block in row]
                                           for row in self.state_hysteresis]
            if self.static_feedback is not None:
                out["static_feedback"] = [[block.export() for block in row]
                                          for row in self.static_feedback]
            if self.overflow is not None:
                out["overflow"] = [{k: v.detach().cpu().numpy().tolist()
                                    for k, v in block.named_parameters()}
                                   for block in self.overflow]
        return out


def _mimo_keys(state_dict: Any) -> dict[str, Any]:
    """A state dict of the one-input, one-output layout (``input_blocks.<name>``,
    ``creep.weights``, ``dynamics.<parameter>``, ``overflow.<parameter>``, a scalar
    ``offset``) in the MIMO one."""
    out = {}
    for key, value in state_dict.items():
        new = re.sub(r"^input_blocks\.(?!\d)", "input_blocks.0.", key)
        new = re.sub(r"^creep\.(?!\d)", "creep.0.", new)
        new = re.sub(r"^(dynamics|resonance|state_hysteresis)\.(?!\d)", r"\1.0.0.", new)
        new = re.sub(r"^overflow\.(?!\d)", "overflow.0.", new)
        if new == "offset" and value.dim() == 0:
            value = value.reshape(1)
        out[new] = value
    return out
