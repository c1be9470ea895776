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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal
from scipy.optimize import least_squares, nnls

from hysteresis_lab.physics.filters import mode_coefficients_np
from hysteresis_lab.physics.play import play_operators, spread_over

log = logging.getLogger(__name__)

EXCITED_FRACTION = 1e-4  # input PSD above this fraction of its peak counts as excited
#: a peak of the output's log power above the excited band counts as a resonance where it
#: stands this far above its surroundings (its prominence: ln 10, ten times the power)
ABOVE_BAND_PROMINENCE = float(np.log(10.0))
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
    i = _resonance_above_band(power, above)
    fn, zeta = _fit_resonance(f, power, i, _half_power_damping(f, power, i))
    log.info("mode above the excited band (ends %.0f Hz), from the output spectrum: %.1f Hz, "
             "damping %.3f", edge, fn, zeta)
    return fn, zeta


def _resonance_above_band(power: np.ndarray, above: np.ndarray) -> int:
    """The bin of the first resonance in the output's power above the excited band: the
    lowest peak of its logarithm that stands `ABOVE_BAND_PROMINENCE` above its surroundings,
    else the largest bin. The distortion a nonlinearity spreads past the band falls off from
    its edge, so the largest bin sits at the edge (zoo plant 2: 562 Hz for a mode at
    3.46 kHz, whose peak stands 6.5 above its surroundings); the lowest mode, not the most
    prominent, shapes the band most (zoo plant 9: modes at 673 and 1252 Hz)."""
    index = np.flatnonzero(above)
    log_power = np.log(np.maximum(power[index], 1e-300))
    peaks, _ = signal.find_peaks(log_power, prominence=ABOVE_BAND_PROMINENCE)
    return int(index[peaks[0]]) if len(peaks) else int(np.argmax(power))


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


# ------------------------------------------------------------------ structure from data
#: most samples of input delay `select_chain_structure` tries
MAX_AUTO_DELAY = 10
#: most modes it tries (one input and output)
MAX_AUTO_MODES = 3
#: a delay one sample longer than the plant's cannot be made up by the amplifier lag: the
#: response's misfit rises by more than this factor from one delay to the next (a shorter
#: delay is made up by the lag, the misfit barely moves), so the chosen delay is the last
#: one before the first such rise
DELAY_JUMP = 1.15
#: the delay where the misfit jumps at none tried (the data do not show it): the former default
UNSEEN_DELAY = 1
#: one more mode is kept only where it brings the response's misfit below this share
MODE_GAIN = 0.9
#: starting frequencies of a further mode, as multiples of the first mode's frequency
#: (a mode above the excited band is placed by its share of the static gain and its phase)
EXTRA_MODE_STARTS = (0.5, 1.5, 2.5, 4.0, 7.0)
#: most frequency bins of the response the structure is fitted to, and most evaluations
#: of each fit (the fits run for every delay and mode count tried: a few seconds in all)
FIT_BINS = 256
#: most phase lag (rad) the fitted response carries at every frequency: a hysteresis loop's
#: lag, which a delay too long would otherwise hide in (it lags the band's top by about a
#: sample at 500 Hz and 20 kHz)
MAX_HYSTERESIS_LAG = 0.5
#: play operators of the hysteresis stand-in with which `select_chain_structure` checks the
#: delay on the recording itself, their thresholds spread over the input's range (a stand-in
#: whose thresholds the input barely opens leaves a wider loop unexplained, which a sample
#: more delay can hide: zoo plant 11, an amplifier at 2.2 kHz and no delay, read 1 sample)
CHECK_PLAY_OPERATORS = 8
#: most samples of the recording, and evaluations of each fit, of that check
CHECK_SAMPLES = 40_000
CHECK_EVALUATIONS = 20
#: a first mode above the excited band stays within this factor of the frequency its peak
#: in the output spectrum shows (its damping within the factor's fourth power)
ABOVE_BAND_SPREAD = 1.02
FIT_EVALUATIONS = 100


@dataclass(frozen=True)
class ChainStructure:
    """The linear dynamics of a grey-box chain read off its best linear approximation
    (`select_chain_structure`): the input delay (samples), the amplifier's cutoff, the
    modes (frequencies, dampings, their shares of the static gain, summing to one), the
    static gain, and the response's misfit per (modes, delay) tried."""

    delay: int
    amplifier_hz: float
    frequencies_hz: np.ndarray
    dampings: np.ndarray
    weights: np.ndarray
    gain: float
    misfits: dict[tuple[int, int], float]

    @property
    def n_modes(self) -> int:
        return len(self.frequencies_hz)


def chain_response(
    f: np.ndarray, fs: float, amplifier_hz: float, delay: int, freqs: np.ndarray,
    damps: np.ndarray,
) -> np.ndarray:
    """Frequency responses (F, modes) of the grey-box's linear chain, one column per mode:
    the amplifier lag (`FirstOrderLag`'s step-invariant pole), ``delay`` samples and the
    unit-DC-gain mode (`mode_coefficients`' bilinear filter)."""
    z1 = np.exp(-2j * np.pi * f / fs)
    pole = np.exp(-2.0 * np.pi * amplifier_hz / fs)
    path = (1.0 - pole) / (1.0 - pole * z1) * z1 ** delay
    return modal_basis(f, fs, np.asarray(freqs, float), np.asarray(damps, float))[
        :, : len(freqs)] * path[:, None]


def _fit_chain(
    f: np.ndarray, h: np.ndarray, fs: float, delay: int, start: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray],
) -> tuple[float, np.ndarray, np.ndarray]:
    """The chain's response fitted to ``h`` (F,) at ``delay``: the amplifier's cutoff, a
    phase lag the same at every frequency (a hysteresis loop's, which lags and does not lead)
    and the modes by `scipy.optimize.least_squares` from ``start`` (``[log f_c, lag, log f_1,
    log zeta_1, ...]``), the modes' weights by non-negative least squares for
    each candidate (a positioner's modes share its static gain; weights of both signs let
    two modes cancel into a shape no structure has). Returns the RMS misfit, the parameters
    and the weights."""
    target = np.r_[h.real, h.imag]

    def solve(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        basis = chain_response(f, fs, np.exp(theta[0]), delay, np.exp(theta[2::2]),
                               np.exp(theta[3::2])) * np.exp(-1j * theta[1])
        a = np.vstack([basis.real, basis.imag])
        coef, _ = nnls(a, target)
        return coef, a @ coef - target

    start = np.clip(start, bounds[0] + 1e-9, bounds[1] - 1e-9)
    try:
        theta = least_squares(lambda t: solve(t)[1], start, bounds=bounds,
                              max_nfev=FIT_EVALUATIONS).x
    except (ValueError, np.linalg.LinAlgError, RuntimeError):  # pragma: no cover - degenerate
        theta = start
    coef, residuals = solve(theta)
    misfit = float(np.sqrt(np.mean(residuals ** 2)))
    return (misfit if np.isfinite(misfit) else np.inf), theta, coef


def _plays(v: np.ndarray, thresholds: Sequence[float]) -> np.ndarray:
    """``v`` (T,) and its play operators' outputs (T, 1 + thresholds), from rest."""
    return np.c_[v, play_operators(np.ascontiguousarray(v, dtype=float),
                                   np.asarray(thresholds, dtype=float))]


def _time_domain_misfit(
    x: np.ndarray, y: np.ndarray, fs: float, delay: int, theta: np.ndarray,
) -> tuple[float, np.ndarray]:
    """The chain at ``delay`` (amplifier and modes from ``theta``, ``[log f_c, log f_1,
    log zeta_1, ...]``, refined by `scipy.optimize.least_squares`) on the recording: each
    column of ``x`` (the input and its plays, a stand-in for the hysteresis) through it, the
    weights of every column and mode and a constant by least squares. The RMS misfit and
    the refined parameters."""
    n_modes = (len(theta) - 1) // 2

    def residuals(t: np.ndarray) -> np.ndarray:
        pole = np.exp(-2.0 * np.pi * np.exp(t[0]) / fs)
        z = signal.lfilter([1.0 - pole], [1.0, -pole], x, axis=0)
        z = np.vstack([np.zeros((delay, z.shape[1])), z[: len(z) - delay]])
        columns = [signal.lfilter(*mode_coefficients_np(np.exp(t[1 + 2 * m]),
                                                        np.exp(t[2 + 2 * m]), fs), z, axis=0)
                   for m in range(n_modes)]
        a = np.hstack([*columns, np.ones((len(z), 1))])
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        return a @ coef - y

    lo = np.r_[np.log(0.01 * fs), [np.log(1e-3 * fs), np.log(DAMPING_RANGE[0])] * n_modes]
    hi = np.r_[np.log(0.45 * fs), [np.log(0.44 * fs), np.log(DAMPING_RANGE[1])] * n_modes]
    start = np.clip(theta, lo + 1e-9, hi - 1e-9)
    try:
        sol = least_squares(residuals, start, bounds=(lo, hi), max_nfev=CHECK_EVALUATIONS)
        refined, misfit = sol.x, float(np.sqrt(np.mean(sol.fun ** 2)))
    except (ValueError, np.linalg.LinAlgError):  # pragma: no cover - degenerate recordings
        refined, misfit = start, np.inf
    return (misfit if np.isfinite(misfit) else np.inf), refined


def _jumps(misfits: Sequence[float]) -> bool:
    """Whether the misfit rises by more than `DELAY_JUMP` from one delay to the next."""
    return any(b > DELAY_JUMP * a for a, b in zip(misfits, misfits[1:], strict=False))


def _last_before_jump(misfits: Sequence[float]) -> int:
    """The delay before the first rise of the misfit by more than `DELAY_JUMP` (the last
    delay tried when there is none)."""
    for d in range(len(misfits) - 1):
        if misfits[d + 1] > DELAY_JUMP * misfits[d]:
            return d
    return len(misfits) - 1


def _checked_delay(
    u: np.ndarray, y: np.ndarray, fs: float, picked: int, fitted: Sequence[int],
    start: Any,
) -> int:
    """The delay the recording itself says near the one the best linear approximation
    picked: a hysteresis loop lags the response by about the same phase at every frequency,
    which at the band's top passes for a sample or two more delay. So the delays from one
    below ``picked`` to one above it are fitted on the recording (`_time_domain_misfit`, with
    plays of the input standing in for the hysteresis, from the response's fit
    ``start(d)``), and shorter ones while the shortest tried is the one taken; the last
    before the misfit jumps (`_last_before_jump`) is taken. Where it does not jump (what the
    stand-in misses hides the delay), ``picked`` stays."""
    n = min(len(u), CHECK_SAMPLES)
    v = (u[:n] - np.mean(u[:n])) / max(float(np.std(u[:n])), 1e-12)
    x = _plays(v, spread_over(v, CHECK_PLAY_OPERATORS))
    misfits: dict[int, float] = {}
    tried = [d for d in fitted if picked - 1 <= d <= picked + 1]
    while True:
        for d in tried:
            if d not in misfits:
                misfits[d] = _time_domain_misfit(x, y[:n], fs, d,
                                                 np.r_[start(d)[0], start(d)[2:]])[0]
        curve = [misfits[d] for d in tried]
        checked = tried[_last_before_jump(curve)]
        if checked != tried[0] or tried[0] - 1 not in fitted:
            break
        tried = [tried[0] - 1, *tried]
    checked = checked if _jumps(curve) else picked
    log.info("delay checked on the recording with plays standing in for the hysteresis: "
             "misfit %s for delays %s: %d samples (the response alone: %d)",
             np.round(curve, 5).tolist(), tried, checked, picked)
    return checked


def select_chain_structure(
    u: np.ndarray, y: np.ndarray, fs: float, *, delay: int | None = None,
    n_modes: int | None = None, max_delay: int = MAX_AUTO_DELAY,
    max_modes: int = MAX_AUTO_MODES, fmin: float = 50.0,
) -> ChainStructure:
    """The input delay and the number of modes of a grey-box chain (amplifier lag, delay,
    modes; one input and output) from recordings ``u`` -> ``y`` (1-D), where not given.

    Its best linear approximation (`mimo_frequency_response`, ~1 Hz bins where the input has
    power, at most `FIT_BINS` of them) is fitted by the chain's response (`chain_response`:
    the amplifier's cutoff and the modes by least squares, their weights by non-negative
    least squares) at each delay from 0 up, with 1 to ``max_modes`` modes:

    * delay: the amplifier lag makes up for a delay shorter than the plant's (the misfit
      barely moves) but not for a longer one, so the delay is the last before the misfit
      first rises by more than `DELAY_JUMP` from one delay to the next (the scan stops
      there; `UNSEEN_DELAY` where it rises so at none up to ``max_delay``), then checked on
      the recording (`_checked_delay`);
    * modes: one more mode is kept where it lowers the misfit below `MODE_GAIN` of the
      fewer modes', at best and at the delay those chose (`more_modes_help`); it starts at the fewer
      modes' fit with the new mode at the best of `EXTRA_MODE_STARTS` (no lower than half the
      first mode's frequency).

    The first mode starts from `estimate_mode`.
    """
    u = np.asarray(u, dtype=float).reshape(-1)
    y = np.asarray(y, dtype=float).reshape(-1)
    f_all, h_all, power = mimo_frequency_response(
        [u[:, None]], [y[:, None]], fs, nperseg=int(min(len(u), 2 ** int(np.ceil(np.log2(fs))))))
    fmax = 0.44 * fs
    band = np.flatnonzero((f_all > 0) & (f_all < fmax)
                          & (power > EXCITED_FRACTION * power.max()))
    if len(band) < 8:
        raise ValueError(f"the input excites fewer than 8 frequency bins below {fmax:g} Hz")
    band = band[np.unique(np.linspace(0, len(band) - 1, min(len(band), FIT_BINS)).astype(int))]
    f, h = f_all[band], h_all[band, 0, 0]
    try:
        f1, z1 = estimate_mode(u, y, fs, fmin=min(fmin, 0.1 * float(f[-1])))
    except ValueError:
        f1, z1 = float(np.sqrt(f[0] * f[-1])), 0.05
    f1 = float(np.clip(f1, 0.6 * float(f[0]), 0.9 * fmax))
    amp = (np.log(0.01 * fs), np.log(0.45 * fs))
    first_mode = ([np.log(max(0.5 * float(f[0]), 1e-3 * fs)), np.log(DAMPING_RANGE[0])],
                  [np.log(fmax), np.log(DAMPING_RANGE[1])])
    above_band = f1 > float(f[-1])
    if above_band:  # above the excited band: its peak in the output spectrum places
        # it; the band's response only bends towards it, which a misplaced mode and another
        # delay can mimic
        first_mode = ([np.log(f1 / ABOVE_BAND_SPREAD), np.log(z1 / ABOVE_BAND_SPREAD ** 4)],
                      [np.log(f1 * ABOVE_BAND_SPREAD), np.log(z1 * ABOVE_BAND_SPREAD ** 4)])
    extra_mode = ([max(first_mode[0][0], np.log(0.5 * f1)), first_mode[0][1]], first_mode[1])

    def bounds(m: int) -> tuple[np.ndarray, np.ndarray]:
        return (np.r_[amp[0], 0.0, first_mode[0], extra_mode[0] * (m - 1)],
                np.r_[amp[1], MAX_HYSTERESIS_LAG, first_mode[1], extra_mode[1] * (m - 1)])

    delays = list(range(max_delay + 1)) if delay is None else [delay]
    counts = list(range(1, max_modes + 1)) if n_modes is None else [n_modes]
    misfits: dict[tuple[int, int], float] = {}
    fits: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def scan(m: int, start: np.ndarray) -> list[float]:
        """``m`` modes at each delay, from ``start`` and the last delay's fit, up to the
        first jump of the misfit; the misfits."""
        curve: list[float] = []
        previous = None
        for d in delays:
            tries = [start] if previous is None else [start, previous]
            best = min((_fit_chain(f, h, fs, d, s, bounds(m)) for s in tries),
                       key=lambda fit: fit[0])
            misfits[(m, d)], fits[(m, d)] = best[0], best[1:]
            curve.append(best[0])
            previous = best[1]
            if len(curve) > 1 and curve[-1] > DELAY_JUMP * curve[-2]:
                break
        return curve

    def more_modes_help(more: int, fewer: int, start: np.ndarray) -> bool:
        """Do ``more`` modes lower the misfit below `MODE_GAIN` of ``fewer`` modes', both at
        best and at the delay the fewer modes chose (fitted there if their scan stopped
        short)? Modes that help only at another delay stand in for the delay's phase (a few
        near a one-mode plant's peak, at no delay), not for dynamics the plant has."""
        if not min(curves[more]) < MODE_GAIN * min(curves[fewer]):
            return False
        at = delays[_last_before_jump(curves[fewer])]
        misfit = misfits.get((more, at))
        if misfit is None:
            last = fits[(more, delays[len(curves[more]) - 1])][0]
            misfit = min(_fit_chain(f, h, fs, at, s, bounds(more))[0] for s in (start, last))
        return misfit < MODE_GAIN * misfits[(fewer, at)]

    curves = {1: scan(1, np.r_[np.log(0.25 * fs), 0.05, np.log(f1), np.log(z1)])}
    chosen = 1 if 1 in counts else None
    for m in range(2, max(counts) + 1):
        d_prev = delays[_last_before_jump(curves[m - 1])]
        last = fits[(m - 1, d_prev)][0]
        starts = [np.r_[last, np.log(min(k * f1, 0.9 * fmax)), np.log(0.05)]
                  for k in EXTRA_MODE_STARTS]
        best_start = min(starts, key=lambda s: _fit_chain(f, h, fs, d_prev, s, bounds(m))[0])
        curves[m] = scan(m, best_start)
        if m in counts and (chosen is None or more_modes_help(m, chosen, best_start)):
            chosen = m
    assert chosen is not None
    picked = delays[_last_before_jump(curves[chosen])]
    if delay is None and not _jumps(curves[chosen]):
        picked = min(UNSEEN_DELAY, delays[-1])
        log.info("the misfit does not jump at any delay up to %d samples: the data do not "
                 "show the delay, %d sample(s) as by default", delays[-1], picked)
    elif delay is None:
        picked = _checked_delay(u, y, fs, picked, [d for d in delays if (chosen, d) in fits],
                                lambda d: fits[(chosen, d)][0])
    theta, coef = fits[(chosen, picked)]
    if above_band:  # the fit only bends it within its bounds; the spectrum's peak places it
        theta = np.r_[theta[:2], np.log(f1), np.log(z1), theta[4:]]
    gain = float(np.sum(coef))
    weights = coef / gain if gain > 1e-12 else np.full(chosen, 1.0 / chosen)
    order = np.argsort(theta[2::2])
    structure = ChainStructure(
        delay=int(picked), amplifier_hz=float(np.exp(theta[0])),
        frequencies_hz=np.exp(theta[2::2])[order], dampings=np.exp(theta[3::2])[order],
        weights=np.asarray(weights)[order], gain=gain, misfits=misfits)
    log.info("chain structure from the best linear approximation (%d bins, %.3g-%.3g Hz): "
             "%d mode(s) at %s Hz, damping %s, delay %d samples, amplifier %.0f Hz; misfit per "
             "delay from 0 for 1..%d modes: %s", len(f), f[0], f[-1], chosen,
             np.round(structure.frequencies_hz, 1).tolist(),
             np.round(structure.dampings, 4).tolist(), picked, structure.amplifier_hz,
             max(counts), {m: np.round(c, 5).tolist() for m, c in curves.items()})
    return structure
