"""Effect registry: entry-point group ``hysteresis_lab.effects`` (built-ins register there too)."""

from __future__ import annotations

from collections.abc import Sequence
from importlib.metadata import entry_points

from hysteresis_lab.effects.base import Effect
from hysteresis_lab.errors import ConfigError

GROUP = "hysteresis_lab.effects"


def available_effects() -> list[str]:
    return sorted(ep.name for ep in entry_points(group=GROUP))


def get_effect(name: str) -> Effect:
    points = {ep.name: ep for ep in entry_points(group=GROUP)}
    if name not in points:
        raise ConfigError(
            f"unknown effect '{name}'. Available: {sorted(points)}. Fix: model.effects=[...] "
            f"with those names, or install a package registering '{GROUP}' entry points."
        )
    return points[name].load()()


def check_effects(names: Sequence[str]) -> None:
    """Refuse unknown effect names (listing the catalogue) and an effect named twice."""
    for name in names:
        get_effect(name)
    repeated = sorted({name for name in names if list(names).count(name) > 1})
    if repeated:
        unique = list(dict.fromkeys(names))
        raise ConfigError(
            f"model.effects names {repeated} more than once. Fix: name each effect once, "
            f"model.effects=[{','.join(unique)}]."
        )
