"""Figures of the loop's report: the residual evidence of a round, as an engineer reads it.

Per diagnosed round: the free-run residual of each diagnosis recording over time beside its
spectrum (`residual_figure`), and every tested effect's held-out score (`scores_figure`). Per
added effect: what of that residual the effect's own signals reproduce, and the residual
against the signal it follows most (`effect_figure`). Pure drawing from arrays already at
hand (no model runs here); pyplot-free, like `hysteresis_lab.evaluation.plots`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.loop.diagnosis.ranking import effect_signals
from hysteresis_lab.loop.diagnosis.spectrum import binned, residual_spectrum

#: at most this many points of a series are drawn (every n-th sample)
MAX_POINTS = 2000
DPI = 90


@dataclass(frozen=True)
class Series:
    """One output of one diagnosis recording, from the sample it is scored from on."""

    label: str
    t: np.ndarray  # seconds from the recording's start
    residual: np.ndarray  # (N,) measured minus free run
    fs: float
    units: str


@dataclass(frozen=True)
class ResidualEvidence:
    """A model's free run on the loop's diagnosis recordings (each simulated end to end and
    scored from ``starts[i]`` on, named ``labels[i]`` as the report names it)."""

    recordings: list[Recording]
    predictions: list[np.ndarray]
    starts: list[int]
    labels: list[str]

    def series(self) -> list[Series]:
        """Every output of every recording, from its start on."""
        out = []
        for rec, y_hat, start, label in zip(self.recordings, self.predictions, self.starts,
                                            self.labels, strict=True):
            residual = rec.y - np.asarray(y_hat, dtype=float).reshape(rec.y.shape)
            for j in range(rec.ny):
                name = label if rec.ny == 1 else f"{label}:{rec.y_names[j]}"
                out.append(Series(name, rec.t[start:], residual[start:, j], rec.fs, rec.y_units))
        return out

    def signals(self, effect: str, context: FeatureContext) -> list[np.ndarray]:
        """``effect``'s diagnosis signals per series (computed on the whole recording, its
        operators' memory included, then cut where the series starts)."""
        whole = effect_signals(effect, self.recordings, context, self.predictions)
        starts = [s for rec, s in zip(self.recordings, self.starts, strict=True)
                  for _ in range(rec.ny)]
        return [x[s:] for x, s in zip(whole, starts, strict=True)]


def _step(n: int) -> int:
    return max(1, n // MAX_POINTS)


def residual_figure(evidence: ResidualEvidence, title: str = "") -> Figure:
    """Per series a row: the residual over time (its RMS in the title) and its Welch PSD
    with the peaks dotted."""
    series = evidence.series()
    fig = Figure(figsize=(10, 2.3 * len(series) + 0.4))
    axes = fig.subplots(len(series), 2, squeeze=False, width_ratios=(2, 1))
    for (time_ax, psd_ax), s in zip(axes, series, strict=True):
        finite = np.isfinite(s.residual)
        step = _step(len(s.t))
        time_ax.plot(s.t[::step], s.residual[::step], color="tab:red", lw=0.7)
        time_ax.axhline(0.0, color="black", lw=0.5)
        rms = float(np.sqrt(np.mean(s.residual[finite] ** 2))) if finite.any() else np.nan
        time_ax.set_title(f"{s.label}: free-run residual (RMS {rms:.4g} {s.units})", fontsize=8)
        time_ax.set_xlabel("t [s]", fontsize=7)
        time_ax.set_ylabel(f"measured - free run [{s.units}]", fontsize=7)
        if finite.sum() > 8:
            freqs, psd, peaks = residual_spectrum(s.residual[finite], s.fs)
            psd_ax.semilogy(freqs[1:], psd[1:], lw=0.8)
            for peak in peaks[:5]:
                psd_ax.axvline(peak["frequency_hz"], color="red", lw=0.6, ls=":")
        psd_ax.set_title("residual PSD (peaks dotted)", fontsize=8)
        psd_ax.set_xlabel("Hz", fontsize=7)
        for ax in (time_ax, psd_ax):
            ax.tick_params(labelsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def scores_figure(
    diagnosis: Sequence[Mapping[str, Any]], min_score: float, added: str | None = None
) -> Figure:
    """Every tested effect's held-out score (share of the residual variance it explains
    beyond the input and the declared effects), significant ones filled, the added one
    named, ``loop.min_score`` dashed."""
    tested = [d for d in diagnosis if d["tested"]]
    fig = Figure(figsize=(6, 0.35 * max(len(tested), 1) + 1.2))
    ax = fig.subplots()
    rows = np.arange(len(tested))[::-1]
    scores = [float(d["score"]) for d in tested]
    colors = ["tab:red" if d["significant"] else "lightgray" for d in tested]
    ax.barh(rows, scores, color=colors, edgecolor="black", lw=0.5)
    labels = [f"{d['effect']}{' (added)' if d['effect'] == added else ''}" for d in tested]
    ax.set_yticks(rows, labels, fontsize=8)
    for row, d in zip(rows, tested, strict=True):
        ax.annotate(f"p {float(d['p_value']):.2g}", (max(float(d["score"]), 0.0), row),
                    xytext=(3, 0), textcoords="offset points", va="center", fontsize=7)
    ax.axvline(min_score, color="black", ls="--", lw=0.8, label=f"loop.min_score {min_score:g}")
    ax.axvline(0.0, color="black", lw=0.5)
    ax.set_xlabel("held-out share of the residual variance explained (score)", fontsize=8)
    ax.set_title("missing effects: score (red: significant)", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    ax.tick_params(labelsize=7)
    fig.tight_layout()
    return fig


def _least_squares_fit(e: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The part of ``e`` that a constant and the columns of ``x`` reproduce (in sample)."""
    design = np.column_stack([np.ones(len(e)), x])
    coef, *_ = np.linalg.lstsq(design, e, rcond=None)
    return design @ coef


def _strongest(e: np.ndarray, x: np.ndarray) -> int:
    """The column of ``x`` whose correlation with ``e`` is largest in magnitude."""
    xc, ec = x - x.mean(axis=0), e - e.mean()
    scale = np.linalg.norm(xc, axis=0) * np.linalg.norm(ec)
    corr = np.abs(xc.T @ ec) / np.where(scale > 0, scale, np.inf)
    return int(np.argmax(corr))


def effect_figure(evidence: ResidualEvidence, effect: str, context: FeatureContext) -> Figure:
    """Per series a row: the residual over time with what ``effect``'s diagnosis signals
    reproduce of it (least squares, in sample, without the diagnosis' lags: an illustration,
    the score is held out), and the residual against the one signal it follows most."""
    series, signals = evidence.series(), evidence.signals(effect, context)
    fig = Figure(figsize=(10, 2.3 * len(series) + 0.4))
    axes = fig.subplots(len(series), 2, squeeze=False, width_ratios=(2, 1))
    for (time_ax, scatter_ax), s, x in zip(axes, series, signals, strict=True):
        x = np.asarray(x, dtype=float).reshape(len(s.residual), -1)
        keep = np.isfinite(s.residual) & np.all(np.isfinite(x), axis=1)
        e, x, t = s.residual[keep], x[keep], s.t[keep]
        step = _step(len(t))
        time_ax.plot(t[::step], e[::step], color="tab:red", lw=0.7, label="residual")
        if len(e) > x.shape[1] + 1:
            fit = _least_squares_fit(e, x)
            share = 1.0 - float(np.var(e - fit) / np.var(e)) if np.var(e) > 0 else 0.0
            label = f"{effect} signals alone, least squares ({100 * share:.0f} % in sample)"
            time_ax.plot(t[::step], fit[::step], color="tab:blue", lw=0.8, label=label)
            j = _strongest(e, x)
            scatter_ax.plot(x[::step, j], e[::step], ".", ms=1.5, color="tab:gray")
            stats = binned(x[:, j], e)
            scatter_ax.plot(stats["x"], stats["mean"], "o-", ms=3, color="tab:red")
            scatter_ax.set_xlabel(f"{effect} signal {j}", fontsize=7)
        time_ax.axhline(0.0, color="black", lw=0.5)
        time_ax.set_title(f"{s.label}: residual and what '{effect}' reproduces", fontsize=8)
        time_ax.set_xlabel("t [s]", fontsize=7)
        time_ax.set_ylabel(f"[{s.units}]", fontsize=7)
        time_ax.legend(fontsize=7, loc="upper right")
        scatter_ax.set_title("residual against its strongest signal (binned mean)", fontsize=8)
        for ax in (time_ax, scatter_ax):
            ax.tick_params(labelsize=7)
    fig.tight_layout()
    return fig
