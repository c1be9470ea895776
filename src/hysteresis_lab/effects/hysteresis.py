"""Hysteresis: rate-independent memory of the drive (a Bouc–Wen or Prandtl–Ishlinskii cell
in the simulator, play operators as evidence).

Faces: Prandtl–Ishlinskii play operators of the input as operators and evidence, and of the
model's own output as state evidence; the simulator's hysteresis cell (Bouc–Wen of any admissible
exponent, or Prandtl–Ishlinskii with any thresholds), which turns the drive into a
displacement (``data.effects.hysteresis``); ``model=linear``'s cell on each input (Bouc–Wen,
`HysteresisCell`, or Prandtl–Ishlinskii, `PlayCell`: ``model.hysteresis``, by default read off
the data as the grey-box's is) and Bouc–Wen restoring force in the dynamics' feedback
(`StateHysteresis`); the grey-box's own hysteresis cell carries it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.blocks import BoucWen, bouc_wen_scaled_params
from hysteresis_lab.blocks.feedback import (
    closed_loop,
    loop_lag,
    loop_state_names,
    loop_step,
    no_feedback,
)
from hysteresis_lab.blocks.sections import StableSections
from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.effects._shared import per_input
from hysteresis_lab.effects.base import (
    Effect,
    FeatureContext,
    GreyBoxPart,
    LinearBlock,
    LinearContext,
    PlantSignals,
)
from hysteresis_lab.physics.bouc_wen import (
    bouc_wen_advance,
    bouc_wen_state,
)
from hysteresis_lab.physics.play import play, play_operators, play_step, spread_thresholds

#: the simulator's hysteresis cells (``data.effects.hysteresis.cell``), and those of
#: ``model=linear``'s input cell (``model.hysteresis``)
CELLS = ("bouc_wen", "prandtl_ishlinskii")
#: play operators of ``model=linear``'s Prandtl–Ishlinskii input cell (`PlayCell`)
PLAY_CELL_OPERATORS = 8


@dataclass
class HysteresisConfig:
    """Rate-independent hysteresis cell: Bouc–Wen (Low & Guo 1995; Goldfarb & Celanovic 1997)
    or Prandtl–Ishlinskii (Kuhnen 2003).

    ``cell=bouc_wen``: ``x = d v - h``, ``dh/dt = alpha d dv/dt - beta |dv/dt| |h|^(n-1) h -
    gamma dv/dt |h|^n`` with ``n = exponent >= 1``; needs ``beta > |gamma|`` (both rates
    ``beta -/+ gamma`` positive: a bounded, passive loop). Defaults: ``n = 1``, ±100 V →
    ±20 µm, major loop ≈ 11 % of the stroke.

    ``cell=prandtl_ishlinskii``: ``x = d ((1 - sum w) v + sum_i w_i play_{r_i}(v))`` with the
    play thresholds ``thresholds_v`` (V, any spacing) and their ``weights`` (each >= 0, summing
    to less than 1, so the displacement follows the drive's direction); ``alpha``, ``beta``,
    ``gamma`` and ``exponent`` are unused (and rate dependence has no ``alpha`` to scale).
    """

    enabled: bool = True
    d_um_per_v: float = 0.23
    alpha: float = 0.32
    beta: float = 0.02
    gamma: float = 0.006
    exponent: float = 1.0
    cell: str = "bouc_wen"
    thresholds_v: list[float] = field(default_factory=list)
    weights: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        # YAML and Hydra overrides give numbers as they are written (ints, ListConfig)
        self.thresholds_v = [float(r) for r in self.thresholds_v]
        self.weights = [float(w) for w in self.weights]


def _register_square_law(cell: nn.Module, square_amplitude: float | None) -> None:
    """``cell.square_weight`` (from zero) and ``cell.square_amplitude`` of the asymmetric square
    law ``q A (v / A)^2`` (`HysteresisCell._square_law`); ``square_weight`` None without one."""
    cell.square_weight = None
    if square_amplitude is None:
        return
    if not square_amplitude > 0:
        raise ValueError(f"square_amplitude must be > 0 (got {square_amplitude})")
    cell.square_weight = nn.Parameter(torch.zeros((), dtype=torch.float64))
    cell.register_buffer("square_amplitude",
                         torch.tensor(float(square_amplitude), dtype=torch.float64))


class HysteresisCell(nn.Module):
    """``v - w h(v)``: the Bouc–Wen state ``h`` (`hysteresis_lab.blocks.BoucWen`) subtracted
    with a weight from zero.

    With ``rate_step`` (effect ``rate``) the hysteresis is rate-dependent: the step into each
    sample runs with ``alpha * max(1 + k |dv| / rate_step, 0)`` (``dv`` the input step, the
    simulator's ``alpha (1 + gain |dv/dt| / rate_ref)`` per sample), so loops widen with the
    input's rate. ``k`` is learnable and starts at 0 (the plain cell); ``rate_step`` is fixed
    from the training input's scale: the steepest step of a sine of the training input's
    amplitude with 200 samples per period (at the simulator's 20 kHz and ±100 V: its
    ``rate_ref``, 62,832 V/s, a 100 Hz sine).

    With ``square_amplitude`` (effect ``asymmetry``) the loop is asymmetric: ``q A (v / A)^2``
    is added (``A`` the training input's amplitude, so ``q`` is the rise at full drive over
    it; the simulator's ``c * stroke * (v / v_ref)^2``); ``q`` is learnable and starts at 0.

    The Bouc–Wen cell starts with the simulator's loop shape, its ±100 V the input's
    ``amplitude`` (scaled units: the training input's, `hysteresis_cell`), so that its loop
    saturates at the same share of the drive whatever the input's scaling; its exponent is 1
    (`hysteresis_lab.blocks.BoucWen`)."""

    def __init__(self, rate_step: float | None = None,
                 square_amplitude: float | None = None, amplitude: float = 1.0) -> None:
        super().__init__()
        if not amplitude > 0:
            raise ValueError(f"amplitude must be > 0 (got {amplitude})")
        # the simulator's loop shape with the input's amplitude (scaled units) as its ±100 V
        volts = 100.0 / amplitude
        self.bouc_wen = BoucWen(**bouc_wen_scaled_params(1.0, 0.32, 0.02, 0.006, volts, volts))
        self.weight = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.rate_gain: nn.Parameter | None = None
        if rate_step is not None:
            if not rate_step > 0:
                raise ValueError(f"rate_step must be > 0 (got {rate_step})")
            self.rate_gain = nn.Parameter(torch.zeros((), dtype=torch.float64))
            self.register_buffer("rate_step", torch.tensor(float(rate_step), dtype=torch.float64))
        _register_square_law(self, square_amplitude)

    @staticmethod
    def _square_law(v: torch.Tensor, q: torch.Tensor, amplitude: torch.Tensor) -> torch.Tensor:
        """``q A (v / A)^2``."""
        return q * v.square() / amplitude

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
        out = v - self.weight * h
        if self.square_weight is not None:
            out = out + self._square_law(v, self.square_weight, self.square_amplitude)
        return out

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

        out = v - weight * (d * v - self.bouc_wen.step(v, state, factor))
        if self.square_weight is not None:
            out = out + self._square_law(v, *frozen(self.square_weight, self.square_amplitude))
        return out


class PlayCell(nn.Module):
    """``v - sum_i w_i (v - play_{r_i}(v))``: a Prandtl–Ishlinskii cell grown from zero weight
    (``model=linear``'s input cell where ``model.hysteresis=prandtl_ishlinskii``).

    Each ``v - play_r(v)`` is bounded by its threshold ``r``, so the cell adds a loop without
    changing the slope far from the turning points; the thresholds are fixed, spread over the
    training input's ``amplitude`` (`spread_thresholds`), the weights ``w_i`` learnable and
    signed, from zero (the cell starts as the identity). ``square_amplitude``: the asymmetric
    square law as in `HysteresisCell`."""

    def __init__(self, amplitude: float = 1.0, square_amplitude: float | None = None,
                 n_operators: int = PLAY_CELL_OPERATORS) -> None:
        super().__init__()
        self.register_buffer("thresholds", torch.tensor(spread_thresholds(amplitude,
                                                                          n_operators)))
        self.weights = nn.Parameter(torch.zeros(n_operators, dtype=torch.float64))
        _register_square_law(self, square_amplitude)

    def forward(self, v: torch.Tensor) -> torch.Tensor:
        v64 = v.double()
        out = v64 - (v64[..., None] - play(v64, self.thresholds)) @ self.weights
        if self.square_weight is not None:
            out = out + HysteresisCell._square_law(v64, self.square_weight,
                                                   self.square_amplitude)
        return out.to(v.dtype)

    def state_names(self) -> list[str]:
        return [f"play{i}" for i in range(self.weights.shape[0])]

    def step(self, v: torch.Tensor, state: StepState) -> torch.Tensor:
        """One sample (B,) -> (B,); state: the operators' outputs."""
        thresholds, weights = frozen(self.thresholds, self.weights)
        out = v - (v[:, None] - play_step(v, thresholds, state)) @ weights
        if self.square_weight is not None:
            out = out + HysteresisCell._square_law(v, *frozen(self.square_weight,
                                                              self.square_amplitude))
        return out


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
        # the closed loop runs the exact update in its own kernel: exponent 1
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
                static: Any | None = None, offset: torch.Tensor | None = None,
                ) -> torch.Tensor:
        """The closed loop's output (B, T) for the dynamics' input ``x`` (B, T); ``static``:
        a static feedback in the same loop (its knots set by the output ``offset``)."""
        b, a, ba, r1, r2 = self._coefficients(dynamics)
        w, knots = ((None, None) if static is None
                    else (static.loop_weights(dynamics), static.knots(offset)))
        return closed_loop(x.double(), b, a, -self.weight, self.weight * self.bouc_wen.d, ba, r1,
                           r2, loop_lag(dynamics), w, knots)

    def state_names(self, dynamics: StableSections) -> list[str]:
        """The step's state: past dynamics' inputs ``e`` and outputs ``y``, Bouc–Wen ``h``."""
        return loop_state_names(dynamics) + [f"h{c}" for c in range(self.n_channels)]

    def step(self, dynamics: StableSections, x: torch.Tensor, state: StepState,
             static: Any | None = None, offset: torch.Tensor | None = None,
             ) -> torch.Tensor:
        """One sample of `forward`: ``x`` (B,) -> ``y`` (B,); state: the past dynamics'
        inputs and outputs (newest first) and the Bouc–Wen states."""
        b, a, ba, r1, r2, weight, d = frozen(*self._coefficients(dynamics), self.weight,
                                             self.bouc_wen.d)
        phi = no_feedback if static is None else static.function(dynamics, offset)

        def force(y: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
            return weight * (d * y - h.sum(dim=1)) + phi(y)

        def advance(h: torch.Tensor, dy: torch.Tensor) -> torch.Tensor:
            return bouc_wen_advance(h, dy[:, None], ba[None], r1[None], r2[None])

        return loop_step(b, a, loop_lag(dynamics), x, state, force, self.n_channels, advance)

    def export(self) -> dict[str, Any]:
        """The weight and the Bouc–Wen parameters."""
        return {"weight": float(self.weight.detach()), **{
            k: np.asarray(v).tolist() for k, v in self.bouc_wen.export().items()}}


def rate_dependent_cell(declared: Sequence[Effect]) -> bool:
    """Whether an effect declared makes the input cell rate-dependent
    (``makes_cell_rate_dependent``: a Bouc–Wen ``alpha`` per sample)."""
    return any(getattr(e, "makes_cell_rate_dependent", False) for e in declared)


def asymmetric_cell(declared: Sequence[Effect]) -> bool:
    """Whether an effect declared gives the input cell a square law of its input
    (``makes_cell_asymmetric``)."""
    return any(getattr(e, "makes_cell_asymmetric", False) for e in declared)


def brings_cell(declared: Sequence[Effect]) -> bool:
    """Whether ``model=linear`` with the effects ``declared`` has an input hysteresis cell:
    ``hysteresis``, or an effect that shapes the cell and brings it where declared alone
    (`rate_dependent_cell`, `asymmetric_cell`)."""
    return (any(e.name == "hysteresis" for e in declared) or rate_dependent_cell(declared)
            or asymmetric_cell(declared))


def input_cell_kind(settings: Mapping[str, Any], declared: Sequence[Effect]) -> str:
    """The cell ``model=linear`` puts on each input: ``model.hysteresis`` where it names one
    of `CELLS`, else (``auto`` not yet read off the data) Bouc–Wen; always Bouc–Wen where the
    cell is rate-dependent (`rate_dependent_cell`: a play has no ``alpha`` to scale)."""
    if rate_dependent_cell(declared):
        return "bouc_wen"
    cell = settings.get("hysteresis")
    return cell if cell in CELLS else "bouc_wen"


def hysteresis_cell(ctx: LinearContext, j: int) -> HysteresisCell | PlayCell:
    """Input ``j``'s hysteresis cell (`input_cell_kind`), rate-dependent or asymmetric where
    an effect declared with it makes it so (``makes_cell_rate_dependent``,
    ``makes_cell_asymmetric``)."""
    rate = rate_dependent_cell(ctx.declared)
    asymmetric = asymmetric_cell(ctx.declared)
    amplitude = ctx.input_amplitude(j)
    if input_cell_kind(ctx.settings, ctx.declared) == "prandtl_ishlinskii":
        return PlayCell(amplitude, amplitude if asymmetric else None)
    return HysteresisCell(HysteresisCell.rate_step_for(amplitude) if rate else None,
                          amplitude if asymmetric else None, amplitude)


class Hysteresis(Effect):
    """Rate-independent hysteresis memory: Prandtl–Ishlinskii play operators (8 thresholds)
    of the input, and of the model's own output as state evidence (in the dynamics'
    feedback)."""

    name = "hysteresis"
    description = "hysteresis memory (Prandtl-Ishlinskii play operators)"
    place = "input"
    rank = 60
    sim_config = HysteresisConfig
    fractions = np.array([0.02, 0.05, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8])
    #: it closes a restoring force around the dynamics: the loop refits the whole model
    linear_whole_refit = True

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        return per_input(
            u,
            lambda x, i: play_operators(
                np.ascontiguousarray(x), self.fractions * ctx.u_amplitude[i]
            ),
        )

    def state_evidence(self, y_model: np.ndarray, span: tuple[float, float]) -> np.ndarray:
        """Play operators of the model's output (thresholds 2-40 % of its span): hysteresis
        in the feedback of the dynamics, such as a Bouc–Wen restoring force."""
        width = max(span[1] - span[0], 1e-12)
        y = np.ascontiguousarray(np.nan_to_num(np.asarray(y_model, dtype=float).reshape(-1)))
        return play_operators(y, np.array([0.02, 0.05, 0.1, 0.2, 0.4]) * width)

    def simulate(self, plant: PlantSignals, cfg: HysteresisConfig) -> None:
        """The cell's displacement (µm): Bouc–Wen ``d v - h`` with ``alpha`` per sample times
        the factor a rate-dependence block left (`PlantSignals.alpha_factor`), or the
        Prandtl–Ishlinskii sum of plays (`HysteresisConfig`)."""
        v = np.ascontiguousarray(plant.v, dtype=float)
        if cfg.cell == "prandtl_ishlinskii":
            weights = np.asarray(cfg.weights, dtype=float)
            plays = play_operators(v, np.asarray(cfg.thresholds_v, dtype=float))
            plant.x = cfg.d_um_per_v * ((1.0 - weights.sum()) * v + plays @ weights)
            return
        alpha = np.full(len(v), cfg.alpha)
        if plant.alpha_factor is not None:
            alpha = alpha * plant.alpha_factor
        h = bouc_wen_state(v, cfg.d_um_per_v, alpha, cfg.beta, cfg.gamma, cfg.exponent)
        plant.x = cfg.d_um_per_v * v - h

    def simulate_disabled(self, plant: PlantSignals, cfg: HysteresisConfig) -> None:
        """Without hysteresis the displacement is the drive times ``d``."""
        plant.x = cfg.d_um_per_v * plant.v

    def validate(self, cfg: HysteresisConfig, key: str) -> list[str]:
        problems = []
        if not cfg.d_um_per_v > 0:
            problems.append(f"{key}.d_um_per_v={cfg.d_um_per_v!r} must be positive.")
        if cfg.cell not in CELLS:
            problems.append(f"{key}.cell={cfg.cell!r} is no hysteresis cell. Fix: "
                            f"{key}.cell=bouc_wen or {key}.cell=prandtl_ishlinskii.")
        elif cfg.cell == "prandtl_ishlinskii":
            problems += _play_problems(cfg, key)
        else:
            if not cfg.beta > abs(cfg.gamma):
                problems.append(f"{key} needs beta > |gamma| (got beta={cfg.beta}, "
                                f"gamma={cfg.gamma}).")
            if not cfg.exponent >= 1.0:
                problems.append(f"{key}.exponent={cfg.exponent!r} must be >= 1 "
                                "(Bouc–Wen's admissible exponents).")
        return problems

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        """A Bouc–Wen cell on each input and a Bouc–Wen restoring force in the dynamics'
        feedback, both weighted from zero."""
        return [
            LinearBlock("series", hysteresis_cell, key="hysteresis"),
            LinearBlock("force", lambda c, pair: StateHysteresis(
                c.forced_extremes[pair[0]][1] - c.forced_extremes[pair[0]][0]),
                attribute="state_hysteresis"),
        ]

    def greybox_part(self) -> GreyBoxPart:
        """The grey-box's own hysteresis cell (``model.hysteresis``) carries it."""
        return GreyBoxPart(in_cell=True)


def _play_problems(cfg: HysteresisConfig, key: str) -> list[str]:
    """Problems of a Prandtl–Ishlinskii cell's thresholds and weights."""
    r, w = np.asarray(cfg.thresholds_v), np.asarray(cfg.weights)
    if len(r) == 0 or len(r) != len(w):
        return [f"{key}.thresholds_v and {key}.weights need one weight per threshold (got "
                f"{len(r)} and {len(w)}). Fix: e.g. {key}.thresholds_v=[5,20,50] "
                f"{key}.weights=[0.05,0.05,0.05]."]
    problems = []
    if not np.all(r > 0):
        problems.append(f"{key}.thresholds_v={cfg.thresholds_v} must all be positive (V).")
    if not (np.all(w >= 0) and w.sum() < 1.0):
        problems.append(f"{key}.weights={cfg.weights} must be >= 0 and sum to less than 1 "
                        "(the share of the drive left elastic).")
    return problems
