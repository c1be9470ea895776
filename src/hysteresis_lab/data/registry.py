"""The data-set registry: every bundled or plugin data set is an entry point.

Group ``hysteresis_lab.datasets``; the entry-point name is what `load_benchmark` and a data
config's ``splits.name`` select. An entry point names a `Dataset` (a loader and how the
accuracy table shows it) or a bare loader ``(root=None, **options) -> DatasetSplits``. A
plugin whose entry point fails to import is left out of `available_datasets` (one warning
naming it); only naming it is an error.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import DataError
from hysteresis_lab.plugins import broken_message, describe, load_or_skip, points, warn_broken

GROUP = "hysteresis_lab.datasets"

Loader = Callable[..., DatasetSplits]


@dataclass(frozen=True)
class Dataset:
    """A registered data set: its loader and how the accuracy table names and scores it."""

    #: ``(root=None, **options) -> DatasetSplits``; ``root`` points it at another copy
    load: Loader
    #: the data config that selects it (``data=<config>``); None: its registry name
    config: str | None = None
    #: its section heading on the accuracy page; None: ``<name> (data=<config>)``
    title: str | None = None
    #: accuracy-table rows that each average the tests whose name starts with a prefix
    #: (row label -> prefix); empty: one row per test
    test_groups: Mapping[str, str] = field(default_factory=dict)

    def config_name(self, name: str) -> str:
        """The ``data=`` choice of the data set registered as ``name``."""
        return self.config or name

    def heading(self, name: str) -> str:
        """The accuracy page's heading of the data set registered as ``name``."""
        return self.title or f"{name} (data={self.config_name(name)})"


def _as_dataset(obj: Any) -> Dataset | None:
    """``obj`` as a `Dataset` (a bare loader gets the defaults); None when it is neither."""
    if isinstance(obj, Dataset):
        return obj
    return Dataset(load=obj) if callable(obj) else None


def _load(name: str) -> Dataset | None:
    """The data set registered as ``name``; None (one warning) where its plugin is broken."""
    point = points(GROUP)[name]
    obj = load_or_skip(point)
    if obj is None:
        return None
    dataset = _as_dataset(obj)
    if dataset is None:
        warn_broken(point, TypeError(f"{obj!r} is neither a Dataset nor a loader"))
    return dataset


def registered_datasets() -> dict[str, Dataset]:
    """Every data set that loads, by registry name in name order (a broken plugin's are left
    out, with one warning naming it)."""
    found = {name: _load(name) for name in sorted(points(GROUP))}
    return {name: dataset for name, dataset in found.items() if dataset is not None}


def available_datasets() -> list[str]:
    """Names of the registered data sets that load."""
    return list(registered_datasets())


def get_dataset(name: str) -> Dataset:
    """The data set registered as ``name``; a one-line error for an unknown or broken one."""
    registered = points(GROUP)
    if name not in registered:
        available = available_datasets()
        fix = (
            f"name one of them (data.splits.name, or its data config such as data=fsm), or "
            f"install a package that registers it under the '{GROUP}' entry-point group"
            if available
            # not even the bundled ones: the installed metadata is older than this code
            else "reinstall hysteresis_lab (pip install -e .), which registers the bundled ones"
        )
        raise DataError(f"unknown dataset '{name}'; available: {available}.", source="data",
                        fix=fix)
    point = registered[name]
    try:
        obj = point.load()
    except Exception as exc:  # named on purpose: say whose it is, no traceback
        raise DataError(f"dataset '{name}' cannot be used: {broken_message(point, exc)}") from exc
    dataset = _as_dataset(obj)
    if dataset is None:
        raise DataError(
            f"dataset '{name}' cannot be used: plugin {describe(point)} names {obj!r}, which is "
            "neither a Dataset nor a loader.",
            fix="point the entry point at a loader function (root=None, **options) -> "
            "DatasetSplits or at a hysteresis_lab.data.registry.Dataset",
        )
    return dataset


def load_dataset(name: str, root: str | Path | None = None, **options: Any) -> DatasetSplits:
    """Load the registered data set ``name``; ``options`` go to its loader."""
    loader = get_dataset(name).load
    try:
        return loader(root=root, **options)
    except TypeError as exc:
        if "unexpected keyword" not in str(exc):
            raise
        raise DataError(
            f"unknown option for dataset '{name}' ({exc}).",
            source="data",
            fix="check the data.splits options of this data set",
        ) from None
