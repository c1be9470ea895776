"""Measured (and reference) benchmark data sets bundled with the package, with official splits.

Each loader returns `DatasetSplits` following the data set's SOURCE.md (licence, citation,
units, estimation/test split, scoring window ``n_init`` and published reference results in
``metadata["reference"]``). ``root`` points a loader at another copy of the files.
"""

from __future__ import annotations

import csv
import logging
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from hysteresis_lab.data.readers import load_mat_variables
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import DataError

log = logging.getLogger(__name__)


def _root(name: str, root: str | Path | None) -> Path:
    path = Path(root) if root else Path(str(resources.files("hysteresis_lab") / "datasets" / name))
    if not path.is_dir():
        raise DataError(
            "data folder not found.",
            source=str(path),
            fix="reinstall hysteresis_lab or pass root=<folder with the files>",
        )
    return path


def _file(folder: Path, name: str) -> Path:
    path = folder / name
    if not path.is_file():
        raise DataError(
            f"expected file '{name}' is missing.",
            source=str(folder),
            fix="restore the data set's files (see its SOURCE.md)",
        )
    return path


# ---------------------------------------------------------------------------- FSM piezo mirror
FSM_AMPLITUDES = (100, 200, 300)
FSM_REFERENCE_UM = {
    "NL-LFR": {100: 0.0866, 200: 0.1309, 300: 0.1686},
    "BLA same amplitude": {100: 0.1142, 200: 0.2161, 300: 0.2277},
}


def fsm_piezo_mirror(amplitude: int | str = "all", root: str | Path | None = None) -> DatasetSplits:
    """CubeSpec fine steering mirror: 3 piezo voltages [V] -> 3 displacements [µm], 6400 Hz.

    One recording per realisation (both steady-state periods in sequence); estimation on
    ``*_train`` (6 realisations per amplitude), test on ``*_test`` (3 per amplitude); the first
    100 samples of each test recording initialise the model and are not scored.
    """
    amplitudes = FSM_AMPLITUDES if str(amplitude) == "all" else (int(amplitude),)
    if any(a not in FSM_AMPLITUDES for a in amplitudes):
        raise DataError(
            f"unknown FSM amplitude {amplitude!r}.",
            source="data 'fsm'",
            fix=f"use data.splits.amplitude=one of {list(FSM_AMPLITUDES)} or all",
        )
    folder = _root("fsm_piezo_mirror", root)
    train, test = [], []
    for amp in amplitudes:
        with np.load(_file(folder, f"fsm_{amp}mV.npz")) as archive:
            for split, target in (("train", train), ("test", test)):
                u, y = archive[f"u_{split}"].astype(float), archive[f"y_{split}"].astype(float)
                for r in range(u.shape[2]):
                    target.append(
                        Recording(
                            u=np.concatenate([u[:, :, r, p] for p in range(u.shape[3])]),
                            y=np.concatenate([y[:, :, r, p] for p in range(y.shape[3])]),
                            fs=6400.0,
                            name=f"{amp}mV_{split}_r{r + 1}",
                            u_units="V",
                            y_units="um",
                            u_names=("u1", "u2", "u3"),
                            y_names=("y1", "y2", "y3"),
                            metadata={"amplitude_mV": amp, "realisation": r + 1},
                        )
                    )
    return DatasetSplits(
        "fsm",
        train=train,
        test=test,
        n_init=100,
        metadata={"reference": FSM_REFERENCE_UM, "reference_units": "um"},
    )


# ---------------------------------------------------------------------------- PI P-885 stack
def piezo_p885(train_fraction: float = 0.7, root: str | Path | None = None) -> DatasetSplits:
    """PI P-885.91 piezo stack, 1 Hz sine: voltage [V] -> displacement [µm] (mean removed), 200 Hz.

    One record only (no official split): the first ``train_fraction`` is for estimation, the
    rest for test.
    """
    if not 0.1 <= train_fraction <= 0.9:
        raise DataError(
            f"train_fraction={train_fraction} must lie in [0.1, 0.9].",
            source="data 'p885'",
            fix="set data.splits.train_fraction=0.7",
        )
    path = _file(_root("piezo_p885", root), "Model_Vi_Do.dat")
    table = np.loadtxt(path)
    u, y = table[:, 0], table[:, 4] - table[:, 4].mean()
    cut = int(round(train_fraction * len(u)))

    def rec(sl: slice, name: str) -> Recording:
        return Recording(
            u=u[sl], y=y[sl], fs=200.0, name=name, u_names=("voltage",), y_names=("displacement",)
        )

    return DatasetSplits(
        "p885",
        train=[rec(slice(0, cut), "p885_estimation")],
        test=[rec(slice(cut, None), "p885_test")],
        metadata={
            "reference": {"tracking RMSE without compensation": 1.68},
            "reference_units": "um",
        },
    )


# ---------------------------------------------------------------------------- Bouc-Wen
def bouc_wen(root: str | Path | None = None) -> DatasetSplits:
    """Bouc–Wen benchmark: force [N] -> displacement [mm], 750 Hz; tests: multisine, sine sweep."""
    folder = _root("bouc_wen", root)
    with h5py.File(_file(folder, "train.h5"), "r") as handle:
        u, y = np.asarray(handle["multisine/u"]), np.asarray(handle["multisine/y"])
    train = Recording(
        u=u, y=y * 1e3, fs=750.0, name="bw_train_multisine", u_units="N", y_units="mm"
    )
    tests = []
    for kind in ("multisine", "sinesweep"):
        u_t = load_mat_variables(_file(folder, f"uval_{kind}.mat"))[f"uval_{kind}"].ravel()
        y_t = load_mat_variables(_file(folder, f"yval_{kind}.mat"))[f"yval_{kind}"].ravel()
        tests.append(
            Recording(
                u=u_t, y=y_t * 1e3, fs=750.0, name=f"bw_test_{kind}", u_units="N", y_units="mm"
            )
        )
    reference = {"PNLSS": 1.87e-2, "dynoNet": 4.52e-2, "NFIR": 16.3e-2}
    return DatasetSplits(
        "bouc_wen",
        train=[train],
        test=tests,
        metadata={
            "reference": reference,
            "reference_units": "mm",
            "reference_test": "bw_test_multisine",
        },
    )


# ---------------------------------------------------------------------------- EMPS
def emps(root: str | Path | None = None) -> DatasetSplits:
    """EMPS: motor force command vir [V] -> position qm [mm], 1 kHz; test: the pulses record."""
    folder = _root("emps", root)

    def rec(file: str, name: str) -> Recording:
        data = load_mat_variables(_file(folder, file))
        t = data["t"].ravel()
        return Recording(
            u=data["vir"].ravel(),
            y=data["qm"].ravel() * 1e3,
            fs=float(round(1.0 / np.median(np.diff(t)))),
            name=name,
            u_units="V",
            y_units="mm",
            u_names=("vir",),
            y_names=("qm",),
        )

    return DatasetSplits(
        "emps",
        train=[rec("DATA_EMPS.mat", "emps_estimation")],
        test=[rec("DATA_EMPS_PULSES.mat", "emps_test_pulses")],
        n_init=20,
        metadata={"reference": {"dynoNet": 2.64}, "reference_units": "mm"},
    )


# ---------------------------------------------------------------------------- cascaded tanks
def cascaded_tanks(root: str | Path | None = None) -> DatasetSplits:
    """Cascaded tanks with overflow: pump voltage [V] -> lower-tank level [V], Ts = 4 s."""
    path = _file(_root("cascaded_tanks", root), "dataBenchmark.csv")
    with path.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    column = {
        key: np.array([float(r[key]) for r in rows]) for key in ("uEst", "uVal", "yEst", "yVal")
    }
    fs = 1.0 / float(rows[0]["Ts"])

    def rec(u: str, y: str, name: str) -> Recording:
        return Recording(
            u=column[u],
            y=column[y],
            fs=fs,
            name=name,
            u_units="V",
            y_units="V",
            u_names=("pump",),
            y_names=("level",),
        )

    reference = {
        "grey-box with overflow": 0.18,
        "neural CT-SS": 0.33,
        "NLSS2": 0.34,
        "GP-SS": 0.45,
        "Volterra": 0.54,
        "BLA": 0.75,
    }
    return DatasetSplits(
        "cascaded_tanks",
        train=[rec("uEst", "yEst", "tanks_estimation")],
        test=[rec("uVal", "yVal", "tanks_test")],
        n_init=50,
        metadata={"reference": reference, "reference_units": "V"},
    )


LOADERS: dict[str, Callable[..., DatasetSplits]] = {
    "fsm_piezo_mirror": fsm_piezo_mirror,
    "piezo_p885": piezo_p885,
    "bouc_wen": bouc_wen,
    "emps": emps,
    "cascaded_tanks": cascaded_tanks,
}


def available_benchmarks() -> list[str]:
    return sorted(LOADERS)


def load_benchmark(name: str, **options: Any) -> DatasetSplits:
    """Load the bundled data set ``name`` (see `available_benchmarks`)."""
    if name not in LOADERS:
        raise DataError(
            f"unknown dataset '{name}'.",
            source="data",
            fix=f"use one of {available_benchmarks()} (data=fsm, data=p885, ...)",
        )
    return LOADERS[name](**options)
