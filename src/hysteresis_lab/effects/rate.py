"""Rate dependence: hysteresis loops that widen with the drive's rate (Ang et al. 2007).

Faces: the input's rate and its magnitude-weighted input as operators and evidence; the
simulator's per-sample factor of the Bouc–Wen ``alpha`` (``data.effects.rate_dependence``);
``model=linear``'s hysteresis cell made rate-dependent (`HysteresisCell` with a rate gain)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hysteresis_lab.effects._shared import per_input
from hysteresis_lab.effects.base import (
    Effect,
    FeatureContext,
    LinearBlock,
    LinearContext,
    PlantSignals,
)
from hysteresis_lab.effects.hysteresis import hysteresis_cell
from hysteresis_lab.physics.static import rate


@dataclass
class RateDependenceConfig:
    """Rate-dependent hysteresis: Bouc–Wen ``alpha`` grows as ``1 + gain * |dv/dt| / rate_ref``.

    Ang et al. 2007 report loop widths growing with excitation frequency in piezo actuators.
    """

    enabled: bool = False
    gain: float = 0.5
    rate_ref_v_per_s: float = 62_832.0  # a ±100 V sine at 100 Hz


class RateDependence(Effect):
    """Rate-dependent behaviour: input rate and its magnitude-weighted input."""

    name = "rate"
    description = "rate dependence (input-rate features)"
    place = "input"
    rank = 70
    #: in the simulator it sets the hysteresis' per-sample ``alpha`` before that element runs
    sim_rank = 55
    sim_config = RateDependenceConfig
    #: the hysteresis cell of ``model=linear`` takes a rate gain where it is declared
    makes_cell_rate_dependent = True
    #: a rate-dependent loop shares out the loop width the cell's ``alpha`` was fitted to at
    #: the training input's rates (``alpha`` must fall as the rate gain grows): the loop
    #: refits the whole model
    linear_whole_refit = True

    @property
    def sim_key(self) -> str:
        return "rate_dependence"

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        def make(x: np.ndarray, i: int) -> np.ndarray:
            r = rate(x, ctx.fs) / (2 * np.pi * 100.0 * max(ctx.u_amplitude[i], 1e-12))
            return np.column_stack([r, np.abs(r) * x / max(ctx.u_amplitude[i], 1e-12)])

        return per_input(u, make)

    def simulate(self, plant: PlantSignals, cfg: RateDependenceConfig) -> None:
        """The factor ``1 + gain |dv/dt| / rate_ref`` of the hysteresis' ``alpha``, per sample."""
        dv_dt = np.abs(np.diff(plant.v, prepend=plant.v[0])) * plant.fs
        plant.alpha_factor = 1.0 + cfg.gain * dv_dt / cfg.rate_ref_v_per_s

    def validate(self, cfg: RateDependenceConfig, key: str) -> list[str]:
        return ([] if cfg.rate_ref_v_per_s > 0 else
                [f"{key}.rate_ref_v_per_s={cfg.rate_ref_v_per_s!r} must be positive."])

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        """The hysteresis cell (shared with ``hysteresis`` where both are declared) with a
        rate gain from zero; declared alone it brings the cell, weight from zero."""
        return [LinearBlock("series", hysteresis_cell, key="hysteresis")]
