"""Affine scaling of inputs and outputs: the study's constants (100 V, 20 um) or statistics."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.errors import ConfigError

SCALING_MODES = ("paper", "standard", "none")

#: The study's fixed scaling constants (``data.scaling.mode=paper``): its simulator's input
#: amplitude in volts and output range in micrometres. Every default in the code reads these;
#: the packaged config (``conf/data/_window.yaml``) states them for users, and a test keeps
#: the two equal.
PAPER_U_SCALE = 100.0
PAPER_Y_SCALE = 20.0
DEFAULT_SCALING_MODE = "paper"


@dataclass(frozen=True)
class ScalingSettings:
    """The ``data.scaling`` settings: the mode and the constants of the ``paper`` mode."""

    mode: str = DEFAULT_SCALING_MODE
    u_scale: float = PAPER_U_SCALE
    y_scale: float = PAPER_Y_SCALE

    @classmethod
    def from_config(cls, scaling: Mapping[str, Any] | None) -> ScalingSettings:
        """From a ``data.scaling`` config node; a missing key takes its default."""
        scaling = scaling or {}
        return cls(**{k: scaling[k] for k in cls.__dataclass_fields__ if k in scaling})


@dataclass(frozen=True)
class Scaler:
    """``scaled = (physical - offset) / scale`` per channel, for inputs and outputs."""

    u_offset: np.ndarray
    u_scale: np.ndarray
    y_offset: np.ndarray
    y_scale: np.ndarray

    @classmethod
    def fit(
        cls,
        recordings: Sequence[Recording],
        mode: str = DEFAULT_SCALING_MODE,
        u_scale: float = PAPER_U_SCALE,
        y_scale: float = PAPER_Y_SCALE,
    ) -> Scaler:
        """Build a scaler.

        ``paper``: divide by the study's constants (``u_scale`` volts, ``y_scale`` um), no offset;
        ``standard``: subtract the training mean and divide by the training std per channel;
        ``none``: identity.
        """
        nu, ny = recordings[0].nu, recordings[0].ny
        if mode == "paper":
            if u_scale <= 0 or y_scale <= 0:
                raise ConfigError(
                    f"scaling constants must be positive (u_scale={u_scale}, y_scale={y_scale}). "
                    "Fix: set data.scaling.u_scale / y_scale to positive numbers."
                )
            return cls(
                np.zeros(nu), np.full(nu, float(u_scale)), np.zeros(ny), np.full(ny, float(y_scale))
            )
        if mode == "standard":
            u = np.concatenate([r.u for r in recordings])
            y = np.concatenate([r.y for r in recordings])
            return cls(u.mean(0), _safe_std(u), y.mean(0), _safe_std(y))
        if mode == "none":
            return cls(np.zeros(nu), np.ones(nu), np.zeros(ny), np.ones(ny))
        raise ConfigError(
            f"unknown scaling mode '{mode}'. Fix: set data.scaling.mode to one of "
            f"{list(SCALING_MODES)}."
        )

    def standardise_inputs_from(self, first: int, recordings: Sequence[Recording]) -> Scaler:
        """Inputs ``first..`` (effect operators, any units) scaled by their mean and std."""
        if first >= len(self.u_scale):
            return self
        u = np.concatenate([r.u[:, first:] for r in recordings])
        u_offset, u_scale = self.u_offset.copy(), self.u_scale.copy()
        u_offset[first:], u_scale[first:] = u.mean(0), _safe_std(u)
        return Scaler(u_offset, u_scale, self.y_offset, self.y_scale)

    def to_dict(self) -> dict[str, list[float]]:
        return {k: np.asarray(v, dtype=float).tolist() for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> Scaler:
        return cls(**{k: np.asarray(values[k], dtype=float) for k in cls.__dataclass_fields__})


def _safe_std(x: np.ndarray) -> np.ndarray:
    std = x.std(0)
    return np.where(std > 0, std, 1.0)
