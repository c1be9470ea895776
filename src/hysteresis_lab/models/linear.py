"""`linear`: stable linear dynamics from the inputs to the outputs, grown into a physical model
by the effect catalogue.

    u_j -> [saturation] -> [dead zone] -> [backlash] -> [hysteresis] -> [creep] -> x_j
    y_o = [overflow_o]([integrator](sum_j dynamics_oj(x_j) (+ [resonance_oj](x_j) in parallel))
                       + offset_o)
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
* ``hysteresis``: ``v - w h(v)``, ``h`` the Bouc–Wen state (the grey-box's cell), or
  ``v - sum_i w_i (v - play_i(v))`` (Prandtl–Ishlinskii, `PlayCell`) as ``model.hysteresis``
  says (``auto``: read off the data, `settings_from_data`), and
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

``model.integrator`` (default: as the data set says, ``DatasetSplits.output_integrates``):
the output integrates the sum of the dynamics (and resonances), before the overflow — a
position from a force or a velocity, as on the EMPS positioning system; the loop forces
(hysteresis in the feedback, nonlinear feedback such as friction) then read the integrand,
over the range of the output's steps.

``model.feedback_on`` says where the loop forces act: ``dynamics`` (around the whole
dynamics) or ``output_stage``: the dynamics as a `StorageCascade` (an upstream part, an
upstream storage, the output stage) with the forces on the output stage's own level, as a
tank's outflow law reads its own level (`LinearModel.refit_variants`: the loop tries both).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.blocks.sections import (
    StableSections,
    arx_least_squares,
    nyquist_share,
    slowest_rate,
    steiglitz_mcbride,
)
from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.blocks.storage import StorageCascade
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.effects.base import Effect, LinearBlock, LinearContext, physical_order
from hysteresis_lab.effects.hysteresis import CELLS, brings_cell, rate_dependent_cell
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.augment import context_from_dict
from hysteresis_lab.models.greybox_cell import cells_from_data
from hysteresis_lab.models.physical_chain import FromEffects, PhysicalChainModule
from hysteresis_lab.physics.filters import iir_filter, tdf2_step

log = logging.getLogger(__name__)

#: the Steiglitz–McBride fit replaces the ARX start only below this share of its free-run
#: error variance on the training recordings: a gross gain says ARX misplaced poles; a
#: modest one is what fitting the free run of these same recordings gives anyway, and can
#: place poles that suit the training recordings only
OUTPUT_ERROR_REPLACES_AT = 0.01
#: ... and only where its slowest mode is at least this share of the ARX fit's slowest
#: (`slowest_rate`): slower dynamics are slow effects (creep, drift) read into the start,
#: which the loop names itself (the creep block carries creep); a start that already holds
#: them leaves the creep refit less to fit and a worse place to fit it from
SLOWEST_MODE_SHARE = 0.5
#: ... or where the ARX start's gain at Nyquist exceeds this share of its static gain while
#: the Steiglitz–McBride fit's does not: a sampled physical low-pass system has far less
#: there; ARX's equation error, whitening the sensor noise above the input's band, puts poles
#: near Nyquist that no training on that band moves, and an input with sharp corners (one
#: clipped by a saturation block) rings in them (experiments/saturation_refit.py) ...
NYQUIST_GAIN_SHARE = 1.0
#: ... where, too, the output-error fit simulates clearly better (below this share of the ARX
#: start's error variance) and keeps ARX's slow dynamics (its slowest mode at least this share
#: of ARX's): it is there to take out the poles near Nyquist, not to read another mode into
#: the start (a fit barely better than ARX's can park a pole at the radius limit, which the
#: refits of the input blocks then cannot move)
NYQUIST_CLEAR_SHARE = 0.9

#: ``model.hysteresis``: the input cell read off the data (`LinearModel.settings_from_data`)
AUTO_CELL = "auto"

#: where the loop forces (hysteresis in the feedback, nonlinear_feedback) act: around the whole
#: dynamics, or on the output stage's own level (`StorageCascade`). A refit that adds an effect
#: whose law reads a storage's own level (`Effect.linear_tries_output_stage`: an outflow law, a
#: rim) tries both; a Bouc–Wen restoring force acts on the whole oscillator, and on the output
#: stage it would fit the validation data's error rather than a storage's
FEEDBACK_PLACES = ("dynamics", "output_stage")

#: where the declared effects' blocks sit (`LinearBlock.site`), in the order the model
#: registers them: the order of the parameters of models saved before, which gradient
#: clipping sums over
SITES = ("series", "parallel", "output", "force", "law")
#: sites with one block at most (the closed loop takes one force with states and one law)
SINGLE_SITES = ("force", "law")


def _pairs(n_out: int, n_in: int, make: Any) -> nn.ModuleList:
    """``[output][input]`` blocks from ``make(output, input)``."""
    return nn.ModuleList(nn.ModuleList(make(o, j) for j in range(n_in)) for o in range(n_out))


class LinearModel(PhysicalChainModule):
    """Stable linear dynamics with the declared effects' blocks (see the module docstring)."""

    #: the effects with a ``model=linear`` face (`Effect.linear_blocks`), in physical order
    carried_effects = FromEffects(lambda effect: effect.linear_carried)
    #: those whose block reshapes what the fitted blocks were fitted to (`Effect.
    #: linear_whole_refit`: a dead zone, a backlash, a force in the loop): the loop refits the
    #: whole model when it adds one
    whole_refit_effects = FromEffects(
        lambda effect: effect.linear_carried and effect.linear_whole_refit)

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
        integrator: bool | None = None,
        hysteresis: str = AUTO_CELL,
        objective: str = "simulation",
        lr: float = 0.002,
        **kwargs: Any,
    ) -> None:
        super().__init__(nu=nu, ny=ny, objective=objective, lr=lr, **kwargs)
        fs = float((kwargs.get("trained_on") or {}).get("fs") or fs)
        if integrator is None:  # as the data set says (EMPS: its position integrates)
            integrator = bool((kwargs.get("trained_on") or {}).get("output_integrates"))
        declared = physical_order([get_effect(e) for e in self.hparams.get("effects") or []])
        problems = []
        unknown = [e.name for e in declared if not e.linear_carried]
        if unknown:
            problems.append(f"effects {unknown} (its blocks: {list(self.carried_effects)})")
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
        if hysteresis not in (*CELLS, AUTO_CELL):
            problems.append(f"model.hysteresis={hysteresis!r} (the input's hysteresis cell: "
                            f"one of {[*CELLS, AUTO_CELL]})")
        if not isinstance(integrator, bool):
            problems.append(f"model.integrator={integrator!r} (true, false, or null: as the data "
                            "set says)")
        elif integrator and feedback_on == "output_stage":
            problems.append("model.feedback_on=output_stage with model.integrator=true (with "
                            "an integrator the loop forces act on the integrand, the dynamics' "
                            "output: model.feedback_on=dynamics)")
        elif integrator and (kwargs.get("trained_on") or {}).get("shared_initial_state"):
            problems.append("model.integrator=true on data whose recordings share one unknown "
                            "initial state (an integrator never settles at a held input, so "
                            "that state cannot be learned: set model.integrator=false)")
        if objective != "simulation":
            problems.append(f"training.objective='{objective}' (it is fitted on the simulation "
                            "error only)")
        if problems:
            raise ConfigError(
                "model=linear cannot take " + "; ".join(problems) + ". Fix: change those "
                "settings (hysteresis_lab/conf/model/linear.yaml has the defaults)."
            )
        n_in = self.n_base_inputs
        extremes = [self._output_extremes(o) for o in range(ny)]
        #: the output is the running sum of the dynamics' output (a position from a force)
        self.integrator = integrator
        #: the range the loop forces read: the output's, or with an integrator its steps'
        #: over their largest size (the integrand's unit, `step_scale`)
        steps = [self._step_extremes(o) for o in range(ny)]
        forced = ([(low / size, high / size) for (low, high), size
                   in zip(steps, self._step_sizes(steps), strict=True)]
                  if integrator else extremes)
        context = LinearContext(
            fs=fs, n_inputs=n_in, n_outputs=ny, input_amplitude=self._input_amplitude,
            output_extremes=extremes, forced_extremes=forced, declared=declared,
            settings={"creep_time_constants_s": creep_time_constants_s,
                      "feedback_knots": feedback_knots, "order": order,
                      "integrator": integrator, "hysteresis": hysteresis})
        sites = self._sites(declared, context)
        #: the containers of the effects' blocks per site (attribute names)
        self.effect_sites: dict[str, list[str]] = {site: [] for site in SITES}
        self.input_blocks = nn.ModuleList(
            nn.ModuleDict((key, block.make(context, j)) for key, block in sites["inputs"])
            for j in range(n_in))
        self._add_blocks(sites, "series", lambda make: nn.ModuleList(
            make(context, j) for j in range(n_in)))
        #: the loop forces act on the output stage's own level (`StorageCascade`)
        self.output_stage = feedback_on == "output_stage"
        if self.output_stage:
            self.dynamics = nn.ModuleList(
                nn.ModuleList(StorageCascade(order, self._storage_rim(declared, low, high))
                              for _ in range(n_in))
                for low, high in extremes)
        else:
            self.dynamics = _pairs(ny, n_in, lambda o, j: StableSections(order))
        self._add_blocks(sites, "parallel", lambda make: _pairs(
            ny, n_in, lambda o, j: make(context, (o, j))))
        self.offset = nn.Parameter(torch.zeros(ny, dtype=torch.float64))
        #: with an integrator: a constant in the integrand (a force offset, a velocity bias),
        #: without which any bias in the fitted dynamics' output is a drift of the output
        self.integrand_offset: nn.Parameter | None = None
        if integrator:
            self.integrand_offset = nn.Parameter(torch.zeros(ny, dtype=torch.float64))
            #: the output's largest step per sample over its scale (from the saved feature
            #: context, else from the training recordings at the start): the integrand is in
            #: this unit, so the dynamics' gain and the integrand's offset are of order one
            #: (the optimiser's steps are: a raw step of order one per sample, summed over a
            #: recording, is a drift no learning rate survives)
            self.register_buffer("step_scale", torch.tensor(self._step_sizes(steps),
                                                            dtype=torch.float64))
        self._add_blocks(sites, "output", lambda make: nn.ModuleList(
            make(context, o) for o in range(ny)))
        for site in SINGLE_SITES:
            self._add_blocks(sites, site, lambda make: _pairs(
                ny, n_in, lambda o, j: make(context, (o, j))))

    @staticmethod
    def _sites(
        declared: Sequence[Effect], context: LinearContext
    ) -> dict[str, list[tuple[str, LinearBlock]]]:
        """The declared effects' blocks (`Effect.linear_blocks`) by site, in physical order,
        each with its key (``"inputs"``: the series blocks kept in ``input_blocks``; a key
        named twice, such as the hysteresis cell of ``hysteresis`` and ``rate``, is one
        block)."""
        sites: dict[str, list[tuple[str, LinearBlock]]] = {"inputs": [], **{s: [] for s in SITES}}
        for effect in declared:
            for block in effect.linear_blocks(context):
                if block.site not in SITES:
                    raise ConfigError(
                        f"effect '{effect.name}' puts a block at site '{block.site}', which "
                        f"model=linear does not have. Fix: one of {list(SITES)} in its "
                        "linear_blocks.")
                site = "inputs" if block.site == "series" and block.attribute is None \
                    else block.site
                key = block.attribute or block.key or effect.name
                if key not in {k for k, _ in sites[site]}:
                    sites[site].append((key, block))
        for site in SINGLE_SITES:
            if len(sites[site]) > 1:
                raise ConfigError(
                    f"model=linear takes one block at site '{site}', the declared effects give "
                    f"{[k for k, _ in sites[site]]}. Fix: declare one of them.")
        return sites

    def _add_blocks(
        self, sites: dict[str, list[tuple[str, LinearBlock]]], site: str,
        build: Any,
    ) -> None:
        """Register the blocks of ``site``, each container built by ``build(make)``."""
        for attribute, block in sites[site]:
            setattr(self, attribute, build(block.make))
            self.effect_sites[site].append(attribute)

    @staticmethod
    def _storage_rim(declared: Sequence[Effect], low: float, high: float) -> float | None:
        """The upstream storage's rim a declared effect puts there (`Effect.
        linear_storage_rim`), for an output of range ``low``-``high``; None: none."""
        for effect in declared:
            rim = effect.linear_storage_rim(low, high)
            if rim is not None:
                return rim
        return None

    def _blocks(self, site: str) -> list[tuple[str, nn.ModuleList]]:
        """The containers of ``site``'s blocks, with their attribute names."""
        return [(name, getattr(self, name)) for name in self.effect_sites[site]]

    def _loop_block(self, site: str, o: int, j: int) -> nn.Module | None:
        """The force or the law (``site``) in the loop of pair ``(o, j)``; None: none."""
        blocks = self._blocks(site)
        return blocks[0][1][o][j] if blocks else None

    def _output_extremes(self, channel: int) -> tuple[float, float]:
        """An output's lowest and highest training value over its scale (the overflow
        block's starting levels; the scaled output's ±3 without a record of them)."""
        context = self.hparams.get("feature_context")
        ctx = context_from_dict(context) if context is not None else None
        scale, offset = float(self.y_scale[channel]), float(self.y_offset[channel])
        if ctx is None or ctx.y_low is None or ctx.y_high is None or scale <= 0:
            return (offset - 3.0 * scale) / scale, (offset + 3.0 * scale) / scale
        return float(ctx.y_low[channel]) / scale, float(ctx.y_high[channel]) / scale

    def _step_extremes(self, channel: int) -> tuple[float, float]:
        """An output's smallest and largest step from one sample to the next over its scale
        (what an integrating model's loop forces read; ±0.05 without a record of them)."""
        context = self.hparams.get("feature_context")
        ctx = context_from_dict(context) if context is not None else None
        scale = float(self.y_scale[channel])
        if ctx is None or ctx.dy_low is None or ctx.dy_high is None or scale <= 0:
            return -0.05, 0.05
        return float(ctx.dy_low[channel]) / scale, float(ctx.dy_high[channel]) / scale

    @staticmethod
    def _step_sizes(steps: Sequence[tuple[float, float]]) -> list[float]:
        """Each output's largest step size from its step extremes (at least 1e-12)."""
        return [max(abs(low), abs(high), 1e-12) for low, high in steps]

    def _forced_offset(self, offset: torch.Tensor) -> torch.Tensor:
        """What the loop forces add to the dynamics' output to read a level: the output's
        offset, or nothing where they read an integrator's integrand."""
        return torch.zeros_like(offset) if self.integrator else offset

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
        for _, blocks in self._blocks("series"):
            x = blocks[j](x)
        return x

    def chain(self, v: torch.Tensor) -> torch.Tensor:
        xs = [self._input_path(v[..., j], j) for j in range(self.n_base_inputs)]
        outputs = []
        for o in range(self.ny):
            y = sum(self._dynamics_path(o, j, x) for j, x in enumerate(xs))
            for _, blocks in self._blocks("parallel"):
                y = y + sum(blocks[o][j](x) for j, x in enumerate(xs))
            if self.integrand_offset is not None:
                y = torch.cumsum(y + self.integrand_offset[o], dim=-1) * self.step_scale[o]
            for _, blocks in self._blocks("output"):  # on the output itself, offset included
                y = blocks[o](y + self.offset[o]) - self.offset[o]
            outputs.append(y)
        return torch.stack(outputs, dim=-1)

    def _dynamics_path(self, o: int, j: int, x: torch.Tensor) -> torch.Tensor:
        """The dynamics of pair ``(o, j)`` on ``x`` (B, T), in a closed loop with the
        force and/or the law in their feedback where declared (with
        ``feedback_on=output_stage``: the loop around the output stage, fed by the upstream
        part and storage)."""
        dynamics = self.dynamics[o][j]
        if self.output_stage:
            x = dynamics.storage_output(x, self.offset[o])
            dynamics = dynamics.stage
        force, law = self._loop_block("force", o, j), self._loop_block("law", o, j)
        offset = self._forced_offset(self.offset[o])
        if force is not None:
            return force(dynamics, x, law, offset)
        if law is not None:
            return law(dynamics, x, offset)
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
        offset = self._forced_offset(offset)
        force, law = self._loop_block("force", o, j), self._loop_block("law", o, j)
        if force is not None:
            return force.step(dynamics, x, state, law, offset)
        if law is not None:
            return law.step(dynamics, x, state, offset)
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
        for site in ("force", "law"):  # the loop's state is the force's where there is one
            for name, blocks in self._blocks(site):
                return names + [f"{name}{o}{j}.{part}"
                                for part in blocks[o][j].state_names(dynamics)]
        if self.output_stage:
            return names + [f"dynamics{o}{j}.stage"]
        return [f"dynamics{o}{j}.{part}" for part in dynamics.state_names()]

    def state_names(self) -> list[str]:
        """Per input: its blocks' states (backlash: the play output; hysteresis: previous
        input and Bouc–Wen state) and series banks' (creep filters); then per output and
        input: the dynamics' delay buffer and second-order section states (or the closed
        loop's), the parallel blocks' (resonance), and with an integrator its running sum."""
        names = []
        for j, blocks in enumerate(self.input_blocks):
            for name, block in blocks.items():
                names += [f"input{j}.{name}.{part}" for part in block.state_names()]
            for name, banks in self._blocks("series"):
                names += [f"input{j}.{name}.{part}" for part in banks[j].state_names()]
        for o in range(self.ny):
            n_in = self.n_base_inputs
            names += [name for j in range(n_in) for name in self._dynamics_state_names(o, j)]
            for name, blocks in self._blocks("parallel"):
                names += [f"{name}{o}{j}.{part}" for j in range(n_in)
                          for part in blocks[o][j].state_names()]
            if self.integrator:
                names.append(f"integrator{o}")
        return names

    def chain_step(self, v: torch.Tensor, state: StepState) -> torch.Tensor:
        xs = []
        for j, blocks in enumerate(self.input_blocks):
            x = v[:, j]
            for block in blocks.values():
                x = block.step(x, state)
            for _, banks in self._blocks("series"):
                x = banks[j].step(x, state)
            xs.append(x)
        outputs = []
        for o in range(self.ny):  # the blocks in the order of `state_names`
            y = sum(self._dynamics_step(o, j, x, state) for j, x in enumerate(xs))
            for _, blocks in self._blocks("parallel"):
                y = y + sum(blocks[o][j].step(x, state) for j, x in enumerate(xs))
            if self.integrand_offset is not None:
                offset, scale = frozen(self.integrand_offset[o], self.step_scale[o])
                y = state.take(1)[:, 0] + (y + offset) * scale
                state.put(y[:, None])
            for _, blocks in self._blocks("output"):
                offset = frozen(self.offset)[0][o]
                y = blocks[o].step(y + offset, state) - offset
            outputs.append(y)
        return torch.stack(outputs, dim=-1)

    # ------------------------------------------------------------------ the loop's refits
    @classmethod
    def refit_variants(cls, model_cfg: dict[str, Any], previous: Any | None,
                       added: str | None) -> list[dict[str, Any]]:
        """The model settings a loop round fits (each a candidate; the held-out loss chooses):
        a refit that adds a storage's law or its overflow (`Effect.linear_tries_output_stage`)
        to a model whose
        forces still act on the whole dynamics tries both places (`FEEDBACK_PLACES`), the
        physics deciding where a law sits: the tanks' outflow law reads the output stage's
        own level, a spring's force the whole oscillator's. Otherwise (and always with an
        integrator) the place the last model was fitted with (``model.feedback_on`` at the
        start). Each place with each input cell `_refit_cells` names (named in the settings
        only where it is not the model's own setting)."""
        cells = cls._refit_cells(model_cfg, previous, added)
        set_cell = [model_cfg.get("hysteresis", AUTO_CELL)]
        cell_settings = [{}] if cells == set_cell else [{"hysteresis": c} for c in cells]
        place = (previous.hparams.get("feedback_on") if previous is not None
                 else None) or model_cfg.get("feedback_on", "dynamics")
        order = model_cfg.get("order", 6)
        places = [place]
        # with an integrator the forces read the integrand: no output stage
        if (not (model_cfg.get("integrator") or getattr(previous, "integrator", False))
                and added is not None and get_effect(added).linear_tries_output_stage
                and place == "dynamics" and previous is not None
                and isinstance(order, int) and order >= 2):
            places = list(FEEDBACK_PLACES)
        return [{"feedback_on": p, **cell} for p in places for cell in cell_settings]

    @staticmethod
    def _refit_cells(model_cfg: dict[str, Any], previous: Any | None,
                     added: str | None) -> list[str]:
        """The input cells a loop refit tries (``model.hysteresis``): as set; with ``auto``,
        both `CELLS` when the refit adds ``hysteresis`` to a model without a cell (the folds'
        held-out loss chooses, as they choose an effect), else the cell the last model was
        fitted with: a cell that ``rate`` or ``asymmetry`` brought is fitted, and a refit
        in the other kind would start from a cell at zero, not from the fitted model."""
        cell = model_cfg.get("hysteresis", AUTO_CELL)
        if cell != AUTO_CELL:
            return [cell]
        standing = [get_effect(e) for e in model_cfg.get("effects") or [] if e != added]
        if added == "hysteresis" and not brings_cell(standing):
            return list(CELLS)
        fitted = previous.hparams.get("hysteresis") if previous is not None else None
        return [fitted if fitted in CELLS else AUTO_CELL]

    @classmethod
    def settings_from_data(
        cls, settings: Mapping[str, Any], splits: DatasetSplits
    ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
        """``model.hysteresis=auto`` with ``hysteresis`` declared, on one input and output:
        the input cell the data test decides, or both where it leaves the choice open (each
        fitted, the lower validation loss kept), as the grey-box chooses its cell
        (`hysteresis_lab.models.greybox_cell.cells_from_data`). Otherwise the settings as
        they are (``auto`` builds a Bouc–Wen cell; an effect that makes the cell
        rate-dependent needs one)."""
        settings = dict(settings)
        declared = [get_effect(e) for e in settings.get("effects") or []]
        if (settings.get("hysteresis", AUTO_CELL) != AUTO_CELL
                or "hysteresis" not in [e.name for e in declared]
                or rate_dependent_cell(declared)):
            return [settings], {}
        train = max(splits.train, key=lambda rec: rec.n_samples)
        if train.u.shape[1] != 1 or train.y.shape[1] != 1:
            return [settings], {}
        val = max(splits.val, key=lambda rec: rec.n_samples) if splits.val else None
        cells, found = cells_from_data(train, val)
        return [{**settings, "hysteresis": cell} for cell in cells], {"hysteresis": found}

    def warm_start_from(self, previous: Any) -> None:
        """`PhysicalChainModule.warm_start_from`; from a model whose forces act on the whole
        dynamics into one with an output stage, the fitted dynamics are factored into the
        `StorageCascade` (`StorageCascade.set_transfer_function`: its poles, delay and static
        gain; the loop forces' weights carry over onto the output stage), and only the
        blocks new to the model (the rim) count as new. With an integrator the integrand's
        unit (`step_scale`) is the fitted model's, whatever the new model's context says."""
        super().warm_start_from(previous)
        if self.integrand_offset is not None and getattr(previous, "integrand_offset", None) \
                is not None:  # the integrand's unit stays the fitted model's
            with torch.no_grad():
                self.step_scale.copy_(previous.step_scale)
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
        measured inputs are read), and the output offsets. With ``model.integrator`` the fits
        are to the output's steps from sample to sample, and their free runs are judged
        integrated.

        ``order`` starts unless its free run from rest is further from the recordings than
        their mean; then every order from 1 up is fitted and the one that simulates best
        starts: on data that excite few frequencies (a single sine) a high-order ARX is not
        identified and its free run can be far off. With an integrator every order is fitted
        and the best in free run starts: the integral of an equation-error fit drifts with any
        error in its static gain, and a high order has more ways to get it wrong.

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
        if self.integrator:  # the integrand's unit from these recordings' own steps
            steps = np.concatenate([np.diff(y, axis=0) for y in ys_s if len(y) > 1]
                                   or [np.zeros((1, self.ny))])
            sizes = self._step_sizes(list(zip(steps.min(axis=0), steps.max(axis=0), strict=True)))
            with torch.no_grad():
                self.step_scale.copy_(torch.as_tensor(sizes, dtype=torch.float64))
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
        targets = ([np.diff(y, prepend=y[:1]) / float(self.step_scale[o]) for y in ys]
                   if self.integrator else list(ys))
        arx = self._arx_start(o, vs, ys, targets)
        order = self.hparams.order
        b, a = steiglitz_mcbride(vs, targets, na=order, nb=self._nb(order),
                                 nk=self.hparams.delay)
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
        # set it again: the last fit tried is in place (with an integrator, its offset too)
        if self.integrator:
            self._set_start(o, vs, ys, *arx[2:])
        else:
            self._set_dynamics(o, *arx[2:])
        return arx[1], arx[3], "ARX"

    def _nb(self, order: int) -> int:
        """Numerator terms of an ARX fit of ``order`` poles after the delay."""
        return max(1, order - max(self.hparams.delay, 1) + 1)

    def _set_start(
        self, o: int, vs: Sequence[np.ndarray], ys: Sequence[np.ndarray], b: np.ndarray,
        a: np.ndarray,
    ) -> float:
        """Set output ``o``'s dynamics to ``b / a`` (with an integrator, its integrand's
        offset to the mean step the dynamics leave); the variance of its free-run error from
        rest on the recordings (the offset comes after), ``inf`` where not finite."""
        self._set_dynamics(o, b, a)
        with torch.no_grad():
            if self.integrand_offset is not None:
                self.integrand_offset[o] = 0.0
            runs = [self.chain(torch.as_tensor(v[None]))[0, :, o].numpy() for v in vs]
            if self.integrand_offset is not None:
                scale = float(self.step_scale[o])
                left = np.concatenate([np.diff(y - run)
                                       for y, run in zip(ys, runs, strict=True)]) / scale
                step = float(np.mean(left)) if left.size else 0.0
                step = step if np.isfinite(step) else 0.0
                self.integrand_offset[o] = step
                runs = [run + step * scale * np.arange(1, len(run) + 1) for run in runs]
            errors = np.concatenate([y - run for y, run in zip(ys, runs, strict=True)])
        error = float(np.var(errors))
        return error if np.isfinite(error) else np.inf

    def _set_dynamics(self, o: int, b: np.ndarray, a: np.ndarray) -> None:
        """Output ``o``'s dynamics from every input: ``b[j] / a``."""
        for j in range(self.n_base_inputs):
            self.dynamics[o][j].set_transfer_function(b[j], a)

    def _arx_start(
        self, o: int, vs: Sequence[np.ndarray], ys: Sequence[np.ndarray],
        targets: Sequence[np.ndarray],
    ) -> tuple[float, int, np.ndarray, np.ndarray]:
        """The ARX fit of `initialise_from_recordings` (``model.order``, else the order
        that simulates best) to ``targets`` (the outputs ``ys``, or with an integrator their
        steps): its free-run error variance on ``ys``, order, ``b`` and ``a``."""
        delay = self.hparams.delay
        spread = float(np.var(np.concatenate(ys)))

        def fit(order: int) -> tuple[float, int, np.ndarray, np.ndarray]:
            b, a = arx_least_squares(vs, targets, na=order, nb=self._nb(order), nk=delay)
            return self._set_start(o, vs, ys, b, a), order, b, a

        full = fit(self.hparams.order)
        if full[0] < spread and not self.integrator:
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
                "integrator": self.integrator,
                "integrand_offset": (None if self.integrand_offset is None
                                     else self.integrand_offset.cpu().numpy().tolist()),
                "inputs": [{name: {k: v.detach().cpu().numpy().tolist()
                                   for k, v in block.named_parameters()}
                            for name, block in blocks.items()} for blocks in self.input_blocks],
            }
            for site in SITES:  # every effect block by its container's name
                for name, blocks in self._blocks(site):
                    out[name] = [[b.export() for b in block] if isinstance(block, nn.ModuleList)
                                 else block.export() for block in blocks]
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
