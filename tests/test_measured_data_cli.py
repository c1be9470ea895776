"""The five measured-data configs through ``hysteresis-lab-train`` (a short fit each), and the
3-output FSM model through ``hysteresis-lab-evaluate``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from helpers import run_app
from hysteresis_lab.data.benchmarks import load_benchmark
from hysteresis_lab.evaluation.accuracy_table import registered

pytestmark = pytest.mark.slow  # every test here runs a console app

#: one epoch of 20 batches: the point is the data path, not the fit
SHORT = ["model=ffnn", "trainer.max_epochs=1", "+trainer.limit_train_batches=20",
         "+trainer.limit_val_batches=5", "trainer.enable_progress_bar=false",
         "trainer.enable_model_summary=false", "logger=none", "plots=false"]

#: data config -> (units, range of each test output's standard deviation in those units: a
#: conversion slip (m for mm, V for um) lands far outside it); every registered data set of
#: this package needs its entry
MEASURED = {
    "p885": ({"u": "V", "y": "um"}, (10.0, 25.0)),
    "bouc_wen": ({"u": "N", "y": "mm"}, (0.3, 1.5)),
    "emps": ({"u": "V", "y": "mm"}, (40.0, 160.0)),
    "cascaded_tanks": ({"u": "V", "y": "V"}, (1.0, 4.0)),
    "fsm": ({"u": "V", "y": "um"}, (1.0, 5.0)),
}
#: the registered data sets this package ships, by data config name -> registry name
BUNDLED = {data: name for data, (name, dataset) in registered().items()
           if dataset.load.__module__.startswith("hysteresis_lab.")}


def train(data: str, run_dir: Path) -> dict:
    proc = run_app("train", f"data={data}", *SHORT, f"hydra.run.dir={run_dir}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads((run_dir / "metrics.json").read_text())


@pytest.fixture(scope="module")
def fsm_run(tmp_path_factory) -> tuple[Path, dict]:
    run_dir = tmp_path_factory.mktemp("fsm_run")
    return run_dir, train("fsm", run_dir)


@pytest.mark.parametrize("data", sorted(BUNDLED))
def test_measured_data_config_trains_and_scores_in_its_units(data, tmp_path, request):
    assert data in MEASURED, f"add the units and output spread of data={data} to MEASURED"
    units, (low, high) = MEASURED[data]
    loader = BUNDLED[data]
    if data == "fsm":
        _, metrics = request.getfixturevalue("fsm_run")
    else:
        metrics = train(data, tmp_path)
    assert metrics["data"] == data and metrics["units"] == units
    assert list(metrics["tests"]) == [rec.name for rec in load_benchmark(loader).test]
    for name, scores in metrics["tests"].items():
        assert all(math.isfinite(v) for v in scores.values()), name
        assert scores["rmse_one_step"] > 0 and scores["rmse_free_run"] > 0
        # rmse / nrmse is the test output's standard deviation, in the benchmark's units
        assert low < scores["rmse_one_step"] / scores["nrmse_one_step"] < high, name
    # even one short epoch predicts one step ahead better than the outputs' mean
    assert metrics["mean"]["nrmse_one_step"] < 1.0
    assert math.isfinite(metrics["val_mse_scaled"])


def test_a_three_output_model_evaluates_again_to_the_same_scores(fsm_run, tmp_path):
    """The FSM (3 inputs, 3 outputs) model, scored again by hysteresis-lab-evaluate on one
    amplitude's tests, gives the training run's scores for those recordings."""
    run_dir, trained = fsm_run
    proc = run_app("evaluate", f"checkpoint={run_dir}", "data=fsm", "data.splits.amplitude=200",
                   "plots=false", f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    again = json.loads((tmp_path / "metrics.json").read_text())
    assert sorted(again["tests"]) == sorted(n for n in trained["tests"] if n.startswith("200mV"))
    assert len(again["tests"]) == 6
    for name, scores in again["tests"].items():
        assert scores == pytest.approx(trained["tests"][name], rel=1e-6), name
