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

`estimate_modes` does it for MIMO data: the most prominent peaks of the MIMO best linear
approximation (`mimo_frequency_response`) start shared modes, which `fit_modes` fits to the
whole frequency response (residues by least squares for each candidate set of modes).
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


def mimo_frequency_response(
    us: list[np.ndarray], ys: list[np.ndarray], fs: float, nperseg: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The best linear approximation ``H(f)`` (F, ny, nu) of recordings ``us`` (T, nu) ->
    ``ys`` (T, ny) from Welch cross-spectra summed over the recordings, ``H = S_yu S_uu^-1``;
    returns the frequencies, ``H`` and the input power (trace of ``S_uu``)."""
    us = [np.asarray(u, dtype=float).reshape(len(u), -1) for u in us]
    ys = [np.asarray(y, dtype=float).reshape(len(y), -1) for y in ys]
    shortest = min(len(u) for u in us)
    if shortest < 64:
        raise ValueError("the MIMO frequency response needs recordings of >= 64 samples")
    if nperseg is None:
        nperseg = int(min(shortest, 2 ** round(np.log2(fs / 5.0))))  # ~5 Hz bins
    nu, ny = us[0].shape[1], ys[0].shape[1]
    s_uu: np.ndarray | float = 0.0
    s_uy: np.ndarray | float = 0.0
    for u, y in zip(us, ys, strict=True):
        f, _ = signal.welch(u[:, 0], fs, nperseg=nperseg)
        s_uu = s_uu + np.stack([np.stack([signal.csd(u[:, i], u[:, j], fs, nperseg=nperseg)[1]
                                          for j in range(nu)], -1) for i in range(nu)], -2)
        s_uy = s_uy + np.stack([np.stack([signal.csd(u[:, i], y[:, o], fs, nperseg=nperseg)[1]
                                          for o in range(ny)], -1) for i in range(nu)], -2)
    # csd(u_i, y_o) = sum_j H_oj csd(u_i, u_j): H^T = S_uu^-1 S_uy (per frequency)
    h = np.swapaxes(np.linalg.pinv(np.asarray(s_uu)) @ np.asarray(s_uy), -1, -2)
    power = np.real(np.trace(np.asarray(s_uu), axis1=-2, axis2=-1))
    return f, h, power


def estimate_modes(
    us: list[np.ndarray], ys: list[np.ndarray], fs: float, n_modes: int,
    fmin: float = 50.0, fmax: float | None = None,
    prefilter: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies (Hz) and dampings of ``n_modes`` shared resonances of a MIMO system.

    The ``n_modes`` most prominent peaks of its best linear approximation
    (`mimo_frequency_response`, ~5 Hz bins, the Frobenius norm over the pairs) between
    ``fmin`` and ``fmax`` where the inputs have power start them (damping from each peak's
    half-power bandwidth; when there are fewer peaks, the rest are spread evenly on a log
    scale over the band at damping 0.1); `fit_modes` then refines them on the finer response.
    ``prefilter`` ``(b, a)``: the linear part of every input's path before the modes (delay,
    amplifier), part of the fitted response.
    """
    f, h, power = mimo_frequency_response(us, ys, fs)
    fmax = 0.45 * fs if fmax is None else fmax
    band = (f >= fmin) & (f <= fmax) & (power > EXCITED_FRACTION * power.max())
    if band.sum() < 3:
        raise ValueError(f"the inputs excite fewer than 3 frequency bins in [{fmin:g}, "
                         f"{fmax:g}] Hz")
    gain = np.where(band, np.sqrt(np.sum(np.abs(h) ** 2, axis=(-2, -1))), 0.0)
    log_gain = np.where(band, np.log(np.maximum(gain, 1e-300)), np.log(gain[band].min()))
    peaks, props = signal.find_peaks(log_gain, prominence=0.1)
    chosen = np.sort(peaks[np.argsort(props["prominences"])[::-1][:n_modes]])
    freqs = [float(f[i]) for i in chosen]
    damps = [_half_power_damping(f, gain ** 2, int(i)) for i in chosen]
    missing = n_modes - len(freqs)
    if missing > 0:
        freqs += list(np.geomspace(float(f[band][0]), float(f[band][-1]), missing + 2)[1:-1])
        damps += [0.1] * missing
    shortest = min(len(u) for u in us)
    fine = int(min(shortest, 2 ** int(np.ceil(np.log2(fs)))))  # ~1 Hz bins
    f, h, power = mimo_frequency_response(us, ys, fs, nperseg=fine)
    band = (f >= fmin) & (f <= fmax) & (power > EXCITED_FRACTION * power.max())
    freqs_fit, damps_fit = fit_modes(f[band], h[band], fs, np.asarray(freqs),
                                     np.asarray(damps), (fmin, fmax), prefilter)
    log.info("modes from the MIMO BLA's %d most prominent peaks%s, fitted to its response: "
             "%s Hz, damping %s", len(chosen),
             f" and {missing} spread over the band" if missing > 0 else "",
             np.round(freqs_fit, 1).tolist(), np.round(damps_fit, 4).tolist())
    return freqs_fit, damps_fit


def modal_basis(
    f: np.ndarray, fs: float, freqs: np.ndarray, damps: np.ndarray,
    prefilter: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Frequency responses (F, 2 modes + 1) of the unit-DC-gain modes (`mode_coefficients`'
    bilinear filter), of their quadratures (`hysteresis_lab.blocks.modal`) and of a static
    gain, each after ``prefilter``."""
    z1 = np.exp(-2j * np.pi * f / fs)
    path = np.ones_like(z1) if prefilter is None else \
        np.polyval(prefilter[0][::-1], z1) / np.polyval(prefilter[1][::-1], z1)
    c = 1.0 / np.tan(np.pi * freqs[None] / fs)
    a0 = c * c + 2.0 * damps[None] * c + 1.0
    zc = z1[:, None]
    den = a0 + 2.0 * (1.0 - c * c) * zc + (c * c - 2.0 * damps * c + 1.0) * zc * zc
    modes, rates = (1.0 + zc) ** 2 / den, c * (1.0 - zc * zc) / den
    return np.hstack([modes, rates, np.ones((len(f), 1))]) * path[:, None]


def fit_modes(
    f: np.ndarray, h: np.ndarray, fs: float, freqs: np.ndarray, damps: np.ndarray,
    band: tuple[float, float], prefilter: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies and dampings of shared modes fitted to a MIMO response ``h`` (F, ny, nu):
    ``h_oj = sum_m (R_ojm mode_m + Q_ojm rate_m) + D_oj`` (`modal_basis`), the residues and
    feedthrough
    by least squares for each candidate (variable projection), the modes by
    `scipy.optimize.least_squares` within ``band`` (Hz) and [0.005, 0.5], from ``freqs`` and
    ``damps``. Returns them sorted by frequency; the start where the fit fails."""
    target = h.reshape(len(f), -1)
    target = np.vstack([target.real, target.imag])
    n = len(freqs)

    def residuals(theta: np.ndarray) -> np.ndarray:
        basis = modal_basis(f, fs, theta[:n], theta[n:], prefilter)
        a = np.vstack([basis.real, basis.imag])
        coef, *_ = np.linalg.lstsq(a, target, rcond=None)
        return (a @ coef - target).ravel()

    lo = np.r_[np.full(n, band[0]), np.full(n, DAMPING_RANGE[0])]
    hi = np.r_[np.full(n, band[1]), np.full(n, DAMPING_RANGE[1])]
    start = np.clip(np.r_[freqs, damps], lo * 1.0001, hi * 0.9999)
    try:
        sol = least_squares(residuals, start, bounds=(lo, hi), x_scale=start, max_nfev=200)
    except (ValueError, np.linalg.LinAlgError):  # pragma: no cover - degenerate responses
        return freqs, damps
    order = np.argsort(sol.x[:n])
    return sol.x[:n][order], sol.x[n:][order]
