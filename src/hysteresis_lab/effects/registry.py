"""Effect registry: entry-point group ``hysteresis_lab.effects`` (built-ins register there too).

A plugin effect that fails to load is left out of the catalogue (one warning naming it), so
the diagnosis and every model that does not declare it run as usual; naming it is an error.
"""

from __future__ import annotations

from collections.abc import Sequence
from importlib.metadata import EntryPoint

from hysteresis_lab.effects.base import Effect
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.plugins import broken_message, load_or_skip, points, warn_broken

GROUP = "hysteresis_lab.effects"


def _instance(point: EntryPoint) -> Effect | None:
    """The effect ``point`` registers; None (one warning) where its plugin is broken."""
    cls = load_or_skip(point)
    if cls is None:
        return None
    try:
        return cls()
    except Exception as exc:  # a plugin's own error, as in loading it
        warn_broken(point, exc)
        return None


def loaded_effects() -> dict[str, Effect]:
    """Every registered effect that loads, by name in name order, each loaded once (a broken
    plugin's are left out, with a warning)."""
    found = {name: _instance(point) for name, point in sorted(points(GROUP).items())}
    return {name: effect for name, effect in found.items() if effect is not None}


def available_effects() -> list[str]:
    """Names of the effects that load (a broken plugin's are left out, with a warning)."""
    return list(loaded_effects())


def get_effect(name: str) -> Effect:
    registered = points(GROUP)
    if name not in registered:
        raise ConfigError(
            f"unknown effect '{name}'. Available: {available_effects()}. Fix: "
            f"model.effects=[...] with those names, or install a package registering "
            f"'{GROUP}' entry points."
        )
    point = registered[name]
    try:
        return point.load()()
    except Exception as exc:  # named on purpose: say whose it is, no traceback
        raise ConfigError(
            f"effect '{name}' cannot be used: {broken_message(point, exc)} Or drop it from "
            "model.effects."
        ) from exc


def check_effects(names: Sequence[str]) -> None:
    """Refuse unknown effect names (listing the catalogue) and an effect named twice."""
    if isinstance(names, str):  # model.effects=creep: a name, not a list of names
        raise ConfigError(
            f"model.effects={names!r} must be a list. Fix: model.effects=[{names}] (brackets "
            "even for one effect)."
        )
    for name in names:
        get_effect(name)
    repeated = sorted({name for name in names if list(names).count(name) > 1})
    if repeated:
        unique = list(dict.fromkeys(names))
        raise ConfigError(
            f"model.effects names {repeated} more than once. Fix: name each effect once, "
            f"model.effects=[{','.join(unique)}]."
        )
