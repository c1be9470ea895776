"""Tensor <-> float64 NumPy conversions of the torch faces, and the state a one-sample step
reads (`StateReader`, implemented by `hysteresis_lab.blocks.step.StepState`)."""

from __future__ import annotations

from typing import Protocol

import numpy as np
import torch


class StateReader(Protocol):
    """A flat step state read part by part: ``take(n)`` the next ``n`` columns (B, n),
    ``put(part)`` a part of the next state."""

    def take(self, n: int) -> torch.Tensor: ...

    def put(self, part: torch.Tensor) -> None: ...


def to_numpy64(x: torch.Tensor) -> np.ndarray:
    """A C-contiguous float64 copy on the CPU (detached)."""
    return np.ascontiguousarray(x.detach().to("cpu", torch.float64).numpy())


def from_numpy(x: np.ndarray, like: torch.Tensor) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(x)).to(device=like.device, dtype=like.dtype)
