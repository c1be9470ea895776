"""``data=csv``: the user's own files composed through Hydra and loaded into `DatasetSplits`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from hysteresis_lab.data.factory import build_splits
from hysteresis_lab.data.readers import write_csv, write_npz
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.data.user_files import load_user_files
from hysteresis_lab.errors import DataError

CONF = Path(__file__).resolve().parents[1] / "src" / "hysteresis_lab" / "conf"


def recording(fs: float = 1000.0, n: int = 400, phase: float = 0.0) -> Recording:
    t = np.arange(n) / fs
    u = 50 * np.sin(2 * np.pi * 5 * t + phase)
    return Recording(u=u, y=0.2 * u + np.cos(t), fs=fs, u_names=("u",), y_names=("y",))


@pytest.fixture
def files(tmp_path) -> dict[str, str]:
    return {
        "train": str(write_csv(recording(), tmp_path / "train.csv")),
        "val": str(write_csv(recording(phase=0.5), tmp_path / "val.csv")),
        "test1": str(write_csv(recording(phase=1.0), tmp_path / "sine1.csv")),
        "test2": str(write_npz(recording(phase=2.0, n=300), tmp_path / "sine2.npz")),
    }


def compose_data(overrides: list[str]):
    with initialize_config_dir(config_dir=str(CONF)):
        return compose("train", overrides=["data=csv", *overrides]).data


def test_compose_data_csv_and_build_splits(files):
    data_cfg = compose_data(
        [f"data.train={files['train']}", f"data.test=[{files['test1']},{files['test2']}]"]
    )
    splits = build_splits(data_cfg)
    assert isinstance(splits, DatasetSplits) and splits.name == "csv"
    assert len(splits.train) == 1 and len(splits.test) == 2 and splits.val == []
    assert splits.fs == pytest.approx(1000.0) and splits.units == {"u": "V", "y": "um"}
    assert [r.n_samples for r in splits.test] == [400, 300]
    np.testing.assert_allclose(splits.test[1].u, recording(phase=2.0, n=300).u, rtol=1e-9)


def test_compose_with_val_units_and_n_init(files):
    data_cfg = compose_data(
        [
            f"data.train=[{files['train']}]",
            f"data.val={files['val']}",
            f"data.test=[{files['test1']}]",
            "data.units.y=nm",
            "data.n_init=25",
        ]
    )
    splits = build_splits(data_cfg)
    assert len(splits.val) == 1 and splits.n_init == 25 and splits.units["y"] == "nm"


def test_missing_train_says_how_to_set_it(files):
    with pytest.raises(DataError, match=r"set data\.train=<path>") as info:
        build_splits(compose_data([f"data.test=[{files['test1']}]"]))
    assert "Fix:" in str(info.value)


def test_single_test_string_and_no_time_column(tmp_path):
    path = tmp_path / "plain.csv"
    np.savetxt(path, np.ones((10, 2)), delimiter=",", header="volts,microns", comments="")
    splits = load_user_files(
        str(path),
        str(path),
        columns={"time": None, "inputs": ["volts"], "outputs": ["microns"]},
        fs=20.0,
    )
    assert splits.fs == 20.0 and len(splits.test) == 1 and splits.train[0].u_names == ("volts",)


def test_different_sampling_rates_name_both_files(tmp_path):
    train = write_csv(recording(fs=1000.0), tmp_path / "slow.csv")
    test = write_csv(recording(fs=2000.0), tmp_path / "fast.csv")
    with pytest.raises(DataError, match="2000 Hz differs from 1000 Hz") as info:
        load_user_files(str(train), [str(test)])
    message = str(info.value)
    assert str(train) in message and str(test) in message and "Fix:" in message


def test_different_channel_counts_name_both_files(tmp_path):
    train = write_csv(recording(), tmp_path / "one.csv")
    test = tmp_path / "two.npz"  # an (N, 2) input matrix is read as two input channels
    np.savez(test, t=np.arange(50) / 1000.0, u=np.zeros((50, 2)), y=np.zeros(50))
    counts = r"two\.npz: 2 input\(s\) / 1 output\(s\) but .*one\.csv has 1 / 1"
    with pytest.raises(DataError, match=counts) as info:
        load_user_files(str(train), [str(test)])
    assert str(train) in str(info.value) and str(test) in str(info.value)


def test_data_limits_reach_every_file_of_data_csv(files, tmp_path):
    """``data.limits`` (conf/data/csv.yaml) bounds the training and the test files alike."""
    big = recording(phase=1.0)
    path = write_csv(Recording(u=big.u, y=big.y * 100, fs=big.fs, u_names=("u",),
                               y_names=("y",)), tmp_path / "big.csv")
    overrides = [f"data.train={files['train']}", f"data.test=[{path}]"]
    assert len(build_splits(compose_data(overrides)).test) == 1  # within the default 1e9
    with pytest.raises(DataError, match=r"big\.csv: value .* in column 'y' at line \d+ is "
                       r"beyond the physical range \|y\| <= 50 um") as info:
        build_splits(compose_data([*overrides, "data.limits.y_abs_max=50"]))
    assert "Fix:" in str(info.value)


def test_a_column_limit_is_set_from_the_command_line(files, tmp_path):
    overrides = [f"data.train={files['train']}", f"data.test=[{files['test1']}]"]
    with pytest.raises(DataError, match=r"train\.csv: value .* in column 'u' at line \d+ is "
                       r"beyond the physical range \|u\| <= 10 V \(data\.limits\.columns\.u;"):
        build_splits(compose_data([*overrides, "+data.limits.columns.u=10"]))
