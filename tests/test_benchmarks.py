"""Every bundled benchmark loader on its real files: shapes, units, splits, scoring windows."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from hysteresis_lab.data.benchmarks import available_benchmarks, load_benchmark
from hysteresis_lab.data.registry import GROUP, available_datasets, get_dataset
from hysteresis_lab.errors import DataError
from hysteresis_lab.plugins import points

REPO = Path(__file__).resolve().parents[1]


def shared_data() -> Path | None:
    """The original benchmark files: ``shared/data`` in the checkout or in a folder above it
    (a worktree beside others); None where no such folder is (a plain clone)."""
    for folder in (REPO, *REPO.parents):
        if (folder / "shared" / "data").is_dir():
            return folder / "shared" / "data"
    return None


SHARED = shared_data()
BUNDLED = Path(str(resources.files("hysteresis_lab") / "datasets"))


def bundled_datasets() -> list[str]:
    """The registered data sets this package ships (a plugin's are left out)."""
    return sorted(name for name, point in points(GROUP).items()
                  if point.value.startswith("hysteresis_lab."))


def test_fsm_piezo_mirror_official_split():
    data = load_benchmark("fsm_piezo_mirror")
    assert data.fs == 6400.0 and data.n_init == 100
    assert (data.nu, data.ny) == (3, 3) and data.units == {"u": "V", "y": "um"}
    # train: 6 realisations x 3 amplitudes, both periods; test: 3 realisations x 2 periods x 3
    assert len(data.train) == 3 * 6 and len(data.test) == 3 * 3 * 2
    assert all(r.n_samples == 2 * 8192 for r in data.train)
    assert all(r.n_samples == 8192 for r in data.test)
    assert data.test[0].name == "100mV_test_r1_p1" and data.test[-1].name == "300mV_test_r3_p2"
    for amp, std in ((100, 1.36), (200, 2.72), (300, 4.04)):  # SOURCE.md: ~4 um at 300 mV
        y = np.concatenate([r.y for r in data.test if r.metadata["amplitude_mV"] == amp])
        u = np.concatenate([r.u for r in data.test if r.metadata["amplitude_mV"] == amp])
        assert y.std() == pytest.approx(std, rel=0.02) and np.abs(y).max() < 25.0
        assert u.std() == pytest.approx(amp / 1000, rel=0.02)
    ref = data.metadata["reference"]
    assert ref["NL-LFR"] == {100: 0.0866, 200: 0.1309, 300: 0.1686}
    assert data.metadata["reference_units"] == "um"
    one = load_benchmark("fsm_piezo_mirror", amplitude=200)
    assert len(one.train) == 6 and {r.metadata["amplitude_mV"] for r in one.test} == {200}
    assert len(load_benchmark("fsm_piezo_mirror", amplitude="300").test) == 6


def test_fsm_bundle_is_small_float32():
    folder = BUNDLED / "fsm_piezo_mirror"
    assert (folder / "SOURCE.md").is_file() and (folder / "convert.py").is_file()
    for amp in (100, 200, 300):
        path = folder / f"fsm_{amp}mV.npz"
        assert path.stat().st_size < 8 * 2**20
        with np.load(path) as archive:
            assert {archive[k].dtype for k in archive.files} == {np.dtype(np.float32)}
            assert archive["y_train"].shape == (8192, 3, 6, 2)
            assert archive["u_test"].shape == (8192, 3, 3, 2)


def test_bundled_files_stay_small():
    files = [p for p in BUNDLED.rglob("*") if p.is_file()]
    assert max(p.stat().st_size for p in files) < 8 * 2**20
    assert sum(p.stat().st_size for p in files) < 30 * 2**20
    # every bundled folder is a registered data set, and every one registered here has its files
    folders = sorted(p.name for p in BUNDLED.iterdir() if (p / "SOURCE.md").is_file())
    assert folders == bundled_datasets() and len(folders) >= 5


@pytest.mark.skipif(SHARED is None, reason="no shared/data folder with the original files")
def test_fsm_bundle_matches_the_original_files():
    bundled = load_benchmark("fsm_piezo_mirror")
    original = load_benchmark("fsm_piezo_mirror", root=SHARED / "fsm_piezo_mirror")
    assert [r.name for r in bundled.test] == [r.name for r in original.test]
    for a, b in zip(bundled.train + bundled.test, original.train + original.test, strict=True):
        np.testing.assert_allclose(a.u, b.u, rtol=1e-6, atol=1e-7)  # float32 precision
        np.testing.assert_allclose(a.y, b.y, rtol=1e-6, atol=1e-5)
    raw = np.load(SHARED / "fsm_piezo_mirror" / "y_100mV_test.npy")  # (N, 3, R, P) in m
    np.testing.assert_allclose(bundled.test[1].y, raw[:, :, 0, 1] * 1e6, rtol=1e-6, atol=1e-5)


def test_piezo_p885():
    data = load_benchmark("piezo_p885")
    assert data.fs == 200.0 and data.units == {"u": "V", "y": "um"} and data.n_init == 0
    n = data.train[0].n_samples + data.test[0].n_samples
    assert n == 8027 and data.train[0].n_samples == round(0.7 * 8027)
    u = np.concatenate([data.train[0].u, data.test[0].u])
    assert u.min() == pytest.approx(0.0) and u.max() == pytest.approx(3.6)
    y = np.concatenate([data.train[0].y, data.test[0].y])
    assert abs(y.mean()) < 1e-9 and np.ptp(y) == pytest.approx(123.059 - 73.636, rel=1e-3)
    assert data.metadata["reference"]["tracking RMSE without compensation"] == 1.68
    half = load_benchmark("piezo_p885", train_fraction=0.5)
    assert half.train[0].n_samples == round(0.5 * 8027)
    with pytest.raises(DataError, match="train_fraction"):
        load_benchmark("piezo_p885", train_fraction=1.5)


def test_bouc_wen():
    data = load_benchmark("bouc_wen")
    assert data.fs == 750.0 and data.units == {"u": "N", "y": "mm"}
    assert data.train[0].n_samples == 40960
    assert [r.name for r in data.test] == ["bw_test_multisine", "bw_test_sinesweep"]
    assert [r.n_samples for r in data.test] == [8192, 153000]
    assert data.test[0].y.std() == pytest.approx(0.667, rel=0.01)  # 6.67e-4 m
    assert np.abs(data.test[0].y).max() == pytest.approx(2.33, rel=0.01)
    assert data.test[0].u.std() == pytest.approx(50.0, rel=1e-3)  # RMS 50 N
    assert data.metadata["reference"]["PNLSS"] == pytest.approx(1.87e-2)  # 1.87e-5 m in mm
    assert data.metadata["reference_units"] == "mm"


def test_emps():
    data = load_benchmark("emps")
    assert data.fs == 1000.0 and data.n_init == 20 and data.units == {"u": "V", "y": "mm"}
    assert data.train[0].n_samples == data.test[0].n_samples == 24841
    assert data.train[0].y.max() == pytest.approx(246.4, rel=1e-3)  # qm up to 0.246 m
    assert data.test[0].y.std() == pytest.approx(82.7, rel=1e-3)  # 0.0827 m
    assert data.metadata["reference"]["dynoNet"] == 2.64


def test_cascaded_tanks():
    data = load_benchmark("cascaded_tanks")
    assert data.fs == pytest.approx(0.25) and data.n_init == 50
    assert data.units == {"u": "V", "y": "V"}
    assert data.train[0].n_samples == data.test[0].n_samples == 1024
    assert data.test[0].y.max() <= 10.0 + 1e-9  # the overflow clips the level sensor
    assert data.train[0].u[0, 0] == pytest.approx(3.2567)
    assert data.test[0].y[0, 0] == pytest.approx(4.9728)
    assert data.metadata["reference"]["grey-box with overflow"] == 0.18


@pytest.mark.parametrize("name", bundled_datasets())
def test_every_registered_data_set_loads_with_its_splits(name):
    data = load_benchmark(name)
    # the splits carry the name of the data config that selects them (data=fsm, ...)
    assert data.name == get_dataset(name).config_name(name)
    assert data.train and data.test and data.fs > 0
    assert data.metadata["reference"] and data.metadata["reference_units"] == data.units["y"]
    for rec in data.train + data.test:
        assert rec.n_samples > data.n_init and np.isfinite(rec.u).all() and np.isfinite(rec.y).all()


def test_every_loader_is_listed_and_unknown_names_fail(tmp_path):
    assert available_benchmarks() == available_datasets()
    assert set(bundled_datasets()) <= set(available_benchmarks())
    with pytest.raises(DataError, match="unknown dataset 'silverbox'.*bouc_wen") as info:
        load_benchmark("silverbox")
    assert "Fix:" in str(info.value)
    with pytest.raises(DataError, match="amplitude"):
        load_benchmark("fsm_piezo_mirror", amplitude=150)
    with pytest.raises(DataError, match="unknown option"):
        load_benchmark("emps", amplitude=100)
    with pytest.raises(DataError, match="missing"):
        load_benchmark("emps", root=tmp_path)
