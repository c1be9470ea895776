"""Parameters of the simulated positioner: one dataclass per physical block, each switchable.

Defaults describe a piezoelectric cantilever positioner driven by a voltage amplifier:
±100 V gives about ±20 µm, the major loop is 10–15 % of the stroke wide, creep adds about
1.5 % per decade of time, the first bending mode sits at 900 Hz, and the displacement sensor
has 0.01 µm RMS noise. Sources are given per block.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from omegaconf import DictConfig, OmegaConf

from hysteresis_lab.errors import ConfigError


@dataclass
class Amplifier:
    """Voltage amplifier: first-order low-pass (driving the piezo's capacitance).

    Piezo amplifiers have a few kHz of small-signal bandwidth (e.g. PI E-505: ~3–10 kHz).
    """

    enabled: bool = True
    cutoff_hz: float = 5000.0


@dataclass
class Saturation:
    """Amplifier output clipping at ``±limit_v`` (e.g. an amplifier rated below the command)."""

    enabled: bool = False
    limit_v: float = 90.0


@dataclass
class DeadZone:
    """Dead zone of ``±width_v`` ahead of the actuator: ``sign(v) max(|v| - width_v, 0)`` (a
    drive stage that does not respond to small commands, stiction of a clamp)."""

    enabled: bool = False
    width_v: float = 10.0


@dataclass
class Backlash:
    """Backlash (mechanical play) of ``±width_v`` ahead of the actuator: a play operator that
    follows the command only once it has moved ``width_v`` the other way (a gear or clamp
    with play)."""

    enabled: bool = False
    width_v: float = 5.0


@dataclass
class Delay:
    """Pure delay in samples (DAC/amplifier latency on the input, sensor latency on the output)."""

    enabled: bool = True
    samples: int = 1


@dataclass
class Hysteresis:
    """Rate-independent Bouc–Wen hysteresis (Low & Guo 1995; Goldfarb & Celanovic 1997).

    ``x = d v - h``, ``dh/dt = alpha d dv/dt - beta |dv/dt| h - gamma dv/dt |h|``; needs
    ``beta > |gamma|``. Defaults: ±100 V → ±20 µm, major loop ≈ 11 % of the stroke.
    """

    enabled: bool = True
    d_um_per_v: float = 0.23
    alpha: float = 0.32
    beta: float = 0.02
    gamma: float = 0.006


@dataclass
class Asymmetry:
    """Asymmetric loop: ``coefficient * stroke * (v / v_ref)^2`` added to the displacement."""

    enabled: bool = False
    coefficient: float = 0.02
    v_ref: float = 100.0


@dataclass
class RateDependence:
    """Rate-dependent hysteresis: Bouc–Wen ``alpha`` grows as ``1 + gain * |dv/dt| / rate_ref``.

    Ang et al. 2007 report loop widths growing with excitation frequency in piezo actuators.
    """

    enabled: bool = False
    gain: float = 0.5
    rate_ref_v_per_s: float = 62_832.0  # a ±100 V sine at 100 Hz


@dataclass
class Creep:
    """Creep: first-order elements (time constants 0.1–100 s) in parallel with the direct path.

    A log-like step response of about ``weight_per_decade`` per decade of time (PI catalogue:
    ~1–2 % per decade; Jung & Gweon 2000; Croft, Shed & Devasia 2001).
    """

    enabled: bool = True
    time_constants_s: list[float] = field(default_factory=lambda: [0.1, 1.0, 10.0, 100.0])
    weight_per_decade: float = 0.015


@dataclass
class Mode:
    """Lightly damped structural mode (unit DC gain).

    ``weight`` is the share of the static gain the second mode carries when it is enabled
    (``y = (1 - w) * mode1(x) + w * mode2(x)``); it is ignored for the first mode.

    Piezo cantilevers/benders have their first bending mode at a few hundred Hz to ~1 kHz.
    """

    enabled: bool = True
    frequency_hz: float = 900.0
    damping: float = 0.03
    weight: float = 1.0


@dataclass
class Drift:
    """Slow thermal/sensor drift, independent of the input: ramp plus slow oscillation."""

    enabled: bool = False
    rate_um_per_s: float = 0.004
    amplitude_um: float = 0.08
    period_s: float = 20.0


@dataclass
class Noise:
    """Gaussian sensor noise (capacitive/laser sensors: ~0.01 µm RMS at 20 kHz)."""

    enabled: bool = True
    rms_um: float = 0.01


@dataclass
class Quantisation:
    """Sensor quantisation step (e.g. a 16-bit ADC over ±30 µm: ~1 nm)."""

    enabled: bool = True
    step_um: float = 0.001


def _second_mode() -> Mode:
    return Mode(enabled=False, frequency_hz=2800.0, damping=0.02, weight=0.15)


def _no_output_delay() -> Delay:
    return Delay(enabled=False, samples=0)


@dataclass
class PositionerConfig:
    """Every block of the simulated positioner (signal chain in `hysteresis_lab.sim`)."""

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
    output_delay: Delay = field(default_factory=_no_output_delay)
    drift: Drift = field(default_factory=Drift)
    noise: Noise = field(default_factory=Noise)
    quantisation: Quantisation = field(default_factory=Quantisation)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | DictConfig | None) -> PositionerConfig:
        """Build from a nested mapping (e.g. ``data.effects``); unknown keys are errors.

        Blocks and parameters left out keep their defaults.
        """
        if isinstance(values, DictConfig):
            values = OmegaConf.to_container(values, resolve=True)  # type: ignore[assignment]
        config = cls()
        for block_name, block_values in (values or {}).items():
            if block_name not in _names(config):
                raise ConfigError(
                    f"unknown effect block '{block_name}'. Valid: {sorted(_names(config))}. "
                    f"Fix: correct the override (e.g. data.effects.creep.enabled=true)."
                )
            if not isinstance(block_values, Mapping):
                raise ConfigError(
                    f"effect block '{block_name}' must be a mapping of parameters, got "
                    f"{block_values!r}. Fix: set e.g. data.effects.{block_name}.enabled=true."
                )
            block = getattr(config, block_name)
            unknown = set(block_values) - _names(block)
            if unknown:
                raise ConfigError(
                    f"effect block '{block_name}' has no parameter(s) {sorted(unknown)}. "
                    f"Valid: {sorted(_names(block))}."
                )
            updates = dict(block_values)
            if "time_constants_s" in updates:
                updates["time_constants_s"] = [float(t) for t in updates["time_constants_s"]]
            setattr(config, block_name, dataclasses.replace(block, **updates))
        config.validate()
        return config

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def enabled_blocks(self) -> list[str]:
        return [f.name for f in fields(self) if getattr(self, f.name).enabled]

    def validate(self) -> None:
        """Reject parameter values that make a block unphysical or unstable."""
        hyst = self.hysteresis
        if hyst.enabled and not hyst.beta > abs(hyst.gamma):
            raise ConfigError(
                f"hysteresis needs beta > |gamma| (got beta={hyst.beta}, gamma={hyst.gamma})."
            )
        for name in ("mode1", "mode2"):
            mode = getattr(self, name)
            if mode.enabled and (mode.frequency_hz <= 0 or mode.damping <= 0):
                raise ConfigError(f"{name} needs frequency_hz > 0 and damping > 0.")
        for name in ("input_delay", "output_delay"):
            if getattr(self, name).samples < 0:
                raise ConfigError(f"{name}.samples must be >= 0.")
        if self.creep.enabled and any(t <= 0 for t in self.creep.time_constants_s):
            raise ConfigError("creep.time_constants_s must all be positive.")
        positive = {
            "amplifier.cutoff_hz": (self.amplifier, self.amplifier.cutoff_hz),
            "saturation.limit_v": (self.saturation, self.saturation.limit_v),
            "dead_zone.width_v": (self.dead_zone, self.dead_zone.width_v),
            "backlash.width_v": (self.backlash, self.backlash.width_v),
            "hysteresis.d_um_per_v": (self.hysteresis, self.hysteresis.d_um_per_v),
            "rate_dependence.rate_ref_v_per_s": (
                self.rate_dependence, self.rate_dependence.rate_ref_v_per_s),
            "asymmetry.v_ref": (self.asymmetry, self.asymmetry.v_ref),
            "drift.period_s": (self.drift, self.drift.period_s),
            "quantisation.step_um": (self.quantisation, self.quantisation.step_um),
        }
        for name, (block, value) in positive.items():
            if block.enabled and not value > 0:
                raise ConfigError(f"{name}={value!r} must be positive.")
        if self.noise.enabled and self.noise.rms_um < 0:
            raise ConfigError(f"noise.rms_um={self.noise.rms_um!r} must be >= 0.")
        if self.mode2.enabled and not 0.0 <= self.mode2.weight <= 1.0:
            raise ConfigError(f"mode2.weight={self.mode2.weight!r} must lie in [0, 1].")

    def validate_rate(self, fs: float) -> None:
        """Reject resonances the sampling rate ``fs`` (Hz) cannot represent."""
        for name in ("mode1", "mode2"):
            mode = getattr(self, name)
            if mode.enabled and mode.frequency_hz >= fs / 2:
                raise ConfigError(
                    f"{name}.frequency_hz={mode.frequency_hz} must lie below fs/2 = {fs / 2} Hz. "
                    "Fix: lower the mode frequency or raise the sampling rate."
                )


def _names(obj: Any) -> set[str]:
    return {f.name for f in fields(obj)}
