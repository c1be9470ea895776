"""Parameters of the simulated positioner's plant-only blocks (amplifier, delays, asymmetry,
modes, noise, quantisation); the effects' own parameters live with the effects."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Amplifier:
    """Voltage amplifier: first-order low-pass (driving the piezo's capacitance).

    Piezo amplifiers have a few kHz of small-signal bandwidth (e.g. PI E-505: ~3–10 kHz).
    """

    enabled: bool = True
    cutoff_hz: float = 5000.0


@dataclass
class Delay:
    """Pure delay in samples (DAC/amplifier latency on the input, sensor latency on the output)."""

    enabled: bool = True
    samples: int = 1


@dataclass
class Asymmetry:
    """Asymmetric loop: ``coefficient * stroke * (v / v_ref)^2`` added to the displacement."""

    enabled: bool = False
    coefficient: float = 0.02
    v_ref: float = 100.0


@dataclass
class Mode:
    """Lightly damped structural mode (unit DC gain).

    ``weight`` is the share of the static gain a later mode carries when it is enabled
    (``y = (1 - w) * y + w * mode(x)``, in order: mode2 on mode1, mode3 on both); it is
    ignored for the first mode.

    Piezo cantilevers/benders have their first bending mode at a few hundred Hz to ~1 kHz.
    """

    enabled: bool = True
    frequency_hz: float = 900.0
    damping: float = 0.03
    weight: float = 1.0


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
