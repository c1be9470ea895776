"""The settings of a network model, grouped and checked once: how it trains
(`TrainingSettings`) and how declared effects reach it (`EffectSettings`).

`hysteresis_lab.models.base.NarxModule` takes them as flat keyword arguments (the ``model``
config and saved checkpoints keep that shape) and builds these objects in its ``__init__``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from hysteresis_lab.effects.base import MODEL_OUTPUT_BLOCKS
from hysteresis_lab.effects.registry import check_effects, get_effect
from hysteresis_lab.errors import ConfigError

LR_SCHEDULES = ("cosine", "plateau", "none")
OBJECTIVES = ("one_step", "simulation")
EFFECT_PATHS = ("network", "linear")

#: the training stages (`hysteresis_lab.training`): the one-step stage (or a whole fit),
#: the free-run error as the only objective, and free-run fine-tuning after a one-step stage
Stage = Literal["one_step", "simulation", "fine_tune"]


@dataclass(frozen=True)
class TrainingSettings:
    """Optimiser, schedule and objective of a network (``model.lr`` ... ``model.refit_lr``)."""

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
        if self.lr_schedule not in LR_SCHEDULES:
            raise ConfigError(
                f"unknown lr_schedule '{self.lr_schedule}'. Fix: model.lr_schedule=one of "
                f"{list(LR_SCHEDULES)}."
            )
        if not self.lr > 0:
            raise ConfigError(f"learning rate lr={self.lr} must be positive. Fix: model.lr=1e-3.")
        check_objective(self.objective, self.horizon, self.simulation_epochs, self.simulation_lr)
        if self.patience is not None and not self.patience >= 1:
            raise ConfigError(
                f"model.patience={self.patience!r} must be >= 1 epochs, or null (no early "
                "stopping)."
            )
        if self.refit_lr is not None and not self.refit_lr > 0:
            raise ConfigError(
                f"model.refit_lr must be positive or null (got {self.refit_lr}). Fix: e.g. "
                "model.refit_lr=1e-4, or null for lr / 10."
            )

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
            f"unknown model.objective '{objective}'. Fix: model.objective=one of "
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
            "model.objective=simulation model.horizon=200 model.simulation_epochs=null."
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
