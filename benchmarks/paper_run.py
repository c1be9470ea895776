"""Time the paper run (``hysteresis-lab-train experiment=paper``) by CPU seconds and wall clock.

    OMP_NUM_THREADS=1 python benchmarks/paper_run.py --out /tmp/paper_runs/new
    python benchmarks/paper_run.py --out /tmp/paper_runs/base --src /path/to/other/tree/src

Runs the experiment in a subprocess (``python -m hysteresis_lab.cli.train experiment=paper``,
any extra ``--override``), samples every descendant process's CPU seconds (user + system)
twice a second, and writes ``paper_run.json`` into ``--out``: the wall clock, the load average
before and after, the CPU seconds of the parent and of each worker process, each model's
``train_seconds``, and Table 2's mean row per model.

On a shared machine the wall clock counts the waits for a core; the estimate for an idle
machine is the parent's own CPU seconds (data, scoring of the last model, Table 2 and Figure 1
run there, not beside the workers) plus the busiest worker's CPU seconds: on an idle machine
with at least as many cores as workers each worker runs on a core of its own.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
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
    summary = {
        "command": " ".join(command),
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


def _model_summary(document: dict[str, Any]) -> dict[str, Any]:
    mean = document.get("mean", {})
    return {
        "train_seconds": document.get("train_seconds"),
        "rmse_free_run": mean.get("rmse_free_run"),
        "rmse_one_step": mean.get("rmse_one_step"),
        "r2_free_run": mean.get("r2_free_run"),
        "r2_one_step": mean.get("r2_one_step"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True,
                        help="folder for the run and its summary")
    parser.add_argument("--src", default=None, help="a tree's src folder to run instead")
    parser.add_argument("--override", action="append", default=[],
                        help="a Hydra override for the run (repeatable)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    summary = run_paper(args.out, args.src, args.override)
    log.info(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
