"""File readers: round trips through every format and every bad-input case."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import scipy.io

from hysteresis_lab.data.readers import (
    read_csv,
    read_recording,
    write_csv,
    write_hdf5,
    write_mat,
    write_npz,
)
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.user_files import load_user_files
from hysteresis_lab.errors import DataError


@pytest.fixture
def rec() -> Recording:
    t = np.arange(200) / 50.0
    return Recording(
        u=np.column_stack([np.sin(t), np.cos(t)]),
        y=np.sin(t - 0.3) * 20,
        fs=50.0,
        name="r",
        u_names=("u", "v"),
        y_names=("y",),
    )


@pytest.mark.parametrize("writer", [write_csv, write_npz, write_mat, write_hdf5])
def test_round_trip(rec, writer, tmp_path):
    suffix = {write_csv: ".csv", write_npz: ".npz", write_mat: ".mat", write_hdf5: ".h5"}[writer]
    path = writer(rec, tmp_path / f"r{suffix}")
    back = read_recording(path, inputs=["u", "v"], outputs=["y"])
    assert back.fs == pytest.approx(50.0)
    np.testing.assert_allclose(back.u, rec.u, rtol=1e-9)
    np.testing.assert_allclose(back.y, rec.y, rtol=1e-9)


def test_mat_v73_is_read_through_h5py(rec, tmp_path):
    path = tmp_path / "v73.mat"
    with h5py.File(path, "w") as handle:  # MATLAB v7.3 stores column-major (1, N) arrays
        for key, values in (("t", rec.t), ("u", rec.u[:, 0]), ("y", rec.y[:, 0])):
            handle.create_dataset(key, data=values[None, :])
    back = read_recording(path)
    np.testing.assert_allclose(back.y[:, 0], rec.y[:, 0])
    assert back.fs == pytest.approx(50.0)


def write_text(tmp_path, text: str, name: str = "bad.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("t,u,y\n0,1,2\n0.1,nan,3\n0.2,1,2\n", "NaN/inf .* at line 3"),
        ("t,u,y\n0,1,2\n0.1,inf,3\n0.2,1,2\n", "NaN/inf"),
        ("t,u,y\n0,1,2\n0.1,1,3\n0.5,1,2\n0.6,1,2\n", "not uniformly sampled"),
        ("t,u,y\n0,1,2\n0.1,1,3\n0.1,1,2\n", "does not increase"),
        ("t,volts,y\n0,1,2\n0.1,1,3\n", r"missing column\(s\) \['u'\]; the file has"),
        ("t,u,y\n", "no data rows"),
        ("", "empty"),
        ("t,u,y\n0,abc,2\n0.1,1,3\n", "non-numeric value 'abc'"),
    ],
)
def test_bad_csv_files(tmp_path, text, message):
    path = write_text(tmp_path, text)
    with pytest.raises(DataError, match=message) as info:
        read_csv(path)
    assert str(path) in str(info.value) and "Fix:" in str(info.value)


def test_missing_time_column_needs_fs(tmp_path):
    path = write_text(tmp_path, "u,y\n1,2\n1,3\n")
    with pytest.raises(DataError, match="no time column and no sampling rate"):
        read_csv(path, time=None)
    assert read_csv(path, time=None, fs=10.0).fs == 10.0


def test_mismatched_lengths_in_npz(tmp_path):
    path = tmp_path / "m.npz"
    np.savez(path, t=np.arange(5.0), u=np.zeros(5), y=np.zeros(4))
    with pytest.raises(DataError, match="different lengths") as info:
        read_recording(path)
    assert_names_file_and_fix(info, path)


def test_unknown_suffix_and_missing_file(tmp_path):
    with pytest.raises(DataError, match="unknown file type '.xlsx'") as info:
        read_recording(tmp_path / "data.xlsx")
    assert_names_file_and_fix(info, tmp_path / "data.xlsx")
    with pytest.raises(DataError, match="no such file"):
        read_recording(tmp_path / "absent.csv")


def test_user_files_reject_mixed_sampling_rates(rec, tmp_path):
    train = write_csv(rec, tmp_path / "train.csv")
    other = Recording(u=rec.u, y=rec.y, fs=100.0, name="fast", u_names=("u", "v"), y_names=("y",))
    test = write_csv(other, tmp_path / "test.csv")
    with pytest.raises(DataError, match=r"test\.csv.*100 Hz differs from 50 Hz.*train\.csv"):
        load_user_files(train, [str(test)], columns={"inputs": ["u", "v"]})
    with pytest.raises(DataError, match="data.train=<path>"):
        load_user_files(None, [str(test)])


def assert_names_file_and_fix(info: pytest.ExceptionInfo, path) -> None:
    message = str(info.value)
    assert str(path) in message and "Fix:" in message


def test_fs_disagreeing_with_time_column(rec, tmp_path):
    path = write_csv(rec, tmp_path / "r.csv")
    with pytest.raises(DataError, match="time column gives fs = 50 Hz but fs = 100 Hz") as info:
        read_recording(path, inputs=["u", "v"], fs=100.0)
    assert_names_file_and_fix(info, path)
    assert read_recording(path, inputs=["u", "v"], fs=50.0).fs == pytest.approx(50.0)


def test_nonuniform_time_column_names_the_row(tmp_path):
    t = np.arange(20) * 0.01
    t[12:] += 0.002
    path = tmp_path / "jitter.csv"
    np.savetxt(path, np.column_stack([t, t, t]), delimiter=",", header="t,u,y", comments="")
    with pytest.raises(DataError, match="not uniformly sampled: step .* at row 12") as info:
        read_csv(path)
    assert_names_file_and_fix(info, path)


@pytest.mark.parametrize("suffix", [".npz", ".mat", ".h5"])
def test_wrong_column_names_list_what_exists(rec, tmp_path, suffix):
    writer = {".npz": write_npz, ".mat": write_mat, ".h5": write_hdf5}[suffix]
    path = writer(rec, tmp_path / f"r{suffix}")
    with pytest.raises(DataError, match=r"missing (column|dataset)\(s\) \['force'\]") as info:
        read_recording(path, inputs=["force"])
    assert "'u'" in str(info.value) and "'v'" in str(info.value)
    assert_names_file_and_fix(info, path)


@pytest.mark.parametrize("suffix", [".npz", ".mat", ".h5"])
def test_nan_and_inf_in_binary_files(tmp_path, suffix):
    y = np.zeros(10)
    y[7] = np.inf if suffix == ".mat" else np.nan
    path = tmp_path / f"bad{suffix}"
    columns = {"t": np.arange(10) / 10.0, "u": np.zeros(10), "y": y}
    if suffix == ".npz":
        np.savez(path, **columns)
    elif suffix == ".mat":
        scipy.io.savemat(path, columns)
    else:
        with h5py.File(path, "w") as handle:
            for key, values in columns.items():
                handle.create_dataset(key, data=values)
    with pytest.raises(DataError, match=r"NaN/inf value.*\((inf|nan)\) at row 8") as info:
        read_recording(path)
    assert_names_file_and_fix(info, path)


def test_missing_time_column_without_fs_in_npz(tmp_path):
    path = tmp_path / "no_t.npz"
    np.savez(path, u=np.zeros(5), y=np.zeros(5))
    with pytest.raises(DataError, match="missing column") as info:
        read_recording(path)
    assert_names_file_and_fix(info, path)
    with pytest.raises(DataError, match="no time column and no sampling rate") as info:
        read_recording(path, time=None)
    assert_names_file_and_fix(info, path)
    assert read_recording(path, time=None, fs=8.0).fs == 8.0


@pytest.mark.parametrize("suffix", [".csv", ".npz", ".mat", ".h5"])
def test_empty_and_corrupt_files(tmp_path, suffix):
    empty = tmp_path / f"empty{suffix}"
    empty.write_bytes(b"")
    with pytest.raises(DataError, match="empty") as info:
        read_recording(empty)
    assert_names_file_and_fix(info, empty)
    if suffix != ".csv":
        junk = tmp_path / f"junk{suffix}"
        junk.write_bytes(b"this is not a data file" * 10)
        with pytest.raises(DataError, match="cannot read") as info:
            read_recording(junk)
        assert_names_file_and_fix(info, junk)


def test_csv_without_header_and_other_delimiters(tmp_path):
    path = write_text(tmp_path, "0,1,2\n0.1,1,3\n")
    with pytest.raises(DataError, match="not a header") as info:
        read_csv(path)
    assert_names_file_and_fix(info, path)
    semi = write_text(tmp_path, "t;u;y\n0;1;2\n0.5;1;3\n", name="semi.csv")
    assert read_csv(semi).fs == pytest.approx(2.0)
    tabs = write_text(tmp_path, "t\tu\ty\n0\t1\t2\n0.5\t1\t3\n", name="tabs.txt")
    assert read_recording(tabs).n_samples == 2


def test_units_names_and_columns_are_configurable(tmp_path):
    path = write_text(tmp_path, "time,v1,v2,x\n0,1,2,3\n0.25,1,2,4\n0.5,1,2,5\n", "m.csv")
    back = read_csv(
        path, time="time", inputs=["v1", "v2"], outputs="x", units={"u": "mV", "y": "nm"}
    )
    assert (back.nu, back.ny, back.fs) == (2, 1, 4.0)
    assert (back.u_units, back.y_units, back.u_names) == ("mV", "nm", ("v1", "v2"))
    assert back.name == "m" and back.metadata["path"] == str(path)
    with pytest.raises(DataError, match="unknown key"):
        read_csv(path, time="time", inputs=["v1"], outputs="x", units={"z": "V"})


def test_hdf5_dataset_paths(rec, tmp_path):
    path = tmp_path / "grouped.hdf5"
    with h5py.File(path, "w") as handle:
        handle.create_dataset("exp/input", data=rec.u[:, 0])
        handle.create_dataset("exp/output", data=rec.y[:, 0])
        handle.attrs["fs"] = 50.0
    back = read_recording(path, time=None, inputs="exp/input", outputs="exp/output")
    assert back.fs == 50.0
    np.testing.assert_allclose(back.y[:, 0], rec.y[:, 0])
    with pytest.raises(DataError, match=r"the file has \['exp/input', 'exp/output'\]"):
        read_recording(path, time=None, inputs="u", outputs="exp/output")


def test_mat_v73_matrix_is_transposed(tmp_path):
    u = np.random.default_rng(0).normal(size=(40, 3))
    path = tmp_path / "mimo73.mat"
    with h5py.File(path, "w") as handle:  # MATLAB writes an N x 3 matrix as a (3, N) dataset
        handle.create_dataset("u", data=u.T)
        handle.create_dataset("y", data=u[:, :1].T * 2)
        handle.create_dataset("t", data=(np.arange(40) / 100.0)[None, :])
    back = read_recording(path)
    assert (back.nu, back.ny, back.fs) == (3, 1, pytest.approx(100.0))
    np.testing.assert_allclose(back.u, u)


def test_scipy_mat_with_matrix_inputs(tmp_path):
    path = tmp_path / "mimo.mat"
    scipy.io.savemat(path, {"u": np.zeros((30, 2)), "y": np.ones((30, 1)), "fs": 10.0})
    back = read_recording(path, time=None, fs=10.0)
    assert back.nu == 2 and back.ny == 1


# ----------------------------------------------------------------------------- value limits
def test_an_absurd_value_is_refused_with_its_line(tmp_path):
    """1e300 is finite, but no measurement: a model trained on it learns NaN (issue #35)."""
    lines = ["t,u,y"] + [f"{k / 100:g},{np.sin(k / 10):.4f},{k / 7:.4f}" for k in range(50)]
    lines.insert(3, "")  # a blank line: a sample's line is still the one an editor shows
    lines[31] = "0.29,0.2392,1e300"
    path = write_text(tmp_path, "\n".join(lines) + "\n", name="run.csv")
    with pytest.raises(DataError, match=r"value 1e\+300 in column 'y' at line 32 is beyond "
                       r"the physical range \|y\| <= 1e\+09 um") as info:
        read_recording(path)
    assert_names_file_and_fix(info, path)
    assert "data.limits.y_abs_max" in info.value.fix
    read_recording(path, limits={"y_abs_max": float("inf")})  # a bound of its own lets it in


@pytest.mark.parametrize("suffix", [".npz", ".mat", ".h5"])
def test_a_value_beyond_a_configured_limit_names_its_row(rec, tmp_path, suffix):
    u = rec.u.copy()
    u[41, 1] = -250.0  # a glitch on the second input, row 42
    spiked = Recording(u=u, y=rec.y, fs=rec.fs, u_names=rec.u_names, y_names=rec.y_names)
    writer = {".npz": write_npz, ".mat": write_mat, ".h5": write_hdf5}[suffix]
    path = writer(spiked, tmp_path / f"r{suffix}")
    with pytest.raises(DataError, match=r"value -250 in column 'v' at row 42 is beyond "
                       r"the physical range \|v\| <= 200 V") as info:
        read_recording(path, inputs=["u", "v"], limits={"u_abs_max": 200})
    assert_names_file_and_fix(info, path)
    assert read_recording(path, inputs=["u", "v"], limits={"u_abs_max": 300}).nu == 2


def test_empty_cell_and_nan_time_name_their_line(tmp_path):
    path = write_text(tmp_path, "t,u,y\n0,1,2\n0.1,1,3\n0.2,,2\n")
    with pytest.raises(DataError, match=r"column 'u' holds 1 NaN/inf value\(s\), the first "
                       r"\(nan\) at line 4") as info:
        read_csv(path)
    assert "empty cell" in info.value.fix
    path = write_text(tmp_path, "t,u,y\n0,1,2\nnan,1,3\n0.2,1,2\n", name="t.csv")
    with pytest.raises(DataError, match="column 't' holds 1 NaN/inf value.* at line 3"):
        read_csv(path)


@pytest.mark.parametrize(
    ("limits", "message"),
    [({"y_max": 3}, r"unknown key\(s\) \['y_max'\]"), ({"y_abs_max": -1}, "not a positive")],
)
def test_malformed_limits_are_refused(rec, tmp_path, limits, message):
    path = write_csv(rec, tmp_path / "r.csv")
    with pytest.raises(DataError, match=message) as info:
        read_recording(path, inputs=["u", "v"], limits=limits)
    assert "Fix:" in str(info.value) and "data.limits" in str(info.value)


def test_a_column_limit_bounds_that_column_only(rec, tmp_path):
    """``data.limits.columns``: a MIMO set's channels of different ranges."""
    path = write_csv(rec, tmp_path / "r.csv")  # |u|, |v| <= 1, |y| <= 20
    limits = {"u_abs_max": 5, "columns": {"v": 0.5}}
    with pytest.raises(DataError, match=r"in column 'v' at line \d+ is beyond the physical range "
                       r"\|v\| <= 0\.5 V \(data\.limits\.columns\.v;") as info:
        read_recording(path, inputs=["u", "v"], limits=limits)
    assert "raise data.limits.columns.v" in info.value.fix
    # the column's own bound wins over u_abs_max, either way
    read_recording(path, inputs=["u", "v"], limits={"u_abs_max": 0.5, "columns": {"u": 2,
                                                                                   "v": 2}})
    with pytest.raises(DataError, match=r"data.limits.columns names \['w'\]"):
        read_recording(path, inputs=["u", "v"], limits={"columns": {"w": 1}})
