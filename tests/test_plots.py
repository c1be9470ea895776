"""Figures draw every output of every test recording (`evaluation.plots`)."""

from __future__ import annotations

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.evaluation.plots import loops_figure, residuals_figure


def _mimo_recording(name: str) -> Recording:
    """Two outputs: the first follows input 1, the second input 2 (input 0 drives neither)."""
    t = np.arange(2000) / 1000.0
    u = np.column_stack([np.sin(2 * np.pi * f * t) for f in (3.0, 5.0, 7.0)])
    y = np.column_stack([2.0 * u[:, 1], -u[:, 2] + 0.1 * u[:, 0]])
    return Recording(u=u, y=y, fs=1000.0, name=name, u_names=("a", "b", "c"),
                     y_names=("x", "z"))


def _visible(fig):
    return [ax for ax in fig.axes if ax.get_visible()]


def test_loops_of_a_mimo_recording_show_each_output_against_its_input():
    recordings = [_mimo_recording("r1"), _mimo_recording("r2")]
    predictions = {r.name: {"free_run": 0.9 * r.y} for r in recordings}
    axes = _visible(loops_figure(recordings, predictions))
    assert [ax.get_title() for ax in axes] == ["r1:x", "r1:z", "r2:x", "r2:z"]
    assert [ax.get_xlabel() for ax in axes[:2]] == ["b [V]", "c [V]"]
    assert [ax.get_ylabel() for ax in axes[:2]] == ["x [um]", "z [um]"]
    # the drawn curves are that output's (2000 samples: under max_points, none skipped):
    # measured z against input c, then the prediction of z
    measured = axes[1].lines[0]
    np.testing.assert_allclose(measured.get_xdata(), recordings[0].u[:, 2])
    np.testing.assert_allclose(measured.get_ydata(), recordings[0].y[:, 1])
    np.testing.assert_allclose(axes[1].lines[1].get_ydata(), 0.9 * recordings[0].y[:, 1])


def test_residuals_of_a_mimo_recording_are_drawn_per_output():
    recordings = [_mimo_recording("r1")]
    predictions = {"r1": {"free_run": recordings[0].y * np.array([1.0, 0.5])}}
    axes = _visible(residuals_figure(recordings, predictions))
    assert [ax.get_title() for ax in axes] == ["r1:x", "r1:z"]
    np.testing.assert_allclose(axes[0].lines[0].get_ydata(), 0.0)
    np.testing.assert_allclose(axes[1].lines[0].get_ydata(), 0.5 * recordings[0].y[:, 1])
