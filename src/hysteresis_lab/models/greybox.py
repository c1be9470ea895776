"""`greybox`: a physics-structured positioner model with a few physical parameters.

    u -> amplifier (first-order lag) -> delay -> hysteresis -> creep -> mode(s) -> + offset -> y

On MIMO data (several inputs or outputs, the FSM mirror's 3x3) each input channel ``j`` has
its own amplifier lag, delay, hysteresis cell and (declared) creep, and the structure's
modes are shared by every pair (`hysteresis_lab.blocks.modal.ModalDynamics`):

    x_j = creep_j(hysteresis_j(delay(amplifier_j(u_j))))
    y_o = sum_j ( D_oj x_j + sum_m R_ojm mode_m(x_j) + Q_ojm rate_m(x_j) ) + offset_o

with a complex residue ``(R, Q)`` per output, input and mode and a static feedthrough ``D``
per pair; ``model.n_modes`` counts the shared modes (up to 32; ``resonance`` adds one). The
modes start from the most prominent resonance peaks of the training data's MIMO best
linear approximation, fitted to its frequency response (`estimate_modes`), residues,
feedthrough and offsets by least squares on all training recordings; while the other
parameters train, those linear weights are solved again by least squares each epoch
(`on_train_start`), not stepped. One input and one output build the one-axis chain below,
parameters and fits exactly as before MIMO.

* hysteresis (``model.hysteresis``): ``bouc_wen`` (a differentiable Bouc–Wen state
  recursion, the class's default), ``prandtl_ishlinskii`` (play operators with learnable
  thresholds and non-negative weights, the recursion the effect catalogue's ``hysteresis``
  uses), ``none`` (a static gain) or ``auto`` (the config's default: one of the two cells
  chosen from the training data, `hysteresis_lab.models.greybox_cell`; a run settles it
  before it builds the model, `settings_from_data`);
* the declared effects' grey-box parts (`hysteresis_lab.effects.base.GreyBoxPart`): a block
  per input after the gain (``creep``: a first-order filter bank, fixed time constants,
  learnable weights), more modes (``resonance``: one), the model's own cell
  (``hysteresis``), or a term added to that cell's output from its input (``asymmetry``:
  the square law of `hysteresis_lab.effects.asymmetry.SquareLaw`, weight from zero);
* every linear block is stable for any parameter value (`hysteresis_lab.blocks`);
* optionally (``model.residual_neurons > 0``, one input and output) a small ReLU network
  adds a static correction from the last ``nb`` inputs and the last ``na`` outputs of the
  physical chain (not fed back, so the physics keeps the memory and the model stays
  stable); its output layer starts at zero, so training starts from the physical model.

The model starts from values read off the data (`initialise_from_data`: the static gain by
least squares, the mode from the best linear approximation's resonance peak, the output
offset, the input delay, which one axis then learns within ``model.delay_span`` samples of
it: `hysteresis_lab.blocks.fractional_delay.LearnedDelay`) and is fitted on the free-run
error of whole recordings, each simulated from rest
(the physical state is known there; a segment cut from the middle of a recording would start
from an unknown hysteresis state). It simulates from the input alone, so its one-step
prediction is its free run (an output-error model's predictor) and it extrapolates to
amplitudes beyond the training data as its physics does.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.blocks import (
    BoucWen,
    Delay,
    FirstOrderLag,
    PlayOperators,
    SecondOrderMode,
    bouc_wen_scaled_params,
    estimate_mode,
    estimate_static_gain,
)
from hysteresis_lab.blocks._util import inv_softplus
from hysteresis_lab.blocks.estimate import (
    MAX_AUTO_DELAY,
    ChainStructure,
    estimate_modes,
)
from hysteresis_lab.blocks.fractional_delay import LearnedDelay
from hysteresis_lab.blocks.modal import ModalDynamics
from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.effects.base import Effect, GreyBoxPart, physical_order
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.augment import context_from_dict
from hysteresis_lab.models.base import NarxModule, mlp
from hysteresis_lab.models.greybox_cell import cell_evidence, cells_from_data, chain_structure
from hysteresis_lab.models.physical_chain import FromEffects, PhysicalChainModule
from hysteresis_lab.physics.play import spread_thresholds

log = logging.getLogger(__name__)

#: ``model.hysteresis``: chosen from the training data (`hysteresis_lab.models.greybox_cell`)
AUTO_CELL = "auto"
HYSTERESIS = ("bouc_wen", "bouc_wen_exponent", "prandtl_ishlinskii", "none", AUTO_CELL)
#: what ``model.hysteresis=auto`` is where the data do not choose (MIMO data; a model built
#: before it reads any data)
DEFAULT_CELL = "bouc_wen"
#: most shared modes of the MIMO dynamics
MAX_MIMO_MODES = 32
#: the MIMO Bouc–Wen cells' starting hysteretic share (one axis: 0.2); with the residues
#: solved by least squares a strong generic loop at the start costs more than it explains
#: (the least squares fit the modes to a loop the data may not have)
MIMO_BOUC_WEN_ALPHA = 0.05
#: a hysteresis cell grown on the fitted chain starts at this hysteretic share (Bouc–Wen
#: ``alpha`` is log-parametrised: it cannot start at zero; Adam's steps on its logarithm grow
#: it by a factor per step, so it still reaches an O(0.1) share within a short refit)
GROWN_CELL_SHARE = 1e-3
#: ``model.learn_exponent``: a Bouc–Wen cell's exponent stays 1 while Adam trains and is
#: learned in the L-BFGS polish (`GreyBox.polish_settings`)
EXPONENT_IN_POLISH = "polish"
#: the MIMO modes' frequencies learn at this share of ``training.lr`` (`configure_optimizers`)
MODE_FREQUENCY_LR_FACTOR = 0.02
#: ``model.delay`` / ``model.n_modes``: chosen from the training data
#: (`select_chain_structure`: its best linear approximation)
AUTO = "auto"
#: what ``auto`` is on MIMO data (not chosen there: the MIMO structure's delay and modes are
#: set, e.g. ``model.n_modes=14`` for data=fsm)
AUTO_MIMO = {"delay": 1, "n_modes": 1}


def _hysteresis_cell(hysteresis: str, operators: int, alpha: float = 0.2,
                     learn_exponent: bool = False, amplitude: float = 1.0) -> nn.Module | None:
    """One input channel's hysteresis cell (None for ``hysteresis='none'``); ``alpha``: the
    Bouc–Wen cell's hysteretic share; ``auto``: the `DEFAULT_CELL` until the data choose;
    ``learn_exponent``: a Bouc–Wen cell learns its exponent from 1 (as ``bouc_wen_exponent``);
    ``amplitude``: the input's peak over its scale, over which play operators' thresholds
    start spread (`spread_thresholds`)."""
    hysteresis = DEFAULT_CELL if hysteresis == AUTO_CELL else hysteresis
    if hysteresis in ("bouc_wen", "bouc_wen_exponent"):
        # a generic loop shape for an input of unit amplitude (not the simulator's values);
        # the gain after the cell is read off the data
        return BoucWen(**bouc_wen_scaled_params(1.0, alpha, 0.015, 0.003, 100.0, 100.0),
                       learn_exponent=learn_exponent or hysteresis == "bouc_wen_exponent")
    if hysteresis == "prandtl_ishlinskii":
        return PlayOperators(n_operators=operators,
                             max_threshold=float(spread_thresholds(amplitude, operators)[-1]))
    return None


def _cell_problem(hysteresis: Any) -> str:
    """What is wrong with a ``model.hysteresis`` value that is no cell."""
    return f"model.hysteresis={hysteresis!r} (one of {list(HYSTERESIS)})"


def _whole(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _part(effect: Effect) -> GreyBoxPart | None:
    return effect.greybox_part()


def _in_cell(effect: Effect) -> bool:
    part = _part(effect)
    return part is not None and part.in_cell


def _on_cell(effect: Effect) -> bool:
    """The effect's part is a term added to the hysteresis cell (`GreyBoxPart.cell_term`)."""
    part = _part(effect)
    return part is not None and part.cell_term is not None


class GreyBox(PhysicalChainModule):
    """Amplifier, delay, hysteresis, creep and modes in series (see the module docstring)."""

    #: the effects with a grey-box part (`Effect.greybox_part`), in physical order
    carried_effects = FromEffects(lambda effect: _part(effect) is not None)
    #: the hysteresis cell and its terms sit ahead of the gain and the modes: they were
    #: fitted to their absence, and the whole chain refits when one is grown
    whole_refit_effects = FromEffects(lambda effect: _in_cell(effect) or _on_cell(effect))
    #: the effects the model's own hysteresis cell carries
    cell_effects = FromEffects(_in_cell)

    @classmethod
    def built_in_effects(cls, settings: Mapping[str, Any]) -> tuple[str, ...]:
        """Its hysteresis cell holds the effects it carries (`GreyBoxPart.in_cell`) unless
        ``model.hysteresis=none``."""
        return () if settings.get("hysteresis", "bouc_wen") == "none" else cls.cell_effects

    def __init__(
        self,
        nu: int,
        ny: int,
        fs: float = 20_000.0,
        hysteresis: str = "bouc_wen",
        learn_exponent: bool | str = EXPONENT_IN_POLISH,
        n_modes: int | str = AUTO,
        mode_hz: float | None = None,
        mode_damping: float | None = None,
        feedthrough: bool = True,
        amplifier_hz: float | None = None,
        delay: int | str = AUTO,
        delay_span: int = 0,  # the config's default is 1; 0 rebuilds models saved before it
        creep_time_constants_s: Sequence[float] = (0.1, 1.0, 10.0, 100.0),
        operators: int = 8,
        residual_neurons: int = 0,
        residual_layers: int = 2,
        recording_repeats: int = 10,
        objective: str = "simulation",
        lr: float = 0.02,
        **kwargs: Any,
    ) -> None:
        super().__init__(nu=nu, ny=ny, objective=objective, lr=lr, **kwargs)
        fs = float((kwargs.get("trained_on") or {}).get("fs") or fs)  # the data's rate
        declared = physical_order([get_effect(e) for e in self.hparams.get("effects") or []])
        unknown = [e.name for e in declared if _part(e) is None]
        parts = [part for e in declared if (part := _part(e)) is not None]
        problems = []
        if hysteresis not in HYSTERESIS:
            problems.append(_cell_problem(hysteresis))
        self.mimo = self.n_base_inputs != 1 or ny != 1
        if self.mimo and residual_neurons:
            problems.append(f"model.residual_neurons={residual_neurons!r} with "
                            f"{self.n_base_inputs} inputs and {ny} outputs (the residual "
                            "network corrects one input and one output; 0 for MIMO data)")
        if unknown:
            problems.append(f"effects {unknown} (its blocks: {list(self.carried_effects)}; "
                            "model=subnet or model=ffnn take any catalogue effect as an input)")
        if objective != "simulation":
            problems.append(f"training.objective='{objective}' (it is fitted on the simulation "
                            "error only)")
        most_modes = MAX_MIMO_MODES if self.mimo else 3
        if not (n_modes == AUTO or _whole(n_modes) and 0 <= n_modes <= most_modes):
            problems.append(f"model.n_modes={n_modes!r} (0-{most_modes}"
                            + (")" if self.mimo else
                               "; more for MIMO data; or auto: 1-3 chosen from the data)"))
        if not (delay == AUTO or _whole(delay) and delay >= 0):
            problems.append(f"model.delay={delay!r} (whole samples >= 0, or auto: 0-"
                            f"{MAX_AUTO_DELAY} chosen from the data)")
        if not (_whole(delay_span) and delay_span >= 0):
            problems.append(f"model.delay_span={delay_span!r} (whole samples >= 0; 0: the "
                            "delay stays fixed)")
        if not (isinstance(residual_neurons, int) and residual_neurons >= 0
                and isinstance(residual_layers, int) and residual_layers >= 1):
            problems.append(f"model.residual_neurons={residual_neurons!r} / residual_layers="
                            f"{residual_layers!r} (>= 0 / >= 1; 0 neurons: no network)")
        if not (isinstance(recording_repeats, int) and recording_repeats >= 1):
            problems.append(f"model.recording_repeats={recording_repeats!r} (>= 1)")
        if not (isinstance(learn_exponent, bool) or learn_exponent == EXPONENT_IN_POLISH):
            problems.append(f"model.learn_exponent={learn_exponent!r} (true, false, or "
                            f"{EXPONENT_IN_POLISH}: learned in the L-BFGS polish only)")
        if problems:
            raise ConfigError(
                "model=greybox cannot take " + "; ".join(problems) + ". Fix: change those "
                "settings (hysteresis_lab/conf/model/greybox.yaml has the defaults)."
            )
        # the blocks' 1 Hz floors scaled down for slow data (cascaded tanks: fs = 0.25 Hz)
        self.f_floor = min(1.0, 1e-3 * fs)
        #: the settings chosen from the data (`select_chain_structure`, one input and output;
        #: MIMO data: `AUTO_MIMO`) when the model is initialised from them
        self.auto_settings = tuple(name for name, value in (("delay", delay),
                                                            ("n_modes", n_modes))
                                   if value == AUTO)
        if self.mimo and hysteresis == AUTO_CELL:  # the data test reads one axis
            hysteresis = DEFAULT_CELL
            self.hparams.update(hysteresis=hysteresis)
        if self.mimo:
            delay = AUTO_MIMO["delay"] if delay == AUTO else delay
            n_modes = AUTO_MIMO["n_modes"] if n_modes == AUTO else n_modes
            self.auto_settings = ()
            self.hparams.update(delay=delay, n_modes=n_modes)
        #: modes the declared effects add (``resonance``)
        self.extra_modes = sum(part.extra_modes for part in parts)
        delay = 1 if delay == AUTO else int(delay)  # placeholders until the data are read
        n_modes = 1 if n_modes == AUTO else int(n_modes)
        modes = n_modes + self.extra_modes
        settings = {"creep_time_constants_s": creep_time_constants_s}
        #: the effects' blocks after the gain: (label, attribute) of each
        self.series_blocks: list[tuple[str, str]] = []
        series = [part for part in parts if part.series is not None]
        #: the effects' terms added to the hysteresis cell from its input: (label, attribute)
        self.cell_terms: list[tuple[str, str]] = []
        terms = [part for part in parts if part.cell_term is not None]
        if self.mimo:
            self._build_mimo(fs, hysteresis, modes, mode_hz, mode_damping, amplifier_hz, delay,
                             series, settings, operators)
            for part in terms:
                setattr(self, part.attribute_mimo, nn.ModuleList(
                    part.cell_term(self._input_amplitude(j)) for j in range(self.n_base_inputs)))
                self.cell_terms.append((part.attribute, part.attribute_mimo))
            return
        nyquist = 0.5 * fs
        self.amplifier = FirstOrderLag(fs, amplifier_hz or 0.25 * fs,
                                       min_cutoff_hz=self.f_floor)
        self.delay = self._delay_block(delay)
        self.hysteresis = _hysteresis_cell(hysteresis, operators,
                                           learn_exponent=self._learns_exponent(),
                                           amplitude=self._input_amplitude(0))
        for part in terms:
            setattr(self, part.attribute, part.cell_term(self._input_amplitude(0)))
            self.cell_terms.append((part.attribute, part.attribute))
        self.gain = nn.Parameter(torch.ones((), dtype=torch.float64))  # after the hysteresis
        for part in series:
            setattr(self, part.attribute, part.series(fs, settings))
            self.series_blocks.append((part.attribute, part.attribute))
        self.mode = (self._modes(fs, mode_hz or 0.1 * nyquist, mode_damping or 0.05, modes)
                     if modes else None)
        self.offset = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.residual: nn.Sequential | None = None
        if residual_neurons:
            self.residual = mlp(self.window.nb + self.window.na, 1, residual_neurons,
                                residual_layers).double()
            with torch.no_grad():
                self.residual[-1].weight.zero_()
                self.residual[-1].bias.zero_()

    def _delay_block(self, samples: int) -> Delay | LearnedDelay:
        """The one-axis chain's input delay: ``samples`` fixed, or learned within
        ``model.delay_span`` samples either side of it (`LearnedDelay`)."""
        span = int(self.hparams.get("delay_span") or 0)
        return LearnedDelay(samples, span) if span else Delay(samples)

    def _modes(self, fs: float, frequency_hz: float | Sequence[float],
               damping: float | Sequence[float], n_modes: int,
               weights: Sequence[float] | None = None) -> SecondOrderMode:
        """One input's modes (`SecondOrderMode`), with a feedthrough share from 0 unless
        ``model.feedthrough=false``."""
        return SecondOrderMode(fs, frequency_hz, damping, n_modes=n_modes, weights=weights,
                               fmin=self.f_floor,
                               feedthrough=bool(self.hparams.get("feedthrough", True)))

    def _input_amplitude(self, channel: int) -> float:
        """A measured input's amplitude over its scale (the training data's peak, saved with
        the model in its ``feature_context`` or ``trained_on``; 1 without either): a cell
        term's scale and the span of the play operators' thresholds."""
        context = self.hparams.get("feature_context")
        peaks = (self.hparams.get("trained_on") or {}).get("u_amplitude")
        scale = float(self.u_scale[channel])
        if context:  # an empty one (no effects' operators) says nothing
            amplitude = float(context_from_dict(context).u_amplitude[channel])
        elif peaks is not None and channel < len(peaks):
            amplitude = float(peaks[channel])
        else:
            return 1.0
        return max(amplitude / scale, 1e-6) if scale > 0 else 1.0

    def _build_mimo(
        self, fs: float, hysteresis: str, n_modes: int, mode_hz: float | None,
        mode_damping: float | None, amplifier_hz: float | None, delay: int,
        series: Sequence[GreyBoxPart], settings: Mapping[str, Any], operators: int,
    ) -> None:
        """Per input channel an amplifier lag, a delay, a hysteresis cell and the declared
        effects' blocks (creep); then shared modes with a residue per output and input
        (`ModalDynamics`) and an offset per output."""
        n_in = self.n_base_inputs
        self.amplifiers = nn.ModuleList(
            FirstOrderLag(fs, amplifier_hz or 0.25 * fs, min_cutoff_hz=self.f_floor)
            for _ in range(n_in))
        self.delays = nn.ModuleList(Delay(delay) for _ in range(n_in))
        cells = [_hysteresis_cell(hysteresis, operators, MIMO_BOUC_WEN_ALPHA,
                                  self._learns_exponent(),
                                  amplitude=self._input_amplitude(j))
                 for j in range(n_in)]
        self.cells = None if hysteresis == "none" else nn.ModuleList(cells)
        for part in series:
            setattr(self, part.attribute_mimo, nn.ModuleList(
                part.series(fs, settings) for _ in range(n_in)))
            self.series_blocks.append((part.attribute, part.attribute_mimo))
        # the SISO convention for a given frequency (mode m at mode_hz * 3^m, clipped);
        # without one, placeholders until the data's modes are read (`initialise_from_data`)
        start = SecondOrderMode(fs, mode_hz or 0.1 * 0.5 * fs, mode_damping or 0.05,
                                n_modes=max(n_modes, 1), fmin=self.f_floor)
        self.dynamics = ModalDynamics(fs, self.ny, n_in,
                                      start.frequency_hz.detach().numpy()[:n_modes],
                                      start.damping.detach().numpy()[:n_modes],
                                      fmin=self.f_floor)
        self.offset = nn.Parameter(torch.zeros(self.ny, dtype=torch.float64))
        self.residual = None

    # ------------------------------------------------------------------ the model
    def chain(self, v: torch.Tensor) -> torch.Tensor:
        """Input over its scale (B, T, nu) -> output before the offset (B, T, ny), from rest."""
        if self.mimo:
            return self.dynamics(torch.stack(
                [self._input_path(v[..., j], j) for j in range(self.n_base_inputs)], dim=-1))
        return self._chain(v[..., 0])[..., None]

    def _input_path(self, v: torch.Tensor, j: int) -> torch.Tensor:
        """MIMO input ``j``'s amplifier, delay, hysteresis and creep: (B, T) -> (B, T)."""
        x = cell_input = self.delays[j](self.amplifiers[j](v))
        if self.cells is not None:
            x = self.cells[j](x)
            x = x[0] if isinstance(x, tuple) else x
        for _, attribute in self.cell_terms:
            x = x + getattr(self, attribute)[j](cell_input)
        for _, attribute in self.series_blocks:
            x = getattr(self, attribute)[j](x)
        return x

    def _chain(self, v: torch.Tensor) -> torch.Tensor:
        """`chain` on (B, T) -> (B, T)."""
        x = cell_input = self.delay(self.amplifier(v))
        v_in = v
        if self.hysteresis is not None:
            x = self.hysteresis(x)
            x = x[0] if isinstance(x, tuple) else x
        for _, attribute in self.cell_terms:
            x = x + getattr(self, attribute)(cell_input)
        x = self.gain * x
        for _, attribute in self.series_blocks:
            x = getattr(self, attribute)(x)
        if self.mode is not None:
            x = self.mode(x)
        if self.residual is not None:
            x = x + self._residual_correction(v_in, x)
        return x

    def _residual_correction(self, v: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """The residual network on the last ``nb`` inputs and ``na`` chain outputs of every
        sample (zeros before the start), (B, T)."""
        assert self.residual is not None
        nb, na = self.window.nb, self.window.na
        v_lags = nn.functional.pad(v, (nb - 1, 0)).unfold(1, nb, 1)  # (B, T, nb)
        x_lags = nn.functional.pad(x, (na - 1, 0)).unfold(1, na, 1)
        return self.residual(torch.cat([v_lags, x_lags], dim=-1))[..., 0]

    def _step_blocks(self) -> list[tuple[str, nn.Module]]:
        """The blocks with a state, in the chain's order (MIMO: per input, then the modes)."""
        if self.mimo:
            blocks = []
            for j in range(self.n_base_inputs):
                blocks += [(f"input{j}.amplifier", self.amplifiers[j]),
                           (f"input{j}.delay", self.delays[j])]
                if self.cells is not None:
                    blocks.append((f"input{j}.hysteresis", self.cells[j]))
                blocks += [(f"input{j}.{label}", getattr(self, attribute)[j])
                           for label, attribute in self.series_blocks]
            return [*blocks, ("dynamics", self.dynamics)]
        blocks = [("amplifier", self.amplifier), ("delay", self.delay),
                  ("hysteresis", self.hysteresis),
                  *((label, getattr(self, attribute)) for label, attribute in self.series_blocks),
                  ("mode", self.mode)]
        return [(name, block) for name, block in blocks if block is not None]

    def state_names(self) -> list[str]:
        """Amplifier lag, delay buffer (oldest first), hysteresis (Bouc–Wen: previous input
        and states; Prandtl–Ishlinskii: play outputs), creep filters, modes' biquad states,
        then the residual network's past inputs and chain outputs (oldest first)."""
        names = [f"{name}.{part}" for name, block in self._step_blocks()
                 for part in block.state_names()]
        if self.residual is not None:
            names += [f"residual.v_lag{i}" for i in range(self.window.nb - 1, 0, -1)]
            names += [f"residual.x_lag{i}" for i in range(self.window.na - 1, 0, -1)]
        return names

    def chain_step(self, v: torch.Tensor, state: StepState) -> torch.Tensor:
        """One sample of `chain`: (B, nu) -> (B, ny)."""
        if self.mimo:
            xs = []
            for j in range(self.n_base_inputs):  # the blocks in the order of `state_names`
                x = cell_input = self.delays[j].step(self.amplifiers[j].step(v[:, j], state),
                                                     state)
                if self.cells is not None:
                    x = self.cells[j].step(x, state)
                for _, attribute in self.cell_terms:
                    x = x + getattr(self, attribute)[j].step(cell_input, state)
                for _, attribute in self.series_blocks:
                    x = getattr(self, attribute)[j].step(x, state)
                xs.append(x)
            return self.dynamics.step(torch.stack(xs, dim=-1), state)
        v_in = v[:, 0]
        x = cell_input = self.delay.step(self.amplifier.step(v_in, state), state)
        if self.hysteresis is not None:
            x = self.hysteresis.step(x, state)
        for _, attribute in self.cell_terms:
            x = x + getattr(self, attribute).step(cell_input, state)
        x = frozen(self.gain)[0] * x
        for _, attribute in self.series_blocks:
            x = getattr(self, attribute).step(x, state)
        if self.mode is not None:
            x = self.mode.step(x, state)
        if self.residual is not None:
            nb, na = self.window.nb, self.window.na
            v_lags = torch.cat([state.take(nb - 1), v_in[:, None]], dim=1)
            x_lags = torch.cat([state.take(na - 1), x[:, None]], dim=1)
            state.put(v_lags[:, 1:])
            state.put(x_lags[:, 1:])
            x = x + self.residual(torch.cat([v_lags, x_lags], dim=-1))[:, 0]
        return x[:, None]

    def _learns_exponent(self) -> bool:
        """Whether a Bouc–Wen cell learns its exponent in this fit: ``model.learn_exponent``
        true (``polish``: only in the polish, `polish_settings`, which sets it true)."""
        return self.hparams.get("learn_exponent") is True

    @classmethod
    def polish_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        """The polish frees a Bouc–Wen cell's exponent (``model.learn_exponent=polish``):
        learned with Adam from the start it moves slowly and disturbs the rest of the fit
        (`docs/results/greybox_exponent.md`); from the fitted model L-BFGS lands on it."""
        settings = dict(settings)
        if settings.get("learn_exponent", EXPONENT_IN_POLISH) == EXPONENT_IN_POLISH:
            settings["learn_exponent"] = True
        return settings

    @classmethod
    def growth_stages(
        cls, settings: Mapping[str, Any]
    ) -> list[tuple[str, dict[str, Any], str | None]]:
        """`PhysicalChainModule.growth_stages` with the hysteresis cell as the first effect
        grown: the chain without its cell (``hysteresis=none``) first, then the cell from
        (nearly) no hysteresis, then the declared effects."""
        cells = cls.built_in_effects(settings)
        if not cells:
            return super().growth_stages(settings)
        effects = [e for e in settings.get("effects") or [] if e not in cells]
        stages = super().growth_stages({**settings, "effects": effects})
        linear = {**stages[0][1], "hysteresis": "none"}
        cell = (cells[0], dict(stages[0][1]), cells[0])
        grown = [stages[0][:1] + (linear, None), cell, *stages[1:]]
        grown[-1] = (grown[-1][0], dict(settings), grown[-1][2])
        return grown

    def _start_new_parameter(self, name: str, value: torch.Tensor, previous: NarxModule) -> None:
        """A new block starts where it changes nothing: an effect's block after the gain at
        zero (creep weights 0), a new mode at weight 0 (MIMO: residues 0) beside the fitted
        ones, a new hysteresis cell at (nearly) no hysteresis (Bouc–Wen ``alpha``
        `GROWN_CELL_SHARE`, play operators' weights that share beside a unit linear
        weight)."""
        cell = re.match(r"^(hysteresis|cells\.\d+)\.(raw_alpha|raw_w0|raw_weights)$", name)
        if cell is not None:
            self._start_new_cell_parameter(cell.group(2), value)
            return
        if self.mimo:
            if name in ("dynamics.residues", "dynamics.quadrature"):
                fitted = previous.get_parameter(name)
                value.zero_()
                value[..., : fitted.shape[-1]] = fitted
            elif name.split(".")[0] in self._series_attributes():
                value.zero_()
            return
        if name.startswith("mode.") and self.mode is not None and previous.mode:
            self._grow_mode(previous.mode)
        elif name.split(".")[0] in self._series_attributes():
            value.zero_()

    def _series_attributes(self) -> set[str]:
        """The attributes of the blocks that start at zero: after the gain, on the cell."""
        return {attribute for _, attribute in (*self.series_blocks, *self.cell_terms)}

    @staticmethod
    def _start_new_cell_parameter(name: str, value: torch.Tensor) -> None:
        """A new hysteresis cell's parameter at (nearly) no hysteresis."""
        if name == "raw_alpha":  # log-parametrised: as near zero as it can still grow from
            value.fill_(math.log(GROWN_CELL_SHARE / value.numel()))
        elif name == "raw_w0":
            value.fill_(inv_softplus(1.0))
        else:
            value.fill_(inv_softplus(GROWN_CELL_SHARE / value.numel()))

    def _grow_mode(self, fitted: SecondOrderMode) -> None:
        """The fitted modes, plus new ones at zero weight."""
        assert self.mode is not None
        n = fitted.n_modes
        self.mode.raw_frequency[:n] = fitted.raw_frequency
        self.mode.raw_damping[:n] = fitted.raw_damping
        self.mode.raw_weights.zero_()
        self.mode.raw_weights[: n - 1] = fitted.raw_weights
        if self.mode.raw_feedthrough is not None:
            self.mode.raw_feedthrough.zero_()
            if fitted.raw_feedthrough is not None:
                self.mode.raw_feedthrough.copy_(fitted.raw_feedthrough)

    # ------------------------------------------------------------------ initial values
    def initialise_from_recordings(self, recordings: Sequence[Recording]) -> None:
        """Starting values from the training recordings: one input and output, from the
        longest one (`initialise_from_data`); MIMO, from all of them (`_initialise_mimo`)."""
        if self.mimo:
            self._initialise_mimo([rec.u for rec in recordings], [rec.y for rec in recordings],
                                  recordings[0].fs)
            return
        longest = max(recordings, key=lambda rec: rec.n_samples)
        self.initialise_from_data(longest.u[:, 0], longest.y[:, 0], longest.fs)

    def initialise_from_data(self, u: np.ndarray, y: np.ndarray, fs: float) -> None:
        """Starting values from a training recording (physical units; 1-D for one channel,
        else (T, channels)): the static gain (least squares), the mode (the BLA's resonance
        peak) and the output offset; MIMO data as `_initialise_mimo`."""
        if self.mimo:
            self._initialise_mimo([u], [y], fs)
            return
        u_s = u / float(self.u_scale[0])
        y_s = y / float(self.y_scale[0])
        gain = estimate_static_gain(u_s - u_s.mean(), y_s - y_s.mean())
        structure = self._choose_structure(u, y, fs) if self.auto_settings else None
        if self.hparams.get("hysteresis") == AUTO_CELL:
            self._choose_cell(u, y, fs)
        with torch.no_grad():
            if structure is not None:
                self._start_from_structure(structure, fs)
            elif self.mode is not None and self.hparams.get("mode_hz") is None:
                try:
                    frequency, damping = estimate_mode(u, y, fs)
                except ValueError as exc:
                    log.warning("no resonance found in the training data (%s): the mode starts "
                                "at %.0f Hz", exc, float(self.mode.frequency_hz[0]))
                else:
                    fresh = self._modes(fs, frequency, damping, self.mode.n_modes)
                    self.mode.load_state_dict(fresh.state_dict())
            base = self._chain(torch.as_tensor(u_s[None], dtype=torch.float64))[0].numpy()
            scale = estimate_static_gain(base - base.mean(), y_s - y_s.mean())
            if not np.isfinite(scale) or scale <= 0:
                scale = gain
            self.gain.fill_(float(scale))
            fitted = scale * base
            self.offset.fill_(float(np.mean(y_s - fitted)))
        log.info("grey-box start: gain %.4g, delay %d, mode %s Hz, offset %.4g (scaled)",
                 float(self.gain.detach()), self.delay.samples,
                 None if self.mode is None else np.round(self.mode.export()["frequency_hz"], 1),
                 float(self.offset.detach()))

    def _choose_structure(self, u: np.ndarray, y: np.ndarray, fs: float) -> ChainStructure | None:
        """The delay and mode count the data say (``auto`` settings, `select_chain_structure`
        on a training recording in physical units), set in the model (its blocks rebuilt,
        ``hparams`` updated so that a saved model is rebuilt with them); None where the data
        say nothing (the placeholders stay: one sample, fixed, and one mode)."""
        delay, n_modes = self.hparams.get("delay"), self.hparams.get("n_modes")
        try:
            structure = chain_structure(u, y, fs, None if delay == AUTO else int(delay),
                                        None if n_modes == AUTO else max(int(n_modes), 1))
        except ValueError as exc:
            placeholders = {name: 1 for name in ("delay", "n_modes") if name in self.auto_settings}
            if delay == AUTO:  # a delay the data cannot show is not learned from them either
                self.hparams.update(delay_span=0)
                placeholders["delay_span"] = 0
            log.warning("the delay and modes cannot be read off the training data (%s): %s", exc,
                        ", ".join(f"model.{name}={value}" for name, value in placeholders.items()))
            self._set_structure(1 if delay == AUTO else int(delay),
                                1 if n_modes == AUTO else int(n_modes), fs)
            return None
        chosen_modes = structure.n_modes if n_modes == AUTO else int(n_modes)
        chosen = self.auto_settings
        self._set_structure(structure.delay, chosen_modes, fs)
        log.info("grey-box structure from the data: %s",
                 ", ".join(f"model.{name}={self.hparams[name]}" for name in chosen))
        return structure

    def _choose_cell(self, u: np.ndarray, y: np.ndarray, fs: float) -> None:
        """``model.hysteresis=auto`` on a model built and initialised directly (a run chooses
        before it builds one, `settings_from_data`): the cell with the lower held-out misfit
        of the data test on this recording (`cell_evidence`), set in the model."""
        delay, n_modes = self.hparams.get("delay"), self.hparams.get("n_modes")
        try:
            structure = chain_structure(u, y, fs, int(delay), max(int(n_modes), 1))
            evidence = cell_evidence(u, y, fs, structure)
        except ValueError as exc:
            log.warning("model.hysteresis=auto: the data test failed (%s): %s", exc, DEFAULT_CELL)
            self._set_cell(DEFAULT_CELL)
            return
        log.info("model.hysteresis=auto: %s (data test: %s)", evidence.lower,
                 evidence.to_dict())
        self._set_cell(evidence.lower)

    def _set_cell(self, hysteresis: str) -> None:
        """Rebuild the (one-axis) hysteresis cell as ``hysteresis``, recorded in ``hparams``."""
        self.hysteresis = _hysteresis_cell(hysteresis, int(self.hparams.get("operators", 8)),
                                           learn_exponent=self._learns_exponent(),
                                           amplitude=self._input_amplitude(0))
        if self.hysteresis is not None:
            self.hysteresis.to(self.offset.device)
        self.hparams.update(hysteresis=hysteresis)

    @classmethod
    def settings_from_data(
        cls, settings: Mapping[str, Any], splits: DatasetSplits
    ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
        """The settings ``model.hysteresis=auto`` comes to on ``splits`` (measured, before
        a model is built; `hysteresis_lab.workflows.grow.train_model`): one, the cell the data
        test decides (`hysteresis_lab.models.greybox_cell`), or both cells where it leaves
        the choice open (each is fitted, the lower validation loss kept); and what the test
        found (for ``metrics.json``). Other settings: as they are."""
        settings = dict(settings)
        hysteresis = settings.get("hysteresis", "bouc_wen")
        if hysteresis not in HYSTERESIS:  # refused before any stage trains
            raise ConfigError(f"model=greybox cannot take {_cell_problem(hysteresis)}. Fix: "
                              "model.hysteresis=auto (chosen from the data) or one of those.")
        if hysteresis != AUTO_CELL:
            return [settings], {}
        train = max(splits.train, key=lambda rec: rec.n_samples)
        if train.u.shape[1] != 1 or train.y.shape[1] != 1:
            log.info("model.hysteresis=auto on MIMO data: %s (the data test reads one axis)",
                     DEFAULT_CELL)
            return [{**settings, "hysteresis": DEFAULT_CELL}], {
                "hysteresis": {"chosen": DEFAULT_CELL, "by": "MIMO data: the default cell"}}
        delay, n_modes = settings.get("delay", AUTO), settings.get("n_modes", AUTO)
        val = max(splits.val, key=lambda rec: rec.n_samples) if splits.val else None
        cells, found = cells_from_data(train, val, None if delay == AUTO else int(delay),
                                       None if n_modes == AUTO else max(int(n_modes), 1))
        return [{**settings, "hysteresis": cell} for cell in cells], {"hysteresis": found}

    def _set_structure(self, delay: int, n_modes: int, fs: float) -> None:
        """Rebuild the delay and the modes (placeholders) for ``delay`` samples and
        ``n_modes`` modes (plus the declared effects'), recorded in ``hparams``."""
        self.delay = self._delay_block(delay).to(self.offset.device)
        modes = n_modes + self.extra_modes
        if self.mode is None or self.mode.n_modes != modes:
            self.mode = (self._modes(fs, self.hparams.get("mode_hz") or 0.05 * fs,
                                     self.hparams.get("mode_damping") or 0.05,
                                     modes).to(self.offset.device)
                         if modes else None)
        self.hparams.update(delay=int(delay), n_modes=int(n_modes))
        self.auto_settings = ()

    def _start_from_structure(self, structure: ChainStructure, fs: float) -> None:
        """The modes (unless ``model.mode_hz`` sets them) from the chain fitted to the best
        linear approximation; a declared effect's extra modes start above them at a small
        weight, as by default. The amplifier starts as before: the fit's cutoff shares the
        phase lag with the hysteresis loop's stand-in, which the model's cell carries."""
        if self.mode is None or self.hparams.get("mode_hz") is not None:
            return
        n_fitted = min(len(structure.frequencies_hz), self.mode.n_modes)
        freqs = list(structure.frequencies_hz[:n_fitted])
        damps = list(structure.dampings[:n_fitted])
        weights = list(structure.weights[:n_fitted])
        for _ in range(self.mode.n_modes - n_fitted):
            freqs.append(min(3.0 * freqs[-1], 0.4 * fs) if freqs else 0.05 * fs)
            damps.append(0.05)
            weights.append(0.05)
        ceiling = 0.98 * self.mode.fmax
        freqs = [float(np.clip(f, 1.01 * self.f_floor, ceiling)) for f in freqs]
        damps = [float(np.clip(z, 2e-4, 3.0)) for z in damps]
        weights = np.asarray(weights) / max(float(np.sum(weights[:n_fitted])), 1e-12)
        fresh = self._modes(fs, freqs, damps, self.mode.n_modes, weights=weights)
        self.mode.load_state_dict(fresh.state_dict())

    def warm_start_from(self, previous: NarxModule) -> None:
        """`PhysicalChainModule.warm_start_from`; a setting left to the data (``auto``)
        takes the value the fitted model chose (its delay, its modes without the declared
        effects' extra ones)."""
        if (self.hparams.get("hysteresis") == AUTO_CELL and isinstance(previous, GreyBox)
                and not self.mimo):  # the fitted model's cell (none: the default's)
            cell = previous.hparams.get("hysteresis")
            self._set_cell(cell if cell not in (None, "none", AUTO_CELL) else DEFAULT_CELL)
        if self.auto_settings and isinstance(previous, GreyBox) and not self.mimo:
            delay = previous.hparams.get("delay")
            n_modes = previous.hparams.get("n_modes")
            if isinstance(delay, int) and isinstance(n_modes, int):
                fs = self.amplifier.fs
                self._set_structure(delay if "delay" in self.auto_settings
                                    else int(self.hparams["delay"]),
                                    n_modes if "n_modes" in self.auto_settings
                                    else int(self.hparams["n_modes"]), fs)
        super().warm_start_from(previous)
        self._start_freed_exponents_off_one(previous)

    def _start_freed_exponents_off_one(self, previous: NarxModule) -> None:
        """A Bouc–Wen exponent this model learns and ``previous`` held at 1 (the polish
        frees it) starts just above 1 (`BoucWen.start_exponent_off_one`): from exactly 1 the
        L-BFGS polish cannot move it."""
        held = {name for name, module in previous.named_modules()
                if isinstance(module, BoucWen) and module.raw_exponent is None}
        for name, module in self.named_modules():
            if name in held and isinstance(module, BoucWen) and module.raw_exponent is not None:
                module.start_exponent_off_one()

    def _initialise_mimo(
        self, us: Sequence[np.ndarray], ys: Sequence[np.ndarray], fs: float
    ) -> None:
        """MIMO starting values from recordings (physical units, (T, channels)): the modes
        from the resonance peaks of the MIMO BLA (`estimate_modes`, unless ``model.mode_hz``
        is set), then residues, feedthrough and output offsets by least squares on the
        outputs of the input channels' blocks."""
        n_in = self.n_base_inputs
        us = [np.asarray(u, dtype=float).reshape(len(u), -1)[:, :n_in] for u in us]
        ys = [np.asarray(y, dtype=float).reshape(len(y), -1) for y in ys]
        dynamics = self.dynamics
        if dynamics.n_modes and self.hparams.get("mode_hz") is None:
            fmax = 0.98 * dynamics.modes[0].fmax
            try:
                freqs, damps = estimate_modes(us, ys, fs, dynamics.n_modes,
                                              fmin=max(min(50.0, 0.01 * fs), 2 * self.f_floor),
                                              fmax=fmax, prefilter=self._input_filter())
            except ValueError as exc:
                log.warning("no resonances found in the training data (%s): the modes start "
                            "at %s Hz", exc, np.round(dynamics.export()["frequency_hz"], 1))
            else:
                dynamics.set_modes(freqs, damps)
        self._fit_linear_weights(us, ys)
        log.info("grey-box start (%d inputs, %d outputs): modes %s Hz, residues and feedthrough "
                 "by least squares on %d recording(s)", n_in, self.ny,
                 np.round(dynamics.export()["frequency_hz"], 1).tolist(), len(us))

    def _fit_linear_weights(self, us: Sequence[np.ndarray], ys: Sequence[np.ndarray]) -> None:
        """MIMO: the residues, feedthrough and output offsets by least squares on recordings
        (physical units, (T, channels)) given the other parameters."""
        n_in = self.n_base_inputs
        scale_u = self.u_scale[:n_in].double().cpu().numpy()
        with torch.no_grad():
            xs = [torch.stack([self._input_path(
                torch.as_tensor(u[None, :, :n_in] / scale_u, device=self.offset.device)[..., j],
                j)[0] for j in range(n_in)], dim=-1) for u in us]
            offset = self.dynamics.fit_residues(
                xs, [y / self.y_scale.double().cpu().numpy() for y in ys])
            self.offset.copy_(torch.as_tensor(offset))

    # ------------------------------------------------------------------ MIMO training
    def on_train_start(self) -> None:
        """MIMO: the weights the output is linear in (residues, feedthrough, offsets) are
        not stepped by the optimiser but solved by least squares on the training recordings
        at the start of every epoch and before every validation, given the other parameters
        (variable projection: a lightly damped mode's residue is far too sensitive for
        Adam's equal steps). Not in a refit that trains only new blocks."""
        self._least_squares = bool(self.mimo and not self.new_inputs_only)
        if self._least_squares:
            for parameter in self._linear_weights():
                parameter.requires_grad_(False)

    def on_train_end(self) -> None:
        if getattr(self, "_least_squares", False):
            for parameter in self._linear_weights():
                parameter.requires_grad_(True)
            self._least_squares = False

    def on_train_epoch_start(self) -> None:
        super().on_train_epoch_start()
        self._refit_linear_weights()

    def on_validation_epoch_start(self) -> None:
        self._refit_linear_weights()

    def configure_optimizers(self) -> Any:
        """MIMO: the shared modes' frequencies step at ``MODE_FREQUENCY_LR_FACTOR`` times the
        learning rate (a step of the raw frequency moves a mode by about that share of its
        frequency, and a lightly damped mode is ~1 % wide: at the full rate Adam's first
        steps throw the modes off their peaks)."""
        configured = super().configure_optimizers()
        if not self.mimo or self.uses_lbfgs:  # L-BFGS takes one group (its line search)
            return configured
        optimizer = configured["optimizer"] if isinstance(configured, dict) else configured
        frequencies = {id(mode.raw_frequency) for mode in self.dynamics.modes}
        group = optimizer.param_groups[0]
        slow = [p for p in group["params"] if id(p) in frequencies]
        if slow:
            group["params"] = [p for p in group["params"] if id(p) not in frequencies]
            optimizer.add_param_group({"params": slow,
                                       "lr": group["lr"] * MODE_FREQUENCY_LR_FACTOR})
        return configured

    def _linear_weights(self) -> list[nn.Parameter]:
        return [*self.dynamics.linear_weights(), self.offset]

    def _refit_linear_weights(self) -> None:
        """`_fit_linear_weights` on the training recordings while training MIMO."""
        if not getattr(self, "_least_squares", False):
            return
        recordings = self.trainer.datamodule.windows.splits.train
        self._fit_linear_weights([rec.u for rec in recordings], [rec.y for rec in recordings])

    def _input_filter(self) -> tuple[np.ndarray, np.ndarray]:
        """The linear part of a MIMO input path at its start (amplifier lag and delay) as
        ``(b, a)``; the channels start alike."""
        with torch.no_grad():
            b, a = (c.numpy() for c in self.amplifiers[0].coefficients())
        return np.r_[np.zeros(self.delays[0].samples), b], a

    def physical_parameters(self) -> dict[str, Any]:
        """Every block's current parameters (for reports); MIMO: per input ``inputs[j]``, the
        shared modes with their residues and feedthrough (``dynamics``), offsets per output."""
        if self.mimo:
            return self._mimo_parameters()
        blocks = {"amplifier": self.amplifier, "hysteresis": self.hysteresis,
                  **{label: getattr(self, attribute) for label, attribute in
                     (*self.cell_terms, *self.series_blocks)},
                  "mode": self.mode}
        out = {name: block.export() for name, block in blocks.items() if block is not None}
        out.update(gain=float(self.gain.detach()), offset=float(self.offset.detach()),
                   delay=self.delay.delay_samples)
        return out

    def _mimo_parameters(self) -> dict[str, Any]:
        """`physical_parameters` of the MIMO layout."""
        inputs = []
        for j in range(self.n_base_inputs):
            blocks = {"amplifier": self.amplifiers[j].export()}
            if self.cells is not None:
                blocks["hysteresis"] = self.cells[j].export()
            for label, attribute in (*self.cell_terms, *self.series_blocks):
                blocks[label] = getattr(self, attribute)[j].export()
            inputs.append(blocks)
        return {"inputs": inputs, "dynamics": self.dynamics.export(),
                "offset": self.offset.detach().cpu().numpy().tolist(),
                "delay": self.delays[0].samples}
