"""Figures: hysteresis loops (displacement against voltage) and residuals per test recording."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # pyplot-free: no global backend state

from hysteresis_lab.data.recording import Recording

MODE_STYLES = {"one_step": ("tab:orange", "--"), "free_run": ("tab:red", "-")}
OTHER_COLORS = ("tab:blue", "tab:green", "tab:purple", "tab:brown", "tab:olive", "tab:cyan")


def _style(label: str, position: int) -> tuple[str, str]:
    """Colour and line style of a curve: fixed for the evaluation modes, cycled otherwise."""
    return MODE_STYLES.get(label, (OTHER_COLORS[position % len(OTHER_COLORS)], "-"))


def _grid(n_panels: int, panel_size: float = 2.6) -> tuple[Figure, np.ndarray]:
    cols = min(4, max(1, n_panels))
    rows = math.ceil(n_panels / cols)
    fig = Figure(figsize=(panel_size * cols, panel_size * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    for ax in axes.flat[n_panels:]:
        ax.set_visible(False)
    return fig, axes


def loops_figure(
    recordings: Sequence[Recording],
    predictions: Mapping[str, Mapping[str, np.ndarray]],
    title: str = "",
    channel: int = 0,
    max_points: int = 4000,
) -> Figure:
    """Figure-1-style grid: measured and predicted output against input, one panel per test.

    ``predictions[recording name][mode]`` is an (N, ny) array; modes are drawn in their own
    colour (free run solid red, one-step dashed orange), the measurement in black.
    """
    fig, axes = _grid(len(recordings))
    for ax, rec in zip(axes.flat, recordings, strict=False):
        step = max(1, rec.n_samples // max_points)
        u = rec.u[::step, min(channel, rec.nu - 1)]
        ax.plot(u, rec.y[::step, channel], color="black", lw=1.2, label="measured")
        for position, (mode, y_hat) in enumerate(predictions.get(rec.name, {}).items()):
            color, style = _style(mode, position)
            ax.plot(
                u,
                np.asarray(y_hat)[::step, channel],
                color=color,
                ls=style,
                lw=0.9,
                label=mode.replace("_", " "),
            )
        ax.set_title(rec.name, fontsize=9)
        ax.set_xlabel(f"u [{rec.u_units}]", fontsize=8)
        ax.set_ylabel(f"y [{rec.y_units}]", fontsize=8)
        ax.tick_params(labelsize=7)
    axes.flat[0].legend(fontsize=7, loc="upper left")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def residuals_figure(
    recordings: Sequence[Recording],
    predictions: Mapping[str, Mapping[str, np.ndarray]],
    title: str = "",
    channel: int = 0,
    max_points: int = 4000,
) -> Figure:
    """Residual (measured minus predicted) against time, one panel per test recording."""
    fig, axes = _grid(len(recordings), panel_size=2.8)
    for ax, rec in zip(axes.flat, recordings, strict=False):
        step = max(1, rec.n_samples // max_points)
        t = rec.t[::step]
        for position, (mode, y_hat) in enumerate(predictions.get(rec.name, {}).items()):
            color, style = _style(mode, position)
            residual = rec.y[::step, channel] - np.asarray(y_hat)[::step, channel]
            ax.plot(t, residual, color=color, ls=style, lw=0.8, label=mode.replace("_", " "))
        ax.axhline(0.0, color="black", lw=0.5)
        ax.set_title(rec.name, fontsize=9)
        ax.set_xlabel("t [s]", fontsize=8)
        ax.set_ylabel(f"residual [{rec.y_units}]", fontsize=8)
        ax.tick_params(labelsize=7)
    axes.flat[0].legend(fontsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def save_figure(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path
