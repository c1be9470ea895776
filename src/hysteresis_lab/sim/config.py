"""Parameters of the simulated positioner: one dataclass per physical block, each switchable,
and the blocks they belong to (`plant_blocks`).

Defaults describe a piezoelectric cantilever positioner driven by a voltage amplifier:
±100 V gives about ±20 µm, the major loop is 10–15 % of the stroke wide, creep adds about
1.5 % per decade of time, the first bending mode sits at 900 Hz, and the displacement sensor
has 0.01 µm RMS noise. Sources are given per block. An effect's parameters live with the
effect (`hysteresis_lab.effects.<name>`, e.g. ``CreepConfig``); a plugin effect with a
simulator face adds its own block under its key (``data.effects.<key>``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from omegaconf import DictConfig, OmegaConf

from hysteresis_lab.effects.backlash import BacklashConfig as Backlash
from hysteresis_lab.effects.base import Block
from hysteresis_lab.effects.creep import CreepConfig as Creep
from hysteresis_lab.effects.dead_zone import DeadZoneConfig as DeadZone
from hysteresis_lab.effects.drift import DriftConfig as Drift
from hysteresis_lab.effects.hysteresis import HysteresisConfig as Hysteresis
from hysteresis_lab.effects.rate import RateDependenceConfig as RateDependence
from hysteresis_lab.effects.saturation import SaturationConfig as Saturation
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.sim.blocks import plant_only_blocks
from hysteresis_lab.sim.plant_configs import Amplifier, Asymmetry, Delay, Mode, Noise, Quantisation

__all__ = ["Amplifier", "Asymmetry", "Backlash", "Creep", "DeadZone", "Delay", "Drift",
           "Hysteresis", "Mode", "Noise", "PositionerConfig", "Quantisation", "RateDependence",
           "Saturation", "plant_blocks"]


def _second_mode() -> Mode:
    return Mode(enabled=False, frequency_hz=2800.0, damping=0.02, weight=0.15)


def _third_mode() -> Mode:
    return Mode(enabled=False, frequency_hz=4500.0, damping=0.02, weight=0.05)


def _no_output_delay() -> Delay:
    return Delay(enabled=False, samples=0)


def plant_blocks() -> dict[str, Block]:
    """The positioner's blocks by their ``data.effects`` key: the plant-only blocks and every
    registered effect with a simulator face, built-in or plugin (a broken plugin is left
    out, with the registry's warning)."""
    from hysteresis_lab.effects.registry import loaded_effects

    blocks: dict[str, Block] = {block.sim_key: block for block in plant_only_blocks()}
    for effect in loaded_effects().values():
        if effect.simulatable:
            blocks.setdefault(effect.sim_key, effect)
    return blocks


@dataclass(eq=False)
class PositionerConfig:
    """Every block of the simulated positioner (signal chain in `hysteresis_lab.sim`); a
    plugin effect's block, where one is configured, in `plugins` (by its key)."""

    amplifier: Amplifier = field(default_factory=Amplifier)
    saturation: Saturation = field(default_factory=Saturation)
    dead_zone: DeadZone = field(default_factory=DeadZone)
    backlash: Backlash = field(default_factory=Backlash)
    input_delay: Delay = field(default_factory=Delay)
    hysteresis: Hysteresis = field(default_factory=Hysteresis)
    asymmetry: Asymmetry = field(default_factory=Asymmetry)
    rate_dependence: RateDependence = field(default_factory=RateDependence)
    creep: Creep = field(default_factory=Creep)
    mode1: Mode = field(default_factory=Mode)
    mode2: Mode = field(default_factory=_second_mode)
    mode3: Mode = field(default_factory=_third_mode)
    output_delay: Delay = field(default_factory=_no_output_delay)
    drift: Drift = field(default_factory=Drift)
    noise: Noise = field(default_factory=Noise)
    quantisation: Quantisation = field(default_factory=Quantisation)

    def __post_init__(self) -> None:
        #: plugin effects' block parameters by key (their blocks in `plant_blocks`)
        self.plugins: dict[str, Any] = {}

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PositionerConfig) and self.to_dict() == other.to_dict()

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | DictConfig | None) -> PositionerConfig:
        """Build from a nested mapping (e.g. ``data.effects``); unknown keys are errors.

        Blocks and parameters left out keep their defaults. A key that is no built-in
        block names a plugin effect's simulator block.
        """
        if isinstance(values, DictConfig):
            values = OmegaConf.to_container(values, resolve=True)  # type: ignore[assignment]
        config = cls()
        known: dict[str, Block] | None = None
        for block_name, block_values in (values or {}).items():
            if block_name not in _names(config):
                known = plant_blocks() if known is None else known
                if block_name not in known:
                    valid = sorted(_names(config) | set(known))
                    raise ConfigError(
                        f"unknown effect block '{block_name}'. Valid: {valid}. "
                        f"Fix: correct the override (e.g. data.effects.creep.enabled=true)."
                    )
                block = known[block_name].sim_config()  # type: ignore[misc]
            else:
                block = getattr(config, block_name)
            if not isinstance(block_values, Mapping):
                raise ConfigError(
                    f"effect block '{block_name}' must be a mapping of parameters, got "
                    f"{block_values!r}. Fix: set e.g. data.effects.{block_name}.enabled=true."
                )
            unknown = set(block_values) - _names(block)
            if unknown:
                raise ConfigError(
                    f"effect block '{block_name}' has no parameter(s) {sorted(unknown)}. "
                    f"Valid: {sorted(_names(block))}."
                )
            updates = dict(block_values)
            if block_name in _names(config):
                setattr(config, block_name, dataclasses.replace(block, **updates))
            else:
                config.plugins[block_name] = dataclasses.replace(block, **updates)
        config.validate()
        return config

    def to_dict(self) -> dict[str, Any]:
        out = {f.name: dataclasses.asdict(getattr(self, f.name)) for f in fields(self)}
        out.update({key: dataclasses.asdict(cfg) for key, cfg in self.plugins.items()})
        return out

    def blocks(self) -> list[tuple[str, Any]]:
        """Each block's key and parameters: the built-in ones, then the plugins'."""
        return [(f.name, getattr(self, f.name)) for f in fields(self)] + list(
            self.plugins.items())

    def enabled_blocks(self) -> list[str]:
        return [key for key, cfg in self.blocks() if cfg.enabled]

    def chain(self) -> list[tuple[Block, Any]]:
        """The blocks in the simulator's signal order, each with its parameters."""
        known = plant_blocks()
        chain = [(known[key], cfg) for key, cfg in self.blocks()]
        return sorted(chain, key=lambda item: item[0].sim_order())

    def validate(self) -> None:
        """Reject parameter values that make a block unphysical or unstable."""
        known = plant_blocks()
        for key, cfg in self.blocks():
            block = known[key]
            problems = block.validate_any(cfg, key)
            if cfg.enabled:
                problems += block.validate(cfg, key)
            if problems:
                raise ConfigError(problems[0])

    def validate_rate(self, fs: float) -> None:
        """Reject resonances the sampling rate ``fs`` (Hz) cannot represent."""
        for block, cfg in self.chain():
            problems = block.validate_rate(cfg, block.sim_key, fs) if cfg.enabled else []
            if problems:
                raise ConfigError(problems[0])


def _names(obj: Any) -> set[str]:
    return {f.name for f in fields(obj)}
