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


def _grid(n_panels: int, panel_size: float = 2.6, cols: int = 4) -> tuple[Figure, np.ndarray]:
    cols = min(cols, max(1, n_panels))
    rows = math.ceil(n_panels / cols)
    fig = Figure(figsize=(panel_size * cols, panel_size * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    for ax in axes.flat[n_panels:]:
        ax.set_visible(False)
    return fig, axes


def _panels(recordings: Sequence[Recording]) -> tuple[list[tuple[Recording, int]], int]:
    """One panel per recording and output, and the grid's column count: four panels a row
    for single-output data, one row per recording (a column per output) for several."""
    panels = [(rec, output) for rec in recordings for output in range(rec.ny)]
    ny = max((rec.ny for rec in recordings), default=1)
    return panels, 4 if ny == 1 else ny


def driving_input(rec: Recording, output: int) -> int:
    """The input whose measured signal correlates most (in magnitude) with ``output``: what
    a loop of that output is drawn against when there are several inputs."""
    if rec.nu == 1:
        return 0
    y = rec.y[:, output] - rec.y[:, output].mean()
    u = rec.u - rec.u.mean(axis=0)
    scale = np.linalg.norm(u, axis=0) * np.linalg.norm(y)
    corr = np.abs(u.T @ y) / np.where(scale > 0, scale, np.inf)
    return int(np.argmax(corr))


def loops_figure(
    recordings: Sequence[Recording],
    predictions: Mapping[str, Mapping[str, np.ndarray]],
    title: str = "",
    max_points: int = 4000,
    labels: Mapping[str, str] | None = None,
) -> Figure:
    """Figure-1-style grid: measured and predicted output against input, one panel per test
    recording and output (each output drawn against the input that drives it most).

    ``predictions[recording name][mode]`` is an (N, ny) array; modes are drawn in their own
    colour (free run solid red, one-step dashed orange), the measurement in black.
    ``labels``: the legend's name of a key of ``predictions`` (else the key, ``_`` as spaces).
    """
    labels = labels or {}
    panels, cols = _panels(recordings)
    fig, axes = _grid(len(panels), cols=cols)
    for ax, (rec, output) in zip(axes.flat, panels, strict=False):
        step = max(1, rec.n_samples // max_points)
        source = driving_input(rec, output)
        u = rec.u[::step, source]
        ax.plot(u, rec.y[::step, output], color="black", lw=1.2, label="measured")
        for position, (mode, y_hat) in enumerate(predictions.get(rec.name, {}).items()):
            color, style = _style(mode, position)
            ax.plot(
                u,
                np.asarray(y_hat)[::step, output],
                color=color,
                ls=style,
                lw=0.9,
                label=labels.get(mode, mode.replace("_", " ")),
            )
        ax.set_title(rec.output_label(output), fontsize=9)
        u_name = f"{rec.u_names[source]} " if rec.nu > 1 else "u "
        y_name = f"{rec.y_names[output]} " if rec.ny > 1 else "y "
        ax.set_xlabel(f"{u_name}[{rec.u_units}]", fontsize=8)
        ax.set_ylabel(f"{y_name}[{rec.y_units}]", fontsize=8)
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
    max_points: int = 4000,
) -> Figure:
    """Residual (measured minus predicted) against time, one panel per test recording and
    output."""
    panels, cols = _panels(recordings)
    fig, axes = _grid(len(panels), panel_size=2.8, cols=cols)
    for ax, (rec, output) in zip(axes.flat, panels, strict=False):
        step = max(1, rec.n_samples // max_points)
        t = rec.t[::step]
        for position, (mode, y_hat) in enumerate(predictions.get(rec.name, {}).items()):
            color, style = _style(mode, position)
            residual = rec.y[::step, output] - np.asarray(y_hat)[::step, output]
            ax.plot(t, residual, color=color, ls=style, lw=0.8, label=mode.replace("_", " "))
        ax.axhline(0.0, color="black", lw=0.5)
        ax.set_title(rec.output_label(output), fontsize=9)
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
