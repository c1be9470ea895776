"""A small nonlinear ARX system with play-operator memory, and the model settings the
architecture, prediction and export tests share."""

from __future__ import annotations

import numpy as np

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.registry import get_model_class


def narx_data(n: int = 1500, nu: int = 1, ny: int = 1, seed: int = 0) -> DatasetSplits:
    """A stable nonlinear ARX system with hysteresis-like memory (play operator)."""
    rng = np.random.default_rng(seed)

    def simulate(u: np.ndarray, name: str) -> Recording:
        y = np.zeros((len(u), ny))
        play = 0.0
        for k in range(2, len(u)):
            play = max(u[k - 1, 0] - 0.2, min(u[k - 1, 0] + 0.2, play))
            y[k] = 0.6 * y[k - 1] - 0.1 * y[k - 2] + 0.5 * play + 0.2 * np.tanh(u[k - 1].sum())
        return Recording(u=u, y=y, fs=100.0, name=name)

    train = simulate(rng.uniform(-1, 1, (n, nu)), "train")
    t = np.arange(400) / 100.0
    test = [
        simulate(np.tile(np.sin(2 * np.pi * f * t)[:, None], (1, nu)), f"sine{f}")
        for f in (1.0, 3.0)
    ]
    return DatasetSplits("narx", train=[train], test=test)


def datamodule_for(name: str, splits: DatasetSplits) -> WindowDataModule:
    layout = get_model_class(name).layout
    return WindowDataModule(splits, layout=layout, scaling="standard", batch_size=64)


CONFIGS = {
    "ffnn": {"name": "ffnn", "num_layers": 3, "neurons": 32},
    "lstm": {"name": "lstm", "num_layers": 2, "lstm_layers": 1, "units": 16, "lr": 5e-3},
    "cnn": {
        "name": "cnn",
        "num_layers": 3,
        "conv_layers": 2,
        "units": 24,
        "kernel_size": 3,
        "lr": 3e-3,
    },
    "svm": {"name": "svm", "kernel": "rbf", "C": 10.0, "gamma": 0.05, "n_components": 200},
}
TRAINER = TrainerSettings(
    max_epochs=4, accelerator="cpu", enable_progress_bar=False, enable_model_summary=False
)
