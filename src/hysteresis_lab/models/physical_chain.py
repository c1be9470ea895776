"""`PhysicalChainModule`: models that simulate whole recordings from rest through a chain of
physical blocks (`hysteresis_lab.blocks`): the grey-box and the linear model.

Such a model reads the input alone (an output-error model): its one-step prediction is its
free run, it trains on the free-run error of whole recordings (each simulated from rest, the
one state that is known; `hysteresis_lab.data.segments.RecordingDataModule`), and its output
is ``chain(v) + offset`` with ``v`` the measured inputs over their scales (zero volts is zero).
Subclasses build their blocks (and an ``offset`` parameter) and implement `chain`, and for
the exported simulation step (`step_physical`, `hysteresis_lab.models.export`) `chain_step`
and `state_names`: the same chain one sample at a time on a flat state, zero at rest.

Where the data set says every recording starts from one shared unknown state
(`DatasetSplits.shared_initial_state`, the cascaded tanks), the model learns it: every
recording is simulated after a burn-in of ``start_input`` held constant (a learned input per
channel, from the training inputs' mean) for as long as the longest training recording, so
it starts where the chain settles for that input (the steady state a system left alone at a
constant input reaches) instead of at rest. `initial_state` is that state for the step.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.effects.base import Effect, physical_order
from hysteresis_lab.effects.registry import loaded_effects
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.base import NarxModule, batches_of
from hysteresis_lab.models.export import export_chain_step
from hysteresis_lab.models.full_batch import CONVERGED, lbfgs_closure, make_lbfgs

log = logging.getLogger(__name__)

#: most steps a fit takes back (`PhysicalChainModule.training_step`)
MAX_STEP_BACKS = 10
#: the burn-in to the learned shared initial state (samples) when the data do not say
BURN_IN_DEFAULT = 1000
#: levels tried along each input before `PhysicalChainModule.free_run_from_estimated_start`'s
#: least squares refines the best
HOLD_GRID_POINTS = 21


class FromEffects:
    """A class attribute computed from the registered effects when it is read: the names of
    those ``pick`` accepts, in physical order (`physical_order`), so that a plugin effect
    with the face a model reads is carried like a built-in one."""

    def __init__(self, pick: Callable[[Effect], bool]) -> None:
        self.pick = pick

    def __get__(self, obj: Any, owner: type | None = None) -> tuple[str, ...]:
        effects = physical_order(list(loaded_effects().values()))
        return tuple(e.name for e in effects if self.pick(e))


class PhysicalChainModule(NarxModule):
    """Base of the models that simulate from rest through physical blocks (see above)."""

    layout = "flat"
    simulation_trained = True
    #: trains on whole recordings simulated from rest (`hysteresis_lab.data.segments`)
    whole_recordings = True
    #: an added block starts at no effect and must travel O(1) at about the rate per Adam
    #: step while the fitted blocks only adjust: at one rate for all, the new block stops
    #: short and the fitted dynamics bend to make up for it
    new_block_lr_factor = 10.0
    predicts_from_outputs = False

    def __init__(self, *args: Any, grow: bool | str = "best", polish: bool = True,
                 **kwargs: Any) -> None:
        """``grow``: how declared effects are fitted (`hysteresis_lab.workflows.grow`):
        ``"best"`` grown on the fitted linear model one stage each (`growth_stages`) and
        trained at once, the lower validation loss kept; true: grown; false: at once.
        ``polish``: the fitted model refined by L-BFGS at the end (`polish_settings`), kept
        where it lowers the validation free-run loss."""
        super().__init__(*args, **kwargs)
        if not (grow == "best" or isinstance(grow, bool)):
            raise ConfigError(f"model.grow={grow!r} must be best, true or false. Fix: "
                              "model.grow=best (grow the declared effects on the fitted "
                              "linear model and train them at once, keep the better), true "
                              "(grow only) or false (train at once only).")
        if not isinstance(polish, bool):
            raise ConfigError(f"model.polish={polish!r} must be true or false. Fix: "
                              "model.polish=true (refine the fitted model with L-BFGS, kept "
                              "where it lowers the validation loss) or false.")
        #: the learned input the shared initial state settles at (None: from rest)
        self.start_input: nn.Parameter | None = None
        if (self.hparams.get("trained_on") or {}).get("shared_initial_state"):
            self._learn_initial_state()

    @classmethod
    def polish_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        """The model settings of the L-BFGS polish (``model.polish``): ``settings`` as they
        are; a class may free there what Adam leaves fixed."""
        return dict(settings)

    def _learn_initial_state(self) -> None:
        """``start_input`` from the training inputs' mean (over their scales), the burn-in
        as long as the longest training recording (``trained_on["burn_in_samples"]``)."""
        n = self.n_base_inputs
        samples = (self.hparams.get("trained_on") or {}).get("burn_in_samples")
        self.start_input = nn.Parameter((self.u_offset[:n] / self.u_scale[:n]).double().clone())
        self.register_buffer("burn_in", torch.tensor(int(samples or BURN_IN_DEFAULT)))

    @classmethod
    def growth_stages(
        cls, settings: Mapping[str, Any]
    ) -> list[tuple[str, dict[str, Any], str | None]]:
        """The stages a declared model grows through, the way the loop grows one: the model
        without effects first, then one declared effect more per stage, in the order the
        physics puts them (`carried_effects`); each ``(label, settings, added effect)``, the
        last holding every declared effect (``settings`` as given)."""
        declared = [str(e) for e in settings.get("effects") or []]
        order = [e for e in cls.carried_effects or () if e in declared]
        order += [e for e in declared if e not in order]
        stages: list[tuple[str, dict[str, Any], str | None]] = [
            ("linear", {**settings, "effects": []}, None)]
        for number, effect in enumerate(order):
            grown = dict(settings) if number == len(order) - 1 else {
                **settings, "effects": order[: number + 1]}
            stages.append((effect, grown, effect))
        return stages

    def _channel_routes(
        self, effects: Sequence[str], feature_context: dict[str, Any] | None, effect_path: str
    ) -> list[str]:
        """Effects are blocks here; their operator channels are not read."""
        return ["base"] * self.nu

    # ------------------------------------------------------------------ training
    @property
    def uses_lbfgs(self) -> bool:
        """True when it trains with L-BFGS (``training.optimizer=lbfgs``)."""
        return self.training_settings.optimizer == "lbfgs"

    @property
    def full_batch_steps(self) -> bool:
        """True when each step reads every training recording (L-BFGS)."""
        return self.uses_lbfgs

    @property
    def recordings_per_epoch(self) -> int:
        """How often an epoch visits each training recording: ``model.recording_repeats``
        Adam steps, or one L-BFGS step of that many iterations."""
        return 1 if self.uses_lbfgs else int(self.hparams.get("recording_repeats", 1))

    def configure_optimizers(self) -> Any:
        if not self.uses_lbfgs:
            return super().configure_optimizers()
        return make_lbfgs(self.parameters(), int(self.hparams.get("recording_repeats", 1)))

    def training_step(self, batch: Any, batch_idx: int) -> torch.Tensor | None:
        """Adam's steps (`NarxModule.training_step`), or one L-BFGS step on the free-run
        error of every training recording (weighted by its samples); once an epoch starts
        less than `CONVERGED` lower than the one before, the stage ends."""
        if not self.uses_lbfgs:
            return super().training_step(batch, batch_idx)
        optimizer = self.optimizers()
        parts = batches_of(batch)
        weights = [part[0].shape[1] for part in parts]

        def loss_of() -> torch.Tensor:
            return sum(self._loss(part) * (w / sum(weights))
                       for part, w in zip(parts, weights, strict=True))

        closure = lbfgs_closure(optimizer.optimizer, loss_of, self.manual_backward)
        value = float(optimizer.step(closure=closure).detach())
        if not math.isfinite(value):
            return None
        if not value < self._lbfgs_start_loss * (1.0 - CONVERGED):
            self.trainer.should_stop = True
        self._lbfgs_start_loss = value
        self._train_loss_sum += value
        self._train_loss_count += 1
        return torch.tensor(value)

    def _on_finite_loss(self) -> None:
        """Remember the weights whose free run was finite (`_on_non_finite_loss`)."""
        self._last_finite = {name: p.detach().clone() for name, p in self.named_parameters()}

    def _on_non_finite_loss(self, optimizer: Any) -> None:
        """A step after which the free run is no longer finite (a feedback force pushed past
        the closed loop's stability, a pole past the unit circle) is taken back and the
        learning rates halved, at most `MAX_STEP_BACKS` times per fit: Adam's first steps
        move every new parameter by the rate whatever its gradient, and one such step can
        leave the stable region."""
        if self._last_finite is None or self._step_backs >= MAX_STEP_BACKS:
            return
        with torch.no_grad():
            for name, parameter in self.named_parameters():
                parameter.copy_(self._last_finite[name])
        for group in getattr(optimizer, "optimizer", optimizer).param_groups:
            group["lr"] *= 0.5
        self._step_backs += 1
        log.warning("a training step left the stable region (non-finite free run): taken back, "
                    "learning rates halved (%d of at most %d)", self._step_backs,
                    MAX_STEP_BACKS)

    def on_fit_start(self) -> None:
        #: the loss the last L-BFGS epoch started from (`training_step`)
        self._lbfgs_start_loss = math.inf
        self._last_finite: dict[str, torch.Tensor] | None = None
        self._step_backs = 0

    # ------------------------------------------------------------------ the model
    def chain(self, v: torch.Tensor) -> torch.Tensor:  # pragma: no cover
        """Measured inputs over their scales (B, T, n_base_inputs) -> outputs over their
        scales before the offset (B, T, ny), from rest."""
        raise NotImplementedError

    def chain_step(self, v: torch.Tensor, state: StepState) -> torch.Tensor:  # pragma: no cover
        """One sample of `chain`: inputs (B, n_base_inputs) -> outputs (B, ny); each block
        reads its part of ``state`` in the order of `state_names`."""
        raise NotImplementedError

    def state_names(self) -> list[str]:  # pragma: no cover
        """The flat step state's columns, in order (``block.part``)."""
        raise NotImplementedError

    def export_onnx(self, path: Path | str, opset: int = 17) -> Path:
        """Only ``<stem>_step.onnx``, its simulation step (an output-error model's one-step
        prediction is its free run); returns that path."""
        path = Path(path)
        return export_chain_step(self, path.with_name(f"{path.stem}_step.onnx"), opset)

    def _physical_input(self, u_scaled: torch.Tensor) -> torch.Tensor:
        """Scaled inputs (B, T, nu) -> the measured inputs over their scales (B, T,
        n_base_inputs): zero volts is zero here, so "at rest" means what it does physically."""
        n = self.n_base_inputs
        return u_scaled[..., :n].double() + (self.u_offset[:n] / self.u_scale[:n]).double()

    def _output_offset(self) -> torch.Tensor:
        """What the scaled outputs add to the chain's (ny,), float64."""
        return self.offset - (self.y_offset / self.y_scale).double()

    def simulate_full(self, u_scaled: torch.Tensor) -> torch.Tensor:
        """Scaled inputs (B, T, nu) -> scaled outputs (B, T, ny), every row from rest (or
        from the learned shared initial state: after the burn-in)."""
        v = self._physical_input(u_scaled)
        if self.start_input is None:
            x = self.chain(v)
        else:
            n_burn = int(self.burn_in)
            held = self.start_input.to(v).expand(v.shape[0], n_burn, -1)
            x = self.chain(torch.cat([held, v], dim=1))[:, n_burn:]
        return (x + self._output_offset()).to(u_scaled.dtype)

    def _after_hold(self, v: torch.Tensor, level: torch.Tensor, n_hold: int) -> torch.Tensor:
        """The chain's outputs over its inputs ``v`` (1, T, n_base_inputs), after ``level``
        (n_base_inputs,) held from rest for ``n_hold`` samples (the state a system left
        alone at that input settles in), before the offset."""
        held = level.to(v).expand(1, n_hold, -1)
        return self.chain(torch.cat([held, v], dim=1))[:, n_hold:]

    def free_run_from_estimated_start(
        self, u_scaled: np.ndarray, y_scaled: np.ndarray, first: int, n_skip: int
    ) -> np.ndarray:
        """The free run (T, ny) of one recording (scaled inputs (T, nu), outputs (T, ny))
        from the start its samples ``first .. n_skip - 1`` show: the input level held
        before the recording (as long as the recording lasts, so that what it can show
        has settled) and the output offset, fitted by least squares on those samples (the
        offset in closed form). Starting from rest, the offset alone, is the fit's first
        candidate, so the estimate never fits those samples worse than it."""
        from scipy.optimize import least_squares

        v = self._physical_input(torch.as_tensor(u_scaled[None], dtype=torch.float64,
                                                 device=self.u_scale.device))
        measured = torch.as_tensor(y_scaled, dtype=torch.float64, device=v.device)
        n_hold = max(BURN_IN_DEFAULT, v.shape[1])
        head = v[:, :n_skip]

        def start_error(level: np.ndarray) -> np.ndarray:
            with torch.inference_mode():
                x = self._after_hold(head, torch.as_tensor(level, dtype=torch.float64), n_hold)
            error = (measured[first:n_skip] - x[0, first:n_skip]).cpu().numpy()
            return (error - error.mean(axis=0)).ravel()

        def cost(level: np.ndarray) -> float:
            return float(np.sum(start_error(level) ** 2))

        low, high = v[0].amin(dim=0).cpu().numpy(), v[0].amax(dim=0).cpu().numpy()
        reach = (high - low) + np.maximum(np.abs(low), np.abs(high)) + 1e-9  # levels near it
        lower, upper = low - reach, high + reach
        # a hysteretic chain's error is flat or kinked in the level near rest: a grid along
        # each input first (the others at the record's first input), then least squares
        first_input = np.clip(v[0, 0].cpu().numpy(), lower, upper)
        grid = [np.where(np.arange(len(first_input)) == i, value, first_input)
                for i in range(len(first_input))
                for value in np.linspace(lower[i], upper[i], HOLD_GRID_POINTS)]
        start_cost, start = min(((cost(level), level) for level in grid), key=lambda c: c[0])
        fitted = least_squares(start_error, start, bounds=(lower, upper), x_scale=reach).x
        rest = np.zeros_like(first_input)  # rest: the offset only
        _, level = min([(cost(rest), rest), (start_cost, start), (cost(fitted), fitted)],
                       key=lambda c: c[0])
        with torch.inference_mode():
            x = self._after_hold(v, torch.as_tensor(level, dtype=torch.float64), n_hold)[0]
        offset = (measured[first:n_skip] - x[first:n_skip]).mean(dim=0)
        return (x + offset).cpu().numpy()

    def initial_state(self) -> torch.Tensor:
        """The step's state (nx,) where every recording starts: zeros (rest), or with a
        learned shared initial state the state after the burn-in (`step_physical` held at
        ``start_input`` in physical units)."""
        state = torch.zeros(1, len(self.state_names()), dtype=torch.float64,
                            device=self.u_scale.device)
        if self.start_input is None:
            return state[0]
        n = self.n_base_inputs
        with torch.no_grad():
            u = (self.start_input.double() * self.u_scale[:n].double())[None]
            for _ in range(int(self.burn_in)):
                _, state = self.step_physical(state, u)
        return state[0]

    def step_physical(
        self, state: torch.Tensor, u: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The simulation step in physical units, float64: ``(state (B, nx), measured inputs
        u (B, n_base_inputs)) -> (outputs y (B, ny) at the sample of u, next state)``; the
        state at rest is zero (`state_names` has its layout). Stepping it over a recording
        from `initial_state` (zeros unless the model learned a shared initial state)
        reproduces `simulate_full`."""
        n = self.n_base_inputs
        u_offset, u_scale, u_rest, y_offset, y_scale, y_add = frozen(
            self.u_offset[:n].double(), self.u_scale[:n].double(),
            (self.u_offset[:n] / self.u_scale[:n]).double(), self.y_offset.double(),
            self.y_scale.double(), self._output_offset())
        v = (u.double() - u_offset) / u_scale + u_rest
        steps = StepState(state.double())
        x = self.chain_step(v, steps)
        y = (x + y_add) * y_scale + y_offset
        return y, steps.next_state()

    def simulate_scaled(self, u: torch.Tensor, y_initial: torch.Tensor) -> torch.Tensor:
        """Training's free run: from rest (or the learned shared initial state) at the first
        sample (``y_initial`` is not needed); predictions of samples first_target..T-1."""
        return self.simulate_full(u)[:, self.window.first_target :]

    def _loss(self, batch: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
        """The free-run error in float64, as the chain simulates: in the float32 of the
        batches, nearby parameters give the same loss (its last digit is ~1e-7 of it), and
        the L-BFGS polish's line search, which compares such losses, ends where it began."""
        u, y = batch
        start = self.window.first_target
        return self.loss_fn(self.simulate_scaled(u.double(), y), y[:, start:].double())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        raise ConfigError(
            f"{type(self).__name__} simulates whole recordings from rest; it has no prediction "
            "from a single regression window. Fix: use hysteresis_lab.evaluation.predict."
            "free_run (one_step and n_step give the free run for it)."
        )

    def simulate_recordings(
        self, u: np.ndarray, y_meas: np.ndarray, reset: np.ndarray, window: WindowSpec,
        lengths: np.ndarray | None = None,
    ) -> np.ndarray:
        """Evaluation's free run of all rows (scaled); restarts change nothing (an
        output-error model does not read measured outputs)."""
        device = next(self.parameters()).device
        with torch.inference_mode():
            y = self.simulate_full(torch.as_tensor(u, dtype=torch.float64, device=device))
        out = np.array(y_meas, dtype=np.float64)
        ft = window.first_target
        out[:, ft:] = y[:, ft:].double().cpu().numpy()
        return out

    def warm_start_from(self, previous: NarxModule) -> None:
        """Start from a fitted model of the same class with fewer blocks (the loop adds
        one): every shared parameter is copied, each new one starts where it changes nothing
        (`_start_new_parameter`), so the grown model simulates what the fitted one did; the
        new parameters are what `train_new_inputs_only` trains."""
        if type(previous) is not type(self):
            raise ConfigError(
                f"cannot warm-start a {type(self).__name__} from a {type(previous).__name__}."
            )
        old = dict(previous.named_parameters())
        self._new_entries = {}
        with torch.no_grad():
            for name, new in self.named_parameters():
                before = old.get(name)
                if before is not None and before.shape == new.shape:
                    new.copy_(before)
                    continue
                self._start_new_parameter(name, new, previous)
                self._new_entries[name] = torch.ones_like(new, dtype=torch.bool)
            old_buffers = dict(previous.named_buffers())
            for name, buffer in self.named_buffers():  # block state such as a fitted delay
                before = old_buffers.get(name)
                if before is not None and before.shape == buffer.shape and "." in name:
                    buffer.copy_(before)

    def _start_new_parameter(self, name: str, value: torch.Tensor, previous: NarxModule) -> None:
        """Set a parameter the fitted model lacks so that it changes nothing (default: its
        initial value already does)."""
