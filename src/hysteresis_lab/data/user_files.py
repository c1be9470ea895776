"""``data=csv``: the user's own recordings (any format `read_recording` understands)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hysteresis_lab.data.readers import read_recording
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import DataError

DEFAULT_COLUMNS = {"time": "t", "inputs": ["u"], "outputs": ["y"]}


def _paths(value: str | Sequence[str] | None) -> list[str]:
    if value is None:
        return []
    return [str(value)] if isinstance(value, str | Path) else [str(v) for v in value]


def load_user_files(
    train: str | Sequence[str] | None,
    test: str | Sequence[str] | None = (),
    val: str | Sequence[str] | None = None,
    columns: Mapping[str, Any] | None = None,
    fs: float | None = None,
    u_units: str = "V",
    y_units: str = "um",
    name: str = "csv",
    n_init: int = 0,
) -> DatasetSplits:
    """Estimation (``train``), optional validation (``val``) and ``test`` recordings from files."""
    if not _paths(train):
        raise DataError(
            "no training file was given.",
            source=f"data '{name}'",
            fix="set data.train=<path> (and data.test=[<path>,...])",
        )
    cols = {**DEFAULT_COLUMNS, **dict(columns or {})}
    unknown = set(cols) - set(DEFAULT_COLUMNS)
    if unknown:
        raise DataError(
            f"unknown key(s) {sorted(unknown)} in data.columns.",
            source=f"data '{name}'",
            fix="use time, inputs and outputs",
        )

    def read(paths: list[str]) -> list[Recording]:
        return [
            read_recording(
                p,
                time=cols["time"],
                inputs=cols["inputs"],
                outputs=cols["outputs"],
                fs=fs,
                u_units=u_units,
                y_units=y_units,
            )
            for p in paths
        ]

    return DatasetSplits(
        name=name,
        train=read(_paths(train)),
        test=read(_paths(test)),
        val=read(_paths(val)),
        n_init=n_init,
    )
