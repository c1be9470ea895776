"""``data=csv`` scales the user's data by statistics of the training file(s), saved with the
model; the study's fixed constants (100 V, 20 um) only when chosen explicitly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from helpers import run_app
from hysteresis_lab.data.factory import build_datamodule
from hysteresis_lab.data.readers import write_csv
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.models.io import load_model

CONF = Path(__file__).resolve().parents[1] / "src" / "hysteresis_lab" / "conf"
FS = 200.0


def p885_like(n: int, phase: float = 0.0) -> Recording:
    """A measured P-885 stack record's ranges: 0-3.6 V in, -123 ... -74 um out."""
    t = np.arange(n) / FS
    u = 1.8 + 1.8 * np.sin(2 * np.pi * t + phase)
    y = -98.5 + 24.5 * np.sin(2 * np.pi * t + phase - 0.2)
    return Recording(u=u, y=y, fs=FS, name="p885", u_names=("u",), y_names=("y",))


@pytest.fixture
def files(tmp_path) -> tuple[Path, Path]:
    return write_csv(p885_like(1400), tmp_path / "train.csv"), write_csv(
        p885_like(400, 1.0), tmp_path / "test.csv"
    )


def datamodule(files: tuple[Path, Path], *overrides: str):
    train, test = files
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose(
            "train", ["data=csv", f"data.train={train}", f"data.test=[{test}]", *overrides]
        )
    return build_datamodule(DataSpec.from_config(cfg.data), "flat")


def test_user_data_is_scaled_by_its_own_statistics_unless_a_fixed_scale_is_chosen(files):
    scaler = datamodule(files).scaler
    train = p885_like(1400)
    np.testing.assert_allclose(scaler.u_offset, [train.u.mean()], rtol=1e-6)
    np.testing.assert_allclose(scaler.u_scale, [train.u.std()], rtol=1e-6)
    np.testing.assert_allclose(scaler.y_offset, [train.y.mean()], rtol=1e-6)
    np.testing.assert_allclose(scaler.y_scale, [train.y.std()], rtol=1e-6)
    # a fixed scale stays available, chosen explicitly
    scaler = datamodule(
        files, "data.scaling.mode=paper", "data.scaling.u_scale=4", "data.scaling.y_scale=130"
    ).scaler
    assert scaler.u_scale.tolist() == [4.0] and scaler.y_scale.tolist() == [130.0]
    assert scaler.u_offset.tolist() == [0.0] and scaler.y_offset.tolist() == [0.0]


@pytest.mark.slow
def test_the_fitted_scaling_is_logged_and_saved_with_the_model(files, tmp_path):
    train, test = files
    proc = run_app(
        "train",
        "data=csv",
        f"data.train={train}",
        f"data.test=[{test}]",
        "trainer.max_epochs=1",
        "plots=false",
        "logger=none",
        "trainer.enable_progress_bar=false",
        f"hydra.run.dir={tmp_path}/run",
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "scaling=standard" in proc.stdout + proc.stderr
    scaler = load_model(tmp_path / "run" / "model.ckpt").scaler
    data = p885_like(1400)
    np.testing.assert_allclose(scaler.y_offset, [data.y.mean()], rtol=1e-5)
    np.testing.assert_allclose(scaler.y_scale, [data.y.std()], rtol=1e-5)
    # scaled like this the outputs lie near [-1.4, 1.4], not at -6 ... -3.7 (divided by 20 um)
    assert np.abs((data.y - scaler.y_offset) / scaler.y_scale).max() < 2
