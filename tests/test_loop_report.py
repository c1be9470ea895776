"""The loop's report page (no training): a start, a kept and a dropped refit written as the
loop writes them, their decisions made by the loop's own rule, their figures drawn from a
residual with known hysteresis."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.evaluation.plots import save_figure
from hysteresis_lab.evaluation.report import write_json
from hysteresis_lab.loop.crossval import FoldsCheck, HeldOut, keep_refit
from hysteresis_lab.loop.diagnosis.excitation import operator_excitation
from hysteresis_lab.loop.diagnosis.ranking import diagnose
from hysteresis_lab.loop.diagnosis.residuals import diagnostics_figure
from hysteresis_lab.loop.driver import (
    LoopSettings,
    _Candidate,
    _decision,
    _LoopState,
    _Standing,
)
from hysteresis_lab.loop.figures import ResidualEvidence
from hysteresis_lab.loop.report import loop_markdown, write_round_figures
from hysteresis_lab.models.augment import feature_context
from hysteresis_lab.physics.play import play_operators
from hysteresis_lab.run_folder import LoopFolder
from hysteresis_lab.workflows.pipeline import RunResult
from loop_notebook import check_loop_notebook, round_sections, subsection

FS = 100.0


def hysteretic() -> tuple[Recording, np.ndarray]:
    """A decaying sine through a play operator, and a linear model's free run (the input)."""
    t = np.arange(2000) / FS
    u = np.sin(2 * np.pi * 0.5 * t) * np.exp(-t / 15)
    y = u + 0.3 * play_operators(u, np.array([0.3]))[:, 0]
    return Recording(u=u, y=y, fs=FS, name="val", u_units="V", y_units="um"), u[:, None]


def scores(rmse: float) -> dict:
    return {"tests": {"sine": {"rmse_free_run": rmse, "rmse_one_step": rmse, "r2_free_run": 0.9}},
            "mean_rmse_free_run": rmse, "mean_rmse_one_step": rmse}


def result(improved: bool = True, rejected: dict | None = None) -> RunResult:
    return RunResult({}, 1.0, None, None, None, improved, {"start": 0.5, "refit": 0.4}, rejected)


def folds(loss: float) -> FoldsCheck:
    return FoldsCheck([HeldOut(loss, {}, [], []), HeldOut(loss, {}, [], [])])


def held(loss: float) -> dict:
    return {"loss": loss, "rmse": {"val[1500:2000]": loss}, "diverging": []}


def write_loop_folder(folder: LoopFolder) -> dict:
    """Round 0 (start, adds hysteresis), round 1 (kept), round 2 (creep, dropped on the
    held-out data), written as `run_loop` writes them."""
    rec, free_run = hysteretic()
    evidence = ResidualEvidence([rec], [free_run], [100], ["val[100:2000]"])
    context = feature_context([rec])
    settings = LoopSettings()
    diagnosis = [d.to_dict() for d in diagnose([rec], [rec.y - free_run], context, [],
                                               predictions=[free_run])]
    start = {"effects": [], **scores(1.0), "diagnosis": diagnosis, "added": "hysteresis",
             "held_out": held(0.5),
             "added_excitation": operator_excitation("hysteresis", [rec], [rec],
                                                     context).to_dict(),
             "figures": {"diagnostics": "round_0/residual_diagnostics.png"}}
    save_figure(diagnostics_figure([rec], {"val": {"free_run": free_run}}, 100),
                folder.path / "round_0" / "residual_diagnostics.png")
    state = _LoopState(effects=[], rounds=[start],
                       kept=[_Standing(result(), [], folds(0.5))])
    refit = {"effects": ["hysteresis"], **scores(0.8), "diagnosis": [], "added": "creep",
             "held_out": held(0.3)}
    kept, reason = keep_refit(folds(0.3), folds(0.5), 0.0)
    refit["decision"] = _decision("hysteresis", kept, reason,
                                  _Candidate({}, None, [], folds(0.3)), state)
    state.rounds.append(refit)
    state.kept.append(_Standing(result(), [], folds(0.3)))
    dropped = {"effects": ["hysteresis", "creep"], **scores(0.8), "diagnosis": [], "added": None,
               "held_out": held(0.3), "rejected": "creep",
               "rejected_held_out": held(0.35),
               "note": "the refit with 'creep' did not beat the last model"}
    kept, reason = keep_refit(folds(0.35), folds(0.3), 0.0)
    dropped["decision"] = _decision("creep", kept, reason,
                                    _Candidate({}, None, [], folds(0.35)), state)
    state.rounds.append(dropped)
    for number, entry in enumerate(state.rounds):
        write_round_figures(folder, number, entry, evidence, context, settings.min_score)
    report = {"units": {"y": "um"}, "data": "toy", "model": "linear",
              "start": {"model": "linear", "effects": []},
              "settings": {"min_score": 0.05, "alpha": 0.01, "significance": "pooled",
                           "min_refit_gain": 0.0},
              "roles": {"train": ["train"], "validation": ["val[1500:2000]"],
                        "diagnosis": ["val[100:2000]"], "test": ["sine"]},
              "result": 1, "rounds": state.rounds}
    write_json(report, folder.report_json)
    folder.report_md.write_text(loop_markdown(report))
    return report


@pytest.fixture(scope="module")
def notebook(tmp_path_factory) -> Path:
    """A loop folder with the three rounds of `write_loop_folder`."""
    path = tmp_path_factory.mktemp("notebook")
    write_loop_folder(LoopFolder(path))
    return path


def test_the_report_is_a_notebook_page_of_its_json(notebook):
    folder = LoopFolder(notebook)
    report = check_loop_notebook(notebook)
    start, kept, dropped = report["rounds"]
    assert start["diagnosis"][0]["effect"] == "hysteresis"  # the residual holds it
    assert kept["decision"] == {
        "effect": "hysteresis", "kept": True, "against_round": 0,
        "held_out_loss": {"before": 0.5, "after": 0.3},
        "fold_losses": {"before": [0.5, 0.5], "after": [0.3, 0.3]},
        "reason": "the refit's pooled held-out loss over 2 folds 0.3 beats the standing "
                  "model's 0.5; it is lower on 2 of 2 folds"}
    assert dropped["decision"]["kept"] is False
    assert dropped["decision"]["against_round"] == 1  # the model that stands, not round 0
    assert dropped["decision"]["held_out_loss"] == {"before": 0.3, "after": 0.35}
    assert set(start["figures"]) == {"diagnostics", "residual", "scores", "added"}
    assert start["figures"]["added"] == "figures/round_0_added_hysteresis.png"
    sections = round_sections(folder.report_md.read_text())
    added = subsection(sections[0], "Effect added")
    assert "- added: hysteresis" in added and "p " in added
    assert "hysteresis_0 " in added  # each operator's excitation ratio
    assert start["added_excitation"]["reading"] in added
    assert "**Dropped**: the refit's pooled held-out loss over 2 folds 0.35 does not beat" \
        in sections[2]
    # the JSON stays what it was: only keys were added
    for entry in report["rounds"]:
        assert {"effects", "tests", "mean_rmse_free_run", "diagnosis", "added",
                "held_out"} <= set(entry)
    assert json.loads(folder.report_json.read_text()) == report


def test_the_check_fails_when_the_page_disagrees_with_the_json(notebook, tmp_path):
    shutil.copytree(notebook, tmp_path, dirs_exist_ok=True)
    folder = LoopFolder(tmp_path)
    page = folder.report_md.read_text()
    assert "| sine | 1 | 0.8 |" in page
    folder.report_md.write_text(page.replace("| sine | 1 | 0.8 |", "| sine | 1 | 0.7 |"))
    with pytest.raises(AssertionError):
        check_loop_notebook(tmp_path)
    folder.report_md.write_text(page)
    (tmp_path / "figures" / "round_0_scores.png").write_bytes(b"not a png")
    with pytest.raises(AssertionError):
        check_loop_notebook(tmp_path)


def test_a_dropped_refit_records_every_folds_loss_and_no_test_scores(notebook):
    report = json.loads((notebook / "loop_report.json").read_text())
    dropped = report["rounds"][2]
    assert dropped["decision"]["fold_losses"] == {"before": [0.3, 0.3], "after": [0.35, 0.35]}
    section = round_sections((notebook / "loop_report.md").read_text())[2]
    assert "- per fold (before -> after): 0.3 -> 0.35, 0.3 -> 0.35" in section
    assert "no test scores" in subsection(section, "Before / after on the tests")


def test_older_reports_without_the_new_keys_still_render():
    """A loop_report.json written before decisions and figures were recorded renders."""
    rate = {"effect": "rate", "score": 0.01, "p_value": 0.5, "significant": False,
            "evidence": "rate", "predictable": True, "tested": True}
    old = {"units": {"y": "um"}, "data": "toy", "model": "linear",
           "start": {"model": "linear", "effects": []}, "result": 0,
           "roles": {"train": ["t"], "validation": [], "diagnosis": [], "test": ["sine"]},
           "rounds": [{"effects": [], **scores(1.0), "diagnosis": [rate], "added": None,
                       "held_out": held(0.5), "note": "no significant missing effect"}]}
    page = loop_markdown(old)
    assert "## Round 0: the start, effects []" in page
    assert "- added: None (no significant missing effect)" in page
    assert "- rate: score 0.010, p 0.5" in page


def test_a_loop_that_stops_says_which_effects_more_held_out_data_would_decide():
    def score(effect: str, value: float, p: float, votes: tuple[int, int, int] | None,
              significant: bool = False) -> dict:
        entry = {"effect": effect, "score": value, "p_value": p, "significant": significant,
                 "evidence": effect, "predictable": True, "tested": True}
        if votes:
            entry["blocks"] = dict(zip(("held_out", "gaining", "losing"), votes, strict=True))
        return entry

    diagnosis = [score("nonlinear_feedback", 0.2, 0.055, (11, 6, 1)),
                 score("saturation", 0.19, 0.03, (11, 8, 2)),  # judged lacking excitation
                 score("rate", 0.01, 0.5, (11, 3, 5)),  # below loop.min_score
                 score("creep", 0.3, 0.2, None)]  # a report older than block votes
    report = {"units": {"y": "V"}, "data": "toy", "model": "linear", "result": 0,
              "start": {"model": "linear", "effects": []},
              "settings": {"min_score": 0.05, "alpha": 0.01, "significance": "pooled",
                           "min_refit_gain": 0.0},
              "roles": {"train": ["t"], "validation": ["v"], "diagnosis": ["v"], "test": ["s"]},
              "rounds": [{"effects": [], **scores(1.0), "diagnosis": diagnosis, "added": None,
                          "held_out": held(0.5), "note": "no significant missing effect",
                          "under_excited": [{"effect": "saturation", "advice": "record more"}]}]}
    section = round_sections(loop_markdown(report))[0]
    assert "- nonlinear_feedback: score 0.200, p 0.055 (6 of 11 blocks gain, 1 lose)" in section
    undecided = subsection(section, "Undecided: more held-out data would decide")
    assert ("- nonlinear_feedback: score 0.200 at p 0.055 (loop.alpha=0.01): of 11 held-out "
            "blocks 6 gain, 1 lose and 4 carry no evidence; 7 blocks give at best p = 0.0078"
            ) in undecided
    assert all(name not in undecided for name in ("saturation", "rate", "creep"))
    per_recording = {**report, "settings": {**report["settings"],
                                            "significance": "per_recording"}}
    assert "give at best" not in loop_markdown(per_recording)  # the floor is the pooled test's
    added = dict(report["rounds"][0], added="nonlinear_feedback")
    assert "Undecided" not in loop_markdown({**report, "rounds": [added]})  # it goes on


def test_a_start_that_diverges_has_no_result():
    page = loop_markdown({
        "units": {"y": "um"}, "data": "toy", "model": "ffnn", "result": None,
        "start": {"model": "ffnn", "effects": []},
        "roles": {"train": ["t"], "validation": ["v"], "diagnosis": ["v"], "test": ["sine"]},
        "rounds": [{"effects": [], **scores(1.0), "diagnosis": [], "added": None,
                    "held_out": {**held(float("inf")), "diverging": ["sine"]},
                    "note": "the start model's free run diverges on ['sine']"}]})
    assert "- the start model's free run diverges on ['sine']" in page
    assert "  - free run diverges on sine" in page
    assert "**No result**" in page and "### Effect added" not in page
