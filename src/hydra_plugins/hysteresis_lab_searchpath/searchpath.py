"""Add the config folders that packages register under the ``hysteresis_lab.configs`` entry points.

A plugin package declares, in its ``pyproject.toml``::

    [project.entry-points."hysteresis_lab.configs"]
    my_models = "my_package.conf"     # an importable package holding model/<name>.yaml

and Hydra then finds ``model=<name>`` beside the built-in configs. An entry whose package
fails to import is skipped with one warning (Hydra would import it to read its configs, and
every command would fail), so only the configs it would add are missing.
"""

from __future__ import annotations

import logging
from importlib import import_module
from importlib.metadata import entry_points

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin

from hysteresis_lab.plugins import warn_broken

log = logging.getLogger(__name__)

GROUP = "hysteresis_lab.configs"


class HysteresisLabSearchPathPlugin(SearchPathPlugin):
    """Append ``pkg://<module>`` for every registered plugin config package."""

    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        for entry in entry_points(group=GROUP):
            try:
                import_module(entry.value)
            except Exception as exc:  # a plugin's own error: it must not stop every command
                warn_broken(entry, exc)
                continue
            search_path.append(provider=f"hysteresis_lab:{entry.name}", path=f"pkg://{entry.value}")
