"""`NarxModule`: the shared base of the NARX networks (FFNN, LSTM, CNN and plugins).

A subclass sets ``layout`` ("flat" or "sequence") and builds ``self.net`` mapping scaled
regressors to the scaled next output. The base owns what every architecture shares:
normalisation (buffers saved with the weights, so a checkpoint maps volts to micrometres on
its own), the MSE loss, Adam and the learning-rate schedule, and the differentiable free run
used by simulation-error training (``objective="simulation"``, see `hysteresis_lab.fitting`).

Training objectives (``objective``): ``"one_step"`` is the study's one-step-ahead MSE on
regression windows; ``"simulation"`` is the free-run MSE over segments of ``horizon`` samples,
each started from its measured first ``first_target`` samples (the NARX state; state-space
subclasses estimate their state from them with an encoder), gradients through the whole
horizon. With ``simulation_epochs`` set, a one-step stage of ``trainer.max_epochs`` epochs
comes first and the simulation stage then runs ``simulation_epochs`` epochs at
``simulation_lr`` (fine-tuning); with it null the simulation error is the only objective.

Declared effects (`hysteresis_lab.effects`) arrive as extra input channels after the
``n_base_inputs`` measured ones. ``effect_path="network"`` feeds them to the network like any
input; ``effect_path="linear"`` keeps them out of the network and adds a linear map of their
lags to its output (``y = net(u, y lags) + W · effect lags``): physically the classical
superposition (a Prandtl–Ishlinskii sum of play operators, a creep filter bank, mode filters),
and a model that extrapolates linearly in the new operators instead of through ReLUs. A
baseline's free run (``model.baseline``, `hysteresis_lab.models.augment`) comes last,
``baseline_channels`` channels, and always enters the network.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

import lightning as L
import numpy as np
import torch
from lightning.pytorch.plugins.precision import Precision
from lightning.pytorch.strategies import SingleDeviceStrategy
from torch import nn

from hysteresis_lab.data.scaling import Scaler
from hysteresis_lab.data.windows import Layout, assemble
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.errors import ConfigError, DivergedError
from hysteresis_lab.kernels.interface import input_lags
from hysteresis_lab.models.augment import context_from_dict
from hysteresis_lab.models.export import export_narx
from hysteresis_lab.models.interface import ModelContract, NetworkModel
from hysteresis_lab.models.settings import (
    MODEL_SETTINGS,
    TRAINING_SETTINGS,
    EffectSettings,
    ModelSettings,
    TrainingSettings,
    refuse_output_effects,
    unknown_settings,
)

log = logging.getLogger(__name__)

#: the hooks Lightning calls around backward and the optimiser step (see `_direct_steps`)
_STEP_HOOKS = ("on_before_backward", "on_after_backward", "on_before_optimizer_step")
#: what a `LightningOptimizer` does around the torch step: the manual loop's step count
_STEP_BOOKKEEPING = ("_on_before_step", "_on_after_step", "optimizer")


class NarxModule(L.LightningModule, ModelContract, NetworkModel):
    """``y[k] = f(u[k-nk-nb+1 .. k-nk], y[k-na .. k-1])`` with normalisation inside.

    Built as ``cls(nu=, ny=, **settings)``: the settings every model shares
    (`ModelSettings`: lags, scaler, effects, ``trained_on``) and how it trains
    (`TrainingSettings`), by name; a subclass adds its own keywords before ``**kwargs``.
    """

    layout: ClassVar[Layout] = "flat"
    is_network: ClassVar[bool] = True
    warm_starts: ClassVar[bool] = True
    #: the keywords ``__init__`` takes through ``**settings`` (`ModelContract.settings_keys`)
    shared_settings: ClassVar[tuple[str, ...]] = (*MODEL_SETTINGS, *TRAINING_SETTINGS)

    def __init__(self, nu: int, ny: int, **settings: Any) -> None:
        super().__init__()
        unknown_settings(settings, self.shared_settings, type(self).__name__)
        # checked here, so a bad setting fails before any data is read
        model = ModelSettings.from_kwargs(nu, ny, settings)
        training = TrainingSettings.from_kwargs(settings)
        if training.optimizer == "lbfgs" and not getattr(type(self), "whole_recordings", False):
            raise ConfigError(
                f"training.optimizer=lbfgs needs a model that trains on whole recordings (a "
                f"full batch); {type(self).__name__} trains on batches of windows. Fix: "
                "training.optimizer=adam, or model=greybox / model=linear."
            )
        effect_settings = model.effects.checked(nu)
        self.window = model.window
        self.save_hyperparameters()
        # every setting with its default, as `training_settings` and a checkpoint read them
        for key, value in {**model.to_kwargs(), **training.to_dict()}.items():
            self.hparams.setdefault(key, value)
        self.hparams["model_name"] = type(self).registry_name or type(self).__name__
        self._register_scaler(model.scaler or {}, nu, ny)
        self.nu, self.ny = nu, ny
        self.n_base_inputs = (nu if effect_settings.n_base_inputs is None
                              else effect_settings.n_base_inputs)
        self.net: nn.Module = nn.Identity()
        #: weights of the linear effect path, (ny, regressor) flat or (ny, features, L) sequence
        self.effect_weight: nn.Parameter | None = None
        #: input block: base inputs += effect channels @ input_weight.T (scaled units)
        self.input_weight: nn.Parameter | None = None
        self._route_effect_channels(effect_settings)
        self.loss_fn = nn.MSELoss()
        #: set by `hysteresis_lab.fitting` while training on free-run segments
        self.simulation_mode = False
        #: the learning rate of the running training stage, set by `hysteresis_lab.fitting`
        self.stage_lr: float | None = None
        #: (gradient_clip_val, gradient_clip_algorithm) of the running stage, set by
        #: `hysteresis_lab.fitting` (a Trainer may not clip under manual optimisation)
        self.gradient_clipping: tuple[float, str | None] | None = None
        self._skipped_batches = 0
        #: after `train_new_inputs_only`: each partly trained tensor's kept values and mask
        self._kept_values: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}
        # manual: a Lightning step may carry a block of batches (see `training_step`)
        self.automatic_optimization = False

    def _register_scaler(self, scaler: dict[str, Sequence[float]], nu: int, ny: int) -> None:
        """Normalisation buffers (saved with the weights): offsets and scales per channel."""
        for key, size in (("u_offset", nu), ("u_scale", nu), ("y_offset", ny), ("y_scale", ny)):
            default = 0.0 if key.endswith("offset") else 1.0
            values = torch.as_tensor(scaler.get(key, [default] * size), dtype=torch.float32)
            self.register_buffer(key, values.reshape(size))

    def _route_effect_channels(self, settings: EffectSettings) -> None:
        """Masks and weights for effect channels that do not enter the network as ordinary
        inputs: the linear effect path (``effect_weight``) and the input block
        (``input_weight``); see `_channel_routes`."""
        routes = self._channel_routes(
            settings.effects, settings.feature_context, settings.effect_path
        )
        self._routed = any(route in ("linear", "input") for route in routes)
        if not self._routed:
            return
        linear = torch.tensor([route == "linear" for route in routes])
        to_input = torch.tensor([route == "input" for route in routes])
        self.register_buffer("away_channels", linear | to_input, persistent=False)
        self.register_buffer(
            "net_mask", (~self._regressor_columns(linear | to_input)).float(), persistent=False
        )
        if linear.any():
            effect_columns = self._regressor_columns(linear)
            self.register_buffer("effect_mask", effect_columns.float(), persistent=False)
            shape = (self.ny, len(effect_columns)) if self.layout == "flat" else (
                self.ny, len(effect_columns), self.window.seq_len)
            self.effect_weight = nn.Parameter(torch.zeros(shape))
        if to_input.any():
            self.register_buffer(
                "input_channels", torch.nonzero(to_input).flatten(), persistent=False
            )
            self.input_weight = nn.Parameter(torch.zeros(self.n_base_inputs, int(to_input.sum())))

    @property
    def scaler(self) -> Scaler:
        """The normalisation it keeps with its weights (offsets and scales per channel)."""
        return Scaler(*(getattr(self, k).detach().cpu().numpy().astype(float)
                        for k in ("u_offset", "u_scale", "y_offset", "y_scale")))

    def predict_scaled(self, x: np.ndarray) -> np.ndarray:
        """Scaled regressors (float32, the class's layout) -> scaled next outputs (N, ny),
        computed on the device of its weights."""
        with torch.inference_mode():
            return self(torch.from_numpy(x).to(self.device)).cpu().numpy()

    def export_onnx(self, path: Path | str, opset: int = 17) -> Path:
        """Its one-step prediction as ONNX in physical units (`export.export_narx`)."""
        return export_narx(self, path, opset)

    @property
    def training_settings(self) -> TrainingSettings:
        """How it trains, read from its saved settings (``hparams``: the one record of them)."""
        return TrainingSettings.from_hparams(self.hparams)

    # ------------------------------------------------------------------ model
    @property
    def n_features(self) -> int:
        """Width of the regressor (flat) or features per time step (sequence)."""
        return self.window.n_features(self.nu, self.ny, self.layout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Scaled regressors (layout of the class) -> scaled next output (B, ny)."""
        if not self._routed:
            return self.net(x)
        network_input = x if self.input_weight is None else self._input_corrected(x)
        out = self.net(network_input * self.net_mask)
        return out if self.effect_weight is None else out + self.effect_term(x)

    def _channel_routes(
        self, effects: Sequence[str], feature_context: dict[str, Any] | None, effect_path: str
    ) -> list[str]:
        """Where each input channel enters: "base" (measured), "network", "linear" (the linear
        effect path) or "input" (the input block of effects with ``block = "input"``). An
        effect on the model's own output (``block = "output"``, after the dynamics, or
        ``"feedback"``, inside them) has no channel and no place in a network: refused."""
        refuse_output_effects(effects, type(self).__name__)
        if self.n_base_inputs == self.nu or feature_context is None:
            return ["base"] * self.nu
        routes = ["base"] * self.n_base_inputs
        baseline = ["network"] * int(self.hparams.get("baseline_channels", 0))
        ctx = context_from_dict(feature_context)
        probe = np.zeros((2, self.n_base_inputs))
        for name in effects:
            effect = get_effect(name)
            if effect.block not in ("network", "input"):
                raise ConfigError(f"effect '{name}' has unknown block '{effect.block}'.")
            route = "input" if effect.block == "input" else (
                "linear" if effect_path == "linear" else "network")
            routes += [route] * effect.features(probe, ctx).shape[1]
        routes += baseline  # a baseline's free run (`hysteresis_lab.models.augment`): last
        if len(routes) != self.nu:
            raise ConfigError(
                f"the effects {list(effects)} give {len(routes) - self.n_base_inputs} channels "
                f"but the model has {self.nu - self.n_base_inputs} beyond the measured inputs."
            )
        return routes

    def _regressor_columns(self, channels: torch.Tensor) -> torch.Tensor:
        """True for the regressor columns (flat) or features (sequence) of ``channels``."""
        outputs = torch.zeros(self.ny, dtype=torch.bool)
        if self.layout == "sequence":
            return torch.cat([channels, outputs])
        return torch.cat([channels.repeat(self.window.nb), outputs.repeat(self.window.na)])

    def _input_corrected(self, x: torch.Tensor) -> torch.Tensor:
        """The input block on scaled regressors: every lag of the measured inputs gets
        ``input_weight @`` the same lag of the input-block channels added."""
        assert self.input_weight is not None
        nu, base, w = self.nu, self.n_base_inputs, self.window
        if self.layout == "flat":
            u, rest = x[:, : w.nb * nu].reshape(len(x), w.nb, nu), x[:, w.nb * nu :]
        else:
            u, rest = x[..., :nu], x[..., nu:]
        correction = u[..., self.input_channels] @ self.input_weight.T
        u = torch.cat([u[..., :base] + correction, u[..., base:]], dim=-1)
        if self.layout == "flat":
            return torch.cat([u.reshape(len(x), -1), rest], dim=1)
        return torch.cat([u, rest], dim=-1)

    def effect_term(self, x: torch.Tensor) -> torch.Tensor:
        """The linear effect path's output for scaled regressors ``x`` (B, ny)."""
        assert self.effect_weight is not None
        if self.layout == "flat":
            return (x * self.effect_mask) @ self.effect_weight.T
        return torch.einsum("blf,yfl->by", x * self.effect_mask, self.effect_weight)

    def free_run_split(self, u_scaled: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """For free-run simulation: the inputs the network sees (input block applied, the
        channels it does not see zeroed) and the linear effect path's output for every target
        sample (B, N, ny), or None.

        Both depend on the inputs alone, so they are computed once for all samples and the
        network's free-run kernels stay unchanged.
        """
        if not self._routed:
            return u_scaled, None
        network_inputs = u_scaled.copy()
        if self.input_weight is not None:
            gain = self.input_weight.detach().double().cpu().numpy()
            channels = self.input_channels.cpu().numpy()
            network_inputs[..., : self.n_base_inputs] += u_scaled[..., channels] @ gain.T
        network_inputs[..., self.away_channels.cpu().numpy()] = 0.0
        if self.effect_weight is None:
            return network_inputs, None
        w = self.window
        batch, length, nu = u_scaled.shape
        term = np.zeros((batch, length, self.ny))
        # zeros before the start, so that every target sample has its nb input lags
        shift = w.nk + w.nb
        padded = np.concatenate([np.zeros((batch, shift, nu)), u_scaled], axis=1)
        y_zero = np.zeros((1, w.na, self.ny), dtype=np.float32)
        with torch.no_grad():
            for start in range(0, length, 8192):
                ks = np.arange(start, min(start + 8192, length))
                u_past = input_lags(padded, w, ks + shift, batch).reshape(-1, w.nb, nu)
                x = assemble(u_past.astype(np.float32),
                             np.broadcast_to(y_zero, (len(u_past), w.na, self.ny)), self.layout)
                out = self.effect_term(torch.as_tensor(x, device=self.effect_weight.device))
                term[:, ks] = out.double().cpu().numpy().reshape(batch, len(ks), self.ny)
        return network_inputs, term

    def scale_inputs(self, u_past: torch.Tensor, y_past: torch.Tensor) -> torch.Tensor:
        """Physical lags (B, nb, nu), (B, na, ny) -> scaled regressors in this model's layout."""
        u = (u_past - self.u_offset) / self.u_scale
        y = (y_past - self.y_offset) / self.y_scale
        return assemble(u, y, self.layout)

    def unscale_output(self, y_scaled: torch.Tensor) -> torch.Tensor:
        return y_scaled * self.y_scale + self.y_offset

    def predict_physical(self, u_past: torch.Tensor, y_past: torch.Tensor) -> torch.Tensor:
        """Physical units in (V, µm lags), physical next output out (B, ny)."""
        return self.unscale_output(self(self.scale_inputs(u_past, y_past)))

    def simulate_scaled(self, u: torch.Tensor, y_initial: torch.Tensor) -> torch.Tensor:
        """Differentiable free run: scaled inputs (B, T, nu) and the first ``first_target``
        measured outputs (B, first_target, ny) -> predictions of samples first_target..T-1."""
        w = self.window
        start = w.first_target
        history = list(y_initial[:, :start].unbind(1))
        predictions = []
        for k in range(start, u.shape[1]):
            u_past = u[:, k - w.nk - w.nb + 1 : k - w.nk + 1]
            y_past = (
                torch.stack(history[k - w.na : k], 1)
                if w.na
                else y_initial.new_zeros(u.shape[0], 0, self.ny)
            )
            prediction = self(assemble(u_past, y_past, self.layout))
            history.append(prediction)
            predictions.append(prediction)
        return torch.stack(predictions, 1)

    def warm_start_from(self, previous: NarxModule) -> None:
        """Start from ``previous``, a fitted model of the same architecture whose inputs are
        this model's first ``previous.nu`` inputs (the loop adds effect channels at the end).

        Every weight is copied; the input weights of the new channels start at zero, so the
        model begins exactly where ``previous`` ended (nested models) and training only has to
        learn what the new channels add. Which entries are new is kept for
        `train_new_inputs_only`.
        """
        if (
            type(previous) is not type(self)
            or previous.window != self.window
            or (previous.ny != self.ny or previous.nu > self.nu)
        ):
            raise ConfigError(
                f"cannot warm-start a {type(self).__name__} (nu={self.nu}) from a "
                f"{type(previous).__name__} (nu={previous.nu}) with another window or outputs."
            )
        old = dict(previous.named_parameters())
        self._new_entries: dict[str, torch.Tensor] = {}
        with torch.no_grad():
            for name, new in self.named_parameters():
                before = old.get(name)
                if before is None and name in ("effect_weight", "input_weight"):
                    new.zero_()  # the linear effect path or input block is new: zero
                    self._new_entries[name] = torch.ones_like(new, dtype=torch.bool)
                elif before is None:
                    raise ConfigError(f"cannot warm-start: '{name}' is not in the fitted model.")
                elif before.shape == new.shape:
                    new.copy_(before)
                elif name == "input_weight" and before.shape[0] == new.shape[0]:
                    new.zero_()  # the new effect's channels come after the old ones
                    new[:, : before.shape[1]] = before
                    self._new_entries[name] = torch.ones_like(new, dtype=torch.bool)
                    self._new_entries[name][:, : before.shape[1]] = False
                elif (positions := self._old_input_positions(name, previous.nu)) is not None and (
                    before.dim() >= 2
                    and before.shape[1] == len(positions)
                    and (before.shape[0] == new.shape[0] and before.shape[2:] == new.shape[2:])
                ):
                    new.zero_()
                    new[:, positions] = before
                    is_new = torch.ones_like(new, dtype=torch.bool)
                    is_new[:, positions] = False
                    self._new_entries[name] = is_new
                else:
                    raise ConfigError(
                        f"cannot warm-start: '{name}' has shape {tuple(before.shape)} in the "
                        f"fitted model and {tuple(new.shape)} here."
                    )

    def train_new_inputs_only(self) -> None:
        """After `warm_start_from`: train only the weights of the new input channels (the
        added effect's operators); every other weight stays exactly as fitted, so a refit
        learns what the new operators add and nothing else moves (nested models)."""
        new_entries = self.new_entries
        if not new_entries:
            raise ConfigError(
                "train_new_inputs_only needs a warm start (warm_start_from) from a model with "
                "fewer inputs: there are no new input weights to train."
            )
        self._kept_values = {}
        for name, parameter in self.named_parameters():
            mask = new_entries.get(name)
            parameter.requires_grad_(mask is not None)
            if mask is not None:
                mask = mask.to(parameter.device)
                parameter.register_hook(lambda grad, m=mask: grad * m.to(grad.device))
                self._kept_values[name] = (parameter.detach().clone(), mask)

    @property
    def new_inputs_only(self) -> bool:
        """True after `train_new_inputs_only`."""
        return bool(self._kept_values)

    def _keep_old_entries(self) -> None:
        """After an optimiser step with `train_new_inputs_only`: put back the old entries of
        the partly trained tensors (their gradient is masked, but Adam's weight decay would
        still shrink them)."""
        if not (self.new_inputs_only and self.training_settings.weight_decay):
            return
        with torch.no_grad():
            parameters = dict(self.named_parameters())
            for name, (kept, mask) in self._kept_values.items():
                value = parameters[name]
                value.copy_(torch.where(mask.to(value.device), value, kept.to(value.device)))

    def _old_input_positions(self, name: str, old_nu: int) -> torch.Tensor | None:
        """Where each input column of parameter ``name`` of a model with ``old_nu`` inputs
        sits in this one's (a warm start copies them there; the rest are new)."""
        return torch.as_tensor(self._old_regressor_positions(old_nu))

    def _old_regressor_positions(self, old_nu: int) -> list[int]:
        """Where each regressor column of a model with ``old_nu`` inputs sits in this one's."""
        w, nu, ny = self.window, self.nu, self.ny
        if self.layout == "sequence":
            return list(range(old_nu)) + [nu + j for j in range(ny)]
        u_part = [lag * nu + ch for lag in range(w.nb) for ch in range(old_nu)]
        return u_part + [w.nb * nu + j for j in range(w.na * ny)]

    # ------------------------------------------------------------------ training
    @property
    def simulation_horizon(self) -> int:
        """Samples simulated per training segment; 0 when the objective is one-step."""
        return self.training_settings.simulation_horizon

    def _loss(self, batch: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
        """One-step loss on (regressors, target) windows, or in ``simulation_mode`` the
        free-run loss on (u, y) segments."""
        if self.simulation_mode:
            u, y = batch
            start = self.window.first_target
            return self.loss_fn(self.simulate_scaled(u, y), y[:, start:])
        x, target = batch
        return self.loss_fn(self(x), target)

    def training_step(self, batch: Any, batch_idx: int) -> torch.Tensor | None:
        """One optimiser step per batch of ``batch``: a batch, or a block of batches
        (`hysteresis_lab.data.blocks`: Lightning's fixed cost per step is then paid once per
        block). Optimisation is manual (`automatic_optimization` is False) for that; the
        order per batch is Lightning's own: loss, zero_grad, backward, clipping, step."""
        optimizer = self.optimizers()
        direct = self._direct_steps(optimizer)
        block_sum, block_rows = 0.0, 0
        for part in batches_of(batch):
            loss = self._loss(part)
            value = float(loss.detach())  # one read: the finiteness test and the epoch mean
            if not math.isfinite(value):
                # a diverging free run (or a bad step) must not update the weights: skip it
                self._skipped_batches += 1
                self._on_non_finite_loss(optimizer)
                continue
            self._on_finite_loss()
            optimizer.zero_grad()
            if direct:
                loss.backward()
            else:
                self.manual_backward(loss)
            if self.gradient_clipping is not None:
                clip, algorithm = self.gradient_clipping
                self.clip_gradients(optimizer, gradient_clip_val=clip,
                                    gradient_clip_algorithm=algorithm)
            if direct:  # the torch step between the bookkeeping Lightning's step does
                optimizer._on_before_step()
                optimizer.optimizer.step()
                optimizer._on_after_step()  # counts the step (trainer.global_step)
            else:
                optimizer.step()
            self._keep_old_entries()
            # The epoch's batch-size-weighted mean, logged once in `on_train_epoch_end`: a
            # `self.log` per step costs Lightning about as much as a small network's own step.
            size = part[0].shape[0]
            block_sum += value * size
            block_rows += size
        if not block_rows:
            return None
        self._train_loss_sum += block_sum
        self._train_loss_count += block_rows
        return torch.tensor(block_sum / block_rows)

    def _on_finite_loss(self) -> None:
        """Called before the step on a batch whose loss is finite (subclasses remember the
        weights that gave it)."""

    def _on_non_finite_loss(self, optimizer: Any) -> None:
        """Called on a batch whose loss is not finite, which is skipped (subclasses may take
        the last step back)."""

    def _direct_steps(self, optimizer: Any) -> bool:
        """May backward and the optimiser step skip Lightning's wrappers? Yes where those
        would only call hooks nobody overrides: plain float32 precision on one device, and no
        callback or module hook around backward or the optimiser step. Lightning's wrappers
        cost ~0.3 ms a step, as much as a small network's step itself."""
        trainer = self.trainer
        if type(trainer.precision_plugin) is not Precision or not isinstance(
            trainer.strategy, SingleDeviceStrategy
        ):
            return False
        if not all(hasattr(optimizer, name) for name in _STEP_BOOKKEEPING):
            return False
        if any(getattr(type(self), hook) is not getattr(L.LightningModule, hook)
               for hook in (*_STEP_HOOKS, "backward", "optimizer_step")):
            return False
        return all(getattr(type(callback), hook) is getattr(L.Callback, hook)
                   for callback in trainer.callbacks for hook in _STEP_HOOKS)

    def on_train_epoch_start(self) -> None:
        self._train_loss_sum = 0.0
        self._train_loss_count = 0
        self._skipped_batches = 0

    def on_train_epoch_end(self) -> None:
        if self._skipped_batches and not self._train_loss_count:
            raise DivergedError(
                f"every batch of epoch {self.current_epoch} gave a non-finite loss "
                f"({'free-run' if self.simulation_mode else 'one-step'} error): the model "
                "diverged. Fix: a smaller training.lr (or training.simulation_lr), a shorter "
                "training.horizon, or trainer.gradient_clip_val=0.5."
            )
        if self._skipped_batches:
            log.warning(
                "epoch %d: %d batch(es) with a non-finite loss were skipped",
                self.current_epoch, self._skipped_batches,
            )
        if self._train_loss_count:
            mean = self._train_loss_sum / self._train_loss_count
            self.log("train_loss", mean, on_step=False, on_epoch=True, prog_bar=True)
        self._step_schedulers()

    def _step_schedulers(self) -> None:
        """Step the epoch-interval learning-rate schedulers (manual optimisation leaves that
        to the module) where Lightning would: after the epoch's validation; a plateau
        scheduler reads ``val_loss``."""
        schedulers = self.lr_schedulers()
        for scheduler in schedulers if isinstance(schedulers, list) else [schedulers]:
            if scheduler is None:
                continue
            if isinstance(scheduler, torch.optim.lr_scheduler.ReduceLROnPlateau):
                metric = self.trainer.callback_metrics.get("val_loss")
                if metric is not None:
                    scheduler.step(metric)
            else:
                scheduler.step()

    def validation_step(self, batch: Any, batch_idx: int) -> torch.Tensor:
        """The loss of a batch, or the rows-weighted mean loss of a block of batches (the
        epoch's ``val_loss`` is the same weighted mean over every validation window)."""
        total, rows = None, 0
        for part in batches_of(batch):
            size = part[0].shape[0]
            weighted = self._loss(part) * size
            total = weighted if total is None else total + weighted
            rows += size
        loss = total / rows
        self.log("val_loss", loss, on_step=False, on_epoch=True, prog_bar=True, batch_size=rows)
        return loss

    #: in a whole refit after `warm_start_from`, the rate of the wholly new parameters (an
    #: added block's, from no effect) over the rest's (1: the same)
    new_block_lr_factor = 1.0

    def _parameter_groups(self, lr: float) -> list[dict[str, Any]]:
        """The trainable parameters; in a whole refit (warm-started, not new-inputs-only)
        the new ones at `new_block_lr_factor` times ``lr``."""
        new = self.new_entries or {}
        named = [(n, p) for n, p in self.named_parameters() if p.requires_grad]
        if not new or self.new_inputs_only or self.new_block_lr_factor == 1.0:
            return [{"params": [p for _, p in named], "lr": lr}]
        groups = [{"params": [p for n, p in named if n not in new], "lr": lr},
                  {"params": [p for n, p in named if n in new],
                   "lr": lr * self.new_block_lr_factor}]
        return [g for g in groups if g["params"]]

    def configure_optimizers(self) -> Any:
        settings = self.training_settings
        lr = self.stage_lr or settings.lr
        optimizer = torch.optim.Adam(self._parameter_groups(lr), lr=lr,
                                     weight_decay=settings.weight_decay)
        schedule = settings.lr_schedule
        if schedule == "cosine":
            epochs = max(1, int(self.trainer.max_epochs or 1))
            scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(
                optimizer, T_max=epochs, eta_min=lr * 0.01
            )
            return {
                "optimizer": optimizer,
                "lr_scheduler": {"scheduler": scheduler, "interval": "epoch"},
            }
        if schedule == "plateau":
            scheduler = torch.optim.lr_scheduler.ReduceLROnPlateau(
                optimizer, factor=0.5, patience=5
            )
            # manual optimisation: `_step_schedulers` steps it on val_loss (a "monitor" key
            # would only earn Lightning's warning that it is ignored)
            monitor = {"monitor": "val_loss"} if self.automatic_optimization else {}
            return {
                "optimizer": optimizer,
                "lr_scheduler": {"scheduler": scheduler, **monitor},
            }
        return optimizer


def batches_of(batch: Any) -> list[Any]:
    """The batches of a loader item: a batch ``(x, target)`` alone, or a block of them."""
    return [batch] if isinstance(batch[0], torch.Tensor) else list(batch)


def mlp(n_in: int, n_out: int, hidden: int, n_hidden_layers: int) -> nn.Sequential:
    """``n_hidden_layers`` ReLU layers of width ``hidden``, then a linear output layer."""
    layers: list[nn.Module] = []
    width = n_in
    for _ in range(n_hidden_layers):
        layers += [nn.Linear(width, hidden), nn.ReLU()]
        width = hidden
    layers.append(nn.Linear(width, n_out))
    return nn.Sequential(*layers)
