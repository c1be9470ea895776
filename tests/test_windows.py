"""Regression windows: lag order, both layouts, recording boundaries, error cases."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import make_recording
from hysteresis_lab.data.windows import WindowSpec, assemble, make_windows
from hysteresis_lab.errors import ConfigError, DataError


def test_lags_are_the_previous_samples(index_recordings):
    spec = WindowSpec(na=10, nb=10, nk=1)
    windows = make_windows(index_recordings, spec)
    assert len(windows) == (50 - 10) + (30 - 10)
    row = 0  # first target of recording "a" is k = 10
    assert windows.index[row] == 10
    np.testing.assert_array_equal(windows.u_past[row, :, 0], np.arange(0, 10))
    np.testing.assert_array_equal(windows.y_past[row, :, 0], -np.arange(0, 10))
    assert windows.target[row, 0] == -10


def test_input_delay_shifts_the_input_lags():
    spec = WindowSpec(na=2, nb=3, nk=2)
    windows = make_windows(make_recording(20, "r"), spec)
    k = windows.index[0]
    assert k == spec.first_target == 4
    np.testing.assert_array_equal(windows.u_past[0, :, 0], [k - 4, k - 3, k - 2])
    np.testing.assert_array_equal(windows.y_past[0, :, 0], [-(k - 2), -(k - 1)])


def test_windows_never_cross_recording_boundaries(index_recordings):
    windows = make_windows(index_recordings, WindowSpec())
    for position, rec in enumerate(index_recordings):
        rows = windows.recording == position
        # every lag of every window comes from the same recording: u = k there, so lags are
        # consecutive integers ending right before the target index
        u = windows.u_past[rows, :, 0]
        np.testing.assert_array_equal(u[:, -1], windows.index[rows] - 1)
        assert u.min() >= 0 and u.max() < rec.n_samples


def test_flat_and_sequence_layouts_hold_the_same_numbers():
    rec = make_recording(40, "mimo", nu=2, ny=3)
    spec = WindowSpec(na=4, nb=6, nk=1)
    windows = make_windows(rec, spec)
    flat = windows.regressors("flat")
    seq = windows.regressors("sequence")
    assert flat.shape == (len(windows), 6 * 2 + 4 * 3)
    assert seq.shape == (len(windows), 6, 2 + 3)
    # newest step is last in the sequence; y lags beyond na are zero-padded at the front
    np.testing.assert_array_equal(seq[:, -1, :2], windows.u_past[:, -1, :])
    np.testing.assert_array_equal(seq[:, -1, 2:], windows.y_past[:, -1, :])
    np.testing.assert_array_equal(seq[:, :2, 2:], 0.0)
    torch_seq = assemble(
        torch.from_numpy(windows.u_past), torch.from_numpy(windows.y_past), "sequence"
    )
    np.testing.assert_array_equal(torch_seq.numpy(), seq)


def test_window_longer_than_data_is_a_clear_error():
    message = r"recording 'short': has 8 samples, but the regression window needs 11 \(na=10, "
    with pytest.raises(DataError, match=message):
        make_windows(make_recording(8, "short"), WindowSpec())


def test_invalid_window_spec():
    with pytest.raises(ConfigError, match=r"window nb=0 is invalid.*data\.window\.nb"):
        WindowSpec(nb=0)
    with pytest.raises(ConfigError, match=r"unknown window layout 'grid'"):
        assemble(np.zeros((1, 2, 1)), np.zeros((1, 2, 1)), "grid")
