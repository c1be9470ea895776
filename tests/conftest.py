"""Shared fixtures: small recordings with known structure."""

from __future__ import annotations

import importlib
import os
from types import ModuleType

import numpy as np
import pytest

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.fitting import build_model, fit
from narx import CONFIGS, TRAINER, datamodule_for, narx_data


def pytest_configure(config: pytest.Config) -> None:
    """In a pytest-xdist worker, one thread per process (the workers already share the
    cores; the console apps the tests start inherit the setting)."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        import torch

        torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))


def optional_dependency(name: str) -> ModuleType:
    """Import an optional dependency (onnxruntime, pgserver): skip the test where it is not
    installed, except in CI (``CI`` set), whose test install includes it: there its absence
    is a failure, not a silent skip."""
    if os.environ.get("CI"):
        return importlib.import_module(name)
    return pytest.importorskip(name)


def make_recording(
    n: int, name: str, nu: int = 1, ny: int = 1, fs: float = 1000.0, seed: int = 0
) -> Recording:
    """A recording whose samples encode their own index: u = k, y = -k (per channel offsets)."""
    k = np.arange(n, dtype=float)[:, None]
    u = k + 1000.0 * np.arange(nu)[None, :]
    y = -k - 1000.0 * np.arange(ny)[None, :]
    return Recording(u=u, y=y, fs=fs, name=name)


@pytest.fixture
def index_recordings() -> list[Recording]:
    return [make_recording(50, "a"), make_recording(30, "b")]


@pytest.fixture(scope="session")
def splits() -> DatasetSplits:
    """The small NARX data set of `narx` (train + two sine tests)."""
    return narx_data()


@pytest.fixture(scope="session")
def trained(splits, tmp_path_factory) -> dict:
    """Every built-in architecture trained briefly on `splits`: name -> (model, datamodule)."""
    models = {}
    for name, cfg in CONFIGS.items():
        dm = datamodule_for(name, splits)
        result = fit(build_model(cfg, dm), dm, TRAINER, tmp_path_factory.mktemp(name))
        models[name] = (result.model, dm)
    return models
