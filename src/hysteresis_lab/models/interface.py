"""The model interface: what the pipeline needs from a registered model class.

Every architecture, built-in or plugin, is one of two kinds:

* `NetworkModel`: a Lightning network that `hysteresis_lab.training` fits (one-step and
  free-run stages, warm starts of the loop). Subclassing `NarxModule` gives all of it.
* `EstimatorModel`: a model fitted in one call on the scaled regression windows (the SVM).

Both implement `SystemModel`: built by `hysteresis_lab.training.build_model` as
``cls(nu=, ny=, na=, nb=, nk=, scaler=, **settings)``, they state their regressor ``layout``
and keep their ``window``, channel counts and settings (``hparams``) for evaluation and saving.

The model registry checks a class against its kind when its entry point is loaded
(`check_model_class`): a method or class attribute it lacks is named in the error. Instance
attributes (``window``, ``nu``, ``ny``, ``hparams``, ...) are set by ``__init__`` and cannot
be checked before a model exists. Optional capabilities the evaluation uses when present
(``free_run_kernel``, ``free_run_split``, ``simulate_recordings``) are described in
`hysteresis_lab.evaluation.predict`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar, Protocol, runtime_checkable

import lightning as L
import numpy as np

from hysteresis_lab.data.scaling import Scaler
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.settings import TrainingSettings


@runtime_checkable
class SystemModel(Protocol):
    """What every registered model offers."""

    #: the regressor layout it reads: "flat" or "sequence"
    layout: ClassVar[str]
    #: the name it is registered under (set on the class by the registry when it loads)
    registry_name: str
    window: WindowSpec
    nu: int
    ny: int
    #: its settings, as saved with it (``trained_on``: the training data's rate and units)
    hparams: Mapping[str, Any]

    def predict_physical(self, u_past: Any, y_past: Any) -> Any:
        """Physical input lags (B, nb, nu) and output lags (B, na, ny) -> next output (B, ny)."""
        ...


@runtime_checkable
class EstimatorModel(SystemModel, Protocol):
    """A model fitted in one call on scaled windows (`hysteresis_lab.models.svm.SVMModel`)."""

    scaler: Scaler

    def fit(self, x: np.ndarray, target: np.ndarray) -> Any:
        """Fit on scaled regressors ``x`` and scaled next outputs ``target``."""
        ...

    def predict_scaled(self, x: np.ndarray) -> np.ndarray:
        """Scaled regressors -> scaled next outputs (N, ny)."""
        ...


@runtime_checkable
class NetworkModel(SystemModel, Protocol):
    """A Lightning network that `hysteresis_lab.training` fits (`NarxModule` and subclasses)."""

    #: True for models built to train on the free-run error alone (no one-step stage)
    simulation_trained: ClassVar[bool]
    #: set by training while it trains on free-run segments
    simulation_mode: bool
    #: the learning rate of the running training stage, set by training
    stage_lr: float | None

    @property
    def training_settings(self) -> TrainingSettings:
        """How it trains: optimiser, schedule, objective and each stage's learning rate."""
        ...

    @property
    def simulation_horizon(self) -> int:
        """Samples simulated per training segment; 0 when the objective is one-step."""
        ...

    def warm_start_from(self, previous: Any) -> None:
        """Start from a fitted model of the same kind with fewer inputs (the loop's refit)."""
        ...

    def train_new_inputs_only(self) -> None:
        """After `warm_start_from`: train only the new input channels' weights."""
        ...


def expected_interface(cls: type) -> type:
    """The interface a model class must implement: `NetworkModel` for a Lightning module,
    else `EstimatorModel`."""
    return NetworkModel if issubclass(cls, L.LightningModule) else EstimatorModel


def missing_members(cls: type, interface: type) -> list[str]:
    """The methods, properties and class attributes of ``interface`` that ``cls`` lacks."""
    return sorted(name for name in class_members(interface) if not hasattr(cls, name))


def class_members(interface: type) -> set[str]:
    """Members of a protocol that a class itself must have: its methods and properties and
    the attributes it declares ``ClassVar`` (instance attributes come with ``__init__``)."""
    names: set[str] = set()
    for klass in interface.__mro__:
        if not getattr(klass, "_is_protocol", False) or klass is Protocol:
            continue
        for name, value in vars(klass).items():
            if not name.startswith("_") and (callable(value) or isinstance(value, property)):
                names.add(name)
        for name, annotation in vars(klass).get("__annotations__", {}).items():
            if str(annotation).startswith(("ClassVar", "typing.ClassVar")):
                names.add(name)
    return names


def check_model_class(cls: Any, name: str, source: str) -> None:
    """Raise `ConfigError` unless ``cls`` (registered as ``name`` by ``source``, the entry
    point) is a class implementing its kind of model interface; the error names every
    member it lacks."""
    if not isinstance(cls, type):
        raise ConfigError(
            f"model '{name}' is registered by {source} as {cls!r}, which is not a class. Fix: "
            "point the 'hysteresis_lab.models' entry point at the model class."
        )
    interface = expected_interface(cls)
    missing = missing_members(cls, interface)
    if missing:
        raise ConfigError(
            f"model '{name}' ({cls.__module__}.{cls.__qualname__}, registered by {source}) "
            f"does not implement hysteresis_lab's {interface.__name__} interface: it lacks "
            f"{', '.join(missing)}. Fix: add {'it' if len(missing) == 1 else 'them'} to the "
            "class (subclassing hysteresis_lab.models.base.NarxModule gives a network all of "
            "them; see hysteresis_lab.models.interface)."
        )
