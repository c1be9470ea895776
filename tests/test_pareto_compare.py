"""`benchmarks/pareto_compare.py`: the compute and the front quality of stored Pareto studies."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import optuna
import pytest
from optuna._hypervolume import compute_hypervolume
from optuna.trial import TrialState

from hysteresis_lab.tuning.pruning import pruning_study_name

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "pareto_compare.py"


@pytest.fixture(scope="module")
def compare():
    spec = importlib.util.spec_from_file_location("pareto_compare", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules["pareto_compare"] = module
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop("pareto_compare", None)


def test_the_hypervolume_is_optunas(compare):
    """The staircase area equals Optuna's own hypervolume on random fronts and clouds."""
    rng = np.random.default_rng(0)
    for _ in range(20):
        points = rng.uniform(0.0, 1.0, size=(int(rng.integers(1, 12)), 2))
        reference = np.array([1.1, 1.2])
        ours = compare.hypervolume_2d([tuple(p) for p in points], tuple(reference))
        assert ours == pytest.approx(compute_hypervolume(points, reference), rel=1e-12)
    assert compare.hypervolume_2d([(2.0, 0.0)], (1.0, 1.0)) == 0.0  # beyond the reference


def _study(folder: Path, epochs: list[int], values: list[tuple[float, float] | None]) -> None:
    """A stored Pareto study of ``ffnn`` and its companion: trial i reports ``epochs[i]``
    epochs and completes with ``values[i]`` (None: pruned)."""
    url = f"sqlite:///{folder}/ffnn_pareto_default.db"
    name = "ffnn_pareto_default"
    study = optuna.create_study(study_name=name, storage=url, directions=["minimize"] * 2)
    companion = optuna.create_study(study_name=pruning_study_name(name), storage=url)
    for n, value in zip(epochs, values, strict=True):
        trial, reports = study.ask(), companion.ask()
        for epoch in range(n):
            reports.report(1.0 / (epoch + 1), step=epoch)
        if value is None:
            study.tell(trial, state=TrialState.PRUNED)
            companion.tell(reports, state=TrialState.PRUNED)
        else:
            study.tell(trial, list(value))
            companion.tell(reports, value[0])


def test_a_run_is_summarised_from_its_stored_studies(compare, tmp_path):
    """States, epochs trained (from the companion's reports), the best error, and a front
    that dominates more scoring a larger hypervolume against the shared reference."""
    wide, narrow = tmp_path / "wide", tmp_path / "narrow"
    wide.mkdir(), narrow.mkdir()
    _study(wide, [10, 3, 10], [(1e-4, 20.0), None, (1e-3, 5.0)])
    _study(narrow, [10, 10], [(1e-3, 20.0), (1e-2, 30.0)])
    a, b = compare.summarise(wide, "ffnn"), compare.summarise(narrow, "ffnn")
    assert a.states == {"complete": 2, "pruned": 1} and a.epochs == 23
    assert b.states == {"complete": 2} and b.epochs == 20
    assert a.best_error == pytest.approx(1e-4) and b.best_error == pytest.approx(1e-3)
    assert b.points == [(pytest.approx(-3.0), 20.0)]  # trial 2 is dominated
    assert compare.summarise(wide, "lstm") is None
    reference = compare.reference_point(a.points + b.points)
    assert compare.hypervolume_2d(a.points, reference) > compare.hypervolume_2d(b.points, reference)

    out = tmp_path / "page.md"
    compare.write_page(["wide", "narrow"], {"ffnn": [a, b], "lstm": [None, None]}, out, [])
    rows = [line for line in out.read_text().splitlines() if line.startswith("| ffnn")]
    assert [row.split(" | ")[1] for row in rows] == ["wide", "narrow"]
    assert "| 23 | 0.0001 |" in rows[0]
    assert not math.isnan(float(rows[1].rstrip(" |").split(" | ")[-1]))
