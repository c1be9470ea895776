"""The accuracy table of ``docs/results/accuracy.md``: scoring a run's ``metrics.json`` the way
each data set scores, merging measured cells into ``accuracy.json`` and rendering the markdown
page beside the published references (``benchmarks/accuracy.py`` trains the runs). The data
sets are the simulator and every registered one (`hysteresis_lab.data.registry`)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from functools import cache
from pathlib import Path
from typing import Any

from hysteresis_lab.data.registry import Dataset, load_dataset, registered_datasets

MODELS = ("subnet", "augmented", "greybox", "linear", "ffnn", "lstm", "cnn", "svm")
#: rows that are no registered model: the row's label -> what it is
ROW_NOTES = {"augmented": "SUBNET augmenting the data set's physical model: its free run is an "
                          "extra input (`model.baseline=<that row's run folder>`)"}
#: the simulated positioner (``data=default``): the table's first data set, no registered one
SIMULATED = "default"
SIMULATED_TITLE = ("Simulated positioner (data=default), twelve ±100 V test sines (no published "
                   "reference)")
#: a data set's references: ``{"reference", "units", "metric", "test"}`` (see `reference_info`)
References = Callable[[str], Mapping[str, Any]]


# ---------------------------------------------------------------------------- data sets
def registered() -> dict[str, tuple[str, Dataset]]:
    """The registered data sets by their data config name: (registry name, `Dataset`)."""
    return {dataset.config_name(name): (name, dataset)
            for name, dataset in registered_datasets().items()}


def table_datasets() -> list[str]:
    """The table's data sets, as ``data=`` names: the simulator, then every registered one."""
    return [SIMULATED, *registered()]


def title(data: str) -> str:
    """The heading of a data set's section."""
    if data == SIMULATED:
        return SIMULATED_TITLE
    found = registered().get(data)
    return found[1].heading(found[0]) if found else data


@cache
def reference_info(data: str) -> dict[str, Any]:
    """``{"reference": {name: value or {amplitude: value}}, "units", "metric", "test"}`` of a
    registered data set, read from its loader's metadata (empty for the simulator)."""
    found = registered().get(data)
    if found is None:
        return {"reference": {}, "units": None, "metric": None, "test": None}
    meta = load_dataset(found[0]).metadata
    return {"reference": meta.get("reference", {}), "units": meta.get("reference_units"),
            "metric": meta.get("reference_metric"), "test": meta.get("reference_test")}


# ---------------------------------------------------------------------------- references


def _reference_value(value: Any, label: str) -> float | None:
    """A reference for one scored row: a per-group dict (the FSM's per amplitude) by the first
    word of the row's label."""
    if isinstance(value, Mapping):
        amp = label.split()[0]
        for key, v in value.items():
            if str(key) == amp:
                return float(v)
        return None
    return float(value)


# ---------------------------------------------------------------------------- scoring
def _mean(values: Sequence[float]) -> float:
    return float(sum(values) / len(values)) if values else math.nan


def scored_rows(data: str, metrics: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The benchmark's scored rows ``{"test", "free_run", "one_step"}`` from a metrics.json,
    in its own units (metrics.json's units; the loaders already convert to the reference's)."""
    tests: Mapping[str, Mapping[str, float]] = metrics["tests"]
    found = registered().get(data)
    groups = found[1].test_groups if found else {}
    if groups:
        rows = []
        for label, prefix in groups.items():
            picked = [m for name, m in tests.items() if name.startswith(prefix)]
            if picked:
                rows.append({"test": label,
                             "free_run": _mean([m["rmse_free_run"] for m in picked]),
                             "one_step": _mean([m["rmse_one_step"] for m in picked])})
        return rows
    if data == SIMULATED:
        worst = max(tests, key=lambda name: tests[name]["rmse_free_run"])
        return [
            {"test": f"mean of {len(tests)} sines",
             "free_run": _mean([m["rmse_free_run"] for m in tests.values()]),
             "one_step": _mean([m["rmse_one_step"] for m in tests.values()])},
            {"test": f"worst sine ({worst})", "free_run": tests[worst]["rmse_free_run"],
             "one_step": tests[worst]["rmse_one_step"]},
        ]
    return [{"test": name, "free_run": m["rmse_free_run"], "one_step": m["rmse_one_step"]}
            for name, m in tests.items()]


def cell_from_metrics(
    model: str, data: str, metrics_path: Path, overrides: Sequence[str], **extra: Any
) -> dict[str, Any]:
    """One measured cell of the table from a run's metrics.json."""
    metrics = json.loads(metrics_path.read_text())
    return {
        "model": model,
        "data": data,
        "units": metrics.get("units", {}).get("y", ""),
        "rows": scored_rows(data, metrics),
        "train_seconds": float(metrics.get("train_seconds", math.nan)),
        "initial_state": str(metrics.get("initial_state", "rest")),
        "overrides": list(overrides),
        "run_dir": str(metrics_path.parent),
        **extra,
    }


# ---------------------------------------------------------------------------- results store
def load_results(path: Path) -> dict[str, Any]:
    """The stored cells (``{"cells": {"<data>/<model>": cell}, "last_run": ...}``)."""
    if path.is_file():
        return json.loads(path.read_text())
    return {"cells": {}, "last_run": None}


def merge_cells(
    results: dict[str, Any], cells: Sequence[Mapping[str, Any]], run: Mapping[str, Any]
) -> dict[str, Any]:
    """``results`` with ``cells`` replacing those of the same (data, model); others kept."""
    merged = {"cells": dict(results.get("cells", {})), "last_run": dict(run)}
    for cell in cells:
        merged["cells"][f"{cell['data']}/{cell['model']}"] = dict(cell)
    return merged


def format_value(value: float | None) -> str:
    """Four significant digits; ``–`` for a missing value."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.4g}"


def format_duration(seconds: float | None) -> str:
    """Seconds below 90 s, else minutes; ``–`` when unknown."""
    if seconds is None or math.isnan(seconds):
        return "–"
    return f"{seconds / 60:.1f} min" if seconds >= 90 else f"{seconds:.0f} s"


def render_markdown(
    results: Mapping[str, Any], references: References = reference_info
) -> str:
    """The accuracy page from the stored cells; ``references(data)`` as `reference_info`."""
    run = results.get("last_run") or {}
    lines = [
        "# Accuracy on the bundled data sets",
        "",
        f"Generated by `{run.get('command', '?')}` at commit `{run.get('commit', '?')}` on "
        f"{run.get('date', '?')} ({run.get('host_note', '')}). Rows measured by earlier runs "
        "keep their own commit and date (column *measured*). Free-run (simulation) and "
        "one-step RMSE in the benchmark's units on its official test split and scoring window "
        "(`n_init`); training time as metrics.json's `train_seconds`. Settings per row below "
        "each table (`benchmarks/accuracy.py`, `RECOMMENDED`).",
        "",
    ]
    cells = results.get("cells", {})
    shown = table_datasets()
    stored = sorted({c["data"] for c in cells.values()} - set(shown))
    for data in [*shown, *stored]:
        mine = [cells[k] for k in sorted(cells) if cells[k]["data"] == data]
        mine.sort(key=lambda c: MODELS.index(c["model"]) if c["model"] in MODELS else 99)
        if not mine:
            continue
        info = references(data)
        units = info["units"] or mine[0].get("units", "")
        names = list(info["reference"])
        lines += [f"## {title(data)}", ""]
        if info["metric"]:
            lines += [f"Reference metric: {info['metric']}.", ""]
        header = ["model", "test", f"free run{_start_heading(mine)} [{units}]",
                  f"one step [{units}]"]
        header += [f"{name} [{units}]" for name in names] + ["train time", "measured"]
        lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for cell in mine:
            if cell.get("skipped"):
                blanks = ["–"] * (len(header) - 2)
                lines.append(f"| {cell['model']} | {cell['skipped']} | " + " | ".join(blanks)
                             + " |")
                continue
            for i, row in enumerate(cell["rows"]):
                applies = info["test"] is None or info["test"] == row["test"]
                refs = [format_value(_reference_value(info["reference"][n], row["test"]))
                        if applies else "–" for n in names]
                first = i == 0
                lines.append("| " + " | ".join([
                    _row_label(cell, mine) if first else "", row["test"],
                    format_value(row["free_run"]),
                    format_value(row["one_step"]), *refs,
                    format_duration(cell.get("train_seconds")) if first else "",
                    f"`{cell.get('commit', '?')}` {cell.get('date', '')}" if first else "",
                ]) + " |")
        lines.append("")
        for cell in mine:
            if not cell.get("skipped"):
                lines.append(f"- {cell['model']}: `{_settings_line(cell, data)}`")
        notes = [f"- *{label}*: {ROW_NOTES[label]}." for label in ROW_NOTES
                 if any(c["model"] == label for c in mine)]
        lines += [*notes, ""]
    return "\n".join(lines)


#: how a cell's free runs started (metrics.json's ``initial_state``), as the table says it
START_LABELS = {"rest": "from rest", "estimate": "from an estimated start"}


def _starts(cells: Sequence[Mapping[str, Any]]) -> set[str]:
    """The free-run starts of a section's measured cells (cells from before the mode was
    recorded started from rest)."""
    return {str(c.get("initial_state", "rest")) for c in cells if not c.get("skipped")}


def _start_heading(cells: Sequence[Mapping[str, Any]]) -> str:
    """`` from rest`` (or the one start every cell shares) for the free-run column; empty
    where the cells differ (each row names its own, `_row_label`)."""
    starts = _starts(cells)
    return f" {START_LABELS.get(next(iter(starts)), next(iter(starts)))}" \
        if len(starts) == 1 else ""


def _row_label(cell: Mapping[str, Any], cells: Sequence[Mapping[str, Any]]) -> str:
    """The model's name, with its free-run start where the section's cells differ."""
    if len(_starts(cells)) <= 1:
        return str(cell["model"])
    start = str(cell.get("initial_state", "rest"))
    return f"{cell['model']} ({START_LABELS.get(start, start)})"


def _settings_line(cell: Mapping[str, Any], data: str) -> str:
    """The CLI settings of a row: ``model=<label>`` unless its overrides name the model."""
    overrides = list(cell["overrides"])
    named = [o for o in overrides if o.startswith("model=")]
    rest = [o for o in overrides if not o.startswith("model=")]
    return " ".join([*(named or [f"model={cell['model']}"]), f"data={data}", *rest])


def write_results(
    cells: Sequence[Mapping[str, Any]],
    run: Mapping[str, Any],
    directory: Path,
    references: References = reference_info,
) -> tuple[Path, Path]:
    """Merge ``cells`` into ``directory``/accuracy.json and regenerate accuracy.md from it."""
    directory.mkdir(parents=True, exist_ok=True)
    json_path, md_path = directory / "accuracy.json", directory / "accuracy.md"
    results = merge_cells(load_results(json_path), cells, run)
    json_path.write_text(json.dumps(results, indent=2, allow_nan=True) + "\n")
    md_path.write_text(render_markdown(results, references))
    return json_path, md_path
