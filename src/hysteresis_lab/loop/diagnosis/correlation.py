"""Residual correlation tests with confidence bounds (linear and Billings' nonlinear tests).

Billings & Voon (1986): for an unbiased model the residual ``e`` satisfies, for all lags
``tau`` (normalised correlations, bounds ``±z/sqrt(N)``)::

    phi_ee(tau)      = delta(tau)         phi_ue(tau)      = 0
    phi_e(eu)(tau)   = 0  (tau >= 0)      phi_(u2)'e(tau)  = 0
    phi_(u2)'e2(tau) = 0
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats


def _normalised_xcorr(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """``corr(a[t], b[t - tau])`` for tau = 0..max_lag, de-meaned, via FFT."""
    a = a - a.mean()
    b = b - b.mean()
    n = len(a)
    size = 1 << (2 * n - 1).bit_length()
    spec = np.fft.rfft(a, size) * np.conj(np.fft.rfft(b, size))
    full = np.fft.irfft(spec, size)[: max_lag + 1]
    denom = np.sqrt(np.sum(a**2) * np.sum(b**2))
    return full / denom if denom > 0 else np.zeros(max_lag + 1)


@dataclass
class CorrelationTest:
    """One correlation function, its bound and whether it stays inside it."""

    name: str
    values: np.ndarray  # lag 0..max_lag
    bound: float
    skip_lag0: bool = False

    @property
    def fraction_outside(self) -> float:
        v = self.values[1:] if self.skip_lag0 else self.values
        return float(np.mean(np.abs(v) > self.bound))

    @property
    def max_abs(self) -> float:
        return float(np.max(np.abs(self.values[1:] if self.skip_lag0 else self.values)))

    @property
    def passed(self) -> bool:
        """About 5 % of lags fall outside a 95 % bound by chance; none should be far outside."""
        return self.fraction_outside <= 0.1 and self.max_abs <= 2.0 * self.bound

    def to_dict(self) -> dict:
        return {
            "bound": self.bound,
            "fraction_outside": self.fraction_outside,
            "passed": self.passed,
            "max_abs": self.max_abs,
        }


def correlation_tests(
    residual: np.ndarray, u: np.ndarray, max_lag: int = 50, confidence: float = 0.95
) -> list[CorrelationTest]:
    """ACF, input-residual CCF and Billings' nonlinear tests of a 1-D residual."""
    e = np.asarray(residual, dtype=float).ravel()
    x = np.asarray(u, dtype=float).ravel()
    bound = float(stats.norm.ppf(0.5 + confidence / 2) / np.sqrt(len(e)))
    x2 = x**2 - np.mean(x**2)
    eu = np.roll(e * x, 1)
    eu[0] = 0.0
    return [
        CorrelationTest("phi_ee", _normalised_xcorr(e, e, max_lag), bound, skip_lag0=True),
        CorrelationTest("phi_ue", _normalised_xcorr(e, x, max_lag), bound),
        CorrelationTest("phi_e(eu)", _normalised_xcorr(e, eu, max_lag), bound),
        CorrelationTest("phi_(u2)'e", _normalised_xcorr(e, x2, max_lag), bound),
        CorrelationTest("phi_(u2)'e2", _normalised_xcorr(e**2, x2, max_lag), bound),
    ]
