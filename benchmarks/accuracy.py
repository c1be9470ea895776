"""Accuracy of every architecture on every registered data set, beside the published references.

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
(``metadata["reference"]``). The scoring and the page live in
`hysteresis_lab.evaluation.accuracy_table`; this script trains the runs.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import logging
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hysteresis_lab.evaluation.accuracy_table import (
    MODELS,
    cell_from_metrics,
    format_duration,
    format_value,
    load_results,
    render_markdown,
    table_datasets,
    write_results,
)
from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.models.registry import available_models
from hysteresis_lab.run_folder import RunFolder

log = logging.getLogger("accuracy")

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "docs" / "results"

#: the study's NARX networks: their defaults plus free-run fine-tuning after the one-step stage
NETWORK_DEFAULTS = ["training.objective=simulation", "training.horizon=200",
                    "training.simulation_epochs=5"]
#: the "augmented" row: SUBNET with the free run of the named row's model as an extra input
#: (`model.baseline`); data set -> that row (trained first when its run folder has no model)
AUGMENTED = "augmented"
AUGMENTED_BASELINE: dict[str, str] = {"default": "greybox", "fsm": "greybox", "p885": "greybox",
                                       "emps": "linear", "cascaded_tanks": "linear"}
#: recommended settings, data set -> model -> Hydra overrides (one place; see docs/results);
#: ``<root>`` stands for the run folders' root (``--root``). A data set or model not named
#: here (a plugin's) trains with its defaults
RECOMMENDED: dict[str, dict[str, list[str]]] = {
    "default": {
        "subnet": ["model.effects=[hysteresis]", "data.window.na=20", "data.window.nb=20",
                   "training.horizon=200", "training.lr=1e-4", "data.batch_size=32",
                   "trainer.max_epochs=40"],
        "greybox": ["model.effects=[asymmetry,creep]"],
        AUGMENTED: ["model=subnet", "model.baseline=<root>/greybox_default", "data.window.na=20",
                    "data.window.nb=20", "training.horizon=200", "training.lr=1e-4",
                    "data.batch_size=32", "trainer.max_epochs=40"],
    },
    "fsm": {
        "subnet": ["model.nx=28", "data.window.na=50", "data.window.nb=50",
                   "training.horizon=300", "training.lr=1e-3", "data.batch_size=64",
                   "trainer.max_epochs=40"],
        # 28 poles (the published BLA's order) per output and input, a Bouc–Wen cell per input
        "linear": ["model.order=28", "model.effects=[hysteresis]", "trainer.max_epochs=18"],
        # the grey-box's Bouc-Wen cells carry the amplitude dependence. 32 neurons: more fit
        # the training realisations without carrying over to unseen ones, and a held-out
        # training realisation chooses 32 (docs/results/fsm_augmented.md, fsm_holdout.md)
        AUGMENTED: ["model=subnet", "model.baseline=<root>/greybox_fsm", "model.nx=28",
                    "model.neurons=32", "data.window.na=50", "data.window.nb=50",
                    "training.horizon=300", "training.lr=3e-3", "data.batch_size=64",
                    "trainer.max_epochs=200"],
        # 14 shared modes (the published BLA's 28 states), a Bouc–Wen cell per input
        "greybox": ["model.n_modes=14", "training.lr=5e-4", "model.recording_repeats=2",
                    "trainer.max_epochs=10"],
        # the study's recurrent and convolutional networks train far slower than the FFNN on
        # these long records: each stage (one-step, then free-run) stops after 7 min, so a
        # pair stays within a 15-min budget
        "lstm": [*NETWORK_DEFAULTS, "+trainer.max_time=00:00:07:00"],
        "cnn": [*NETWORK_DEFAULTS, "+trainer.max_time=00:00:07:00"],
    },
    "p885": {
        "subnet": ["training.horizon=200", "training.lr=1e-3", "data.batch_size=16",
                   "trainer.max_epochs=300"],
        AUGMENTED: ["model=subnet", "model.baseline=<root>/greybox_p885", "training.horizon=200",
                    "training.lr=1e-3", "data.batch_size=16", "trainer.max_epochs=300"],
        "greybox": [],
    },
    "bouc_wen": {
        "subnet": ["training.horizon=100", "training.lr=3e-3", "data.batch_size=32",
                   "trainer.max_epochs=250"],
        "greybox": [],
    },
    "emps": {
        "subnet": ["training.horizon=300", "training.lr=1e-3", "data.batch_size=16",
                   "trainer.max_epochs=100"],
        "greybox": [],
        # a force moves the cart: its position integrates (stable dynamics alone drift off)
        "linear": ["model.integrator=true"],
        AUGMENTED: ["model=subnet", "model.baseline=<root>/linear_emps", "training.horizon=300",
                    "training.lr=1e-3", "data.batch_size=16", "trainer.max_epochs=100"],
    },
    "cascaded_tanks": {
        "subnet": ["model.nx=3", "model.neurons=16", "model.hidden_layers=1",
                   "model.encoder_neurons=16", "model.encoder_layers=1",
                   "training.weight_decay=1e-3", "training.horizon=300", "training.lr=3e-3",
                   "data.batch_size=2", "trainer.max_epochs=600"],
        "greybox": [],
        # the tanks' physics on the linear model: the lower tank's outflow law on its own
        # level (the output stage) and the upper tank's rim (overflow on the output stage)
        "linear": ["model.effects=[nonlinear_feedback,overflow]", "model.feedback_on=output_stage",
                   "training.lr=0.01", "trainer.max_epochs=300"],
        AUGMENTED: ["model=subnet", "model.baseline=<root>/linear_cascaded_tanks", "model.nx=3",
                    "model.neurons=16", "model.hidden_layers=1", "model.encoder_neurons=16",
                    "model.encoder_layers=1", "training.weight_decay=1e-3", "training.horizon=300",
                    "training.lr=3e-3", "data.batch_size=2", "trainer.max_epochs=600"],
    },
}
#: pairs a model cannot take, with the reason (shown in the table)
UNSUPPORTED: dict[tuple[str, str], str] = {}
#: added to every run: no TensorBoard, no progress bar
COMMON = ["logger=none", "trainer.enable_progress_bar=false"]


def recommended(model: str, data: str) -> list[str]:
    """The Hydra overrides a (model, data set) pair trains with."""
    if model in RECOMMENDED.get(data, {}):
        return list(RECOMMENDED[data][model])
    return list(NETWORK_DEFAULTS) if model in ("ffnn", "lstm", "cnn") else []


# ---------------------------------------------------------------------------- training runs
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
    if model == AUGMENTED and data not in AUGMENTED_BASELINE:
        return {"model": model, "data": data, **stamp,
                "skipped": "no physical model to augment is chosen for this data set"}
    overrides = recommended(model, data)
    run_dir = root / f"{model}_{data}"
    metrics_path = RunFolder(run_dir).metrics
    settings_path = run_dir / "accuracy_settings.json"
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
    model_args = [] if any(o.startswith("model=") for o in overrides) else [f"model={model}"]
    command = [*train_command(), *model_args, f"data={data}",
               *(o.replace("<root>", str(root)) for o in overrides), *COMMON,
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
             ", ".join(f"{r['test']} {format_value(r['free_run'])} {cell['units']}"
                       for r in cell["rows"]), format_duration(cell["train_seconds"]))
    return cell


def _with_baselines(models: Sequence[str], data: str) -> list[str]:
    """``models`` in order, with the augmented row's baseline row just before it (added when
    missing): the augmented row reads that row's run folder."""
    baseline = AUGMENTED_BASELINE.get(data)
    if AUGMENTED not in models or baseline is None:
        return list(models)
    others = [m for m in models if m != baseline]
    at = others.index(AUGMENTED)
    return [*others[:at], baseline, *others[at:]]


def _choices(text: str, allowed: Sequence[str], what: str) -> list[str]:
    picked = [item.strip() for item in text.split(",") if item.strip()]
    bad = [item for item in picked if item not in allowed]
    if bad:
        raise SystemExit(f"unknown {what} {bad}: choose from {','.join(allowed)}")
    return picked


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--models", default=",".join(MODELS), help="comma-separated models")
    datasets = table_datasets()  # the simulator and every registered data set
    parser.add_argument("--data", default=",".join(datasets), help="comma-separated data sets")
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
    # a registered plugin model may be named too (its row follows the built-in ones)
    known = [*MODELS, *(name for name in available_models() if name not in MODELS)]
    models = _choices(args.models, known, "models")
    datasets = _choices(args.data, datasets, "data sets")
    stamp = {"commit": commit_stamp(REPO), "date": dt.date.today().isoformat()}
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
        for model in _with_baselines(models, data):
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
