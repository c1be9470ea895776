"""The settings a model is built with, grouped and checked once: what every model shares
(`ModelSettings`: channels, lags, scaling, declared effects and how they reach it, the
training data's record), and how a network trains (`TrainingSettings`, the ``training``
config).

Models take them as flat keyword arguments (the configs and saved checkpoints keep that
shape: ``cls(nu=, ny=, na=, ..., lr=, ...)``) and build these objects in their ``__init__``
(`ModelSettings.from_kwargs`, `TrainingSettings.from_kwargs`); the lists of names are here
only (`MODEL_SETTINGS`, `TRAINING_SETTINGS`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.effects.base import MODEL_OUTPUT_BLOCKS
from hysteresis_lab.effects.registry import check_effects, get_effect
from hysteresis_lab.errors import ConfigError

LR_SCHEDULES = ("cosine", "plateau", "none")
#: ``adam`` for every model; ``lbfgs`` (full-batch, a line search) for models that train on
#: whole recordings (`PhysicalChainModule`)
OPTIMIZERS = ("adam", "lbfgs")
OBJECTIVES = ("one_step", "simulation")
EFFECT_PATHS = ("network", "linear")

#: the training stages (`hysteresis_lab.fitting`): the one-step stage (or a whole fit),
#: the free-run error as the only objective, and free-run fine-tuning after a one-step stage
Stage = Literal["one_step", "simulation", "fine_tune"]


@dataclass(frozen=True)
class TrainingSettings:
    """Optimiser, schedule and objective of a network: the ``training`` config
    (``conf/training/default.yaml``; ``training.lr`` ... ``training.refit_lr``).

    ``optimizer``: ``adam``, or ``lbfgs`` (L-BFGS with a strong-Wolfe line search over whole
    recordings, for the physical models; ``lr`` and the schedule then do not apply);
    ``lr``: Adam's learning rate; ``lr_schedule``: cosine, plateau or none; ``objective``:
    ``one_step`` (the study's one-step error) or ``simulation`` (the free-run error over
    ``horizon`` samples); ``simulation_epochs``: with the simulation objective, a one-step
    stage first and then this many free-run epochs at ``simulation_lr`` (default a tenth of
    the rate); ``patience``: epochs without a better validation free-run loss before a
    free-run stage stops; ``refit_lr``: the rate of a warm-started refit (default a tenth).
    """

    optimizer: str = "adam"
    lr: float = 1e-3
    lr_schedule: str = "cosine"
    weight_decay: float = 0.0
    objective: str = "one_step"
    horizon: int = 200
    simulation_epochs: int | None = None
    simulation_lr: float | None = None
    patience: int | None = None
    refit_lr: float | None = None

    def __post_init__(self) -> None:
        if self.optimizer not in OPTIMIZERS:
            raise ConfigError(
                f"unknown optimizer '{self.optimizer}'. Fix: training.optimizer=one of "
                f"{list(OPTIMIZERS)} (lbfgs for model=greybox or model=linear only)."
            )
        if self.lr_schedule not in LR_SCHEDULES:
            raise ConfigError(
                f"unknown lr_schedule '{self.lr_schedule}'. Fix: training.lr_schedule=one of "
                f"{list(LR_SCHEDULES)}."
            )
        if not self.lr > 0:
            raise ConfigError(
                f"learning rate lr={self.lr} must be positive. Fix: training.lr=1e-3.")
        check_objective(self.objective, self.horizon, self.simulation_epochs, self.simulation_lr)
        if self.patience is not None and not self.patience >= 1:
            raise ConfigError(
                f"training.patience={self.patience!r} must be >= 1 epochs, or null (no early "
                "stopping)."
            )
        if self.refit_lr is not None and not self.refit_lr > 0:
            raise ConfigError(
                f"training.refit_lr must be positive or null (got {self.refit_lr}). Fix: e.g. "
                "training.refit_lr=1e-4, or null for lr / 10."
            )

    @classmethod
    def from_kwargs(cls, values: Mapping[str, Any]) -> TrainingSettings:
        """The settings among keyword arguments ``values`` (defaults for those missing)."""
        return cls(**{k: v for k, v in values.items() if k in TRAINING_SETTINGS})

    def to_dict(self) -> dict[str, Any]:
        """Every setting by name (the keyword arguments a network takes)."""
        return dataclasses.asdict(self)

    def with_changes(self, **changes: Any) -> TrainingSettings:
        """A copy with ``changes`` (checked as new settings are)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_hparams(cls, hparams: Mapping[str, Any]) -> TrainingSettings:
        """The settings saved in a model's ``hparams`` (defaults for those it lacks)."""
        names = cls.__dataclass_fields__
        return cls(**{k: v for k, v in hparams.items() if k in names})

    @property
    def simulation_horizon(self) -> int:
        """Samples simulated per training segment; 0 when the objective is one-step."""
        return int(self.horizon or 0) if self.objective == "simulation" else 0

    def stage_lr(self, stage: Stage, refit: bool = False) -> float:
        """The learning rate of a training ``stage``, decided here only: ``lr``, or for a
        warm-started refit ``refit_lr`` (default ``lr / 10``); the fine-tuning stage after a
        one-step stage runs at ``simulation_lr``, default a tenth of that."""
        lr = float(self.lr)
        if refit:
            lr = float(self.refit_lr or 0.1 * lr)
        if stage == "fine_tune":
            lr = float(self.simulation_lr or 0.1 * lr)
        return lr


@dataclass(frozen=True)
class EffectSettings:
    """Declared effects and where their channels enter (``model.effects``,
    ``model.effect_path``); ``feature_context``: the training data's effect context, which the
    pipeline supplies; ``n_base_inputs``: the measured inputs before the effect channels."""

    effects: tuple[str, ...] = ()
    feature_context: dict[str, Any] | None = None
    effect_path: str = "network"
    n_base_inputs: int | None = None
    #: channels of a baseline's free run after the effect channels
    #: (`hysteresis_lab.models.augment`)
    baseline_channels: int = 0

    def checked(self, nu: int) -> EffectSettings:
        """These settings, refused with a clear error unless they fit a model of ``nu``
        inputs."""
        check_effects(self.effects)
        if self.effects and self.feature_context is None:
            raise ConfigError(
                "a model with effects needs the feature_context of its training data. Fix: "
                "build it through hysteresis_lab.workflows.pipeline (hysteresis-lab-train), which "
                "supplies it."
            )
        if self.effect_path not in EFFECT_PATHS:
            raise ConfigError(
                f"unknown effect_path '{self.effect_path}'. Fix: model.effect_path=one of "
                f"{list(EFFECT_PATHS)}."
            )
        if self.n_base_inputs is not None and not 1 <= self.n_base_inputs <= nu:
            raise ConfigError(f"n_base_inputs={self.n_base_inputs} must lie in 1..nu={nu}.")
        return self


@dataclass(frozen=True)
class ModelSettings:
    """What every model is built with: ``nu`` inputs and ``ny`` outputs, its ``window``
    of lags (``na``, ``nb``, ``nk``), the ``scaler`` of its data (offsets and scales per
    channel, saved with it), its declared effects (`EffectSettings`) and ``trained_on``, what
    it keeps of its training data (sampling rate, units) to refuse data it cannot score."""

    nu: int
    ny: int
    window: WindowSpec = field(default_factory=lambda: WindowSpec(na=10, nb=10, nk=1))
    scaler: dict[str, Sequence[float]] | None = None
    effects: EffectSettings = field(default_factory=EffectSettings)
    trained_on: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        check_channels(self.nu, self.ny)

    @classmethod
    def from_kwargs(cls, nu: int, ny: int, values: Mapping[str, Any]) -> ModelSettings:
        """The settings among a model's keyword arguments ``values`` (`MODEL_SETTINGS`;
        defaults for those missing)."""
        window = WindowSpec(na=values.get("na", 10), nb=values.get("nb", 10),
                            nk=values.get("nk", 1))
        effects = EffectSettings(
            as_effect_names(values.get("effects", ())), values.get("feature_context"),
            values.get("effect_path", "network"), values.get("n_base_inputs"),
            int(values.get("baseline_channels", 0)),
        )
        return cls(nu, ny, window, values.get("scaler"), effects, values.get("trained_on"))

    def to_kwargs(self) -> dict[str, Any]:
        """The flat keyword arguments (and saved ``hparams``) these settings came from."""
        w, e = self.window, self.effects
        return {"nu": self.nu, "ny": self.ny, "na": w.na, "nb": w.nb, "nk": w.nk,
                "scaler": self.scaler, "effects": list(e.effects),
                "feature_context": e.feature_context, "effect_path": e.effect_path,
                "n_base_inputs": e.n_base_inputs, "baseline_channels": e.baseline_channels,
                "trained_on": self.trained_on}


#: the training settings' names (`TrainingSettings`): the ``training`` config's keys
TRAINING_SETTINGS = tuple(f.name for f in dataclasses.fields(TrainingSettings))
#: the shared model settings' names besides ``nu`` and ``ny`` (`ModelSettings.from_kwargs`)
MODEL_SETTINGS = ("na", "nb", "nk", "scaler", "effects", "feature_context", "effect_path",
                  "n_base_inputs", "baseline_channels", "trained_on")


def unknown_settings(values: Mapping[str, Any], known: Sequence[str], owner: str) -> None:
    """Refuse keyword arguments ``values`` not among ``known`` (as Python refuses an
    unexpected keyword argument)."""
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise TypeError(f"{owner}.__init__() got unexpected keyword argument(s) {unknown}")


def check_channels(nu: int, ny: int) -> None:
    """Refuse a model without inputs or outputs."""
    if nu < 1 or ny < 1:
        raise ConfigError(
            f"a model needs nu >= 1 and ny >= 1 (got nu={nu}, ny={ny}). Fix: give the data "
            "at least one input and one output column."
        )


def check_objective(
    objective: str, horizon: int, simulation_epochs: int | None, simulation_lr: float | None
) -> None:
    """Refuse training-objective settings that cannot train (see
    `hysteresis_lab.models.base`)."""
    if objective not in OBJECTIVES:
        raise ConfigError(
            f"unknown training.objective '{objective}'. Fix: training.objective=one of "
            f"{list(OBJECTIVES)} (simulation: the free-run error, our recommendation)."
        )
    bad = []
    if objective == "simulation" and not (isinstance(horizon, int) and horizon >= 1):
        bad.append(f"horizon={horizon!r} (a whole number >= 1)")
    if simulation_epochs is not None and not simulation_epochs >= 1:
        bad.append(f"simulation_epochs={simulation_epochs!r} (>= 1, or null)")
    if simulation_lr is not None and not simulation_lr > 0:
        bad.append(f"simulation_lr={simulation_lr!r} (> 0, or null)")
    if bad:
        raise ConfigError(
            f"simulation-error training settings out of range: {', '.join(bad)}. Fix: e.g. "
            "training.objective=simulation training.horizon=200 training.simulation_epochs=null."
        )


def as_effect_names(effects: Sequence[str]) -> tuple[str, ...]:
    """``effects`` as a tuple of names (a Hydra ListConfig or list in, a tuple out)."""
    return tuple(str(name) for name in effects)


def refuse_output_effects(effects: Sequence[str], model_class: str) -> None:
    """Refuse effects that act on the model's own output (``block = "output"``, after the
    dynamics, or ``"feedback"``, inside them): a network has no channel for them, and
    dropping them silently would train a model without what was declared."""
    on_output = {name: get_effect(name).block for name in effects
                 if get_effect(name).block in MODEL_OUTPUT_BLOCKS}
    if on_output:
        blocks = " and ".join(repr(b) for b in sorted(set(on_output.values())))
        raise ConfigError(
            f"effects {list(on_output)} act in the model's {blocks} block, which "
            f"{model_class} does not have (it has no channel for them). Fix: model=linear "
            "carries them, or leave them out of model.effects.")
