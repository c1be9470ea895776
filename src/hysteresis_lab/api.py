"""The Python API: compose, train, simulate and score a model from a script or notebook.

The same packaged configs and overrides as the console apps, so a notebook and
``hysteresis-lab-train`` give the same model for the same settings:

```python
import hysteresis_lab as hl

cfg = hl.compose("model=ffnn", "trainer.max_epochs=20")
run = hl.train(cfg, "outputs/notebook")     # the run folder hysteresis-lab-train writes
data = hl.load_data(cfg)
y = hl.simulate(run.model, data.test)       # free run: from the input alone
```
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omegaconf import DictConfig, open_dict

from hysteresis_lab.errors import ConfigError

if TYPE_CHECKING:
    import numpy as np

    from hysteresis_lab.data.recording import Recording
    from hysteresis_lab.data.splits import DatasetSplits
    from hysteresis_lab.evaluation.evaluate import Evaluation
    from hysteresis_lab.workflows.pipeline import RunResult

#: the packaged Hydra configs (``src/hysteresis_lab/conf``)
CONFIG_MODULE = "hysteresis_lab.conf"


def compose(*overrides: str, config: str = "train") -> DictConfig:
    """The packaged config ``config`` (``train``, ``loop``, ``evaluate``, ``simulate``) with
    Hydra ``overrides`` such as ``"model=lstm"`` or ``"trainer.max_epochs=20"``, composed and
    checked as the console app of that name does: an unknown group choice or an override
    that changes a value's type (``training.lr=abc``) is a `ConfigError` naming the fix; a
    training setting under its old name (``model.lr=1e-4``) is taken as its new one
    (``training.lr``), with a deprecation warning."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_module

    from hysteresis_lab.cli._overrides import (
        check_group_choices,
        check_overrides,
        renamed_overrides,
    )

    overrides = tuple(renamed_overrides(list(overrides)))
    check_group_choices(config, list(overrides))
    with warnings.catch_warnings():
        # outputs/optuna/best exists only after a finished sweep; until then its search-path
        # entry is empty, which is normal (the console apps mute the same warning)
        warnings.filterwarnings("ignore", message=r"provider=hydra\.searchpath in main, "
                                r"path=outputs/optuna/best is not", category=UserWarning)
        with initialize_config_module(config_module=CONFIG_MODULE):
            cfg = hydra_compose(config_name=config, overrides=list(overrides),
                                return_hydra_config=True)
            hydra_cfg = cfg.hydra
            with open_dict(cfg):
                del cfg["hydra"]
            check_overrides(cfg, hydra_cfg)
    return cfg


def load_data(cfg: DictConfig) -> DatasetSplits:
    """The data set of a composed config (its ``data`` node): the simulated positioner, a
    bundled benchmark or your CSV files, split into training, validation and test recordings."""
    from hysteresis_lab.data.factory import build_splits

    return build_splits(cfg.data)


def train(
    cfg: DictConfig, output_dir: str | Path, splits: DatasetSplits | None = None
) -> RunResult:
    """Train the model of a composed ``train`` config and score it on every test recording, as
    ``hysteresis-lab-train`` does; its run folder (``model.ckpt`` or ``model.skops``,
    ``metrics.json``, figures, TensorBoard logs unless ``logger=none``) goes to
    ``output_dir``. ``splits``: data already loaded with `load_data` (else loaded here)."""
    from hysteresis_lab.workflows.pipeline import train_from_config

    if cfg.get("task", "train") != "train":
        raise ConfigError(
            f"train() runs task=train, not task={cfg.task}. Fix: compose without "
            "experiment=paper, or run hysteresis-lab-train experiment=paper."
        )
    return train_from_config(cfg, Path(output_dir), splits=splits)


def simulate(model: Any, recordings: Sequence[Recording]) -> list[np.ndarray]:
    """Free-run simulation of a fitted model: each recording's output (samples x outputs,
    physical units) predicted from its input alone, the first window taken from the
    measurement as initial conditions."""
    from hysteresis_lab.evaluation.predict import free_run
    from hysteresis_lab.models.augment import for_model

    return free_run(model, for_model(model, recordings), model.window)


def evaluate(model: Any, recordings: Sequence[Recording], n_init: int = 0) -> Evaluation:
    """Score a fitted model on ``recordings`` in both modes, one-step and free run: RMSE, R²
    and NRMSE per recording (``.metrics[name]["rmse_free_run"]``) and the predictions behind
    them. ``n_init``: samples not scored at the start (the data set's ``n_init``)."""
    from hysteresis_lab.evaluation.evaluate import evaluate_model
    from hysteresis_lab.models.augment import for_model

    return evaluate_model(model, for_model(model, recordings), model.window, n_init)
