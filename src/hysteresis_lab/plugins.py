"""Load plugin entry points so that a broken plugin disables only itself.

Models, effects, data sets and config folders are entry points (groups
``hysteresis_lab.models``, ``hysteresis_lab.effects``, ``hysteresis_lab.datasets``,
``hysteresis_lab.configs``). An entry point whose import raises is
skipped by the code that only lists or scans them, with one warning per process naming its
package and entry point; only a command that names it fails (with a clear error).
"""

from __future__ import annotations

import logging
from importlib.metadata import EntryPoint, entry_points
from typing import Any

log = logging.getLogger("hysteresis_lab.plugins")

#: (group, name, value) of the broken entry points already warned about in this process
_WARNED: set[tuple[str, str, str]] = set()


def package_of(point: EntryPoint) -> str:
    """The distribution that registers ``point`` (its module path where none is known)."""
    return point.dist.name if point.dist is not None else point.value


def describe(point: EntryPoint) -> str:
    """``'<package>' (entry point <name> = <value> in <group>)``."""
    return f"'{package_of(point)}' (entry point {point.name} = {point.value} in {point.group})"


def broken_message(point: EntryPoint, exc: BaseException) -> str:
    """What is wrong with a plugin whose entry point fails to load, and the fix."""
    return (
        f"plugin {describe(point)} fails to load: {type(exc).__name__}: {exc}. Fix: repair or "
        f"reinstall that package, or uninstall it (pip uninstall {package_of(point)})."
    )


def warn_broken(point: EntryPoint, exc: BaseException) -> None:
    """Log, once per process and entry point, that ``point`` is skipped because it is broken."""
    key = (point.group, point.name, point.value)
    if key in _WARNED:
        return
    _WARNED.add(key)
    log.warning("%s It is skipped.", broken_message(point, exc))


def points(group: str) -> dict[str, EntryPoint]:
    """The entry points of ``group`` by name."""
    return {point.name: point for point in entry_points(group=group)}


def load_or_skip(point: EntryPoint) -> Any | None:
    """The object ``point`` names; None (and one warning) where loading it raises."""
    try:
        return point.load()
    except Exception as exc:  # a plugin's own error: it must not stop what does not use it
        warn_broken(point, exc)
        return None
