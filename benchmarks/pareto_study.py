"""Time a compute-aware tuning study: ``hparams_search=<arch>_pareto`` for each architecture.

    python benchmarks/pareto_study.py                     # the target: 4 x 100 trials
    python benchmarks/pareto_study.py --archs ffnn --n-trials 5 --max-epochs 3 \\
        --out docs/results/pareto_study.md                # a small version

Runs ``hysteresis-lab-train -m hparams_search=<arch>_pareto`` for each architecture, one after
the other (``--workers`` processes per study sharing its storage, two by default: one per
core of the 2-core CPU the budget is set for; default data, the study's default pruner:
successive halving on the CPU),
records each study's wall time and its trials' states, and writes a page with the command,
commit, date, machine, the times against the budget (``--budget-h``) and the table of best
trials: each study's Pareto front (validation free-run MSE x training seconds). The studies
go to ``--results`` (SQLite); run it again with the same folder and each study resumes.
"""

from __future__ import annotations

import argparse
import datetime
import logging
import os
import platform
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import optuna

from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.tuning.bookkeeping import counted
from hysteresis_lab.tuning.pareto import objective_names, pareto_points

log = logging.getLogger("pareto_study")

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "pareto_study.md"
ARCHS = ("ffnn", "lstm", "cnn", "svm")


def command(arch: str, args: argparse.Namespace, worker: int = 0) -> list[str]:
    """The sweep command of one worker of one architecture's study (every worker shares the
    study's storage, each writes its trials' folders apart)."""
    results = Path(args.results).resolve()
    cmd = [
        sys.executable,
        "-m",
        "hysteresis_lab.cli.train",
        "-m",
        f"hparams_search={arch}_pareto",
        f"hydra.sweeper.n_trials={args.n_trials}",
        f"hydra.sweeper.results_dir={results}",
        f"hydra.sweep.dir={results}/runs/{arch}/worker_{worker}",
        "trainer.enable_progress_bar=false",
    ]
    if args.max_epochs is not None:
        cmd.append(f"trainer.max_epochs={args.max_epochs}")
    return cmd + list(args.overrides)


def run_study(arch: str, args: argparse.Namespace) -> dict[str, Any]:
    """Run one study with ``args.workers`` worker processes sharing its storage (they run
    ``n_trials`` trials together); its wall time, exit status and the stored study's
    trials."""
    Path(args.results).mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    _create_study(arch, args)
    workers = []
    for worker in range(args.workers):
        cmd = command(arch, args, worker)
        log.info("%s, worker %d: %s", arch, worker, shlex.join(cmd))
        handle = (Path(args.results) / f"{arch}_sweep_{worker}.log").open("w")
        workers.append((subprocess.Popen(cmd, cwd=REPO, stdout=handle,
                                         stderr=subprocess.STDOUT), handle))
    returncode = 0
    for process, handle in workers:
        returncode = max(returncode, process.wait())
        handle.close()
    seconds = time.perf_counter() - start
    name = f"{arch}_pareto_default"
    url = f"sqlite:///{Path(args.results).resolve()}/{name}.db"
    study = optuna.load_study(study_name=name, storage=url)
    trials = [t for t in study.get_trials(deepcopy=False) if counted(t)]
    states: dict[str, int] = {}
    for t in trials:
        states[t.state.name] = states.get(t.state.name, 0) + 1
    log.info("%s: %.0f s, exit %d, %s", arch, seconds, returncode, states)
    return {
        "arch": arch,
        "seconds": seconds,
        "returncode": returncode,
        "states": states,
        "study": study,
    }


def _create_study(arch: str, args: argparse.Namespace) -> None:
    """One worker's sweep alone, with no trial, so that the study's storage exists before
    the workers start together (two that create it at once can collide)."""
    cmd = [*command(arch, args), "hydra.sweeper.n_trials=0"]
    with (Path(args.results) / f"{arch}_create.log").open("w") as handle:
        subprocess.run(cmd, cwd=REPO, stdout=handle, stderr=subprocess.STDOUT, check=False)


def write_page(rows: list[dict[str, Any]], args: argparse.Namespace, argv: list[str]) -> None:
    """The page: provenance, the times against the budget, each study's front."""
    total = sum(r["seconds"] for r in rows)
    budget_s = args.budget_h * 3600
    lines = [
        "# Compute-aware tuning: time of a Pareto study",
        "",
        "Written by `benchmarks/pareto_study.py` (do not edit by hand).",
        "",
        f"- command: `OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '?')} python "
        f"benchmarks/pareto_study.py {shlex.join(argv)}`",
        f"- commit: {args.commit or commit_stamp(REPO, ['src'])}",
        f"- date: {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC",
        f"- machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"load average at the end {os.getloadavg()[0]:.2f}",
        f"- studies: {', '.join(r['arch'] for r in rows)}; {args.n_trials} trials each, run by "
        f"{args.workers} worker process{'es' * (args.workers != 1)} sharing the study; "
        f"trainer.max_epochs={args.max_epochs or 'the default'}; extra overrides: "
        f"{' '.join(args.overrides) or 'none'}",
        "",
        "| study | wall time (s) | trials (states) | exit |",
        "|---|---|---|---|",
    ]
    for r in rows:
        states = ", ".join(f"{n} {k.lower()}" for k, n in sorted(r["states"].items()))
        lines.append(f"| {r['arch']}_pareto | {r['seconds']:.0f} | {states} | {r['returncode']} |")
    verdict = "within" if total <= budget_s else "over"
    done = [r["arch"] for r in rows]
    target = (
        sorted(done) == sorted(ARCHS)
        and args.n_trials == 100
        and args.max_epochs is None
        and not args.overrides
    )
    scope = (
        "This run is the target: four architectures, 100 trials each, the configs' epochs."
        if target
        else "This run is smaller than the target (four architectures x 100 trials at the "
        "configs' epochs): it shows the mechanism end to end; it does not measure the "
        "target."
    )
    if len(done) < len(args.archs):
        rest = [a for a in args.archs if a not in done]
        scope += (f" Written after {len(done)} of {len(args.archs)} studies: "
                  f"{', '.join(rest)} not (yet) run.")
    lines += [
        "",
        f"Total: {total:.0f} s = {total / 3600:.2f} h, {verdict} the budget of "
        f"{args.budget_h:g} h. {scope}",
        "",
        "## Best trials (Pareto fronts)",
        "",
        "Complete trials and pruned ones, each pruned trial at its stop (`stopped`: its model "
        "as it stood when pruned, scored on the same objectives).",
        "",
    ]
    for r in rows:
        study: optuna.Study = r["study"]
        names = objective_names(study)
        front = pareto_points(study)
        lines += [f"### {study.study_name}", ""]
        if not front:
            lines += ["No trial with its objectives.", ""]
            continue
        params = sorted({name for point in front for name in point.params})
        header = ["trial", *names, "stopped", *params]
        lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for point in front:
            cells = [
                str(point.number),
                *(f"{v:.4g}" for v in point.values),
                point.stopped,
                *(_cell(point.params.get(name, "")) for name in params),
            ]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines))
    log.info("wrote %s", args.out)


def _cell(value: Any) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--archs", nargs="+", default=list(ARCHS), choices=list(ARCHS) + ["subnet"])
    parser.add_argument("--n-trials", type=int, default=100)
    parser.add_argument(
        "--max-epochs",
        type=int,
        default=None,
        help="trainer.max_epochs of every trial (default: the config's)",
    )
    parser.add_argument("--budget-h", type=float, default=2.0)
    parser.add_argument("--workers", type=int, default=2, help="worker processes per study, "
                        "sharing its storage (one per core; each trains with one torch thread "
                        "under OMP_NUM_THREADS=1)")
    parser.add_argument("--results", default="outputs/pareto_study")
    parser.add_argument("--out", default=str(OUT))
    parser.add_argument("--commit", default=None, help="the commit measured, where this copy "
                        "of the project has no git history (a device machine's copy)")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides for every study")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    rows = []
    for arch in args.archs:  # the page after each study: a run cut short keeps those done
        rows.append(run_study(arch, args))
        write_page(rows, args, sys.argv[1:])


if __name__ == "__main__":
    main()
