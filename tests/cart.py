"""A simulated cart for the tests of integrating models (EMPS-like): a mass pushed by a force
against viscous and, optionally, Coulomb friction; its position in mm."""

from __future__ import annotations

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits

FS = 1000.0


def cart_position(u: np.ndarray, coulomb: float = 0.0) -> np.ndarray:
    """The cart's position (mm) under the force ``u``; ``coulomb``: the friction force
    (smoothed over a small velocity), 0 for viscous friction alone."""
    position, velocity = np.zeros(len(u)), 0.0
    for k in range(1, len(u)):
        force = u[k - 1] - 2.0 * velocity - coulomb * np.clip(velocity / 0.002, -1.0, 1.0)
        velocity += force / FS * 20.0
        position[k] = position[k - 1] + velocity / FS
    return 1000.0 * position


def pushes(rng: np.random.Generator, n: int, smallest: float) -> np.ndarray:
    """Back-and-forth pushes of random length and of a size between ``smallest`` and 3."""
    u, k = np.zeros(n), 0
    while k < n:
        length = int(rng.integers(100, 400))
        u[k:k + length] = rng.uniform(smallest, 3.0) * (1 if (k // 250) % 2 == 0 else -1)
        k += length
    return u


def cart_data(coulomb: float = 0.0, smallest_push: float = 1.0) -> DatasetSplits:
    """Training, validation and test recordings of the cart (1 µm of sensor noise)."""
    rng = np.random.default_rng(0)
    recordings = []
    for name, n in (("train", 6000), ("val", 2000), ("test", 3000)):
        u = pushes(rng, n, smallest_push)
        y = cart_position(u, coulomb) + 1e-3 * rng.standard_normal(n)
        recordings.append(Recording(u=u[:, None], y=y[:, None], fs=FS, name=name))
    return DatasetSplits("cart", train=recordings[:1], val=recordings[1:2],
                         test=recordings[2:])
