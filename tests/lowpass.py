"""Test helper: a clipped second-order low-pass under a multisine, the loop tests' small plant
(its output saturates at 0.6, like an overflowing tank)."""

from __future__ import annotations

import numpy as np
from scipy import signal

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.signals import multisine

FS = 100.0


def clipped_lowpass(n: int, seed: int, name: str) -> Recording:
    """``n`` samples at `FS` of a 1 Hz Butterworth low-pass clipped at 0.6, with 0.01 noise."""
    u = multisine(n, fs=FS, n_components=20, f_max=2.0, seed=seed)
    b, a = signal.butter(2, 1.0, fs=FS)
    y = np.minimum(signal.lfilter(b, a, u), 0.6)
    return Recording(u=u, y=y + 0.01 * np.random.default_rng(seed).standard_normal(n), fs=FS,
                     name=name)
