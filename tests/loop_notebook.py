"""Checks that a loop folder's ``loop_report.md`` is the notebook page ``loop_report.json``
describes: a section per round, its figures on disk as PNGs, the before/after table and the
validation decision as the JSON has them."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest
from matplotlib.image import imread

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def round_sections(markdown: str) -> dict[int, str]:
    """The ``## Round n`` sections of the page, by round."""
    sections = re.split(r"^## ", markdown, flags=re.MULTILINE)[1:]
    return {int(m.group(1)): s for s in sections if (m := re.match(r"Round (\d+)", s))}


def subsection(section: str, title: str) -> str:
    """The text under ``### title`` up to the next ``###`` heading."""
    parts = re.split(r"^### ", section, flags=re.MULTILINE)
    return next(p for p in parts if p.startswith(title))


def table_rows(text: str) -> dict[str, list[str]]:
    """The body rows of the markdown table in ``text``: first cell -> the others."""
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| ") and not cells[0].startswith("---") and cells[0] != "test":
            rows[cells[0]] = cells[1:]
    return rows


def assert_png(path: Path) -> None:
    assert path.is_file(), f"{path} is missing"
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    image = imread(path)
    assert image.ndim == 3 and min(image.shape[:2]) > 100


def _assert_row(row: list[str], before: float, after: float) -> None:
    assert float(row[0]) == pytest.approx(before, rel=5e-4)
    assert float(row[1]) == pytest.approx(after, rel=5e-4)
    assert float(row[2].split()[0]) == pytest.approx(100 * (after - before) / before, abs=0.051)


def check_loop_notebook(run: Path) -> dict[str, Any]:
    """Assert that ``run``'s report page matches its JSON; returns the JSON."""
    report = json.loads((run / "loop_report.json").read_text())
    markdown = (run / "loop_report.md").read_text()
    sections = round_sections(markdown)
    assert sorted(sections) == list(range(len(report["rounds"])))
    plots = report.get("plots", True)
    if not plots:  # plots=false: no figure drawn, none linked
        assert not list(run.rglob("*.png")) and "![" not in markdown
    for number, entry in enumerate(report["rounds"]):
        section = sections[number]
        figures = entry.get("figures", {})
        if entry["diagnosis"] and plots:
            assert {"residual", "scores", "diagnostics"} <= set(figures)
            assert "### Residual evidence" in section
        if entry["added"] and plots:
            assert "added" in figures and f"added_{entry['added']}" in figures["added"]
        for advice in entry.get("under_excited", []):  # recordings to add, as the JSON says
            assert advice["advice"] in subsection(section, "Not judged: recordings to add")
        for path in figures.values():
            assert f"]({path})" in section  # linked from its own round's section
            assert_png(run / path)
        decision = entry.get("decision")
        if decision is None:
            assert number == 0
            continue
        assert decision["kept"] is ("rejected" not in entry)
        assert entry["effects"][-1] == decision["effect"]  # the effects the refit declared
        assert f"effects {entry['effects']}" in subsection(section, "Fit")
        title = section.splitlines()[0]
        assert title == f"Round {number}: + {decision['effect']}, " + (
            "kept" if decision["kept"] else "dropped")
        verdict = subsection(section, "Validation decision")
        assert verdict.splitlines()[2].startswith(
            "**Kept**: " if decision["kept"] else "**Dropped**: ")
        assert decision["reason"] in verdict
        held = decision["held_out_loss"]
        if decision["kept"]:
            assert held["after"] < held["before"]
        if not decision["kept"] and "rejected_refit" not in entry:  # the folds dropped it
            assert "no test scores" in subsection(section, "Before / after on the tests")
            continue
        before = report["rounds"][decision["against_round"]] if decision["kept"] else entry
        after = entry if decision["kept"] else entry["rejected_refit"]
        rows = table_rows(subsection(section, "Before / after on the tests"))
        assert set(rows) == {*entry["tests"], "**mean**"}
        for name in entry["tests"]:
            _assert_row(rows[name], before["tests"][name]["rmse_free_run"],
                        after["tests"][name]["rmse_free_run"])
        _assert_row(rows["**mean**"], before["mean_rmse_free_run"], after["mean_rmse_free_run"])
    assert "## Result" in markdown and "## Data roles" in markdown
    return report
