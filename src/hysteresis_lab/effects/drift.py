"""Drift: a slow trend of the output that does not depend on the input (thermal expansion,
sensor drift).

Faces: time ramps as operators and evidence (a model can fit them one step ahead, not in free
run); the simulator's ramp plus slow oscillation (``data.effects.drift``). No model carries it
as a block."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hysteresis_lab.effects.base import Effect, FeatureContext, PlantSignals


@dataclass
class DriftConfig:
    """Slow thermal/sensor drift, independent of the input: ramp plus slow oscillation."""

    enabled: bool = False
    rate_um_per_s: float = 0.004
    amplitude_um: float = 0.08
    period_s: float = 20.0


class Drift(Effect):
    """Drift / offset: a slow trend that does not depend on the input (time ramps)."""

    name = "drift"
    description = "drift / offset (slow trend, independent of the input)"
    predictable = False
    place = "output"
    rank = 30
    sim_config = DriftConfig

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        t = np.arange(len(u)) / ctx.fs
        scale = max(ctx.duration_s, 1e-9)
        return np.column_stack([t / scale, (t / scale) ** 2])

    def simulate(self, plant: PlantSignals, cfg: DriftConfig) -> None:
        """Ramp plus a slow oscillation of random phase (thermal expansion, sensor drift)."""
        y = plant.y
        t = np.arange(len(y)) / plant.fs
        phase = plant.rng.uniform(0.0, 2.0 * np.pi)
        wave = np.sin(2.0 * np.pi * t / cfg.period_s + phase) - np.sin(phase)
        plant.y = y + (cfg.rate_um_per_s * t + cfg.amplitude_um * wave)

    def validate(self, cfg: DriftConfig, key: str) -> list[str]:
        return [] if cfg.period_s > 0 else [f"{key}.period_s={cfg.period_s!r} must be positive."]

