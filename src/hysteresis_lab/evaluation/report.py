"""Write run results: ``metrics.json`` per model and the study's Table 2 (markdown + CSV)."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

MODES = ("one_step", "free_run")
MODE_TITLES = {"one_step": "One-step-ahead prediction", "free_run": "Free-run simulation"}


def metrics_document(
    model_name: str,
    units: Mapping[str, str],
    per_test: Mapping[str, Mapping[str, float]],
    train_seconds: float,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``metrics.json`` document: per-test metrics, their mean and std, training time."""
    keys = sorted({key for metrics in per_test.values() for key in metrics})
    mean = {k: _mean([m[k] for m in per_test.values() if k in m]) for k in keys}
    std = {k: _std([m[k] for m in per_test.values() if k in m]) for k in keys}
    document: dict[str, Any] = {
        "model": model_name,
        "units": dict(units),
        "tests": {name: {k: float(v) for k, v in m.items()} for name, m in per_test.items()},
        "mean": mean,
        "std": std,
        "train_seconds": float(train_seconds),
    }
    document.update(extra or {})
    return document


def write_json(document: Mapping[str, Any], path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document, indent=2, allow_nan=True) + "\n")
    return path


def table2_markdown(
    results: Mapping[str, Mapping[str, Any]], labels: Mapping[str, str] | None = None
) -> str:
    """Table-2-style markdown: R² and RMSE per test signal for every model, one table per mode.

    ``results`` maps model name to its metrics document (see `metrics_document`); ``labels``
    names a model's columns (else its name).
    """
    models = list(results)
    names = {m: (labels or {}).get(m, m) for m in models}
    tests = list(next(iter(results.values()))["tests"])
    unit = next(iter(results.values()))["units"].get("y", "")
    lines: list[str] = []
    for mode in MODES:
        lines += [f"### {MODE_TITLES[mode]}{_start_label(results) if mode == 'free_run' else ''}",
                  ""]
        header = (["test"] + [f"{names[m]} R²" for m in models]
                  + [f"{names[m]} RMSE [{unit}]" for m in models])
        lines.append("| " + " | ".join(header) + " |")
        lines.append("|" + "---|" * len(header))
        rows = [(name, lambda doc, name=name: doc["tests"].get(name, {})) for name in tests]
        rows += [("**mean**", lambda doc: doc["mean"]), ("std", lambda doc: doc["std"])]
        for label, pick in rows:
            cells = [label]
            cells += [_fmt(pick(results[m]).get(f"r2_{mode}"), 6) for m in models]
            cells += [_fmt(pick(results[m]).get(f"rmse_{mode}"), 4) for m in models]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def _start_label(results: Mapping[str, Mapping[str, Any]]) -> str:
    """How the free runs started (``evaluation.initial_state``), for the free-run heading:
    `` (from rest)`` or `` (initial state estimated from the first n_init samples)``; each
    model's own where they differ."""
    label = {"rest": "from rest",
             "estimate": "initial state estimated from the first n_init samples"}
    starts = {m: str(doc.get("initial_state", "rest")) for m, doc in results.items()}
    if len(set(starts.values())) == 1:
        return f" ({label.get(next(iter(starts.values())), next(iter(starts.values())))})"
    return " (" + "; ".join(f"{m}: {label.get(v, v)}" for m, v in starts.items()) + ")"


def write_table2(
    results: Mapping[str, Mapping[str, Any]], directory: Path,
    labels: Mapping[str, str] | None = None,
) -> tuple[Path, Path]:
    """Write ``table2.md`` (columns named by ``labels``, see `table2_markdown`) and the
    long-format ``table2.csv`` (model, test, mode, r2, rmse)."""
    directory.mkdir(parents=True, exist_ok=True)
    md_path = directory / "table2.md"
    md_path.write_text(table2_markdown(results, labels))
    csv_path = directory / "table2.csv"
    with csv_path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["model", "test", "mode", "r2", "rmse", "unit"])
        for model, doc in results.items():
            unit = doc["units"].get("y", "")
            rows = [*doc["tests"].items(), ("mean", doc["mean"]), ("std", doc["std"])]
            for test, metrics in rows:
                for mode in MODES:
                    writer.writerow(
                        [
                            model,
                            test,
                            mode,
                            metrics.get(f"r2_{mode}"),
                            metrics.get(f"rmse_{mode}"),
                            unit,
                        ]
                    )
    return md_path, csv_path


def _mean(values: list[float]) -> float:
    return float(sum(values) / len(values)) if values else math.nan


def _std(values: list[float]) -> float:
    if len(values) < 2:
        return 0.0 if values else math.nan
    mean = _mean(values)
    return float(math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1)))


def _fmt(value: float | None, digits: int) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.{digits}g}"
