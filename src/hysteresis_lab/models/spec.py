"""`ModelSpec`: a ``model`` config as an object, built once where a run starts.

The ``model`` config is a registered name plus that architecture's settings, which differ
from model to model (``conf/model/<name>.yaml``). `ModelSpec.from_config` checks the name,
looks the class up in the registry once and keeps the settings apart, so everything below
the application boundary reads ``spec.cls``, ``spec.layout``, ``spec.is_network`` and
``spec.effects`` instead of probing a dict and the registry again.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import lightning as L

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.registry import get_model_class


@dataclass(frozen=True)
class ModelSpec:
    """A model config: its registered ``name``, the class registered under it and its
    ``settings`` (every other key of the config)."""

    name: str
    cls: type
    settings: Mapping[str, Any]

    @classmethod
    def from_config(cls, model_cfg: Mapping[str, Any] | ModelSpec) -> ModelSpec:
        """The spec of a ``model`` config (a plain mapping with ``name``); a spec as is.
        An unknown name is refused here, with the registered ones."""
        if isinstance(model_cfg, ModelSpec):
            return model_cfg
        name = model_cfg.get("name")
        if not name:
            raise ConfigError("the model config has no 'name'. Fix: choose one with model=<name>.")
        settings = {str(k): v for k, v in model_cfg.items() if k != "name"}
        return cls(str(name), get_model_class(str(name)), settings)

    @property
    def layout(self) -> str:
        """The regressor layout the model reads ("flat" or "sequence")."""
        return str(self.cls.layout)

    @property
    def is_network(self) -> bool:
        """Whether it trains with Lightning (and the ``trainer`` config)."""
        return issubclass(self.cls, L.LightningModule)

    @property
    def effects(self) -> list[str]:
        """The catalogue effects it declares (``model.effects``)."""
        return [str(e) for e in (self.settings.get("effects") or [])]

    def to_config(self) -> dict[str, Any]:
        """The config it came from: ``{"name": ..., **settings}``."""
        return {"name": self.name, **self.settings}
