"""The values a file may hold: finite numbers within a physical range (``data.limits``).

A logger's overflow code (9.9e37), a corrupt row (1e300) or a missing value (NaN) is not a
measurement: trained on, it turns every loss and metric into NaN. The readers refuse such a
value with the file, the line (or row) a user finds it at, and the fix.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hysteresis_lab.errors import DataError

#: the default bound on |u| and |y| (in the data set's units): far beyond any volt, micrometre,
#: newton or encoder count a bench records, far below what overflows a float32 loss
DEFAULT_ABS_MAX = 1.0e9


@dataclass(frozen=True)
class ValueLimits:
    """The largest physical |value| of the inputs (``u_abs_max``) and the outputs
    (``y_abs_max``), in the data set's units, and of single columns by name (``columns``,
    which take precedence: a MIMO set's channels of different ranges) (``data.limits``)."""

    u_abs_max: float = DEFAULT_ABS_MAX
    y_abs_max: float = DEFAULT_ABS_MAX
    columns: Mapping[str, float] = field(default_factory=dict)

    @classmethod
    def from_config(cls, limits: Mapping[str, Any] | ValueLimits | None) -> ValueLimits:
        """From a ``data.limits`` node; a missing key (or null) takes its default."""
        if isinstance(limits, ValueLimits):
            return limits
        limits = dict(limits or {})
        unknown = set(limits) - set(cls.__dataclass_fields__)
        if unknown:
            raise DataError(
                f"unknown key(s) {sorted(unknown)} in data.limits.",
                source="data.limits",
                fix="use u_abs_max and y_abs_max (the largest |input| and |output| a "
                "recording may hold, in its units) and columns: {<column>: <largest |value|>}",
            )
        columns = limits.pop("columns", None) or {}
        if not isinstance(columns, Mapping):
            raise DataError(
                f"columns={columns!r} is not a mapping of column names to bounds.",
                source="data.limits",
                fix="give +data.limits.columns.<column>=<largest |value|>",
            )
        values = {k: _bound(k, v) for k, v in limits.items() if v is not None}
        per_column = {str(k): _bound(f"columns.{k}", v) for k, v in columns.items()
                      if v is not None}
        return cls(**values, columns=per_column)

    def bound(self, column: str, kind: str) -> tuple[float, str]:
        """The bound on ``column`` (an input, ``kind`` "u", or an output, "y") and the
        setting that gives it."""
        if column in self.columns:
            return self.columns[column], f"data.limits.columns.{column}"
        return getattr(self, f"{kind}_abs_max"), f"data.limits.{kind}_abs_max"


def _bound(key: str, value: Any) -> float:
    """A positive bound (inf allowed), else a `DataError` naming ``data.limits.<key>``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if not number > 0:  # also NaN
        raise DataError(
            f"{key}={value!r} is not a positive number.",
            source="data.limits",
            fix=f"give data.limits.{key} in the data's units, e.g. "
            f"data.limits.{key}=1000 (or data.limits.{key}=inf for no limit)",
        )
    return number


def check_values(
    columns: Mapping[str, np.ndarray],
    inputs: Sequence[str],
    outputs: Sequence[str],
    limits: ValueLimits,
    source: str,
    units: tuple[str, str] = ("", ""),
    lines: Sequence[int] | None = None,
    time: str | None = None,
) -> None:
    """Refuse the first NaN/inf (any column, ``time`` included) or out-of-range value (the
    ``inputs`` beyond ``limits.u_abs_max``, the ``outputs`` beyond ``limits.y_abs_max``).

    ``lines``: the file's 1-based line number of every sample (a text file); without them a
    sample is named by its 1-based row."""

    def where(index: int) -> str:
        return f"line {lines[index]}" if lines is not None else f"row {index + 1}"

    wanted = ([time] if time else []) + [*inputs, *outputs]
    for name in wanted:
        values = np.asarray(columns[name], dtype=float).ravel()
        bad = ~np.isfinite(values)
        if bad.any():
            first = int(np.argmax(bad))
            raise DataError(
                f"column '{name}' holds {int(bad.sum())} NaN/inf value(s), the first "
                f"({values[first]:g}) at {where(first)}.",
                source=source,
                fix="remove or interpolate the missing samples (an empty cell reads as NaN) "
                "before loading",
            )
    unknown = sorted(set(limits.columns) - set(inputs) - set(outputs))
    if unknown:
        raise DataError(
            f"data.limits.columns names {unknown}, which are not among the input and output "
            f"columns {[*inputs, *outputs]}.",
            source=source,
            fix="name the columns as data.columns.inputs / outputs do",
        )
    ranges = [(n, "u", units[0]) for n in inputs] + [(n, "y", units[1]) for n in outputs]
    for name, kind, unit in ranges:
        bound, setting = limits.bound(name, kind)
        values = np.asarray(columns[name], dtype=float).ravel()
        beyond = np.abs(values) > bound
        if beyond.any():
            first = int(np.argmax(beyond))
            unit_text = f" {unit}" if unit else ""
            raise DataError(
                f"value {values[first]:g} in column '{name}' at {where(first)} is beyond the "
                f"physical range |{name}| <= {bound:g}{unit_text} ({setting}; "
                f"{int(beyond.sum())} such value(s)).",
                source=source,
                fix=f"correct or remove that sample (an overflow code or a corrupt row), or, "
                f"if the signal really reaches it, raise {setting}",
            )
