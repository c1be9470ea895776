"""The rule of experiments/undeclared_effects.py: an effect the start holds is a pass."""

from __future__ import annotations

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "experiments" / "undeclared_effects.py"


def _script():
    spec = importlib.util.spec_from_file_location("undeclared_effects", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _verdict(row: dict) -> str:
    return _script().verdict(row)


def _row(share: float, ceilings: dict[str, float]) -> dict:
    """A case whose effect was not named: ``share`` of the residual, these ceilings (%)."""
    return {"top": "creep", "expected": ["resonance"], "significant": False,
            "effect_share_max": share, "ceiling_pct": ceilings, "predictable": True}


def test_an_effect_the_start_holds_passes_unnamed():
    """A linear second mode the linear start fits: nothing in the residual, nothing in any
    test's error (ceilings of a few %): not naming it meets the rule."""
    assert _verdict(_row(0.002, {"sine_100Hz": 0.4, "sine_500Hz": 5.0})).startswith("PASS")


def test_an_effect_the_diagnosis_cannot_see_is_no_pass():
    """Creep on a 1 s validation multisine: below min_score of the residual there, but most
    of the slow tests' error (ceiling 98 %): not applicable, not a pass; shown and not named
    is a failure."""
    assert _verdict(_row(0.001, {"sine_0.1Hz": 98.0})).startswith("n/a")
    assert _verdict(_row(0.5, {"sine_0.1Hz": 1.0})).startswith("FAIL")


def test_the_refit_judged_is_the_first_the_loop_keeps():
    """Round 0 adds hysteresis, which loses on held-out data; the loop then tries backlash and
    keeps it: the backlash refit is what round 0's diagnosis led to. Where every refit lost,
    the first one tried is shown (as rejected)."""
    judged = _script().judged_refit
    start = {"effects": []}
    dropped = {"effects": ["hysteresis"], "rejected": "hysteresis"}
    kept = {"effects": ["backlash"]}
    assert judged([start, dropped, kept]) is kept
    assert judged([start, dropped, {"effects": ["backlash"], "rejected": "backlash"}]) is dropped


def test_a_rerun_with_the_recommended_recordings_says_so_and_the_first_row_stands():
    """Saturation not judged on the validation multisine: the first run's row keeps its FAIL
    and shows the recordings its report recommends; the rerun's verdict names them."""
    script = _script()
    override = ["data.splits.train_sines=[0.32,22]", "data.splits.val_sines=[3.2]"]
    report = {"rounds": [{"under_excited": [
        {"effect": "dead_zone", "override": ["data.splits.train_sines=[7]"]},
        {"effect": "saturation", "override": override}]}]}
    assert script.recommended_recordings(report, ("saturation",)) == override
    assert script.recommended_recordings({"rounds": [{}]}, ("saturation",)) is None
    assert script.recommended_recordings(report, ("creep",)) is None  # not the case's effect
    first = {"verdict": "FAIL: not named as the top significant effect", "recommends": override,
             "added_recordings": []}
    cell = script._verdict_cell(first)
    assert cell.startswith("FAIL: not named") and " ".join(override) in cell
    assert script._with_recommended("PASS") == "PASS with the recommended recordings"
    assert script._with_recommended("FAIL: > 5 % worse on ['sine_1Hz']") == (
        "FAIL with the recommended recordings: > 5 % worse on ['sine_1Hz']")
    assert script.command_for("saturation", 1, tuple(override))[-5:-3] == override
