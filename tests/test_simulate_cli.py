"""``hysteresis-lab-simulate``: Hydra overrides reach the simulator and a t,u,y CSV is written."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # every test here runs a console app


def simulate(tmp_path: Path, *overrides: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "hysteresis_lab.cli.simulate", *overrides],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_cli_writes_a_sine_csv(tmp_path):
    out = tmp_path / "x.csv"
    result = simulate(
        tmp_path,
        "signal.kind=sine",
        "signal.frequency=10",
        "effects.creep.enabled=false",
        f"output={out}",
    )
    assert result.returncode == 0, result.stderr
    assert str(out) in result.stdout + result.stderr  # the path is logged
    assert out.read_text().splitlines()[0] == "t,u,y"
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    assert data.shape == (4000, 3)  # two periods of 10 Hz at 20 kHz
    np.testing.assert_allclose(data[:, 0], np.arange(4000) / 20_000.0)
    assert np.max(np.abs(data[:, 1])) == np.float64(100.0)
    assert 36.0 < np.ptp(data[:, 2]) < 44.0  # ±100 V -> about ±20 um
    assert (tmp_path / "outputs" / "simulate").is_dir()  # Hydra's run dir stays under outputs/


def test_cli_default_output_path_and_multisine(tmp_path):
    result = simulate(
        tmp_path, "signal.n_samples=2000", "signal.n_components=50", "signal.f_max=50"
    )
    assert result.returncode == 0, result.stderr
    data = np.loadtxt(
        tmp_path / "outputs" / "simulated" / "multisine.csv", delimiter=",", skiprows=1
    )
    assert data.shape == (2000, 3)


def test_cli_reports_config_errors_without_traceback(tmp_path):
    result = simulate(tmp_path, "signal.kind=square", f"output={tmp_path / 'y.csv'}")
    assert result.returncode == 2
    assert "unknown signal.kind 'square'" in result.stderr + result.stdout
    assert "Traceback" not in result.stderr
    result = simulate(tmp_path, "+effects.creap.enabled=false", f"output={tmp_path / 'y.csv'}")
    assert result.returncode == 2
    assert "unknown effect block 'creap'" in result.stderr + result.stdout
