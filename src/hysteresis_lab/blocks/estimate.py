"""Initial values from data: the dominant resonance and the static gain.

`estimate_mode` uses the best linear approximation ``H(f) = S_uy / S_uu`` where the input
has power. When the resonance lies inside the excited band, its peak (above ``fmin``) and
half-power bandwidth give frequency and damping. When the input's band ends below it (the
study's multisine stops at 500 Hz, the mode sits at 900 Hz), ``H`` is only noise there; the
output spectrum above the excited band still shows the mode, rung by the hysteresis'
distortion and the noise, so its peak and half-power bandwidth are used instead. Either way
the peak and bandwidth only start a least-squares fit of the resonance's shape
``C / ((1 - r^2)^2 + (2 zeta r)^2)`` (``r = f / f_n``) to the log power spectrum between
0.7 and 1.4 ``f_n`` (robust loss), which gives a far steadier damping than the -3 dB points
of a noisy spectrum.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy import signal
from scipy.optimize import least_squares

log = logging.getLogger(__name__)

EXCITED_FRACTION = 1e-4  # input PSD above this fraction of its peak counts as excited
DAMPING_RANGE = (0.005, 0.5)


def _half_power_damping(f: np.ndarray, power: np.ndarray, i_peak: int) -> float:
    """``zeta = bandwidth / (2 f_n)`` from the -3 dB points of ``power`` around ``i_peak``
    (linear interpolation between bins; one side mirrors the other if it leaves the data)."""
    half = power[i_peak] / 2.0

    def crossing(step: int) -> float | None:
        i = i_peak
        while 0 <= i + step < len(power):
            j = i + step
            if power[j] <= half:
                t = (power[i] - half) / (power[i] - power[j])
                return float(f[i] + t * (f[j] - f[i]))
            i = j
        return None

    lo, hi = crossing(-1), crossing(1)
    fn = float(f[i_peak])
    if lo is None and hi is None:
        return DAMPING_RANGE[1]
    width = (hi - lo) if lo is not None and hi is not None else \
        2.0 * abs((hi if hi is not None else lo) - fn)
    return float(np.clip(width / (2.0 * fn), *DAMPING_RANGE))


def _fit_resonance(
    f: np.ndarray, power: np.ndarray, i_peak: int, zeta0: float
) -> tuple[float, float]:
    """Refine ``(f_n, zeta)`` by fitting the resonance's power shape near ``i_peak``."""
    fn0 = float(f[i_peak])
    window = (f > 0.7 * fn0) & (f < 1.4 * fn0) & (power > 0)
    if window.sum() < 5:
        return fn0, zeta0
    ff, log_p = f[window], np.log(power[window])

    def residuals(theta: np.ndarray) -> np.ndarray:
        r = ff / np.exp(theta[0])
        zeta = np.exp(theta[1])
        return theta[2] - np.log((1 - r * r) ** 2 + (2 * zeta * r) ** 2) - log_p

    theta0 = [np.log(fn0), np.log(zeta0), np.log(power[i_peak] * (2 * zeta0) ** 2)]
    try:
        sol = least_squares(residuals, theta0, loss="soft_l1")
    except (ValueError, np.linalg.LinAlgError):  # pragma: no cover - degenerate spectra
        return fn0, zeta0
    fn, zeta = float(np.exp(sol.x[0])), float(np.exp(sol.x[1]))
    if not (sol.success and 0.7 * fn0 < fn < 1.4 * fn0):
        return fn0, zeta0
    return fn, float(np.clip(zeta, *DAMPING_RANGE))


def estimate_mode(
    u: np.ndarray, y: np.ndarray, fs: float, fmin: float = 50.0, nperseg: int | None = None
) -> tuple[float, float]:
    """Frequency (Hz) and damping of the dominant resonance of ``y`` driven by ``u`` (1-D).

    Damping from the half-power bandwidth, clipped to [0.005, 0.5].
    """
    u = np.asarray(u, dtype=float).reshape(-1)
    y = np.asarray(y, dtype=float).reshape(-1)
    if u.shape != y.shape or len(u) < 64:
        raise ValueError("estimate_mode needs 1-D u and y of equal length (>= 64 samples)")
    if nperseg is None:
        nperseg = int(min(len(u), 2 ** round(np.log2(fs / 5.0))))  # ~5 Hz bins
    f, s_uu = signal.welch(u, fs, nperseg=nperseg)
    _, s_uy = signal.csd(u, y, fs, nperseg=nperseg)
    excited = s_uu > EXCITED_FRACTION * s_uu.max()
    band = (f >= fmin) & excited
    if band.sum() >= 3:
        gain = np.where(band, np.abs(s_uy) / np.where(excited, s_uu, 1.0), 0.0)
        i = int(np.argmax(gain))
        top = np.flatnonzero(band)[-1]
        interior = i < top and gain[i] > 2.0 * np.median(gain[band])
        if interior:
            power = np.where(band, gain, 0.0) ** 2
            fn, zeta = _fit_resonance(f, power, i, _half_power_damping(f, power, i))
            log.info("mode from the BLA peak: %.1f Hz, damping %.3f", fn, zeta)
            return fn, zeta
        edge = f[top]
    else:
        edge = fmin
    _, s_yy = signal.welch(y, fs, nperseg=nperseg)
    above = (f > max(edge * 1.05, fmin)) & ~excited
    if not above.any():
        raise ValueError(f"no resonance found above {fmin} Hz: |H| has no interior peak and "
                         "the input excites the whole band")
    power = np.where(above, s_yy, 0.0)
    i = int(np.argmax(power))
    fn, zeta = _fit_resonance(f, power, i, _half_power_damping(f, power, i))
    log.info("mode above the excited band (ends %.0f Hz), from the output spectrum: %.1f Hz, "
             "damping %.3f", edge, fn, zeta)
    return fn, zeta


def estimate_static_gain(u: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of ``y`` on ``u`` (through the origin)."""
    u = np.asarray(u, dtype=float).reshape(-1)
    y = np.asarray(y, dtype=float).reshape(-1)
    return float(np.dot(u, y) / np.dot(u, u))
