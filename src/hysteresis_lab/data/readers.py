"""Read and write recordings: CSV (named columns), NPZ, MAT (v5 via scipy, v7.3 via h5py), HDF5.

Every reader returns a validated `Recording`; every failure is a `DataError` naming the file,
the problem and the fix.
"""

from __future__ import annotations

import csv
import logging
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import scipy.io

from hysteresis_lab.data.limits import ValueLimits, check_values
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.errors import DataError

log = logging.getLogger(__name__)

UNIFORM_TOLERANCE = 1e-3  # relative spread of the sampling interval still called uniform
#: a number written with a decimal comma (1,5 or -0,25e-3)
DECIMAL_COMMA = re.compile(r"^[+-]?\d+,\d+([eE][+-]?\d+)?$")


def _names(value: str | Sequence[str]) -> list[str]:
    return [value] if isinstance(value, str) else list(value)


def _units(
    units: Mapping[str, str] | None, u_units: str, y_units: str, source: Path
) -> tuple[str, str]:
    """``units={"u": ..., "y": ...}`` overrides ``u_units``/``y_units``."""
    if not units:
        return u_units, y_units
    unknown = set(units) - {"u", "y"}
    if unknown:
        raise DataError(
            f"unknown key(s) {sorted(unknown)} in units.",
            source=str(source),
            fix="give units as {u: <input unit>, y: <output unit>} (e.g. data.units.y=um)",
        )
    return str(units.get("u", u_units)), str(units.get("y", y_units))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _check_file(path: Path) -> Path:
    path = Path(path)
    if not path.is_file():
        raise DataError(
            "no such file.", source=str(path), fix="check the path (data.train / data.test)"
        )
    if path.stat().st_size == 0:
        raise DataError("the file is empty.", source=str(path), fix="supply a file with data")
    return path


def sampling_rate(t: np.ndarray, fs: float | None, source: str) -> float:
    """The sampling rate from a time column (checked for uniformity) and/or a given ``fs``."""
    if t is None:
        if fs is None:
            raise DataError(
                "there is no time column and no sampling rate.",
                source=source,
                fix="add a time column (columns.time) or give the sampling rate (data.fs=...)",
            )
        return float(fs)
    t = np.asarray(t, dtype=float).ravel()
    if len(t) < 2:
        raise DataError("fewer than two samples.", source=source, fix="supply a longer recording")
    dt = np.diff(t)
    if np.any(dt <= 0):
        first = int(np.argmax(dt <= 0))
        raise DataError(
            f"the time column does not increase at row {first + 1} (t={t[first]:g} -> "
            f"{t[first + 1]:g}).",
            source=source,
            fix="sort the samples by time and remove duplicates",
        )
    median = float(np.median(dt))
    spread = np.abs(dt - median) / median
    if spread.max() > UNIFORM_TOLERANCE:
        row = int(np.argmax(spread))
        raise DataError(
            f"the time column is not uniformly sampled: step {dt[row]:g} s at row {row + 1} "
            f"against a median step of {median:g} s.",
            source=source,
            fix="resample the recording to a uniform rate before loading",
        )
    rate = 1.0 / median
    if fs is not None and not np.isclose(rate, fs, rtol=1e-3):
        raise DataError(
            f"the time column gives fs = {rate:g} Hz but fs = {fs:g} Hz was configured.",
            source=source,
            fix="drop the data.fs override or correct it",
        )
    return rate


def _recording(
    columns: Mapping[str, np.ndarray],
    source: Path,
    time: str | None,
    inputs: Sequence[str],
    outputs: Sequence[str],
    fs: float | None,
    u_units: str,
    y_units: str,
    name: str | None,
    units: Mapping[str, str] | None = None,
    limits: Mapping[str, Any] | ValueLimits | None = None,
    lines: Sequence[int] | None = None,
) -> Recording:
    """The recording of ``columns``, its values checked against ``limits`` (``lines``: the
    file's line number of every sample, for a text file)."""
    u_units, y_units = _units(units, u_units, y_units, source)
    wanted = ([time] if time else []) + list(inputs) + list(outputs)
    missing = [c for c in wanted if c not in columns]
    if missing:
        raise DataError(
            f"missing column(s) {missing}; the file has {sorted(columns)}.",
            source=str(source),
            fix="name the columns in data.columns (time / inputs / outputs), or set "
            "data.columns.time=null with data.fs=<Hz> when there is no time column",
        )
    lengths = {c: len(np.ravel(columns[c])) for c in wanted}
    if len(set(lengths.values())) > 1:
        raise DataError(
            f"columns have different lengths {lengths}.",
            source=str(source),
            fix="store one value per sample in every column",
        )
    try:
        numeric = {c: np.asarray(columns[c], dtype=float).ravel() for c in wanted}
    except (TypeError, ValueError) as exc:
        raise DataError(
            f"non-numeric values ({exc}).",
            source=str(source),
            fix="keep only numbers in the data columns",
        ) from None
    check_values(
        numeric, inputs, outputs, ValueLimits.from_config(limits), str(source),
        units=(u_units, y_units), lines=lines, time=time,
    )
    rate = sampling_rate(numeric[time] if time else None, fs, str(source))
    u = np.column_stack([numeric[c] for c in inputs])
    y = np.column_stack([numeric[c] for c in outputs])
    try:
        return Recording(
            u=u,
            y=y,
            fs=rate,
            name=name or source.stem,
            u_units=u_units,
            y_units=y_units,
            u_names=tuple(inputs),
            y_names=tuple(outputs),
            metadata={"path": str(source)},
        )
    except DataError as exc:
        raise DataError(exc.problem, source=str(source), fix=exc.fix) from None


def read_csv(
    path: str | Path,
    time: str | None = "t",
    inputs: str | Sequence[str] = ("u",),
    outputs: str | Sequence[str] = ("y",),
    fs: float | None = None,
    units: Mapping[str, str] | None = None,
    name: str | None = None,
    u_units: str = "V",
    y_units: str = "um",
    limits: Mapping[str, Any] | ValueLimits | None = None,
    delimiter: str | None = None,
) -> Recording:
    """A CSV file with a header row of column names (``t,u,y`` by default).

    The delimiter (comma, semicolon or tab) is detected from the header unless given; a value
    that is not finite or lies beyond ``limits`` (`ValueLimits`) is refused with its line.
    """
    path = _check_file(Path(path))
    with path.open(newline="") as handle:
        first = handle.readline()
        if delimiter is None:
            delimiter = next((d for d in (",", ";", "\t") if d in first), ",")
        handle.seek(0)
        reader = csv.reader(handle, delimiter=delimiter)
        header = [h.strip() for h in next(reader, [])]
        rows, lines = [], []  # the data rows and the line each ends on (as an editor counts)
        for row in reader:
            if any(cell.strip() for cell in row):
                rows.append(row)
                lines.append(reader.line_num)
    if not any(header) or all(_is_number(h) for h in header if h):
        raise DataError(
            f"the first line {first.strip()!r} is not a header of column names.",
            source=str(path),
            fix="start the file with a header row such as 't,u,y'",
        )
    duplicated = sorted({h for h in header if h and header.count(h) > 1})
    if duplicated:
        raise DataError(
            f"the header names column(s) {duplicated} more than once ({first.strip()!r}).",
            source=str(path),
            fix="give every column its own name in the header row (e.g. y1,y2)",
        )
    if not rows:
        raise DataError(
            "the file has a header but no data rows.",
            source=str(path),
            fix="supply a file with data",
        )
    table: dict[str, list[float]] = {h: [] for h in header if h}
    for number, row in zip(lines, rows, strict=True):
        if any(cell.strip() for cell in row[len(header) :]):
            decimal_comma = delimiter == "," and len(row) >= 2 * len(header)
            raise DataError(
                f"line {number} has {len(row)} values but the header names {len(header)} "
                f"columns ({first.strip()!r})"
                + (
                    ": it looks like decimal commas between comma separators."
                    if decimal_comma
                    else "."
                ),
                source=str(path),
                fix="write numbers with a decimal point (1.5, not 1,5), or separate the columns "
                "with ';' or tab"
                if decimal_comma
                else "give every row one value per header column",
            )
        for key, cell in zip(header, row, strict=False):
            if not key:
                continue
            try:
                table[key].append(float(cell) if cell.strip() else np.nan)
            except ValueError:
                if DECIMAL_COMMA.match(cell.strip()):
                    raise DataError(
                        f"value {cell!r} in column '{key}', line {number}, has a decimal comma.",
                        source=str(path),
                        fix="write numbers with a decimal point (1.5, not 1,5): export the file "
                        "with a '.' decimal separator, keeping ';' or tab between columns",
                    ) from None
                raise DataError(
                    f"non-numeric value {cell!r} in column '{key}', line {number}.",
                    source=str(path),
                    fix="keep only numbers below the header row",
                ) from None
    columns = {k: np.asarray(v) for k, v in table.items()}
    return _recording(
        columns, path, time, _names(inputs), _names(outputs), fs, u_units, y_units, name, units,
        limits, lines,
    )


def read_npz(
    path: str | Path,
    time: str | None = "t",
    inputs: str | Sequence[str] = ("u",),
    outputs: str | Sequence[str] = ("y",),
    fs: float | None = None,
    units: Mapping[str, str] | None = None,
    name: str | None = None,
    u_units: str = "V",
    y_units: str = "um",
    limits: Mapping[str, Any] | ValueLimits | None = None,
) -> Recording:
    """An NPZ archive with one array per column (``t``, ``u``, ``y`` by default)."""
    path = _check_file(Path(path))
    try:
        with np.load(path, allow_pickle=False) as archive:
            columns = {k: archive[k] for k in archive.files}
    except (OSError, ValueError) as exc:
        raise DataError(
            f"cannot read the NPZ archive ({exc}).",
            source=str(path),
            fix="check that the file is an uncorrupted .npz",
        ) from None
    if "fs" in columns and fs is None and (time is None or time not in columns):
        fs = float(np.ravel(columns["fs"])[0])
    columns, inputs, outputs = _expand_matrices(columns, _names(inputs), _names(outputs))
    return _recording(
        columns, path, time, inputs, outputs, fs, u_units, y_units, name, units, limits
    )


def read_mat(
    path: str | Path,
    time: str | None = "t",
    inputs: str | Sequence[str] = ("u",),
    outputs: str | Sequence[str] = ("y",),
    fs: float | None = None,
    units: Mapping[str, str] | None = None,
    name: str | None = None,
    u_units: str = "V",
    y_units: str = "um",
    limits: Mapping[str, Any] | ValueLimits | None = None,
) -> Recording:
    """A MATLAB file: v4-v7 via scipy.io, v7.3 (HDF5) via h5py."""
    path = _check_file(Path(path))
    columns = load_mat_variables(path)
    columns, inputs, outputs = _expand_matrices(columns, _names(inputs), _names(outputs))
    return _recording(
        columns, path, time, inputs, outputs, fs, u_units, y_units, name, units, limits
    )


def load_mat_variables(path: Path) -> dict[str, np.ndarray]:
    """All numeric variables of a MAT file (any version) as NumPy arrays."""
    if h5py.is_hdf5(path):  # MATLAB v7.3 = HDF5, column-major
        with h5py.File(path, "r") as handle:
            return {k: np.asarray(v).T for k, v in handle.items() if isinstance(v, h5py.Dataset)}
    try:
        raw = scipy.io.loadmat(path)
    except (ValueError, OSError, NotImplementedError) as exc:
        raise DataError(
            f"cannot read the MAT file ({exc}).",
            source=str(path),
            fix="check that the file is an uncorrupted MATLAB .mat file",
        ) from None
    return {k: np.asarray(v) for k, v in raw.items() if not k.startswith("__")}


def read_hdf5(
    path: str | Path,
    time: str | None = "t",
    inputs: str | Sequence[str] = ("u",),
    outputs: str | Sequence[str] = ("y",),
    fs: float | None = None,
    units: Mapping[str, str] | None = None,
    name: str | None = None,
    u_units: str = "V",
    y_units: str = "um",
    limits: Mapping[str, Any] | ValueLimits | None = None,
) -> Recording:
    """An HDF5 file; column names are dataset paths (e.g. ``"multisine/u"``)."""
    path = _check_file(Path(path))
    wanted = ([time] if time else []) + _names(inputs) + _names(outputs)
    try:
        with h5py.File(path, "r") as handle:
            columns = {k: np.asarray(handle[k]) for k in wanted if k in handle}
            available = _hdf5_datasets(handle)
            if fs is None and "fs" in handle.attrs:
                fs = float(handle.attrs["fs"])
    except OSError as exc:
        raise DataError(
            f"cannot read the HDF5 file ({exc}).",
            source=str(path),
            fix="check that the file is an uncorrupted HDF5 file",
        ) from None
    missing = [k for k in wanted if k not in columns]
    if missing:
        raise DataError(
            f"missing dataset(s) {missing}; the file has {available}.",
            source=str(path),
            fix="name the datasets in data.columns",
        )
    return _recording(
        columns, path, time, _names(inputs), _names(outputs), fs, u_units, y_units, name, units,
        limits,
    )


def _hdf5_datasets(handle: h5py.File) -> list[str]:
    names: list[str] = []
    handle.visititems(lambda n, obj: names.append(n) if isinstance(obj, h5py.Dataset) else None)
    return names


def _expand_matrices(
    columns: dict[str, np.ndarray], inputs: list[str], outputs: list[str]
) -> tuple[dict[str, np.ndarray], list[str], list[str]]:
    """Split a single (N, k) input/output matrix into k named columns (``u`` -> ``u0, u1``)."""
    columns = dict(columns)

    def expand(names: list[str]) -> list[str]:
        if len(names) != 1 or names[0] not in columns:
            return names
        arr = np.asarray(columns[names[0]])
        if arr.ndim == 2 and min(arr.shape) > 1:
            arr = arr if arr.shape[0] >= arr.shape[1] else arr.T
            new = [f"{names[0]}{i}" for i in range(arr.shape[1])]
            columns.update({n: arr[:, i] for i, n in enumerate(new)})
            return new
        return names

    return columns, expand(inputs), expand(outputs)


READERS: dict[str, Callable[..., Recording]] = {
    ".csv": read_csv,
    ".txt": read_csv,
    ".npz": read_npz,
    ".mat": read_mat,
    ".h5": read_hdf5,
    ".hdf5": read_hdf5,
}


def read_recording(path: str | Path, **options: Any) -> Recording:
    """Read any supported file, choosing the reader by suffix."""
    path = Path(path)
    if path.is_dir():
        raise DataError(
            "is a folder, not a file.",
            source=str(path),
            fix="give the path of a recording inside it (e.g. data.train=<folder>/run.csv)",
        )
    reader = READERS.get(path.suffix.lower())
    if reader is None and not path.suffix:
        _check_file(path)  # "no such file" rather than "unknown file type ''"
    if reader is None:
        raise DataError(
            f"unknown file type '{path.suffix}'.",
            source=str(path),
            fix=f"use one of {sorted(READERS)}",
        )
    return reader(path, **options)


# ---------------------------------------------------------------------------------- writers
def _columns(rec: Recording) -> dict[str, np.ndarray]:
    columns = {"t": rec.t}
    columns.update({n: rec.u[:, i] for i, n in enumerate(rec.u_names)})
    columns.update({n: rec.y[:, i] for i, n in enumerate(rec.y_names)})
    return columns


def write_csv(rec: Recording, path: str | Path) -> Path:
    """CSV with header ``t,<input names>,<output names>`` (s and the recording's units)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = _columns(rec)
    np.savetxt(
        path,
        np.column_stack(list(columns.values())),
        delimiter=",",
        header=",".join(columns),
        comments="",
        fmt="%.10g",
    )
    return path


def write_npz(rec: Recording, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **_columns(rec))
    return path


def write_mat(rec: Recording, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    scipy.io.savemat(path, {k: v[:, None] for k, v in _columns(rec).items()})
    return path


def write_hdf5(rec: Recording, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(path, "w") as handle:
        for key, values in _columns(rec).items():
            handle.create_dataset(key, data=values)
        handle.attrs["fs"] = rec.fs
    return path
