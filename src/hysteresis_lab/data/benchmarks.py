"""Measured (and reference) benchmark data sets bundled with the package, with official splits.

Each loader returns `DatasetSplits` following the data set's SOURCE.md (licence, citation,
units, estimation/test split, scoring window ``n_init`` and published reference results in
``metadata["reference"]``). ``root`` points a loader at another copy of the files. Each is
registered (a `Dataset` below) under the ``hysteresis_lab.datasets`` entry points, where plugin
data sets join them (`hysteresis_lab.data.registry`).
"""

from __future__ import annotations

import csv
import logging
from importlib import resources
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from hysteresis_lab.data.readers import load_mat_variables
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.registry import Dataset, available_datasets, load_dataset
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
FSM_FS = 6400.0
FSM_N_INIT = 100
FSM_REFERENCE_UM = {
    "NL-LFR": {100: 0.0866, 200: 0.1309, 300: 0.1686},
    "BLA same amplitude": {100: 0.1142, 200: 0.2161, 300: 0.2277},
}
FSM_REFERENCE_SINGLE_BLA_UM = {100: 0.2523, 200: 0.1790, 300: 0.6575}


def fsm_piezo_mirror(amplitude: int | str = "all", root: str | Path | None = None) -> DatasetSplits:
    """CubeSpec fine steering mirror: 3 piezo voltages [V] -> 3 displacements [µm], 6400 Hz.

    Estimation: the 6 ``*_train`` realisations per amplitude, each one recording of its two
    steady-state periods in sequence. Test: the 3 ``*_test`` realisations per amplitude, one
    recording per realisation *and period* (``<amp>mV_test_r<r>_p<p>``) because the official
    score is the RMSE per output/realisation/period after the first ``n_init = 100`` samples.
    ``root`` may hold the bundled ``fsm_<amp>mV.npz`` files or the original ``.npy`` files.
    """
    amplitudes = FSM_AMPLITUDES if str(amplitude) == "all" else None
    if amplitudes is None:
        try:
            amplitudes = (int(amplitude),)
        except (TypeError, ValueError):
            amplitudes = ()
    if not amplitudes or any(a not in FSM_AMPLITUDES for a in amplitudes):
        raise DataError(
            f"unknown FSM amplitude {amplitude!r}.",
            source="data 'fsm'",
            fix=f"use data.splits.amplitude=one of {list(FSM_AMPLITUDES)} or all (mV RMS)",
        )
    folder = _root("fsm_piezo_mirror", root)
    train: list[Recording] = []
    test: list[Recording] = []
    for amp in amplitudes:
        arrays = _fsm_arrays(folder, amp)
        for split, target in (("train", train), ("test", test)):
            u, y = arrays[f"u_{split}"].astype(float), arrays[f"y_{split}"].astype(float)
            n_real, n_per = u.shape[2], u.shape[3]
            for r in range(n_real):
                pieces = [range(n_per)] if split == "train" else [[p] for p in range(n_per)]
                for periods in pieces:
                    label = f"{amp}mV_{split}_r{r + 1}"
                    if split == "test":
                        label += f"_p{periods[0] + 1}"
                    target.append(
                        Recording(
                            u=np.concatenate([u[:, :, r, p] for p in periods]),
                            y=np.concatenate([y[:, :, r, p] for p in periods]),
                            fs=FSM_FS,
                            name=label,
                            u_units="V",
                            y_units="um",
                            u_names=("u1", "u2", "u3"),
                            y_names=("y1", "y2", "y3"),
                            metadata={
                                "amplitude_mV": amp,
                                "realisation": r + 1,
                                "periods": [p + 1 for p in periods],
                            },
                        )
                    )
    reference = {**FSM_REFERENCE_UM, "single BLA all amplitudes": FSM_REFERENCE_SINGLE_BLA_UM}
    return DatasetSplits(
        "fsm",
        train=train,
        test=test,
        n_init=FSM_N_INIT,
        metadata={
            "reference": reference,
            "reference_units": "um",
            "reference_metric": "free-run RMSE per output/realisation/period after n_init=100, "
            "averaged over periods, realisations and outputs, per amplitude (mV RMS)",
            "amplitudes_mV": list(amplitudes),
            "licence": "CC BY 4.0 (M. Floren, KU Leuven); see datasets/fsm_piezo_mirror/SOURCE.md",
        },
    )


def _fsm_arrays(folder: Path, amp: int) -> dict[str, np.ndarray]:
    """``u_/y_{train,test}`` arrays (N, 3, R, P), y in µm: bundled NPZ or original NPY (m)."""
    bundled = folder / f"fsm_{amp}mV.npz"
    if bundled.is_file():
        with np.load(bundled) as archive:
            return {k: archive[k] for k in archive.files}
    arrays = {}
    for split in ("train", "test"):
        arrays[f"u_{split}"] = np.load(_file(folder, f"u_{amp}mV_{split}.npy"))
        arrays[f"y_{split}"] = np.load(_file(folder, f"y_{amp}mV_{split}.npy")) * 1e6  # m -> µm
    return arrays


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
    try:
        table = np.loadtxt(path)
    except ValueError as exc:
        raise DataError(
            f"cannot parse the table ({exc}).",
            source=str(path),
            fix="restore the original tab-separated file (see SOURCE.md)",
        ) from None
    u, y = table[:, 0], table[:, 4] - table[:, 4].mean()
    cut = int(round(train_fraction * len(u)))

    def rec(sl: slice, name: str) -> Recording:
        return Recording(
            u=u[sl],
            y=y[sl],
            fs=200.0,
            name=name,
            u_units="V",
            y_units="um",
            u_names=("voltage",),
            y_names=("displacement",),
        )

    return DatasetSplits(
        "p885",
        train=[rec(slice(0, cut), "p885_estimation")],
        test=[rec(slice(cut, None), "p885_test")],
        metadata={
            "reference": {
                "tracking RMSE without compensation": 1.68,
                "tracking RMSE with discrete-backlash-operator feedforward": 0.58,
            },
            "reference_units": "um",
            "reference_metric": "tracking errors of the compensated actuator (Aye & Ang 2018), "
            "not forward-model errors",
            "train_fraction": train_fraction,
            "licence": "MIT (Y. N. Aye); see datasets/piezo_p885/SOURCE.md",
        },
    )


# ---------------------------------------------------------------------------- Bouc-Wen
def bouc_wen(root: str | Path | None = None) -> DatasetSplits:
    """Bouc–Wen benchmark (simulated): force [N] -> displacement [mm], 750 Hz.

    Estimation: ``train.h5`` (generated multisine, 5 periods, first one transient; not an
    official file). Tests: the official multisine (8192) and sine sweep (153000) records. The
    files store metres; everything here, references included, is in millimetres.
    """
    folder = _root("bouc_wen", root)
    with h5py.File(_file(folder, "train.h5"), "r") as handle:
        u, y = np.asarray(handle["multisine/u"]), np.asarray(handle["multisine/y"])
        fs = float(np.ravel(handle["multisine/fs"])[0]) if "multisine/fs" in handle else 750.0
    train = Recording(
        u=u,
        y=y * 1e3,  # m -> mm
        fs=fs,
        name="bw_train_multisine",
        u_units="N",
        y_units="mm",
        u_names=("force",),
        y_names=("displacement",),
    )
    tests = []
    for kind in ("multisine", "sinesweep"):
        u_t = load_mat_variables(_file(folder, f"uval_{kind}.mat"))[f"uval_{kind}"].ravel()
        y_t = load_mat_variables(_file(folder, f"yval_{kind}.mat"))[f"yval_{kind}"].ravel()
        tests.append(
            Recording(
                u=u_t,
                y=y_t * 1e3,  # m -> mm
                fs=750.0,
                name=f"bw_test_{kind}",
                u_units="N",
                y_units="mm",
                u_names=("force",),
                y_names=("displacement",),
            )
        )
    # published multisine-test free-run RMSE, 1.87e-5 / 4.52e-5 / 16.3e-5 m, here in mm
    reference = {"PNLSS": 1.87e-2, "dynoNet": 4.52e-2, "NFIR": 16.3e-2}
    return DatasetSplits(
        "bouc_wen",
        train=[train],
        test=tests,
        metadata={
            "reference": reference,
            "reference_units": "mm",
            "reference_test": "bw_test_multisine",
            "reference_metric": "free-run RMSE on the multisine test (dynoNet fit 93.2 %)",
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
            y=data["qm"].ravel() * 1e3,  # m -> mm
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
        output_integrates=True,  # the cart's position integrates the motor's force
        metadata={
            "reference": {"dynoNet": 2.64},
            "reference_units": "mm",
            "reference_fit_percent": {"dynoNet": 96.8, "best linear model": 25.4},
            "reference_metric": "free-run RMSE of qm on the pulses test record after n_init=20",
            "gtau_N_per_V": 35.15,
        },
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
        "neural CT-SS soft-constrained": 0.40,
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
        shared_initial_state=True,  # SOURCE.md: the same unknown state for estimation and test
        metadata={
            "reference": reference,
            "reference_units": "V",
            "reference_metric": "free-run RMSE on the test output (recent: after n_init=50; "
            "older papers: whole record)",
        },
    )


# ---------------------------------------------------------------------------- registry entries
# registered in pyproject.toml under "hysteresis_lab.datasets"; the titles are the accuracy
# page's headings, the FSM is scored per amplitude as its benchmark is
FSM_PIEZO_MIRROR = Dataset(
    fsm_piezo_mirror,
    config="fsm",
    title="FSM piezo mirror (data=fsm), 3x3 MIMO, official test set",
    test_groups={f"{amp} mV": f"{amp}mV_" for amp in FSM_AMPLITUDES},
)
PIEZO_P885 = Dataset(
    piezo_p885, config="p885", title="PI P-885 piezo stack (data=p885), last 30 % of the record"
)
BOUC_WEN = Dataset(
    bouc_wen, title="Bouc–Wen benchmark (data=bouc_wen), in mm (1e-5 m = 0.01 mm)"
)
EMPS = Dataset(emps, title="EMPS (data=emps), pulses test record")
CASCADED_TANKS = Dataset(cascaded_tanks, title="Cascaded tanks (data=cascaded_tanks)")


def available_benchmarks() -> list[str]:
    """Names of the registered data sets (bundled and plugins; `registry.available_datasets`)."""
    return available_datasets()


def load_benchmark(name: str, root: str | Path | None = None, **options: Any) -> DatasetSplits:
    """Load the registered data set ``name`` (see `available_benchmarks`); data configs name
    this function as their ``splits._target_``.

    ``root`` points the loader at another copy of the files (e.g. the original folder);
    ``options`` go to the loader (``amplitude`` for FSM, ``train_fraction`` for P-885).
    """
    return load_dataset(name, root=root, **options)
