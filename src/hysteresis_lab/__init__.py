"""hysteresis_lab: deep-learning identification of hysteretic actuators.

The curated Python API (imported on first use, so ``import hysteresis_lab`` stays light):

- configs and data: `compose`, `load_data`, `make_default_dataset`, `load_benchmark`,
  `available_benchmarks`, `load_user_files`, `Recording`, `DatasetSplits`;
- models: `available_models`, `train`, `save_model`, `load_model`;
- prediction and scores: `simulate` (free run), `evaluate` (one-step and free run),
  `rmse`, `r2`, `nrmse`;
- errors: `HysteresisLabError` and its subclasses in `hysteresis_lab.errors`.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

__version__ = "0.1.0"

#: public name -> module that defines it
_EXPORTS = {
    "compose": "hysteresis_lab.api",
    "load_data": "hysteresis_lab.api",
    "train": "hysteresis_lab.api",
    "simulate": "hysteresis_lab.api",
    "evaluate": "hysteresis_lab.api",
    "make_default_dataset": "hysteresis_lab.sim.default_dataset",
    "load_benchmark": "hysteresis_lab.data.benchmarks",
    "available_benchmarks": "hysteresis_lab.data.benchmarks",
    "load_user_files": "hysteresis_lab.data.user_files",
    "Recording": "hysteresis_lab.data.recording",
    "DatasetSplits": "hysteresis_lab.data.splits",
    "available_models": "hysteresis_lab.models.registry",
    "save_model": "hysteresis_lab.models.io",
    "load_model": "hysteresis_lab.models.io",
    "rmse": "hysteresis_lab.evaluation.metrics",
    "r2": "hysteresis_lab.evaluation.metrics",
    "nrmse": "hysteresis_lab.evaluation.metrics",
    "HysteresisLabError": "hysteresis_lab.errors",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    """Import a public name's module on first use (PEP 562)."""
    if name not in _EXPORTS:
        raise AttributeError(f"module 'hysteresis_lab' has no attribute {name!r}")
    value = getattr(import_module(_EXPORTS[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
