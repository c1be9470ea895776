"""Small helpers shared by the blocks: raw-parameter inverses and tensor <-> float64 numpy."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch


def inv_softplus(y: float) -> float:
    """``x`` with ``softplus(x) == y`` (``y > 0``)."""
    return y + math.log(-math.expm1(-y))


def logit(p: float) -> float:
    return math.log(p) - math.log1p(-p)


def to_numpy64(x: torch.Tensor) -> np.ndarray:
    """A C-contiguous float64 copy on the CPU (detached)."""
    return np.ascontiguousarray(x.detach().to("cpu", torch.float64).numpy())


def from_numpy(x: np.ndarray, like: torch.Tensor) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(x)).to(device=like.device, dtype=like.dtype)


def as_float_array(values: float | np.ndarray | Sequence[float], n: int) -> np.ndarray:
    """``values`` broadcast to ``n`` float64 values."""
    arr = np.asarray(values, dtype=float).reshape(-1)
    if arr.size == 1:
        arr = np.full(n, float(arr[0]))
    if arr.size != n:
        raise ValueError(f"expected 1 or {n} values, got {arr.size}")
    return arr
