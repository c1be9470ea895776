"""Static laws of a sampled signal: the dead zone, the clip, the backward-difference rate."""

from __future__ import annotations

import numpy as np


def dead_zone(u: np.ndarray, width: float) -> np.ndarray:
    """``u`` with the band ``±width`` around zero removed: ``sign(u) max(|u| - width, 0)``."""
    return np.sign(u) * np.maximum(np.abs(u) - width, 0.0)


def rate(u: np.ndarray, fs: float) -> np.ndarray:
    """Backward-difference rate of change (units per second)."""
    return np.diff(u, prepend=u[0]) * fs
