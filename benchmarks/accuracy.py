"""Accuracy of every architecture on every bundled data set, beside the published references.

    python benchmarks/accuracy.py                                  # everything (hours)
    python benchmarks/accuracy.py --models subnet,greybox --data bouc_wen,fsm
    python benchmarks/accuracy.py --models subnet --data default --resume
    python benchmarks/accuracy.py --render                         # only rewrite the markdown

Each (model, data set) pair is trained with its recommended settings (`RECOMMENDED`, the one
place they live) through the real CLI, ``hysteresis-lab-train ... hydra.run.dir=<root>/<model>_
<data>``; its ``metrics.json`` is scored the way the benchmark scores (FSM per amplitude, the
Bouc–Wen multisine test, ...) in the benchmark's own units. Every measured cell is merged into
``docs/results/accuracy.json`` (a partial run replaces only its own cells) and
``docs/results/accuracy.md`` is regenerated from it, with the references the loaders hold
(``metadata["reference"]``).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import logging
import math
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from functools import cache
from pathlib import Path
from typing import Any

log = logging.getLogger("accuracy")

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "docs" / "results"

MODELS = ("subnet", "greybox", "ffnn", "lstm", "cnn", "svm")
DATASETS = ("default", "fsm", "p885", "bouc_wen", "emps", "cascaded_tanks")
#: data config name -> bundled loader name (`hysteresis_lab.data.benchmarks.LOADERS`)
LOADER = {"fsm": "fsm_piezo_mirror", "p885": "piezo_p885", "bouc_wen": "bouc_wen",
          "emps": "emps", "cascaded_tanks": "cascaded_tanks"}
TITLES = {
    "default": "Simulated positioner (data=default), twelve ±100 V test sines (no published "
               "reference)",
    "fsm": "FSM piezo mirror (data=fsm), 3x3 MIMO, official test set",
    "p885": "PI P-885 piezo stack (data=p885), last 30 % of the record",
    "bouc_wen": "Bouc–Wen benchmark (data=bouc_wen), in mm (1e-5 m = 0.01 mm)",
    "emps": "EMPS (data=emps), pulses test record",
    "cascaded_tanks": "Cascaded tanks (data=cascaded_tanks)",
}
#: the study's NARX networks: their defaults plus free-run fine-tuning after the one-step stage
NETWORK_DEFAULTS = ["model.objective=simulation", "model.horizon=200",
                    "model.simulation_epochs=5"]
#: recommended settings, data set -> model -> Hydra overrides (one place; see docs/results)
RECOMMENDED: dict[str, dict[str, list[str]]] = {
    "default": {
        "subnet": ["model.effects=[hysteresis]", "data.window.na=20", "data.window.nb=20",
                   "model.horizon=200", "model.lr=1e-4", "data.batch_size=32",
                   "trainer.max_epochs=40"],
        "greybox": ["model.effects=[creep]"],
    },
    "fsm": {
        "subnet": ["model.nx=28", "data.window.na=50", "data.window.nb=50",
                   "model.horizon=300", "model.lr=1e-3", "data.batch_size=64",
                   "trainer.max_epochs=40"],
    },
    "p885": {
        "subnet": ["model.horizon=200", "model.lr=1e-3", "data.batch_size=16",
                   "trainer.max_epochs=300"],
        "greybox": [],
    },
    "bouc_wen": {
        "subnet": ["model.horizon=100", "model.lr=3e-3", "data.batch_size=32",
                   "trainer.max_epochs=250"],
        "greybox": [],
    },
    "emps": {
        "subnet": ["model.horizon=300", "model.lr=1e-3", "data.batch_size=16",
                   "trainer.max_epochs=100"],
        "greybox": [],
    },
    "cascaded_tanks": {
        "subnet": ["model.nx=3", "model.neurons=16", "model.hidden_layers=1",
                   "model.encoder_neurons=16", "model.encoder_layers=1",
                   "model.weight_decay=1e-3", "model.horizon=300", "model.lr=3e-3",
                   "data.batch_size=2", "trainer.max_epochs=600"],
        "greybox": [],
    },
}
#: pairs a model cannot take, with the reason (shown in the table)
UNSUPPORTED = {("greybox", "fsm"): "SISO only (FSM is 3x3 MIMO)"}
#: added to every run: no TensorBoard, no progress bar
COMMON = ["logger=none", "trainer.enable_progress_bar=false"]


def recommended(model: str, data: str) -> list[str]:
    """The Hydra overrides a (model, data set) pair trains with."""
    if model in RECOMMENDED.get(data, {}):
        return list(RECOMMENDED[data][model])
    return list(NETWORK_DEFAULTS) if model in ("ffnn", "lstm", "cnn") else []


# ---------------------------------------------------------------------------- references
@cache
def reference_info(data: str) -> dict[str, Any]:
    """``{"reference": {name: value or {amplitude: value}}, "units", "metric", "test"}`` of a
    bundled benchmark, read from its loader's metadata (empty for the simulator)."""
    if data not in LOADER:
        return {"reference": {}, "units": None, "metric": None, "test": None}
    from hysteresis_lab.data.benchmarks import load_benchmark

    meta = load_benchmark(LOADER[data]).metadata
    return {"reference": meta.get("reference", {}), "units": meta.get("reference_units"),
            "metric": meta.get("reference_metric"), "test": meta.get("reference_test")}


def _reference_value(value: Any, label: str) -> float | None:
    """A reference for one scored row: per-amplitude dicts (FSM) by the row's amplitude."""
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


def score(data: str, metrics: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The benchmark's scored rows ``{"test", "free_run", "one_step"}`` from a metrics.json,
    in its own units (metrics.json's units; the loaders already convert to the reference's)."""
    tests: Mapping[str, Mapping[str, float]] = metrics["tests"]
    if data == "fsm":
        rows = []
        for amp in (100, 200, 300):
            picked = [m for name, m in tests.items() if name.startswith(f"{amp}mV_")]
            if picked:
                rows.append({"test": f"{amp} mV",
                             "free_run": _mean([m["rmse_free_run"] for m in picked]),
                             "one_step": _mean([m["rmse_one_step"] for m in picked])})
        return rows
    if data == "default":
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
        "rows": score(data, metrics),
        "train_seconds": float(metrics.get("train_seconds", math.nan)),
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


def _fmt(value: float | None) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.4g}"


def _duration(seconds: float | None) -> str:
    if seconds is None or math.isnan(seconds):
        return "–"
    return f"{seconds / 60:.1f} min" if seconds >= 90 else f"{seconds:.0f} s"


def render_markdown(
    results: Mapping[str, Any], references: Any = reference_info
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
    for data in DATASETS:
        mine = [cells[k] for k in sorted(cells) if cells[k]["data"] == data]
        mine.sort(key=lambda c: MODELS.index(c["model"]) if c["model"] in MODELS else 99)
        if not mine:
            continue
        info = references(data)
        units = info["units"] or mine[0].get("units", "")
        names = list(info["reference"])
        lines += [f"## {TITLES.get(data, data)}", ""]
        if info["metric"]:
            lines += [f"Reference metric: {info['metric']}.", ""]
        header = ["model", "test", f"free run [{units}]", f"one step [{units}]"]
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
                refs = [_fmt(_reference_value(info["reference"][n], row["test"]))
                        if applies else "–" for n in names]
                first = i == 0
                lines.append("| " + " | ".join([
                    cell["model"] if first else "", row["test"], _fmt(row["free_run"]),
                    _fmt(row["one_step"]), *refs,
                    _duration(cell.get("train_seconds")) if first else "",
                    f"`{cell.get('commit', '?')}` {cell.get('date', '')}" if first else "",
                ]) + " |")
        lines.append("")
        for cell in mine:
            if not cell.get("skipped"):
                settings = " ".join([f"model={cell['model']}", f"data={data}", *cell["overrides"]])
                lines.append(f"- {cell['model']}: `{settings}`")
        lines.append("")
    return "\n".join(lines)


def write_results(
    cells: Sequence[Mapping[str, Any]],
    run: Mapping[str, Any],
    directory: Path = RESULTS,
    references: Any = reference_info,
) -> tuple[Path, Path]:
    """Merge ``cells`` into ``directory``/accuracy.json and regenerate accuracy.md from it."""
    directory.mkdir(parents=True, exist_ok=True)
    json_path, md_path = directory / "accuracy.json", directory / "accuracy.md"
    results = merge_cells(load_results(json_path), cells, run)
    json_path.write_text(json.dumps(results, indent=2, allow_nan=True) + "\n")
    md_path.write_text(render_markdown(results, references))
    return json_path, md_path


# ---------------------------------------------------------------------------- training runs
def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def commit() -> str:
    """Short HEAD, ``+dirty`` when tracked files outside docs/results differ from it."""
    status = _git("status", "--porcelain", "--untracked-files=no")
    dirty = [line for line in status.splitlines() if "docs/results/" not in line]
    return _git("rev-parse", "--short", "HEAD") + ("+dirty" if dirty else "")


def train_command() -> list[str]:
    """The CLI of this interpreter's environment (else the one on PATH)."""
    beside = Path(sys.executable).parent / "hysteresis-lab-train"
    found = str(beside) if beside.is_file() else shutil.which("hysteresis-lab-train")
    if not found:
        raise SystemExit("hysteresis-lab-train not found: install the package (pip install -e .)")
    return [found]


def run_pair(
    model: str, data: str, root: Path, resume: bool, stamp: Mapping[str, str]
) -> dict[str, Any] | None:
    """Train (or with ``resume`` reuse) one pair; its cell, or None when the run failed."""
    if (model, data) in UNSUPPORTED:
        return {"model": model, "data": data, "skipped": UNSUPPORTED[(model, data)], **stamp}
    overrides = recommended(model, data)
    run_dir = root / f"{model}_{data}"
    metrics_path, settings_path = run_dir / "metrics.json", run_dir / "accuracy_settings.json"
    if resume and metrics_path.is_file():
        saved = json.loads(settings_path.read_text()) if settings_path.is_file() else {}
        if saved.get("overrides") == overrides:
            log.info("%s on %s: reusing %s", model, data, metrics_path)
            return cell_from_metrics(model, data, metrics_path, overrides,
                                     wall_seconds=saved.get("wall_seconds"),
                                     commit=saved.get("commit", stamp["commit"]),
                                     date=saved.get("date", stamp["date"]))
        log.info("%s on %s: %s was made with other settings: training again",
                 model, data, metrics_path)
    if run_dir.is_dir():  # a fresh run: no checkpoint or metrics of an older one stay
        shutil.rmtree(run_dir)
    run_dir.mkdir(parents=True)
    command = [*train_command(), f"model={model}", f"data={data}", *overrides, *COMMON,
               f"hydra.run.dir={run_dir}"]
    log.info("%s on %s: %s (log: %s)", model, data, " ".join(command[1:]),
             run_dir / "accuracy_train.log")
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1"),
           "MKL_NUM_THREADS": os.environ.get("MKL_NUM_THREADS", "1")}
    start = time.perf_counter()
    with (run_dir / "accuracy_train.log").open("w") as handle:
        proc = subprocess.run(command, cwd=REPO, env=env, stdout=handle,
                              stderr=subprocess.STDOUT, check=False)
    wall = time.perf_counter() - start
    if proc.returncode != 0 or not metrics_path.is_file():
        log.error("%s on %s failed (exit %d): see %s", model, data, proc.returncode,
                  run_dir / "accuracy_train.log")
        return None
    settings_path.write_text(json.dumps({"overrides": overrides, "wall_seconds": wall,
                                         **stamp}, indent=2) + "\n")
    cell = cell_from_metrics(model, data, metrics_path, overrides, wall_seconds=wall, **stamp)
    log.info("%s on %s: free run %s, trained in %s", model, data,
             ", ".join(f"{r['test']} {_fmt(r['free_run'])} {cell['units']}"
                       for r in cell["rows"]), _duration(cell["train_seconds"]))
    return cell


def _choices(text: str, allowed: Sequence[str], what: str) -> list[str]:
    picked = [item.strip() for item in text.split(",") if item.strip()]
    bad = [item for item in picked if item not in allowed]
    if bad:
        raise SystemExit(f"unknown {what} {bad}: choose from {','.join(allowed)}")
    return picked


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--models", default=",".join(MODELS), help="comma-separated models")
    parser.add_argument("--data", default=",".join(DATASETS), help="comma-separated data sets")
    parser.add_argument("--root", type=Path, default=REPO / "outputs" / "accuracy",
                        help="run folders <root>/<model>_<data>")
    parser.add_argument("--results", type=Path, default=RESULTS,
                        help="folder of accuracy.json / accuracy.md")
    parser.add_argument("--resume", action="store_true",
                        help="reuse runs whose metrics.json exists (same settings)")
    parser.add_argument("--render", action="store_true",
                        help="only regenerate accuracy.md from accuracy.json")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    models = _choices(args.models, MODELS, "models")
    datasets = _choices(args.data, DATASETS, "data sets")
    stamp = {"commit": commit(), "date": dt.date.today().isoformat()}
    shown = ["python", "benchmarks/accuracy.py", *(argv if argv is not None else sys.argv[1:])]
    run = {"command": " ".join(shown), **stamp,
           "host_note": f"{os.cpu_count()} CPU cores, torch threads "
                        f"{os.environ.get('OMP_NUM_THREADS', '1')} per training"}
    if args.render:
        results = load_results(args.results / "accuracy.json")
        (args.results / "accuracy.md").write_text(render_markdown(results))
        return 0
    cells, failed = [], []
    for data in datasets:
        for model in models:
            cell = run_pair(model, data, args.root, args.resume, stamp)
            if cell is None:
                failed.append(f"{model}/{data}")
                continue
            cells.append(cell)
            write_results([cell], run, args.results)  # after each pair: a stop keeps the rest
    json_path, md_path = write_results(cells, run, args.results)
    log.info("wrote %s and %s", md_path, json_path)
    if failed:
        log.error("failed: %s", ", ".join(failed))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
