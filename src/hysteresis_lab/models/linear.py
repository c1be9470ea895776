"""`linear`: stable linear dynamics from the input to the output, grown into a physical model
by the effect catalogue.

    u -> [saturation] -> [dead zone] -> [backlash] -> [hysteresis] -> [creep]
      -> dynamics (+ [resonance] in parallel) -> + offset -> [overflow] -> y

The dynamics are an output-error model of ``model.order`` poles, stable for any parameter
value (`hysteresis_lab.blocks.StableSections`), started from a least-squares ARX fit and
refined on the free-run error of whole recordings. Each declared effect (``model.effects``)
puts its block where the physics puts it, and every block starts where it changes nothing
(its weight at zero), so ``effects=[hysteresis]`` starts as the linear model and a loop
refit that adds an effect starts exactly from the model it grows:

* ``saturation``: ``v - w (v - clip(v, ±c))``, amplifier clipping ahead of the actuator;
* ``dead_zone``: ``v - w clip(v, ±c)``; ``backlash``: ``v + w (play_c(v) - v)``;
* ``hysteresis``: ``v - w h(v)``, ``h`` the Bouc–Wen state (the grey-box's cell), and
  inside the dynamics' feedback to first order: play operators of the linear response,
  weighted from zero, subtracted from the dynamics' input (a hysteretic restoring force);
* ``creep``: a first-order filter bank (the grey-box's block), weights from zero;
* ``resonance``: a second-order section in parallel with the dynamics, numerator from zero;
* ``overflow``: ``y - w_hi relu(y - c_hi) + w_lo relu(c_lo - y)`` on the output, after the
  dynamics (a tank that overflows, a sensor that clips), levels from the training output's
  extremes.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.blocks import BoucWen, CreepBank, bouc_wen_scaled_params, play
from hysteresis_lab.blocks.sections import StableSections, arx_least_squares
from hysteresis_lab.effects.augment import context_from_dict
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.physical_chain import PhysicalChainModule

log = logging.getLogger(__name__)

#: catalogue effects the linear model carries as blocks, in physical order
LINEAR_EFFECTS = ("saturation", "dead_zone", "backlash", "hysteresis", "creep", "resonance",
                  "overflow")


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


class Saturation(_Level):
    def forward(self, v: torch.Tensor) -> torch.Tensor:
        c = self.level
        return v - self.weight * (v - torch.maximum(torch.minimum(v, c), -c))


class DeadZone(_Level):
    def forward(self, v: torch.Tensor) -> torch.Tensor:
        c = self.level
        return v - self.weight * torch.maximum(torch.minimum(v, c), -c)


class Backlash(_Level):
    def forward(self, v: torch.Tensor) -> torch.Tensor:
        return v + self.weight * (play(v, self.level.reshape(1))[..., 0] - v)


class HysteresisCell(nn.Module):
    """``v - w h(v)``: the Bouc–Wen state ``h`` (`hysteresis_lab.blocks.BoucWen`) subtracted
    with a weight from zero."""

    def __init__(self) -> None:
        super().__init__()
        self.bouc_wen = BoucWen(**bouc_wen_scaled_params(1.0, 0.32, 0.02, 0.006, 100.0, 100.0))
        self.weight = nn.Parameter(torch.zeros((), dtype=torch.float64))

    def forward(self, v: torch.Tensor) -> torch.Tensor:
        x, _ = self.bouc_wen(v)
        h = self.bouc_wen.d * v - x
        return v - self.weight * h


class Overflow(nn.Module):
    """Output saturation after the dynamics: ``y - w_hi relu(y - c_hi) + w_lo relu(c_lo - y)``
    (``w = 1``: a hard clip at ``c``), the weights from zero, the levels from ``low`` and
    ``high`` (the output over its scale)."""

    def __init__(self, low: float, high: float) -> None:
        super().__init__()
        self.weights = nn.Parameter(torch.zeros(2, dtype=torch.float64))  # (low, high)
        self.levels = nn.Parameter(torch.tensor([low, high], dtype=torch.float64))

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        low, high = self.levels[0], self.levels[1]
        return (y - self.weights[1] * torch.relu(y - high)
                + self.weights[0] * torch.relu(low - y))


class StateHysteresis(nn.Module):
    """Hysteresis in the dynamics' feedback (a hysteretic restoring force, as in the
    Bouc–Wen oscillator), to first order: play operators of the linear response ``y`` at
    ``thresholds`` (the output over its scale), weighted from zero, are subtracted from the
    dynamics' input: ``x - w @ play(y)``."""

    def __init__(self, thresholds: Sequence[float]) -> None:
        super().__init__()
        self.register_buffer("thresholds", torch.as_tensor(thresholds, dtype=torch.float64))
        self.weights = nn.Parameter(torch.zeros(len(thresholds), dtype=torch.float64))

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return x - play(y, self.thresholds) @ self.weights


class LinearModel(PhysicalChainModule):
    """Stable linear dynamics with the declared effects' blocks (see the module docstring)."""

    carried_effects = LINEAR_EFFECTS

    def __init__(
        self,
        nu: int,
        ny: int,
        order: int = 6,
        delay: int = 1,
        fs: float = 20_000.0,
        creep_time_constants_s: Sequence[float] = (0.1, 1.0, 10.0, 100.0),
        recording_repeats: int = 10,
        objective: str = "simulation",
        lr: float = 0.002,
        **kwargs: Any,
    ) -> None:
        super().__init__(nu=nu, ny=ny, objective=objective, lr=lr, **kwargs)
        fs = float((kwargs.get("trained_on") or {}).get("fs") or fs)
        effects = list(self.hparams.get("effects") or [])
        problems = []
        if self.n_base_inputs != 1 or ny != 1:
            problems.append(f"{self.n_base_inputs} input(s) and {ny} output(s) (it models one "
                            "input and one output; model=subnet takes MIMO data)")
        unknown = [e for e in effects if e not in LINEAR_EFFECTS]
        if unknown:
            problems.append(f"effects {unknown} (its blocks: {list(LINEAR_EFFECTS)})")
        if not (isinstance(order, int) and order >= 1):
            problems.append(f"model.order={order!r} (poles, >= 1)")
        if not (isinstance(delay, int) and delay >= 0):
            problems.append(f"model.delay={delay!r} (whole samples >= 0)")
        if objective != "simulation":
            problems.append(f"model.objective='{objective}' (it is fitted on the simulation "
                            "error only)")
        if problems:
            raise ConfigError(
                "model=linear cannot take " + "; ".join(problems) + ". Fix: change those "
                "settings (hysteresis_lab/conf/model/linear.yaml has the defaults)."
            )
        amplitude = self._input_amplitude()
        self.input_blocks = nn.ModuleDict()
        for name, block in (("saturation", lambda: Saturation(0.9 * amplitude)),
                            ("dead_zone", lambda: DeadZone(0.05 * amplitude)),
                            ("backlash", lambda: Backlash(0.05 * amplitude)),
                            ("hysteresis", HysteresisCell)):
            if name in effects:
                self.input_blocks[name] = block()
        self.creep = CreepBank(fs, creep_time_constants_s) if "creep" in effects else None
        self.dynamics = StableSections(order)
        self.resonance: StableSections | None = None
        if "resonance" in effects:
            self.resonance = StableSections(2)
            with torch.no_grad():
                self.resonance.numerators.zero_()
                self.resonance.raw_denominators[:, 1] = 2.0  # a lightly damped pair to start
        self.offset = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.overflow = Overflow(*self._output_extremes()) if "overflow" in effects else None
        self.state_hysteresis = None
        if "hysteresis" in effects:
            low, high = self._output_extremes()
            self.state_hysteresis = StateHysteresis(
                [f * (high - low) for f in (0.02, 0.05, 0.1, 0.2, 0.4)])

    def _output_extremes(self) -> tuple[float, float]:
        """The training output's lowest and highest value over its scale (the overflow
        block's starting levels; the scaled output's ±3 without a record of them)."""
        context = self.hparams.get("feature_context")
        ctx = context_from_dict(context) if context is not None else None
        scale, offset = float(self.y_scale[0]), float(self.y_offset[0])
        if ctx is None or ctx.y_low is None or ctx.y_high is None or scale <= 0:
            return (offset - 3.0 * scale) / scale, (offset + 3.0 * scale) / scale
        return float(ctx.y_low[0]) / scale, float(ctx.y_high[0]) / scale

    def _input_amplitude(self) -> float:
        """The measured input's amplitude over its scale (for the levels of input blocks)."""
        context = self.hparams.get("feature_context")
        if context is None:
            return 1.0
        amplitude = float(context_from_dict(context).u_amplitude[0])
        scale = float(self.u_scale[0])
        return max(amplitude / scale, 1e-6) if scale > 0 else 1.0

    def chain(self, v: torch.Tensor) -> torch.Tensor:
        x = v
        for block in self.input_blocks.values():
            x = block(x)
        if self.creep is not None:
            x = self.creep(x)
        y = self.dynamics(x)
        if self.state_hysteresis is not None:  # the linear response's hysteresis fed back
            y = self.dynamics(self.state_hysteresis(x, y))
        if self.resonance is not None:
            y = y + self.resonance(x)
        if self.overflow is not None:  # on the output itself, offset included
            y = self.overflow(y + self.offset) - self.offset
        return y

    def initialise_from_data(self, u: np.ndarray, y: np.ndarray, fs: float) -> None:
        """The dynamics from a least-squares ARX fit (up to ``order`` poles, ``delay``) and
        the output offset, on a training recording (physical units, 1-D). Every order from
        1 to ``order`` is fitted and simulated from rest; ``order`` starts unless its free run
        is further from the recording than its mean, then the order that simulates best
        does: on data that excite few frequencies (a single sine) a high-order ARX is not
        identified and its free run can be far off."""
        v = torch.as_tensor(u[None] / float(self.u_scale[0]), dtype=torch.float64)
        y_s = y / float(self.y_scale[0])
        delay = self.hparams.delay
        fits = []
        for order in range(1, self.hparams.order + 1):
            nb = max(1, order - max(delay, 1) + 1)
            b, a = arx_least_squares(v[0].numpy(), y_s, na=order, nb=nb, nk=delay)
            self.dynamics.set_transfer_function(b, a)
            with torch.no_grad():
                base = self.chain(v)[0].numpy()
            error = float(np.mean((y_s - base - np.mean(y_s - base)) ** 2))
            fits.append((error if np.isfinite(error) else np.inf, order, nb, b, a))
        full = fits[-1]  # a start that simulates worse than the mean is no start
        _, order, nb, b, a = full if full[0] < np.var(y_s) else min(fits, key=lambda f: f[0])
        self.dynamics.set_transfer_function(b, a)
        with torch.no_grad():
            base = self.chain(v)[0].numpy()
            self.offset.fill_(float(np.mean(y_s - base)))
        log.info("linear start: ARX(%d, %d, %d) by least squares (model.order=%d), poles "
                 "|p| <= %.4f", order, nb, delay, self.hparams.order,
                 float(np.max(np.abs(np.roots(a)))))

    def physical_parameters(self) -> dict[str, Any]:
        """Every block's current parameters (for reports)."""
        with torch.no_grad():
            out: dict[str, Any] = {"dynamics": self.dynamics.export(),
                                   "offset": float(self.offset)}
            for name, block in self.input_blocks.items():
                out[name] = {k: v.detach().cpu().numpy().tolist()
                             for k, v in block.named_parameters()}
            if self.creep is not None:
                out["creep"] = self.creep.export()
            if self.resonance is not None:
                out["resonance"] = self.resonance.export()
            if self.overflow is not None:
                out["overflow"] = {k: v.detach().cpu().numpy().tolist()
                                   for k, v in self.overflow.named_parameters()}
        return out
