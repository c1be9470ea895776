"""The model registry: every architecture, built-in or plugin, is an entry point.

Group ``hysteresis_lab.models``; the entry-point name is what ``model=<name>`` selects. A
class is checked against the model interface (`hysteresis_lab.models.interface`) when it loads.
A plugin whose entry point fails to import is left out of `available_models` (one warning
naming it); only naming it is an error.
"""

from __future__ import annotations

from importlib.metadata import EntryPoint, entry_points

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.interface import check_model_class
from hysteresis_lab.plugins import load_or_skip

GROUP = "hysteresis_lab.models"


def _entry_points() -> dict[str, EntryPoint]:
    return {ep.name: ep for ep in entry_points(group=GROUP)}


def available_models() -> list[str]:
    """Names of the registered architectures that load (a broken plugin's are left out, with
    one warning naming it)."""
    return sorted(name for name, point in _entry_points().items()
                  if load_or_skip(point) is not None)


def get_model_class(name: str) -> type:
    """The class registered as ``name``; a clear error for unknown or broken entries and for
    a class that lacks part of the model interface."""
    points = _entry_points()
    if name not in points:
        raise ConfigError(
            f"unknown model '{name}'. Available: {sorted(points)}. Fix: choose one with "
            "model=<name>, or install a plugin package that registers it under the "
            f"'{GROUP}' entry-point group."
        )
    point = points[name]
    package = point.dist.name if point.dist else point.value
    try:
        cls = point.load()
    except Exception as exc:  # a plugin's import error must not look like ours
        raise ConfigError(
            f"model '{name}' is registered by '{package}' ({point.value}) but fails to import: "
            f"{type(exc).__name__}: {exc}. Fix: repair or reinstall that package."
        ) from exc
    check_model_class(cls, name, f"'{package}' (entry point {name} = {point.value})")
    cls.registry_name = name
    return cls
