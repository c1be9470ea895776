"""Time the paper run (``hysteresis-lab-train experiment=paper``) by CPU seconds and wall clock.

    OMP_NUM_THREADS=1 python benchmarks/paper_run.py --out /tmp/paper_runs/new
    OMP_NUM_THREADS=1 python benchmarks/paper_run.py --out /tmp/paper_runs/base --src <tree>/src
    python benchmarks/paper_run.py --page docs/results/paper_run.md \
        --runs base=/tmp/paper_runs/base new=/tmp/paper_runs/new

Runs the experiment in a subprocess (``python -m hysteresis_lab.cli.train experiment=paper``,
any extra ``--override``), samples every descendant process's CPU seconds (user + system)
twice a second, and writes ``paper_run.json`` into ``--out``: the wall clock, the load average
before and after, the CPU seconds of the parent and of each worker process, each model's
``train_seconds``, and Table 2's mean row per model.

On a shared machine the wall clock counts the waits for a core; the estimate for an idle
machine is the parent's own CPU seconds (the data before the workers start, Table 2 and
Figure 1 after they end; each worker trains and scores its models) plus the busiest worker's
CPU seconds: on an idle machine with at least as many cores as workers each worker runs on a
core of its own.
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

log = logging.getLogger("paper_run")

SAMPLE_EVERY_S = 0.5


TICKS = os.sysconf("SC_CLK_TCK")


def _stat(pid: int) -> tuple[int, float] | None:
    """(parent pid, user + system CPU seconds) of a process from ``/proc`` (Linux), or None
    when it has ended."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2 :].split()  # after "pid (name) "
    return int(fields[1]), (int(fields[11]) + int(fields[12])) / TICKS


def descendants_cpu(root: int) -> dict[int, float]:
    """CPU seconds of ``root`` and of every process below it, by pid."""
    stats = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (stat := _stat(int(entry.name))) is not None:
            stats[int(entry.name)] = stat
    found, frontier = {}, [root]
    while frontier:
        pid = frontier.pop()
        if pid in stats:
            found[pid] = stats[pid][1]
            frontier += [child for child, (parent, _) in stats.items() if parent == pid]
    return found


def run_paper(out: Path, src: str | None, overrides: list[str]) -> dict[str, Any]:
    """Run the paper experiment into ``out`` and measure it (see the module's docstring)."""
    out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    if src:  # another tree's package first on the path (a baseline)
        env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    command = [sys.executable, "-m", "hysteresis_lab.cli.train", "experiment=paper",
               f"hydra.run.dir={out / 'run'}", "paper.resume=false", *overrides]
    load_before = os.getloadavg()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.monotonic()
    with open(out / "stdout.log", "w") as stdout:
        child = subprocess.Popen(command, env=env, stdout=stdout, stderr=subprocess.STDOUT)
        seen: dict[int, float] = {}  # the last CPU seconds read of each process
        while child.poll() is None:
            seen.update(descendants_cpu(child.pid))
            time.sleep(SAMPLE_EVERY_S)
    wall = time.monotonic() - started
    load_after = os.getloadavg()
    if child.returncode:
        raise RuntimeError(f"the paper run failed (exit {child.returncode}): see {out}/stdout.log")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    # exact for the whole tree (every process of it was waited for); the workers' own as
    # last sampled, the rest is the parent's (and its short-lived helpers')
    total_cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    seen.pop(child.pid, None)
    workers = sorted((cpu for cpu in seen.values() if cpu > 1.0), reverse=True)
    parent_cpu = total_cpu - sum(workers)
    results = json.loads((out / "run" / "paper_results.json").read_text())
    tree = Path(src).parent if src else Path(__file__).resolve().parents[1]
    summary = {
        "command": " ".join(command),
        "commit": _commit(tree),
        "windows": _windows(out / "run"),
        "epochs": next((int(o.split("=", 1)[1]) for o in overrides
                        if o.startswith("trainer.max_epochs=")), 100),
        "wall_s": wall,
        "load_before": load_before,
        "load_after": load_after,
        "parent_cpu_s": parent_cpu,
        "worker_cpu_s": workers,
        "total_cpu_s": total_cpu,
        "idle_estimate_s": parent_cpu + (workers[0] if workers else 0.0),
        "models": {key: _model_summary(document) for key, document in results.items()},
    }
    (out / "paper_run.json").write_text(json.dumps(summary, indent=2))
    return summary


def _commit(tree: Path) -> str:
    """The short commit of the tree ``tree`` ("+" when it has uncommitted changes)."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=tree, check=True,
                              capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=tree, capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+" if dirty else "")


def _windows(run: Path) -> dict[str, int] | None:
    """The training and validation windows a network's log names, or None."""
    for log_file in sorted(run.glob("*/train.log")):
        found = re.search(r"(\d+) training and (\d+) validation windows", log_file.read_text())
        if found:
            return {"train": int(found[1]), "val": int(found[2])}
    return None


def _model_summary(document: dict[str, Any]) -> dict[str, Any]:
    mean = document.get("mean", {})
    return {
        "train_seconds": document.get("train_seconds"),
        "rmse_free_run": mean.get("rmse_free_run"),
        "rmse_one_step": mean.get("rmse_one_step"),
        "r2_free_run": mean.get("r2_free_run"),
        "r2_one_step": mean.get("r2_one_step"),
    }


def training_floor(summary: dict[str, Any]) -> list[dict[str, Any]]:
    """Multiply-adds of each network's training in the run (forward and backward on every
    training window, a forward on every validation window, each epoch) and the seconds they
    take at least: one core at the peak of its FMA units."""
    from overhead import CONFIGS, _peak_macs_per_s, macs_per_step

    from hysteresis_lab.models.registry import get_model_class

    windows = summary.get("windows") or {"train": 71_991, "val": 7_999}
    epochs = int(summary.get("epochs", 100))
    peak = _peak_macs_per_s()
    rows = []
    for name in ("lstm", "cnn", "ffnn"):
        cfg = {k: v for k, v in CONFIGS[name].items() if k != "name"}
        model = get_model_class(name)(nu=1, ny=1, **cfg)
        per_window = macs_per_step(model.net, model.window.seq_len)
        # backward: the gradient of every weight and of every layer's input, twice the forward
        per_epoch = per_window * (3 * windows["train"] + windows["val"])
        rows.append({"network": name, "per_window": per_window, "per_run": per_epoch * epochs,
                     "floor_s": per_epoch * epochs / peak, "epochs": epochs})
    return rows


def write_page(page: Path, runs: dict[str, Path]) -> None:
    """The page of the runs ``label -> folder`` (each holding the `run_paper` summary)."""
    from overhead import _machine, _peak_macs_per_s

    summaries = {label: json.loads((folder / "paper_run.json").read_text())
                 for label, folder in runs.items()}
    lines = [
        "# The paper run: CPU seconds, wall clock and the arithmetic floor",
        "",
        "Written by `benchmarks/paper_run.py` (do not edit by hand).",
        "",
        f"- page: `python benchmarks/paper_run.py --page {page} --runs "
        + " ".join(f"'{label}=<folder>'" for label in runs) + "`",
        f"- date: {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC",
        f"- machine: {_machine()}",
        "",
        "Each run: `hysteresis-lab-train experiment=paper` (the study's settings: 100 epochs, "
        "batch 128, Adam; FFNN, LSTM, CNN, SVM and the grey-box; two worker processes of one "
        "torch thread each; a run with fewer epochs or models says so), timed by "
        "`benchmarks/paper_run.py --out <folder>` with "
        "`OMP_NUM_THREADS=1`. *CPU*: user + system seconds; *idle estimate*: the parent "
        "process's CPU seconds plus the busiest worker's (on an idle machine each worker has "
        "a core of its own and the parent's work comes before and after theirs). On a shared "
        "machine the wall clock counts the waits for a core, and the CPU seconds grow too "
        "(a bare LSTM training step of the study's size took 10.4 ms of CPU under a load "
        "of 9 on these 2 cores, against the 4.3 ms of `docs/results/speed.md` on a quiet "
        "one), so both are upper bounds for an idle machine.",
        "",
        "| run | commit | epochs | models | load (1 min) before / after | wall [s] | CPU, "
        "all [s] | CPU, parent [s] | CPU, workers [s] | idle estimate [s] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for label, s in summaries.items():
        workers = " + ".join(f"{cpu:.0f}" for cpu in s["worker_cpu_s"])
        lines.append(
            f"| {label} | {s.get('commit', '?')} | {s.get('epochs', 100)} | "
            f"{', '.join(s['models'])} | {s['load_before'][0]:.1f} / "
            f"{s['load_after'][0]:.1f} | {s['wall_s']:.0f} | {s['total_cpu_s']:.0f} | "
            f"{s['parent_cpu_s']:.0f} | {workers} | {s['idle_estimate_s']:.0f} |")
    lines += [
        "",
        "## Table 2, mean over the twelve test sines",
        "",
        "Free-run / one-step RMSE [µm] of each model (the training seed as the run says; "
        "nan: not in that run).",
        "",
        "| model | " + " | ".join(summaries) + " |",
        "|---|" + "---|" * len(summaries),
    ]
    models = dict.fromkeys(key for s in summaries.values() for key in s["models"])
    for key in models:
        cells = []
        for s in summaries.values():
            m = s["models"].get(key, {})
            cells.append(f"{m.get('rmse_free_run', float('nan')):.4g} / "
                         f"{m.get('rmse_one_step', float('nan')):.4g}")
        lines.append(f"| {key} | " + " | ".join(cells) + " |")
    floor = training_floor(next(iter(summaries.values())))
    peak = _peak_macs_per_s()
    total = sum(r["floor_s"] for r in floor)
    lines += [
        "",
        "## The floor: multiply-adds against the cores' peak",
        "",
        "Multiply-adds of the networks' training alone (forward on each window, twice that "
        "backward, a forward on each validation window, 100 epochs) against one core's "
        f"float32 peak ({peak / 1e9:.0f} G multiply-adds/s, both FMA units busy every cycle).",
        "",
        "| network | multiply-adds per window | per run | seconds at peak on one core | "
        "per epoch [s] (compare `docs/results/speed.md`) |",
        "|---|---|---|---|---|",
    ]
    for r in floor:
        lines.append(f"| {r['network']} | {r['per_window']:,} | {r['per_run'] / 1e12:.1f} T | "
                     f"{r['floor_s']:.0f} | {r['floor_s'] / r['epochs']:.2f} |")
    lines += [
        "",
        f"Together {total:.0f} core-seconds at peak, {total / 2:.0f} s on two cores if both "
        "ran at peak all the time; the SVM, the grey-box, the free runs, data and figures "
        "come on top.",
        "",
    ]
    page.write_text("\n".join(lines))
    log.info("wrote %s", page)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, help="folder for the run and its summary")
    parser.add_argument("--src", default=None, help="a tree's src folder to run instead")
    parser.add_argument("--override", action="append", default=[],
                        help="a Hydra override for the run (repeatable)")
    parser.add_argument("--page", type=Path, help="write this page from --runs")
    parser.add_argument("--runs", nargs="+", default=[], metavar="LABEL=FOLDER",
                        help="the runs' folders (of --out) for --page")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.out is not None:
        summary = run_paper(args.out, args.src, args.override)
        log.info(json.dumps(summary, indent=2))
    if args.page is not None:
        runs = dict(item.rsplit("=", 1) for item in args.runs)  # a label may hold "="
        write_page(args.page, {label: Path(folder) for label, folder in runs.items()})


if __name__ == "__main__":
    main()
