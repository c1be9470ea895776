"""Metrics against values computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.errors import DataError
from hysteresis_lab.evaluation.metrics import nrmse, r2, rmse, score


def test_rmse_r2_nrmse_by_hand():
    y = np.array([1.0, 2.0, 3.0, 4.0])
    p = np.array([1.0, 2.0, 3.0, 6.0])
    # errors 0,0,0,2 -> MSE 1 -> RMSE 1; SST = 5 -> R2 = 1 - 4/5; std = sqrt(1.25)
    assert rmse(y, p) == pytest.approx(1.0)
    assert r2(y, p) == pytest.approx(0.2)
    assert nrmse(y, p) == pytest.approx(1.0 / np.sqrt(1.25))


def test_mimo_rmse_averages_per_channel_rmse():
    y = np.zeros((4, 2))
    p = np.column_stack([np.full(4, 3.0), np.full(4, 1.0)])
    assert rmse(y, p) == pytest.approx(2.0)  # mean of 3 and 1, not sqrt((9 + 1) / 2)


def test_score_skips_initial_samples_and_checks_shapes():
    rec = Recording(u=np.zeros(5), y=np.array([0.0, 0.0, 1.0, 2.0, 3.0]), fs=1.0, name="r")
    predicted = np.array([9.0, 9.0, 1.0, 2.0, 4.0])
    scores = score(rec, predicted, n_skip=2)
    assert scores["rmse"] == pytest.approx(np.sqrt(1 / 3))
    assert scores["r2"] == pytest.approx(1 - 1 / 2)
    with pytest.raises(DataError, match="shape"):
        score(rec, np.zeros(4))
    with pytest.raises(DataError, match="nothing left"):
        score(rec, predicted, n_skip=5)



def _document(initial_state: str) -> dict:
    scores = {"r2_one_step": 0.9, "rmse_one_step": 0.1, "r2_free_run": 0.8, "rmse_free_run": 0.2}
    return {"tests": {"sine_1Hz": scores}, "mean": scores, "std": scores,
            "units": {"y": "um"}, "initial_state": initial_state}


def test_table2_names_how_the_free_runs_started():
    from hysteresis_lab.evaluation.report import table2_markdown

    rest = table2_markdown({"ffnn": _document("rest"), "svm": _document("rest")})
    assert "### Free-run simulation (from rest)" in rest
    assert "### One-step-ahead prediction\n" in rest
    mixed = table2_markdown({"ffnn": _document("rest"), "greybox": _document("estimate")})
    assert "ffnn: from rest; greybox: initial state estimated" in mixed
