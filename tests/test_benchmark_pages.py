"""Benchmark pages say where their numbers come from: a zoo fit run again names its own
commit; a grey-box comparison without CPU records times each run by its log."""

from __future__ import annotations

import copy
import importlib.util
import json
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _script(name: str, monkeypatch):
    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))
    spec = importlib.util.spec_from_file_location(f"_page_{name}", REPO / "benchmarks" /
                                                  f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)
    spec.loader.exec_module(module)
    return module


def test_a_refitted_zoo_model_names_its_own_commit(monkeypatch):
    zoo = _script("zoo", monkeypatch)
    kept = json.loads((REPO / "docs" / "results" / "zoo.json").read_text())
    kept = copy.deepcopy({seed: kept[seed] for seed in list(kept)[:2]})
    for row in kept.values():
        row["fits"]["greybox"]["commit"] = "refit0a"
    page = zoo.render(kept)
    lines = summary_lines(page)
    assert lines["greybox"].rstrip(" |").endswith("refit0a")
    assert "refit0a" not in lines["linear+hysteresis"]
    assert "refit0a" in page.splitlines()[2]  # the page's provenance lists it too


def summary_lines(page: str) -> dict[str, str]:
    """The zoo page's summary rows by model (``| greybox (13 plants) | ...``)."""
    return {line.split("|")[1].split(" (")[0].strip(): line for line in page.splitlines()
            if line.startswith("| ") and " plants) |" in line.split("|")[1] + "|"}


def test_a_model_fitted_on_fewer_plants_is_counted_over_its_own(monkeypatch):
    """``--fits``: a plant without the loop's fit shows none, and the loop's statistics count
    only the plants it was fitted on."""
    zoo = _script("zoo", monkeypatch)
    kept = json.loads((REPO / "docs" / "results" / "zoo.json").read_text())
    kept = copy.deepcopy({seed: kept[seed] for seed in list(kept)[:3]})
    del kept[list(kept)[0]]["fits"]["loop"]
    page = zoo.render(kept)
    lines = summary_lines(page)
    assert "(3 plants)" in lines["greybox"]
    assert "(2 plants)" in lines["loop"]
    assert "| 0 |" in lines["loop"]  # no plant counted as diverged for a fit never run
    assert "not fitted" in page
    assert "Fitted on fewer plants: `loop` on 2." in page


def test_a_piece_the_loop_can_grow_and_did_not_is_its_diagnosis_not_its_structure(
        monkeypatch):
    """Creep or asymmetry a loop fit lacks is named as not added (the loop can grow it), a
    Bouc-Wen exponent as structure; once the loop keeps creep, creep is no reason."""
    zoo = _script("zoo", monkeypatch)
    kept = json.loads((REPO / "docs" / "results" / "zoo.json").read_text())
    row = copy.deepcopy(kept["12"])  # Bouc-Wen n 2.43 with creep
    row["gaps"].update(creep=11.0, exponent=58.0)
    row["fits"]["loop"]["effects"] = ["hysteresis"]
    reasons = zoo.why(row, "loop")
    assert "diagnosis: not added, though the loop can: creep" in reasons
    assert "structure (each piece's size alone): Bouc–Wen n = 2.43" in reasons
    greybox = zoo.why(row, "greybox")  # the grey-box cannot grow creep undeclared
    assert "structure (each piece's size alone): creep" in greybox and "diagnosis" not in greybox
    row["fits"]["loop"]["effects"] = ["hysteresis", "creep"]
    assert "creep" not in zoo.why(row, "loop")


def test_a_comparison_without_cpu_records_is_timed_by_its_logs(monkeypatch, tmp_path):
    pair = _script("greybox_pair", monkeypatch)
    comparison = pair.COMPARISONS["feedthrough"]
    for setting, seconds in ((comparison.base, 7), (comparison.variant, 19)):
        folder = tmp_path / "default" / setting.name
        folder.mkdir(parents=True)
        (folder / "metrics.json").write_text(json.dumps(
            {"tests": {"a": {"rmse_free_run": 1.0}}, "val_mse_scaled": 1e-3}))
        (folder / "fit.log").write_text(
            "[2026-11-28 10:00:00,000][x][INFO] - start\nno stamp\n"
            f"[2026-11-28 10:00:{seconds:02d},500][x][INFO] - end\n")
    (tmp_path / "default" / comparison.base.name / "cputime").write_text("3.0\n")
    row = pair.row("default", comparison, tmp_path)
    assert row[comparison.variant.name]["wall_s"] == pytest.approx(19.5)
    label, key, _ = pair.time_column([row], comparison)
    assert (label, key) == ("wall s", "wall_s")  # one fit lacks its CPU record
    (tmp_path / "default" / comparison.variant.name / "cputime").write_text("5.0\n")
    row = pair.row("default", comparison, tmp_path)
    assert pair.time_column([row], comparison)[1] == "cpu_s"
