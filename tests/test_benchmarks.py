"""Every bundled benchmark loader on its real files: shapes, units, splits, scoring windows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hysteresis_lab.data.benchmarks import available_benchmarks, load_benchmark
from hysteresis_lab.errors import DataError

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def test_fsm_piezo_mirror_official_split():
    data = load_benchmark("fsm_piezo_mirror")
    assert data.fs == 6400.0 and data.n_init == 100
    assert (data.nu, data.ny) == (3, 3) and data.units == {"u": "V", "y": "um"}
    assert len(data.train) == 3 * 6 and len(data.test) == 3 * 3
    assert all(r.n_samples == 2 * 8192 for r in data.train + data.test)
    y300 = np.concatenate([r.y for r in data.test if r.metadata["amplitude_mV"] == 300])
    assert 2.0 < y300.std() < 8.0  # about 4 um at 300 mV (SOURCE.md)
    assert data.metadata["reference"]["NL-LFR"][100] == pytest.approx(0.0866)
    one = load_benchmark("fsm_piezo_mirror", amplitude=200)
    assert len(one.train) == 6 and {r.metadata["amplitude_mV"] for r in one.test} == {200}


@pytest.mark.skipif(not (SHARED / "fsm_piezo_mirror").is_dir(), reason="original data not here")
def test_fsm_bundle_matches_the_original_files():
    data = load_benchmark("fsm_piezo_mirror", amplitude=100)
    y = np.load(SHARED / "fsm_piezo_mirror" / "y_100mV_test.npy")  # (N, 3, R, P) in m
    original = np.concatenate([y[:, :, 0, 0], y[:, :, 0, 1]]) * 1e6
    np.testing.assert_allclose(data.test[0].y, original, rtol=1e-6, atol=1e-6)


def test_piezo_p885():
    data = load_benchmark("piezo_p885")
    assert data.fs == 200.0 and data.units == {"u": "V", "y": "um"}
    n = data.train[0].n_samples + data.test[0].n_samples
    assert n == 8027 and data.train[0].n_samples == round(0.7 * 8027)
    u = data.train[0].u
    assert u.min() >= 0.0 and u.max() <= 3.7
    y = np.concatenate([data.train[0].y, data.test[0].y])
    assert abs(y.mean()) < 1e-9 and 15 < np.ptp(y) < 60  # about +-25 um


def test_bouc_wen():
    data = load_benchmark("bouc_wen")
    assert data.fs == 750.0 and data.units == {"u": "N", "y": "mm"}
    assert data.train[0].n_samples == 40960
    assert [r.n_samples for r in data.test] == [8192, 153000]
    assert 0.3 < data.test[0].y.std() < 1.2  # std about 6.7e-4 m = 0.67 mm


def test_emps():
    data = load_benchmark("emps")
    assert data.fs == 1000.0 and data.n_init == 20 and data.units["y"] == "mm"
    assert data.train[0].n_samples == data.test[0].n_samples == 24841
    assert 200 < data.train[0].y.max() < 260  # qm up to 0.246 m


def test_cascaded_tanks():
    data = load_benchmark("cascaded_tanks")
    assert data.fs == pytest.approx(0.25) and data.n_init == 50
    assert data.train[0].n_samples == data.test[0].n_samples == 1024
    assert data.test[0].y.max() <= 10.0 + 1e-9  # the overflow clips the level sensor


def test_every_loader_is_listed_and_unknown_names_fail():
    assert available_benchmarks() == sorted(
        ["fsm_piezo_mirror", "piezo_p885", "bouc_wen", "emps", "cascaded_tanks"])
    with pytest.raises(DataError, match="unknown dataset 'silverbox'.*bouc_wen"):
        load_benchmark("silverbox")
    with pytest.raises(DataError, match="amplitude"):
        load_benchmark("fsm_piezo_mirror", amplitude=150)
