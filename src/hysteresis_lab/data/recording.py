"""`Recording`: one uniformly sampled input/output experiment, validated at construction."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from hysteresis_lab.errors import DataError


def _as_2d(values: Any, what: str, source: str) -> np.ndarray:
    """Return ``values`` as a float64 array of shape (N, channels)."""
    try:
        arr = np.array(values, dtype=np.float64)  # a copy: the caller keeps a writable array
    except (TypeError, ValueError) as exc:
        raise DataError(
            f"{what} is not numeric ({exc}).",
            source=source,
            fix=f"pass {what} as an array of numbers",
        ) from None
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise DataError(
            f"{what} has shape {arr.shape}; expected (N,) or (N, channels).",
            source=source,
            fix=f"reshape {what} to one row per sample and one column per channel",
        )
    return arr


@dataclass(frozen=True)
class Recording:
    """A uniformly sampled experiment: inputs ``u`` (N x nu), outputs ``y`` (N x ny).

    ``fs`` is the sampling rate in Hz; ``u_units``/``y_units`` give the physical units
    (e.g. ``"V"`` and ``"um"``); ``u_names``/``y_names`` label the channels.
    Construction validates everything, so a `Recording` in hand is always usable.
    """

    u: np.ndarray
    y: np.ndarray
    fs: float
    name: str = "recording"
    u_units: str = "V"
    y_units: str = "um"
    u_names: tuple[str, ...] = ()
    y_names: tuple[str, ...] = ()
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        source = f"recording '{self.name}'"
        u = _as_2d(self.u, "u", source)
        y = _as_2d(self.y, "y", source)
        if u.shape[0] != y.shape[0]:
            raise DataError(
                f"u has {u.shape[0]} samples but y has {y.shape[0]}.",
                source=source,
                fix="give u and y the same number of rows (one per sample)",
            )
        if u.shape[0] == 0:
            raise DataError("it has no samples.", source=source, fix="supply a non-empty recording")
        if u.shape[1] == 0 or y.shape[1] == 0:
            raise DataError(
                "it has no input or no output channel.",
                source=source,
                fix="supply at least one input and one output column",
            )
        for what, arr, names in (("u", u, self.u_names), ("y", y, self.y_names)):
            bad = ~np.isfinite(arr)
            if bad.any():
                row, col = np.argwhere(bad)[0]
                channel = f"'{names[col]}'" if len(names) == arr.shape[1] else str(col)
                raise DataError(
                    f"{what} contains {int(bad.sum())} NaN/inf value(s), the first at row "
                    f"{row + 1} (1-based), channel {channel}.",
                    source=source,
                    fix="remove or interpolate the missing samples before loading",
                )
        try:
            fs = float(self.fs)
        except (TypeError, ValueError):
            fs = float("nan")
        if not np.isfinite(fs) or fs <= 0:
            raise DataError(
                f"sampling rate fs={self.fs!r} is not a positive number.",
                source=source,
                fix="give fs in Hz (e.g. fs=20000)",
            )
        u_names = tuple(self.u_names) or tuple(f"u{i}" for i in range(u.shape[1]))
        y_names = tuple(self.y_names) or tuple(f"y{i}" for i in range(y.shape[1]))
        if len(u_names) != u.shape[1] or len(y_names) != y.shape[1]:
            raise DataError(
                f"{len(u_names)} input / {len(y_names)} output names for "
                f"{u.shape[1]} / {y.shape[1]} channels.",
                source=source,
                fix="give one name per channel",
            )
        u.setflags(write=False)
        y.setflags(write=False)
        object.__setattr__(self, "u", u)
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "fs", fs)
        object.__setattr__(self, "u_names", u_names)
        object.__setattr__(self, "y_names", y_names)
        object.__setattr__(self, "metadata", dict(self.metadata))

    # ------------------------------------------------------------------ properties
    @property
    def n_samples(self) -> int:
        return int(self.u.shape[0])

    @property
    def nu(self) -> int:
        return int(self.u.shape[1])

    @property
    def ny(self) -> int:
        return int(self.y.shape[1])

    @property
    def dt(self) -> float:
        return 1.0 / self.fs

    @property
    def duration(self) -> float:
        return self.n_samples / self.fs

    @property
    def t(self) -> np.ndarray:
        """Time stamps in seconds, starting at zero."""
        return np.arange(self.n_samples) / self.fs

    # ------------------------------------------------------------------ helpers
    def slice(self, start: int | None = None, stop: int | None = None, name: str | None = None):
        """Return the samples ``start:stop`` as a new recording."""
        return replace(
            self,
            u=self.u[start:stop],
            y=self.y[start:stop],
            name=name or self.name,
        )

    def output_label(self, output: int) -> str:
        """The recording's name, with the output's (``<name>:<output>``) when it has several:
        how the residual analysis and the diagnosis name one output's series."""
        return self.name if self.ny == 1 else f"{self.name}:{self.y_names[output]}"

    def with_output(self, y: np.ndarray, name: str | None = None) -> Recording:
        """Return a copy with the output replaced (e.g. by a model's prediction)."""
        return replace(self, y=y, name=name or self.name)

    def summary(self) -> str:
        return (
            f"{self.name}: {self.n_samples} samples at {self.fs:g} Hz ({self.duration:g} s), "
            f"nu={self.nu} [{self.u_units}], ny={self.ny} [{self.y_units}]"
        )


def check_compatible(recordings: Sequence[Recording], purpose: str = "this data set") -> None:
    """Raise `DataError` unless all recordings share fs, channel counts and units."""
    if not recordings:
        raise DataError(f"{purpose} has no recordings.", fix="supply at least one recording")
    first = recordings[0]

    def where(rec: Recording) -> str:
        return rec.metadata.get("path") or f"recording '{rec.name}'"

    for rec in recordings[1:]:
        if not np.isclose(rec.fs, first.fs, rtol=1e-9):
            raise DataError(
                f"sampling rate {rec.fs:g} Hz differs from {first.fs:g} Hz of {where(first)}.",
                source=where(rec),
                fix="resample the recordings to one rate before combining them",
            )
        if (rec.nu, rec.ny) != (first.nu, first.ny):
            raise DataError(
                f"has nu={rec.nu}, ny={rec.ny} but '{first.name}' has nu={first.nu}, "
                f"ny={first.ny}.",
                source=f"recording '{rec.name}'",
                fix="use recordings with the same input and output channels",
            )
        if (rec.u_units, rec.y_units) != (first.u_units, first.y_units):
            raise DataError(
                f"units ({rec.u_units}, {rec.y_units}) differ from ({first.u_units}, "
                f"{first.y_units}) of '{first.name}'.",
                source=f"recording '{rec.name}'",
                fix="convert the recordings to common units",
            )
