"""`DataSpec`: a ``data`` config as an object, built once where a run starts.

The ``data`` config (``conf/data/<name>.yaml``) is a Hydra ``_target_`` node that loads the
data set (``splits``) beside the settings of the windows, scaling, batching and the loop's
diagnosis. `DataSpec.from_config` resolves it once and reads those settings into typed
fields (the window checked), so everything below the application boundary reads
``spec.window``, ``spec.scaling``, ``spec.batch_size``… instead of indexing a dict; the
``splits`` node is instantiated from it by `hysteresis_lab.data.factory.build_splits`, and
`DataSpec.to_config` gives the resolved node back (what a fit record fingerprints).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from omegaconf import DictConfig, OmegaConf

from hysteresis_lab.data.scaling import ScalingSettings
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError

#: the kinds of plant a data set may declare (``data.plant``): the loop prefers the effect whose
#: physics fits the kind when the evidence does not tell effects apart
PLANT_KINDS = ("positioner", "tank", "motion", "oscillator")

#: the ``data.columns`` keys that `hysteresis_lab.data.readers.read_recording` takes
_COLUMN_OPTIONS = ("time", "inputs", "outputs")


@dataclass(frozen=True)
class DataSpec:
    """A resolved ``data`` config and the settings the runs read from it.

    ``recording_options``: the keyword arguments of
    `hysteresis_lab.data.readers.read_recording` for a further file of this data set (its
    columns, rate and units; data=csv), e.g. one the loop diagnoses on.
    """

    config: Mapping[str, Any] = field(repr=False)
    name: str | None = None
    window: WindowSpec = WindowSpec()
    scaling: ScalingSettings = ScalingSettings()
    val_fraction: float = 0.1
    batch_size: int = 128
    num_workers: int = 0
    diagnose: tuple[str, ...] = ()
    #: the declared kind of plant (one of `PLANT_KINDS`); None: undeclared, no preference
    plant: str | None = None
    recording_options: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any] | DictConfig | DataSpec) -> DataSpec:
        """The spec of a ``data`` config node (resolved when a Hydra node); a spec passes
        through. Refuses a malformed ``window`` node."""
        if isinstance(cfg, DataSpec):
            return cfg
        config = _resolved(cfg)
        name = config.get("name")
        return cls(
            config=config,
            name=None if name is None else str(name),
            window=window_spec(config),
            scaling=ScalingSettings.from_config(config.get("scaling")),
            val_fraction=config.get("val_fraction", 0.1),
            batch_size=config.get("batch_size", 128),
            num_workers=config.get("num_workers", 0),
            diagnose=tuple(map(str, config.get("diagnose") or ())),
            plant=plant_kind(config.get("plant")),
            recording_options=_recording_options(config),
        )

    def to_config(self) -> dict[str, Any]:
        """The resolved ``data`` config (a copy): what a fit record fingerprints."""
        return copy.deepcopy(dict(self.config))


def plant_kind(value: Any) -> str | None:
    """``data.plant`` checked: one of `PLANT_KINDS`, or None (undeclared)."""
    if value is None or value in PLANT_KINDS:
        return value
    raise ConfigError(
        f"data.plant={value!r} is not a kind of plant this project knows. Fix: data.plant=one "
        f"of {list(PLANT_KINDS)}, or data.plant=null (no preference)."
    )


def window_spec(data_cfg: Mapping[str, Any]) -> WindowSpec:
    """The regression window ``data_cfg.window`` describes (checked)."""
    window = data_cfg.get("window", {}) or {}
    unknown = set(window) - {"na", "nb", "nk"}
    if unknown:
        raise ConfigError(
            f"unknown key(s) {sorted(unknown)} in data.window. Fix: use na, nb and nk."
        )
    return WindowSpec(**window)


def _resolved(cfg: Mapping[str, Any] | DictConfig) -> dict[str, Any]:
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
    return dict(cfg)


def _recording_options(config: Mapping[str, Any]) -> dict[str, Any]:
    """What `read_recording` takes from the data config: columns, rate, units and limits."""
    columns = dict(config.get("columns") or {})
    options = {key: columns[key] for key in _COLUMN_OPTIONS if key in columns}
    if config.get("fs") is not None:
        options["fs"] = config["fs"]
    if config.get("units"):
        options["units"] = dict(config["units"])
    if config.get("limits"):
        options["limits"] = dict(config["limits"])
    return options
