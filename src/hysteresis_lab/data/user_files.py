"""``data=csv``: the user's own recordings (any format `read_recording` understands)."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hysteresis_lab.data.limits import ValueLimits
from hysteresis_lab.data.readers import read_recording
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import DataError

log = logging.getLogger(__name__)

DEFAULT_COLUMNS: dict[str, Any] = {"time": "t", "inputs": ["u"], "outputs": ["y"]}
DEFAULT_UNITS: dict[str, str] = {"u": "V", "y": "um"}


def _paths(value: str | Path | Sequence[str | Path] | None) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str | Path):
        return [str(value)] if str(value).strip() else []
    return [str(v) for v in value]


def _check_same_format(recordings: list[Recording]) -> None:
    """Sampling rate and channel counts must agree; the message names both files."""
    first = recordings[0]
    for rec in recordings[1:]:
        here, there = rec.metadata["path"], first.metadata["path"]
        if not np.isclose(rec.fs, first.fs, rtol=1e-6):
            raise DataError(
                f"sampling rate {rec.fs:g} Hz differs from {first.fs:g} Hz of {there}.",
                source=here,
                fix="resample all recordings to one rate (or correct the time column / data.fs)",
            )
        if (rec.nu, rec.ny) != (first.nu, first.ny):
            raise DataError(
                f"{rec.nu} input(s) / {rec.ny} output(s) but {there} has {first.nu} / {first.ny}.",
                source=here,
                fix="use the same input and output columns (data.columns) in every file",
            )


def load_user_files(
    train: str | Sequence[str] | None,
    test: str | Sequence[str] | None = (),
    val: str | Sequence[str] | None = None,
    columns: Mapping[str, Any] | None = None,
    fs: float | None = None,
    units: Mapping[str, str] | None = None,
    name: str = "csv",
    n_init: int = 0,
    u_units: str | None = None,
    y_units: str | None = None,
    limits: Mapping[str, Any] | None = None,
) -> DatasetSplits:
    """Estimation (``train``), optional validation (``val``) and ``test`` recordings from files.

    ``train`` and ``test`` take one path or a list; ``columns`` names the time, input and output
    columns (``time: null`` with ``fs`` when the files have no time column); ``units`` gives
    ``{u: ..., y: ...}`` (``u_units``/``y_units`` are accepted as older spellings); ``limits``
    the largest physical ``{u_abs_max: ..., y_abs_max: ...}`` (`ValueLimits`): a value beyond,
    or NaN/inf, is refused with its file and line.
    """
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
    unit_map = {**DEFAULT_UNITS, **dict(units or {})}
    if u_units is not None:
        unit_map["u"] = u_units
    if y_units is not None:
        unit_map["y"] = y_units
    value_limits = ValueLimits.from_config(limits)

    def read(paths: list[str]) -> list[Recording]:
        return [
            read_recording(
                p,
                time=cols["time"],
                inputs=cols["inputs"],
                outputs=cols["outputs"],
                fs=fs,
                units=unit_map,
                limits=value_limits,
            )
            for p in paths
        ]

    train_recs, val_recs, test_recs = read(_paths(train)), read(_paths(val)), read(_paths(test))
    _check_same_format([*train_recs, *val_recs, *test_recs])
    if not test_recs:
        log.warning("data '%s' has no test files (data.test=[<path>,...]).", name)
    return DatasetSplits(
        name=name,
        train=train_recs,
        test=test_recs,
        val=val_recs,
        n_init=int(n_init),
        metadata={"files": {"train": _paths(train), "val": _paths(val), "test": _paths(test)}},
    )
