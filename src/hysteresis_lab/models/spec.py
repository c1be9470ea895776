"""`ModelSpec`: a ``model`` config as an object, built once where a run starts.

The ``model`` config is a registered name plus that architecture's settings, which differ
from model to model (``conf/model/<name>.yaml``). `ModelSpec.from_config` checks the name,
looks the class up in the registry once and keeps the settings apart, so everything below
the application boundary reads ``spec.cls``, ``spec.layout``, ``spec.is_network`` and
``spec.effects`` instead of probing a dict and the registry again.

How a network trains is not the model's config but the ``training`` config
(`TrainingSettings`, ``conf/training/default.yaml``); `ModelSpec.training_settings` joins
the model class's own defaults with it. Training settings still given under ``model``
(``model.lr=...``, the keys before the ``training`` group) are taken out of the model's
settings, with one deprecation warning each naming the new key, and take effect as before.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.registry import get_model_class
from hysteresis_lab.models.settings import TRAINING_SETTINGS, TrainingSettings

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ModelSpec:
    """A model config: its registered ``name``, the class registered under it, its
    ``settings`` (every other key of the config) and ``legacy_training``: training settings
    the config still gave under ``model`` (deprecated; they win over the ``training``
    config, as an explicit ``model.*`` override did)."""

    name: str
    cls: type
    settings: Mapping[str, Any]
    legacy_training: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_config(cls, model_cfg: Mapping[str, Any]) -> ModelSpec:
        """The spec of a ``model`` config (a plain mapping with ``name``). An unknown name is
        refused here, with the registered ones."""
        name = model_cfg.get("name")
        if not name:
            raise ConfigError("the model config has no 'name'. Fix: choose one with model=<name>.")
        settings = {str(k): v for k, v in model_cfg.items() if k != "name"}
        legacy = {k: settings.pop(k) for k in list(settings) if k in TRAINING_SETTINGS}
        for key, value in legacy.items():
            log.warning("model.%s is deprecated: training settings have their own group. "
                        "Fix: training.%s=%s", key, key, value)
        return cls(str(name), get_model_class(str(name)), settings, legacy)

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        """Pickled by name (a paper worker's process): the class is looked up in that
        process's registry again, which names it (``registry_name``) there too."""
        return _registered, (self.name, dict(self.settings), dict(self.legacy_training))

    @property
    def layout(self) -> str:
        """The regressor layout the model reads ("flat" or "sequence")."""
        return str(self.cls.layout)

    @property
    def is_network(self) -> bool:
        """Whether it trains with Lightning (and the ``trainer`` and ``training`` configs)."""
        return bool(self.cls.is_network)

    @property
    def effects(self) -> list[str]:
        """The catalogue effects it declares (``model.effects``)."""
        return [str(e) for e in (self.settings.get("effects") or [])]

    def with_settings(self, settings: Mapping[str, Any]) -> ModelSpec:
        """The same model class with other ``settings`` (a loop round's, a growth stage's)."""
        return ModelSpec(self.name, self.cls, dict(settings), self.legacy_training)

    def training_settings(self, training_cfg: Mapping[str, Any] | None = None) -> TrainingSettings:
        """How the model trains: its class's defaults (`ModelContract.training_defaults`),
        then the set (non-null) values of the ``training`` config, then the deprecated
        ``model.*`` ones. An unknown key of ``training_cfg`` is refused."""
        given = dict(training_cfg or {})
        unknown = sorted(set(given) - set(TRAINING_SETTINGS))
        if unknown:
            raise ConfigError(
                f"unknown training setting(s) {unknown}. Valid: {list(TRAINING_SETTINGS)}. "
                "Fix: correct the training.* override."
            )
        chosen = {k: v for k, v in given.items() if v is not None}
        return TrainingSettings(
            **{**self.cls.training_defaults(), **chosen, **self.legacy_training})

    def to_config(self) -> dict[str, Any]:
        """The model config (``{"name": ..., **settings}``), without training settings."""
        return {"name": self.name, **self.settings}


def _registered(name: str, settings: dict[str, Any], legacy: dict[str, Any]) -> ModelSpec:
    """A spec unpickled: its class from the registry (`ModelSpec.__reduce__`)."""
    return ModelSpec(name, get_model_class(name), settings, legacy)
