"""Small helpers shared by the blocks: raw-parameter inverses, value broadcasting, and the
physics floor's tensor <-> float64 NumPy conversions."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from hysteresis_lab.physics.tensors import from_numpy, to_numpy64

__all__ = ["as_float_array", "from_numpy", "inv_softplus", "logit", "to_numpy64"]


def inv_softplus(y: float) -> float:
    """``x`` with ``softplus(x) == y`` (``y > 0``)."""
    return y + math.log(-math.expm1(-y))


def logit(p: float) -> float:
    return math.log(p) - math.log1p(-p)


def as_float_array(values: float | np.ndarray | Sequence[float], n: int) -> np.ndarray:
    """``values`` broadcast to ``n`` float64 values."""
    arr = np.asarray(values, dtype=float).reshape(-1)
    if arr.size == 1:
        arr = np.full(n, float(arr[0]))
    if arr.size != n:
        raise ValueError(f"expected 1 or {n} values, got {arr.size}")
    return arr
