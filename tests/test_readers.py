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
        ("t,u,y\n0,1,2\n0.1,nan,3\n0.2,1,2\n", "NaN/inf .* sample 1"),
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
    with pytest.raises(DataError, match="different lengths"):
        read_recording(path)


def test_unknown_suffix_and_missing_file(tmp_path):
    with pytest.raises(DataError, match="unknown file type '.xlsx'"):
        read_recording(tmp_path / "data.xlsx")
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


def test_scipy_mat_with_matrix_inputs(tmp_path):
    path = tmp_path / "mimo.mat"
    scipy.io.savemat(path, {"u": np.zeros((30, 2)), "y": np.ones((30, 1)), "fs": 10.0})
    back = read_recording(path, time=None, fs=10.0)
    assert back.nu == 2 and back.ny == 1
