"""Residual diagnostics of one model on its test recordings: numbers (JSON) and figures (PNG)."""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from hysteresis_lab.analysis.correlation import correlation_tests
from hysteresis_lab.analysis.spectrum import binned, residual_spectrum
from hysteresis_lab.data.recording import Recording

MODES = ("one_step", "free_run")


def residual_analysis(recordings: list[Recording], predictions: dict[str, dict[str, np.ndarray]],
                      n_skip: int, max_lag: int = 50) -> dict[str, Any]:
    """Per recording and mode: correlation tests, spectrum peaks, residual vs level/rate/time."""
    out: dict[str, Any] = {}
    for rec in recordings:
        per_mode = {}
        for mode in MODES:
            if mode not in predictions.get(rec.name, {}):
                continue
            e = (rec.y - predictions[rec.name][mode])[n_skip:, 0]
            u = rec.u[n_skip:, 0]
            _, _, peaks = residual_spectrum(e, rec.fs)
            per_mode[mode] = {
                "rms": float(np.sqrt(np.mean(e**2))),
                "correlation": {t.name: t.to_dict() for t in correlation_tests(e, u, max_lag)},
                "spectrum_peaks": peaks,
                "vs_input": binned(u, e),
                "vs_rate": binned(np.gradient(u) * rec.fs, e),
                "vs_time": binned(rec.t[n_skip:], e),
            }
        out[rec.name] = per_mode
    return out


def diagnostics_figure(recordings: list[Recording], predictions: dict[str, dict[str, np.ndarray]],
                       n_skip: int, mode: str = "free_run", max_lag: int = 50) -> Figure:
    """Rows per recording: ACF, CCF, spectrum, residual vs input, labelled with the mode."""
    fig = Figure(figsize=(13, 2.4 * len(recordings)))
    axes = fig.subplots(len(recordings), 4, squeeze=False)
    for row, rec in zip(axes, recordings, strict=True):
        e = (rec.y - predictions[rec.name][mode])[n_skip:, 0]
        u = rec.u[n_skip:, 0]
        tests = {t.name: t for t in correlation_tests(e, u, max_lag)}
        for ax, key in zip(row[:2], ("phi_ee", "phi_ue"), strict=True):
            test = tests[key]
            ax.stem(np.arange(len(test.values)), test.values, markerfmt=" ", basefmt=" ")
            ax.axhline(test.bound, color="red", ls="--", lw=0.8)
            ax.axhline(-test.bound, color="red", ls="--", lw=0.8)
            ax.set_title(f"{rec.name} {mode}: {key}", fontsize=8)
        freqs, psd, peaks = residual_spectrum(e, rec.fs)
        row[2].semilogy(freqs, psd, lw=0.8)
        for peak in peaks[:5]:
            row[2].axvline(peak["frequency_hz"], color="red", lw=0.6, ls=":")
        row[2].set_title("residual PSD (peaks dotted)", fontsize=8)
        row[2].set_xlabel("Hz", fontsize=7)
        stats = binned(u, e)
        row[3].plot(stats["x"], stats["mean"], "o-", ms=3)
        row[3].set_title(f"residual vs input [{rec.u_units}]", fontsize=8)
        for ax in row:
            ax.tick_params(labelsize=7)
    fig.tight_layout()
    return fig
