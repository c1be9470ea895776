"""The simulated positioner: the blocks of `hysteresis_lab.sim.blocks` chained in physical order."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.errors import DataError
from hysteresis_lab.sim import blocks
from hysteresis_lab.sim.config import PositionerConfig

log = logging.getLogger(__name__)

NOMINAL_STROKE_UM = 40.0  # peak-to-peak at ±100 V, scales the asymmetry term


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
        rng = np.random.default_rng(seed)
        v = blocks.amplifier(u, fs, c.amplifier) if c.amplifier.enabled else u
        if c.saturation.enabled:
            v = blocks.saturation(v, c.saturation)
        if c.dead_zone.enabled:
            v = blocks.dead_zone(v, c.dead_zone)
        if c.backlash.enabled:
            v = blocks.backlash(v, c.backlash)
        if c.input_delay.enabled:
            v = blocks.delay(v, c.input_delay.samples)
        if c.hysteresis.enabled:
            x = blocks.hysteresis(v, fs, c.hysteresis, c.rate_dependence)
        else:
            x = c.hysteresis.d_um_per_v * v
        if c.asymmetry.enabled:
            x = blocks.asymmetry(x, v, c.asymmetry, NOMINAL_STROKE_UM)
        if c.creep.enabled:
            x = blocks.creep(x, fs, c.creep)
        y = blocks.mode_filter(x, fs, c.mode1) if c.mode1.enabled else x
        if c.mode2.enabled:
            y = (1.0 - c.mode2.weight) * y + c.mode2.weight * blocks.mode_filter(x, fs, c.mode2)
        if c.output_delay.enabled:
            y = blocks.delay(y, c.output_delay.samples)
        if c.drift.enabled:
            y = y + blocks.drift(len(y), fs, c.drift, rng)
        if c.noise.enabled:
            y = y + blocks.noise(len(y), c.noise, rng)
        if c.quantisation.enabled:
            y = blocks.quantise(y, c.quantisation)
        return y


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
