"""`greybox`: a physics-structured positioner model with a few physical parameters.

    u -> amplifier (first-order lag) -> delay -> hysteresis -> creep -> mode(s) -> + offset -> y

* hysteresis (``model.hysteresis``): ``bouc_wen`` (a differentiable Bouc–Wen state
  recursion, the default), ``prandtl_ishlinskii`` (play operators with learnable thresholds
  and non-negative weights, the recursion the effect catalogue's ``hysteresis`` uses) or
  ``none`` (a static gain);
* creep when ``model.effects`` holds ``creep`` (a first-order filter bank, fixed time
  constants, learnable weights), a second mode when it holds ``resonance``;
* every linear block is stable for any parameter value (`hysteresis_lab.blocks`);
* optionally (``model.residual_neurons > 0``) a small ReLU network adds a static correction
  from the last ``nb`` inputs and the last ``na`` outputs of the physical chain (not fed
  back, so the physics keeps the memory and the model stays stable); its output layer
  starts at zero, so training starts from the physical model.

The model starts from values read off the data (`initialise_from_data`: the static gain by
least squares, the mode from the best linear approximation's resonance peak, the output
offset) and is fitted on the free-run error of whole recordings, each simulated from rest
(the physical state is known there; a segment cut from the middle of a recording would start
from an unknown hysteresis state). It simulates from the input alone, so its one-step
prediction is its free run (an output-error model's predictor) and it extrapolates to
amplitudes beyond the training data as its physics does.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.blocks import (
    BoucWen,
    CreepBank,
    Delay,
    FirstOrderLag,
    PlayOperators,
    SecondOrderMode,
    bouc_wen_scaled_params,
    estimate_mode,
    estimate_static_gain,
)
from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.base import NarxModule, mlp
from hysteresis_lab.models.physical_chain import PhysicalChainModule

log = logging.getLogger(__name__)

HYSTERESIS = ("bouc_wen", "prandtl_ishlinskii", "none")
#: catalogue effects the grey-box carries as physical blocks
BLOCK_EFFECTS = ("hysteresis", "creep", "resonance")


class GreyBox(PhysicalChainModule):
    """Amplifier, delay, hysteresis, creep and modes in series (see the module docstring)."""

    carried_effects = BLOCK_EFFECTS

    def __init__(
        self,
        nu: int,
        ny: int,
        fs: float = 20_000.0,
        hysteresis: str = "bouc_wen",
        n_modes: int = 1,
        mode_hz: float | None = None,
        mode_damping: float | None = None,
        amplifier_hz: float | None = None,
        delay: int = 1,
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
        effects = list(self.hparams.get("effects") or [])
        unknown = [e for e in effects if e not in BLOCK_EFFECTS]
        problems = []
        if hysteresis not in HYSTERESIS:
            problems.append(f"model.hysteresis='{hysteresis}' (one of {list(HYSTERESIS)})")
        if self.n_base_inputs != 1 or ny != 1:
            problems.append(f"{self.n_base_inputs} input(s) and {ny} output(s) (it models one "
                            "actuator axis: 1 and 1; model=linear and model=subnet take MIMO data)")
        if unknown:
            problems.append(f"effects {unknown} (its blocks: {list(BLOCK_EFFECTS)}; model=subnet "
                            "or model=ffnn take any catalogue effect as an input)")
        if objective != "simulation":
            problems.append(f"model.objective='{objective}' (it is fitted on the simulation "
                            "error only)")
        if not (isinstance(n_modes, int) and 0 <= n_modes <= 3):
            problems.append(f"model.n_modes={n_modes!r} (0-3)")
        if not (isinstance(delay, int) and delay >= 0):
            problems.append(f"model.delay={delay!r} (whole samples >= 0)")
        if not (isinstance(residual_neurons, int) and residual_neurons >= 0
                and isinstance(residual_layers, int) and residual_layers >= 1):
            problems.append(f"model.residual_neurons={residual_neurons!r} / residual_layers="
                            f"{residual_layers!r} (>= 0 / >= 1; 0 neurons: no network)")
        if not (isinstance(recording_repeats, int) and recording_repeats >= 1):
            problems.append(f"model.recording_repeats={recording_repeats!r} (>= 1)")
        if problems:
            raise ConfigError(
                "model=greybox cannot take " + "; ".join(problems) + ". Fix: change those "
                "settings (hysteresis_lab/conf/model/greybox.yaml has the defaults)."
            )
        nyquist = 0.5 * fs
        # the blocks' 1 Hz floors scaled down for slow data (cascaded tanks: fs = 0.25 Hz)
        self.f_floor = min(1.0, 1e-3 * fs)
        self.amplifier = FirstOrderLag(fs, amplifier_hz or 0.25 * fs,
                                       min_cutoff_hz=self.f_floor)
        self.delay = Delay(delay)
        self.hysteresis: nn.Module | None
        if hysteresis == "bouc_wen":
            # a generic loop shape for an input of unit amplitude (not the simulator's
            # values); the gain after the cell is read off the data
            self.hysteresis = BoucWen(**bouc_wen_scaled_params(1.0, 0.2, 0.015, 0.003,
                                                               100.0, 100.0))
        elif hysteresis == "prandtl_ishlinskii":
            self.hysteresis = PlayOperators(n_operators=operators, max_threshold=0.8)
        else:
            self.hysteresis = None
        self.gain = nn.Parameter(torch.ones((), dtype=torch.float64))  # after the hysteresis
        self.creep = CreepBank(fs, creep_time_constants_s) if "creep" in effects else None
        modes = n_modes + int("resonance" in effects)
        self.mode = (
            SecondOrderMode(fs, mode_hz or 0.1 * nyquist, mode_damping or 0.05, n_modes=modes,
                            fmin=self.f_floor)
            if modes else None
        )
        self.offset = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.residual: nn.Sequential | None = None
        if residual_neurons:
            self.residual = mlp(self.window.nb + self.window.na, 1, residual_neurons,
                                residual_layers).double()
            with torch.no_grad():
                self.residual[-1].weight.zero_()
                self.residual[-1].bias.zero_()

    # ------------------------------------------------------------------ the model
    def chain(self, v: torch.Tensor) -> torch.Tensor:
        """Input over its scale (B, T, 1) -> output before the offset (B, T, 1), from rest."""
        return self._chain(v[..., 0])[..., None]

    def _chain(self, v: torch.Tensor) -> torch.Tensor:
        """`chain` on (B, T) -> (B, T)."""
        x = self.delay(self.amplifier(v))
        v_in = v
        if self.hysteresis is not None:
            x = self.hysteresis(x)
            x = x[0] if isinstance(x, tuple) else x
        x = self.gain * x
        if self.creep is not None:
            x = self.creep(x)
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
        """The blocks with a state, in the chain's order."""
        blocks = [("amplifier", self.amplifier), ("delay", self.delay),
                  ("hysteresis", self.hysteresis), ("creep", self.creep), ("mode", self.mode)]
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
        """One sample of `chain`: (B, 1) -> (B, 1)."""
        v_in = v[:, 0]
        x = self.delay.step(self.amplifier.step(v_in, state), state)
        if self.hysteresis is not None:
            x = self.hysteresis.step(x, state)
        x = frozen(self.gain)[0] * x
        if self.creep is not None:
            x = self.creep.step(x, state)
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

    def _start_new_parameter(self, name: str, value: torch.Tensor, previous: NarxModule) -> None:
        """A new block starts where it changes nothing: creep weights 0, a new mode at
        weight 0 beside the fitted ones."""
        if name.startswith("mode.") and self.mode is not None and previous.mode:
            self._grow_mode(previous.mode)
        elif name.startswith("creep."):
            value.zero_()

    def _grow_mode(self, fitted: SecondOrderMode) -> None:
        """The fitted modes, plus new ones at zero weight."""
        assert self.mode is not None
        n = fitted.n_modes
        self.mode.raw_frequency[:n] = fitted.raw_frequency
        self.mode.raw_damping[:n] = fitted.raw_damping
        self.mode.raw_weights.zero_()
        self.mode.raw_weights[: n - 1] = fitted.raw_weights

    # ------------------------------------------------------------------ initial values
    def initialise_from_data(self, u: np.ndarray, y: np.ndarray, fs: float) -> None:
        """Starting values from a training recording (physical units, 1-D): the static gain
        (least squares), the mode (the BLA's resonance peak) and the output offset."""
        u_s = u / float(self.u_scale[0])
        y_s = y / float(self.y_scale[0])
        gain = estimate_static_gain(u_s - u_s.mean(), y_s - y_s.mean())
        with torch.no_grad():
            if self.mode is not None and self.hparams.get("mode_hz") is None:
                try:
                    frequency, damping = estimate_mode(u, y, fs)
                except ValueError as exc:
                    log.warning("no resonance found in the training data (%s): the mode starts "
                                "at %.0f Hz", exc, float(self.mode.frequency_hz[0]))
                else:
                    fresh = SecondOrderMode(fs, frequency, damping, n_modes=self.mode.n_modes,
                                            fmin=self.f_floor)
                    self.mode.load_state_dict(fresh.state_dict())
            base = self._chain(torch.as_tensor(u_s[None], dtype=torch.float64))[0].numpy()
            scale = estimate_static_gain(base - base.mean(), y_s - y_s.mean())
            if not np.isfinite(scale) or scale <= 0:
                scale = gain
            self.gain.fill_(float(scale))
            fitted = scale * base
            self.offset.fill_(float(np.mean(y_s - fitted)))
        log.info("grey-box start: gain %.4g, mode %s Hz, offset %.4g (scaled)",
                 float(self.gain.detach()),
                 None if self.mode is None else np.round(self.mode.export()["frequency_hz"], 1),
                 float(self.offset.detach()))

    def physical_parameters(self) -> dict[str, Any]:
        """Every block's current parameters (for reports)."""
        blocks = {"amplifier": self.amplifier, "hysteresis": self.hysteresis,
                  "creep": self.creep, "mode": self.mode}
        out = {name: block.export() for name, block in blocks.items() if block is not None}
        out.update(gain=float(self.gain.detach()), offset=float(self.offset.detach()),
                   delay=self.delay.samples)
        return out
