"""The model contract: what the pipeline needs from a registered model class.

Every architecture, built-in or plugin, subclasses `ModelContract`, the one place that
declares the optional capabilities the evaluation, training, the loop and growing use, each
with its default (a model without a capability behaves as the default says): a compiled
free run (`ModelContract.free_run_kernel`), its own simulation of whole recordings, the
refit variants and growth stages of the loop, the effects it carries, starting values from
the data, the warm start's bookkeeping (`ModelContract.new_entries`) and ONNX export.

Beyond that, a model is one of two kinds, each a protocol of the members it must have:

* `NetworkModel`: a Lightning network that `hysteresis_lab.fitting` fits (one-step and
  free-run stages, warm starts of the loop). Subclassing `NarxModule` gives all of it.
* `EstimatorModel`: a model fitted in one call on the scaled regression windows (the SVM).

Both implement `SystemModel`: built by `hysteresis_lab.fitting.build_model` as
``cls(nu=, ny=, na=, nb=, nk=, scaler=, **settings)`` (the shared ones grouped by
`hysteresis_lab.models.settings.ModelSettings`), they state their regressor ``layout`` and
keep their ``window``, channel counts and settings (``hparams``) for evaluation and saving.

The model registry checks a class when its entry point is loaded (`check_model_class`): it
must subclass `ModelContract`, and a member of its kind's protocol it lacks is named in the
error. Instance attributes (``window``, ``nu``, ``ny``, ``hparams``, ...) are set by
``__init__`` and cannot be checked before a model exists.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

import lightning as L
import numpy as np
import torch

from hysteresis_lab.data.scaling import Scaler
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.settings import TRAINING_SETTINGS, TrainingSettings

if TYPE_CHECKING:
    from hysteresis_lab.data.recording import Recording
    from hysteresis_lab.kernels.interface import FreeRunKernel

#: a growth stage: its label, the model settings it trains with, the effect it adds (None:
#: the first stage)
GrowthStage = tuple[str, dict[str, Any], "str | None"]


class ModelContract:
    """The base of every registered model: its optional capabilities, each with the default
    a model that does not offer it gets. Subclasses override what they offer."""

    #: the regressor layout it reads: "flat" or "sequence"
    layout: ClassVar[str] = "flat"
    #: the name it is registered under (set on the class by the registry when it loads)
    registry_name: ClassVar[str] = ""
    #: True for a Lightning network that `hysteresis_lab.fitting` trains (and the
    #: ``trainer`` and ``training`` configs apply to); False for a model fitted in one call
    is_network: ClassVar[bool] = False
    #: the catalogue effects the model can take in ``effects`` (None: every effect whose
    #: operators reach it through its inputs, none that acts on its output)
    carried_effects: ClassVar[tuple[str, ...] | None] = None
    #: carried effects that change what the fitted dynamics were fitted to: a block taking a
    #: share of the large-signal gain off what they see (a dead zone: the gain the fit lowered
    #: to meet it must come back) or one inside their feedback (a restoring force changes the
    #: loop they sit in). A loop refit adding one trains the whole model
    whole_refit_effects: ClassVar[tuple[str, ...]] = ()
    #: True for models built to train on the free-run error alone (no one-step stage)
    simulation_trained: ClassVar[bool] = False
    #: False for a model that does not read measured outputs: its one-step prediction is
    #: its free run
    predicts_from_outputs: ClassVar[bool] = True
    #: True for a model that trains on whole recordings simulated from rest (not segments)
    whole_recordings: ClassVar[bool] = False
    #: True for a model that can start from a fitted model with fewer inputs or blocks
    #: (`warm_start_from`); the loop then refits it instead of training it afresh
    warm_starts: ClassVar[bool] = False
    #: the fitted model whose free run it reads as extra inputs (`hysteresis_lab.models.
    #: baseline`), saved with it; None: none
    baseline: Any = None

    # ------------------------------------------------------------------ settings
    @classmethod
    def settings_keys(cls) -> set[str]:
        """Every keyword its constructor takes (the ``model`` config's keys, the training
        settings of a network and what the data give), following ``**kwargs`` up the class
        hierarchy; a class whose constructor passes ``**kwargs`` on to the shared settings
        (`hysteresis_lab.models.settings.ModelSettings`) takes theirs too."""
        names: set[str] = set()
        for klass in cls.__mro__:
            init = klass.__dict__.get("__init__")
            if init is None:
                continue
            params = inspect.signature(init).parameters.values()
            names |= {p.name for p in params if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
            if not any(p.kind == p.VAR_KEYWORD for p in params):
                break
            if klass.__dict__.get("shared_settings"):
                names |= set(klass.__dict__["shared_settings"])
                break
        return names - {"self"}

    @classmethod
    def training_defaults(cls) -> dict[str, Any]:
        """The training settings its constructor defaults to (`TrainingSettings`' own where
        the class does not set one: ``lr=0.02`` for the grey-box, 1e-3 for a network); empty
        for a model that is no network."""
        if not cls.is_network:
            return {}
        defaults: dict[str, Any] = {}
        for klass in cls.__mro__:
            init = klass.__dict__.get("__init__")
            if init is None:
                continue
            params = inspect.signature(init).parameters.values()
            for p in params:
                if p.name in TRAINING_SETTINGS and p.default is not p.empty:
                    defaults.setdefault(p.name, p.default)
            if not any(p.kind == p.VAR_KEYWORD for p in params):
                break
        return {**TrainingSettings().to_dict(), **defaults}

    @classmethod
    def built_in_effects(cls, settings: Mapping[str, Any]) -> tuple[str, ...]:
        """Catalogue effects the structure holds whatever ``effects`` declares (a grey-box's
        hysteresis cell), given the model config's ``settings``: the loop's diagnosis counts
        them as held and never adds them. Default: none."""
        return ()

    @classmethod
    def refit_variants(cls, model_cfg: dict[str, Any], previous: Any | None,
                       added: str | None) -> list[dict[str, Any]]:
        """The model settings a loop round that adds ``added`` to ``previous`` fits, each a
        candidate the held-out loss chooses among (e.g. where a law sits). Default: one, the
        round's settings as they are (``[{}]``)."""
        return [{}]

    @classmethod
    def growth_stages(cls, settings: Mapping[str, Any]) -> list[GrowthStage]:
        """The stages a model declared with ``settings`` grows through, the way the loop
        grows one (`hysteresis_lab.workflows.grow`), each ``(label, settings, added
        effect)``. Default: one stage, the model as declared."""
        return [("declared", dict(settings), None)]

    # ------------------------------------------------------------------ training
    def initialise_from_recordings(self, recordings: Sequence[Recording]) -> None:
        """Starting values read off the training ``recordings`` before training. Default:
        `initialise_from_data` on the longest recording's first input and output."""
        longest = max(recordings, key=lambda rec: rec.n_samples)
        self.initialise_from_data(longest.u[:, 0], longest.y[:, 0], longest.fs)

    def initialise_from_data(self, u: np.ndarray, y: np.ndarray, fs: float) -> None:
        """Starting values from one input ``u`` and output ``y`` sampled at ``fs``. Default:
        none (the constructor's)."""

    @property
    def new_entries(self) -> dict[str, torch.Tensor] | None:
        """The warm start's bookkeeping: after `warm_start_from`, a mask per parameter that
        holds new entries (True where new: the added effect's weights), what
        `train_new_inputs_only` trains; ``{}`` for a warm start that added nothing; None for
        a model that was not warm-started (it trains from the data's starting values)."""
        return vars(self).get("_new_entries")

    @property
    def warm_started(self) -> bool:
        """Whether it started from a fitted model (`warm_start_from`): a refit, whose
        starting values stay and whose learning rate is the refit's."""
        return self.new_entries is not None

    def warm_start_from(self, previous: Any) -> None:
        """Start from a fitted model of the same kind with fewer inputs or blocks (the
        loop's refit); records the new entries (`new_entries`). Default: refused."""
        raise ConfigError(
            f"{type(self).__name__} cannot start from a fitted model. Fix: loop.warm_start=false "
            "(each round trains afresh)."
        )

    def train_new_inputs_only(self) -> None:
        """After `warm_start_from`: train only the new entries. Default: refused."""
        raise ConfigError(
            f"{type(self).__name__} cannot train only new inputs. Fix: loop.refit=full."
        )

    # ------------------------------------------------------------------ evaluation
    def free_run_kernel(self, u_scaled: np.ndarray, window: WindowSpec) -> FreeRunKernel | None:
        """A fast free-run step over the scaled inputs (`hysteresis_lab.kernels.interface.
        FreeRunKernel`; NumPy or compiled), or None: the evaluation steps the model itself.
        Default: None."""
        return None

    def free_run_split(self, u_scaled: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """For free-run simulation: the inputs its free-run step sees and an input-only term
        added to every predicted sample (B, N, ny), or None. Default: the inputs, no term."""
        return u_scaled, None

    def simulate_recordings(
        self, u: np.ndarray, y_meas: np.ndarray, reset: np.ndarray, window: WindowSpec,
        lengths: np.ndarray | None = None,
    ) -> np.ndarray:
        """The free run of every row of scaled inputs ``u`` by the model's own state (a
        state-space or physical model), restarted where ``reset`` says; offered where
        `simulates_recordings` is True. Default: not offered."""
        raise NotImplementedError(f"{type(self).__name__} does not simulate recordings itself")

    def free_run_from_estimated_start(
        self, u_scaled: np.ndarray, y_scaled: np.ndarray, first: int, n_skip: int
    ) -> np.ndarray | None:
        """For ``evaluation.initial_state=estimate``: the free run (scaled, (T, ny)) of one
        recording of scaled inputs (T, nu) and outputs (T, ny) from the state and output
        offset its samples ``first .. n_skip - 1`` show (a physical model's own state), or
        None: the evaluation shifts the free run by the offset alone (a NARX model or SUBNET
        already reads its first lags, or its encoder's, from the recording). Default: None."""
        return None

    @property
    def simulates_recordings(self) -> bool:
        """True where the class runs its own free run (`simulate_recordings`) instead of the
        evaluation's step-by-step loop."""
        return type(self).simulate_recordings is not ModelContract.simulate_recordings

    @property
    def device(self) -> torch.device:
        """Where it computes (a network: where its weights are). Default: the CPU."""
        return torch.device("cpu")

    def export_onnx(self, path: Path | str, opset: int = 17) -> Path:
        """Write the model to ONNX in physical units (`hysteresis_lab.models.export`).
        Default: refused."""
        raise ConfigError(
            f"ONNX export covers the networks; {type(self).__name__} cannot be exported. Fix: "
            "export a network model (ffnn, lstm, cnn, subnet, linear, greybox)."
        )



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
    """A Lightning network that `hysteresis_lab.fitting` fits (`NarxModule` and subclasses)."""

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
    if not missing and not issubclass(cls, ModelContract):
        raise ConfigError(
            f"model '{name}' ({cls.__module__}.{cls.__qualname__}, registered by {source}) "
            "does not subclass hysteresis_lab.models.interface.ModelContract, which gives "
            "every model its optional capabilities with their defaults. Fix: subclass it "
            "(hysteresis_lab.models.base.NarxModule does, for a network)."
        )
    if missing:
        raise ConfigError(
            f"model '{name}' ({cls.__module__}.{cls.__qualname__}, registered by {source}) "
            f"does not implement hysteresis_lab's {interface.__name__} interface: it lacks "
            f"{', '.join(missing)}. Fix: add {'it' if len(missing) == 1 else 'them'} to the "
            "class (subclassing hysteresis_lab.models.base.NarxModule gives a network all of "
            "them; see hysteresis_lab.models.interface)."
        )
