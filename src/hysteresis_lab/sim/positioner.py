"""The simulated positioner: its blocks (plant-only blocks and the effects' simulator faces,
`hysteresis_lab.sim.config.PositionerConfig.chain`) run in signal order."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.base import PlantSignals
from hysteresis_lab.errors import DataError
from hysteresis_lab.sim.config import PositionerConfig

log = logging.getLogger(__name__)


class Positioner:
    """A piezo positioner model: volts in, micrometres out (see `hysteresis_lab.sim`)."""

    def __init__(self, config: PositionerConfig | Mapping[str, Any] | None = None) -> None:
        if not isinstance(config, PositionerConfig):
            config = PositionerConfig.from_dict(config)
        self.config = config

    def simulate(self, u: np.ndarray, fs: float, seed: int = 0) -> np.ndarray:
        """Displacement (µm) for the command voltage ``u`` (V, 1-D), starting at rest."""
        u = np.asarray(u, dtype=float)
        if u.ndim != 1 or not np.all(np.isfinite(u)) or len(u) == 0:
            raise DataError(
                "the simulator needs a non-empty 1-D input of finite values.",
                source="simulated positioner",
                fix="pass one input channel as a 1-D array without NaN",
            )
        c = self.config
        c.validate_rate(fs)
        plant = PlantSignals(fs=fs, rng=np.random.default_rng(seed), v=u)
        for block, cfg in c.chain():  # the blocks in signal order (`PositionerConfig.chain`)
            if cfg.enabled:
                block.simulate(plant, cfg)
            else:
                block.simulate_disabled(plant, cfg)
        return plant.y


def simulate_recording(
    u: np.ndarray,
    fs: float,
    config: PositionerConfig | Mapping[str, Any] | None = None,
    seed: int = 0,
    name: str = "sim",
) -> Recording:
    """Simulate the positioner and wrap input and output in a `Recording` (V, µm)."""
    positioner = Positioner(config)
    y = positioner.simulate(u, fs, seed)
    metadata = {"source": "simulator", "effects": positioner.config.enabled_blocks(), "seed": seed}
    return Recording(u=u, y=y, fs=fs, name=name, u_names=("u",), y_names=("y",),
                     metadata=metadata)
