"""The positioner's plant-only blocks: amplifier, delays, asymmetry, modes, noise and
quantisation, in the vocabulary of the effects (`hysteresis_lab.effects.base.Block`: a place,
a rank, a config dataclass and ``simulate``). The effects' own simulator blocks live with the
effects (`hysteresis_lab.effects`); `hysteresis_lab.sim.config.plant_blocks` lists them all."""

from __future__ import annotations

from typing import Any

import numpy as np

from hysteresis_lab.effects.base import Block, PlantSignals
from hysteresis_lab.physics.filters import first_order_lowpass
from hysteresis_lab.physics.filters import mode_filter as physics_mode_filter
from hysteresis_lab.sim.plant_configs import Amplifier, Asymmetry, Delay, Mode, Noise, Quantisation

NOMINAL_STROKE_UM = 40.0  # peak-to-peak at ±100 V, scales the asymmetry term


def amplifier(v: np.ndarray, fs: float, cfg: Amplifier) -> np.ndarray:
    return first_order_lowpass(v, fs, 1.0 / (2.0 * np.pi * cfg.cutoff_hz))


def delay(x: np.ndarray, samples: int) -> np.ndarray:
    if samples <= 0:
        return x
    return np.concatenate([np.zeros(samples), x[:-samples]])[: len(x)]


def asymmetry(x: np.ndarray, v: np.ndarray, cfg: Asymmetry, stroke_um: float) -> np.ndarray:
    return x + cfg.coefficient * stroke_um * (v / cfg.v_ref) ** 2


def mode_filter(x: np.ndarray, fs: float, cfg: Mode) -> np.ndarray:
    """Second-order resonance ``wn^2 / (s^2 + 2 zeta wn s + wn^2)``; bilinear, prewarped at wn."""
    return physics_mode_filter(x, fs, cfg.frequency_hz, cfg.damping)


def noise(n: int, cfg: Noise, rng: np.random.Generator) -> np.ndarray:
    return rng.normal(0.0, cfg.rms_um, n)


def quantise(y: np.ndarray, cfg: Quantisation) -> np.ndarray:
    return np.round(y / cfg.step_um) * cfg.step_um


def _positive(key: str, parameter: str, value: float) -> list[str]:
    return [] if value > 0 else [f"{key}.{parameter}={value!r} must be positive."]


class PlantBlock(Block):
    """A block only the simulated plant has (no diagnosis, no trainable face)."""

    def __init__(self, name: str) -> None:
        self.name = name


class AmplifierBlock(PlantBlock):
    """The voltage amplifier's first-order low-pass, on the drive."""

    place = "input"
    rank = 10
    sim_config = Amplifier

    def simulate(self, plant: PlantSignals, cfg: Amplifier) -> None:
        plant.v = amplifier(plant.v, plant.fs, cfg)

    def validate(self, cfg: Amplifier, key: str) -> list[str]:
        return _positive(key, "cutoff_hz", cfg.cutoff_hz)


class DelayBlock(PlantBlock):
    """A pure delay of the drive (input place) or of the output (output place)."""

    sim_config = Delay

    def __init__(self, name: str, place: str, rank: int) -> None:
        super().__init__(name)
        self.place, self.rank = place, rank  # type: ignore[misc]

    def simulate(self, plant: PlantSignals, cfg: Delay) -> None:
        if self.place == "input":
            plant.v = delay(plant.v, cfg.samples)
        else:
            plant.y = delay(plant.y, cfg.samples)

    def validate_any(self, cfg: Delay, key: str) -> list[str]:
        return [f"{key}.samples must be >= 0."] if cfg.samples < 0 else []


class AsymmetryBlock(PlantBlock):
    """An asymmetric loop: a square law of the drive added to the displacement."""

    place = "dynamics"
    rank = 10
    sim_config = Asymmetry

    def simulate(self, plant: PlantSignals, cfg: Asymmetry) -> None:
        plant.x = asymmetry(plant.x, plant.v, cfg, NOMINAL_STROKE_UM)

    def validate(self, cfg: Asymmetry, key: str) -> list[str]:
        return _positive(key, "v_ref", cfg.v_ref)


class ModeBlock(PlantBlock):
    """A structural mode: the first turns the displacement into the output (switched off:
    the output is the displacement), a later one adds its share of the displacement's
    response (``y = (1 - w) y + w mode(x)``)."""

    place = "dynamics"
    sim_config = Mode

    def __init__(self, name: str, rank: int, first: bool) -> None:
        super().__init__(name)
        self.rank, self.first = rank, first  # type: ignore[misc]

    def simulate(self, plant: PlantSignals, cfg: Mode) -> None:
        if self.first:
            plant.y = mode_filter(plant.x, plant.fs, cfg)
        else:
            plant.y = (1.0 - cfg.weight) * plant.y + cfg.weight * mode_filter(plant.x, plant.fs,
                                                                              cfg)

    def simulate_disabled(self, plant: PlantSignals, cfg: Mode) -> None:
        if self.first:
            plant.y = plant.x

    def validate(self, cfg: Mode, key: str) -> list[str]:
        problems = []
        if cfg.frequency_hz <= 0 or cfg.damping <= 0:
            problems.append(f"{key} needs frequency_hz > 0 and damping > 0.")
        if not self.first and not 0.0 <= cfg.weight <= 1.0:
            problems.append(f"{key}.weight={cfg.weight!r} must lie in [0, 1].")
        return problems

    def validate_rate(self, cfg: Mode, key: str, fs: float) -> list[str]:
        if cfg.frequency_hz >= fs / 2:
            return [f"{key}.frequency_hz={cfg.frequency_hz} must lie below fs/2 = {fs / 2} Hz. "
                    "Fix: lower the mode frequency or raise the sampling rate."]
        return []


class NoiseBlock(PlantBlock):
    """Gaussian sensor noise on the output."""

    place = "output"
    rank = 40
    sim_config = Noise

    def simulate(self, plant: PlantSignals, cfg: Noise) -> None:
        plant.y = plant.y + noise(len(plant.y), cfg, plant.rng)

    def validate(self, cfg: Noise, key: str) -> list[str]:
        return [f"{key}.rms_um={cfg.rms_um!r} must be >= 0."] if cfg.rms_um < 0 else []


class QuantisationBlock(PlantBlock):
    """The sensor's resolution."""

    place = "output"
    rank = 50
    sim_config = Quantisation

    def simulate(self, plant: PlantSignals, cfg: Quantisation) -> None:
        plant.y = quantise(plant.y, cfg)

    def validate(self, cfg: Quantisation, key: str) -> list[str]:
        return _positive(key, "step_um", cfg.step_um)


def plant_only_blocks() -> list[Any]:
    """The blocks of the positioner that are no effect, one per ``data.effects`` key."""
    return [AmplifierBlock("amplifier"), DelayBlock("input_delay", "input", 50),
            AsymmetryBlock("asymmetry"), ModeBlock("mode1", 50, first=True),
            ModeBlock("mode2", 60, first=False), ModeBlock("mode3", 70, first=False),
            DelayBlock("output_delay", "output", 20),
            NoiseBlock("noise"), QuantisationBlock("quantisation")]
