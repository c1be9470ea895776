"""Residual diagnostics of one model on its test recordings: numbers (JSON) and figures (PNG)."""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.loop.diagnosis.correlation import correlation_tests
from hysteresis_lab.loop.diagnosis.spectrum import binned, residual_spectrum

MODES = ("one_step", "free_run")


def residual_analysis(recordings: list[Recording], predictions: dict[str, dict[str, np.ndarray]],
                      n_skip: int, max_lag: int = 50) -> dict[str, Any]:
    """Per recording (and output, for several) and mode: correlation tests, spectrum peaks,
    residual vs level/rate/time. With several inputs the tests and the binned residual are
    given per input (keyed by its name)."""
    out: dict[str, Any] = {}
    for rec in recordings:
        for output in range(rec.ny):
            per_mode = {}
            for mode in MODES:
                if mode not in predictions.get(rec.name, {}):
                    continue
                e = (rec.y - predictions[rec.name][mode])[n_skip:, output]
                _, _, peaks = residual_spectrum(e, rec.fs)
                per_input = {name: _against_input(e, rec.u[n_skip:, i], rec.fs, max_lag)
                             for i, name in enumerate(rec.u_names)}
                per_mode[mode] = {
                    "rms": float(np.sqrt(np.mean(e**2))),
                    "spectrum_peaks": peaks,
                    "vs_time": binned(rec.t[n_skip:], e),
                    **(next(iter(per_input.values())) if rec.nu == 1 else {"inputs": per_input}),
                }
            out[rec.output_label(output)] = per_mode
    return out


def _against_input(e: np.ndarray, u: np.ndarray, fs: float, max_lag: int) -> dict[str, Any]:
    """The residual ``e`` against one input ``u``: correlation tests and binned residual."""
    return {
        "correlation": {t.name: t.to_dict() for t in correlation_tests(e, u, max_lag)},
        "vs_input": binned(u, e),
        "vs_rate": binned(np.gradient(u) * fs, e),
    }


def diagnostics_figure(recordings: list[Recording], predictions: dict[str, dict[str, np.ndarray]],
                       n_skip: int, mode: str = "free_run", max_lag: int = 50) -> Figure:
    """Rows per recording (and output): ACF, CCF, spectrum, residual vs input, labelled with
    the mode. With several inputs the CCF and the residual are shown against the input the
    residual correlates with most (named in the titles)."""
    series = [(rec, output) for rec in recordings for output in range(rec.ny)]
    fig = Figure(figsize=(13, 2.4 * len(series)))
    axes = fig.subplots(len(series), 4, squeeze=False)
    for row, (rec, output) in zip(axes, series, strict=True):
        e = (rec.y - predictions[rec.name][mode])[n_skip:, output]
        by_input = [
            {t.name: t for t in correlation_tests(e, rec.u[n_skip:, i], max_lag)}
            for i in range(rec.nu)
        ]
        strongest = int(np.argmax([np.max(np.abs(t["phi_ue"].values)) for t in by_input]))
        tests, u, u_name = by_input[strongest], rec.u[n_skip:, strongest], rec.u_names[strongest]
        label = rec.output_label(output)
        for ax, key in zip(row[:2], ("phi_ee", "phi_ue"), strict=True):
            test = tests[key]
            ax.stem(np.arange(len(test.values)), test.values, markerfmt=" ", basefmt=" ")
            ax.axhline(test.bound, color="red", ls="--", lw=0.8)
            ax.axhline(-test.bound, color="red", ls="--", lw=0.8)
            suffix = f" ({u_name})" if key == "phi_ue" and rec.nu > 1 else ""
            ax.set_title(f"{label} {mode}: {key}{suffix}", fontsize=8)
        freqs, psd, peaks = residual_spectrum(e, rec.fs)
        row[2].semilogy(freqs, psd, lw=0.8)
        for peak in peaks[:5]:
            row[2].axvline(peak["frequency_hz"], color="red", lw=0.6, ls=":")
        row[2].set_title("residual PSD (peaks dotted)", fontsize=8)
        row[2].set_xlabel("Hz", fontsize=7)
        stats = binned(u, e)
        row[3].plot(stats["x"], stats["mean"], "o-", ms=3)
        row[3].set_title(f"residual vs input {u_name} [{rec.u_units}]", fontsize=8)
        for ax in row:
            ax.tick_params(labelsize=7)
    fig.tight_layout()
    return fig
