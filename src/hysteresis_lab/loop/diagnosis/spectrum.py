"""Residual spectrum with significant peaks, and residual against input level, rate and time."""

from __future__ import annotations

import numpy as np
from scipy import signal


def residual_spectrum(
    residual: np.ndarray, fs: float, prominence: float = 10.0
) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """Welch PSD of the residual; peaks ``prominence`` times above the median level."""
    e = np.asarray(residual, dtype=float).ravel()
    nperseg = int(min(len(e), max(256, 2 ** int(np.log2(max(len(e) // 8, 256))))))
    freqs, psd = signal.welch(e - e.mean(), fs=fs, nperseg=nperseg)
    floor = np.median(psd[1:]) if len(psd) > 1 else 0.0
    peaks, _ = signal.find_peaks(psd, height=prominence * floor)
    marked = [
        {
            "frequency_hz": float(freqs[p]),
            "psd": float(psd[p]),
            "above_median": float(psd[p] / floor) if floor > 0 else float("inf"),
        }
        for p in peaks
    ]
    marked.sort(key=lambda item: -item["psd"])
    return freqs, psd, marked[:10]


def binned(x: np.ndarray, residual: np.ndarray, bins: int = 12) -> dict[str, list[float]]:
    """Mean and RMS of the residual in equal-count bins of ``x`` (input level, rate, time)."""
    x = np.asarray(x, dtype=float).ravel()
    e = np.asarray(residual, dtype=float).ravel()
    edges = np.unique(np.quantile(x, np.linspace(0, 1, bins + 1)))
    which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    centres, means, rms = [], [], []
    for b in range(len(edges) - 1):
        sel = which == b
        if sel.any():
            centres.append(float(x[sel].mean()))
            means.append(float(e[sel].mean()))
            rms.append(float(np.sqrt(np.mean(e[sel] ** 2))))
    return {"x": centres, "mean": means, "rms": rms}
