"""Creep: the slow drift of a displacement after a step, about 1-2 % per decade of time
(Jung & Gweon 2000; Croft, Shed & Devasia 2001; PI catalogue).

Faces: a slow first-order filter bank of the input as operators and evidence; the
simulator's parallel first-order elements (``data.effects.creep``); a filter bank with
learnable weights (`hysteresis_lab.blocks.CreepBank`) in ``model=linear`` and the grey-box."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hysteresis_lab.blocks.linear import CreepBank
from hysteresis_lab.effects._shared import per_input, seconds
from hysteresis_lab.effects.base import (
    Effect,
    FeatureContext,
    GreyBoxPart,
    LinearBlock,
    LinearContext,
    PlantSignals,
)
from hysteresis_lab.physics.filters import first_order_lowpass, lowpass_bank


@dataclass
class CreepConfig:
    """Creep: first-order elements (time constants 0.1–100 s) in parallel with the direct path.

    A log-like step response of about ``weight_per_decade`` per decade of time (PI catalogue:
    ~1–2 % per decade; Jung & Gweon 2000; Croft, Shed & Devasia 2001).
    """

    enabled: bool = True
    time_constants_s: list[float] = field(default_factory=lambda: [0.1, 1.0, 10.0, 100.0])
    weight_per_decade: float = 0.015

    def __post_init__(self) -> None:
        # an override such as [1, 10] gives whole numbers; the filters take seconds as floats
        self.time_constants_s = [float(t) for t in self.time_constants_s]


class Creep(Effect):
    """Creep: slow first-order filter bank of the input (time constants 0.1 s ... 100 s).

    Creep is the slow drift after a step, counted from 0.1 s on (the manufacturers' law
    ``x(t) = x(0.1 s) * (1 + gamma * log10(t / 0.1 s))``); faster memory is the actuator's
    dynamics, which the network's lags and the resonance effect cover. Only time constants
    the training data can show are used: at least 20 samples and at most half the longest
    training recording (a slower filter never moves during training, and on a long test
    signal its output would lie far outside what the model was fitted on).
    """

    name = "creep"
    description = "creep (slow first-order filter bank, 0.1-100 s)"
    place = "dynamics"
    rank = 20
    sim_config = CreepConfig
    time_constants_s = np.array([0.1, 1.0, 10.0, 100.0])

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        return per_input(u, lambda x, i: lowpass_bank(x, ctx.fs, self.usable(ctx)))

    #: a filter is used where the training data hold this many samples of its time constant…
    MIN_SAMPLES_PER_TAU = 20.0
    #: … and their longest recording is at least this many of its time constants
    MIN_DURATION_PER_TAU = 2.0

    def _bounds(self, ctx: FeatureContext) -> tuple[float, float]:
        """The fastest and the slowest time constant (s) the training data can show."""
        fastest = self.MIN_SAMPLES_PER_TAU / ctx.fs
        return fastest, max(ctx.duration_s / self.MIN_DURATION_PER_TAU, fastest)

    def usable(self, ctx: FeatureContext) -> np.ndarray:
        taus = self.time_constants_s
        fastest, slowest = self._bounds(ctx)
        usable = taus[(taus >= fastest) & (taus <= slowest)]
        # training data too short for any of them: the slowest filter it can still show
        return usable if len(usable) else np.array([min(slowest, taus[-1])])

    def unshown(
        self, ctx: FeatureContext, settings: Mapping[str, Any] | None = None
    ) -> str | None:
        """The filters the training data are too short (or too coarsely sampled) for: the
        operators leave them out; a model with filters of its own (``settings``'
        ``creep_time_constants_s``: the linear and grey-box models) keeps them, unidentified."""
        own = (settings or {}).get("creep_time_constants_s")
        taus = np.sort(np.asarray(own if own else self.time_constants_s, dtype=float))
        fastest, slowest = self._bounds(ctx)
        fate = "never move over it" if own else "are left out"
        parts = []
        too_slow = taus[taus > slowest]
        if len(too_slow):
            parts.append(
                f"its slowest filter is {taus[-1]:g} s but the longest training record is "
                f"{ctx.duration_s:.3g} s, so the filters of {seconds(too_slow)} {fate} "
                f"(a filter needs a record {self.MIN_DURATION_PER_TAU:g}x its time constant); "
                f"record at least {self.MIN_DURATION_PER_TAU * taus[-1]:g} s, or drop creep "
                "from model.effects"
            )
        too_fast = taus[taus < fastest]
        if len(too_fast):
            parts.append(
                f"its filters of {seconds(too_fast)} span fewer than "
                f"{self.MIN_SAMPLES_PER_TAU:g} samples at {ctx.fs:g} Hz"
                + ("" if own else " and are left out")
                + f"; sample at {self.MIN_SAMPLES_PER_TAU / too_fast[0]:g} Hz or faster to "
                "show them"
            )
        if not parts:
            return None
        used = "" if own else f" (used: {seconds(self.usable(ctx))})"
        return f"creep: {'; '.join(parts)}{used}."

    def simulate(self, plant: PlantSignals, cfg: CreepConfig) -> None:
        """``x + w * sum_i lowpass_tau_i(x)``: each decade of time adds about ``w`` of the step."""
        x = plant.x
        out = np.array(x, dtype=float)
        for tau in cfg.time_constants_s:
            out += cfg.weight_per_decade * first_order_lowpass(x, plant.fs, tau)
        plant.x = out

    def validate(self, cfg: CreepConfig, key: str) -> list[str]:
        if any(t <= 0 for t in cfg.time_constants_s):
            return [f"{key}.time_constants_s must all be positive."]
        return []

    def linear_blocks(self, ctx: LinearContext) -> list[LinearBlock]:
        """A first-order filter bank on each input (``model.creep_time_constants_s``),
        weights from zero."""
        return [LinearBlock("series", lambda c, j: CreepBank(
            c.fs, c.settings["creep_time_constants_s"]), attribute="creep")]

    def greybox_part(self) -> GreyBoxPart:
        """A first-order filter bank after the gain (per input on MIMO data)."""
        return GreyBoxPart(
            series=lambda fs, settings: CreepBank(fs, settings["creep_time_constants_s"]),
            attribute="creep", attribute_mimo="creeps")

