"""The loop on measured data, before and after: one default command per data set.

Runs ``hysteresis-lab-loop data=<name>`` (start ``model=linear effects=[]``, default
settings; only the progress bar and TensorBoard are off, which change no number) for each
data set, times it and reads its ``loop_report.json``. Each data set's row (its command,
commit, date and the parts of the report the table shows) is merged into
``docs/results/loop_measured.json``, so a run of some data sets replaces only their rows;
``docs/results/loop_measured.md`` is regenerated from all kept rows.

    python benchmarks/loop_measured.py                       # cascaded_tanks, bouc_wen
    python benchmarks/loop_measured.py --data cascaded_tanks bouc_wen p885 fsm emps
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
import time
from pathlib import Path
from typing import Any

from hysteresis_lab.cli.loop import run_fresh_loop
from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.run_folder import LoopFolder, RunFolder

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "loop_measured.md"
KEPT = OUT.with_suffix(".json")
#: the issue's targets: the effect the loop should name and the free-run RMSE it should reach
TARGETS = {
    "cascaded_tanks": ("overflow", "free-run RMSE <= 0.25 V"),
    "bouc_wen": ("hysteresis", "free-run RMSE cut >= 60 %"),
    "p885": (None, "not worse than the start"),
    "fsm": (None, "not worse than the start"),
    "emps": (None, "not worse than the start"),
}
QUIET = ["trainer.enable_progress_bar=false", "logger=none"]
#: the round fields the table reads (the rest of loop_report.json stays in the run folder)
ROUND_FIELDS = ("mean_rmse_free_run", "rejected", "added", "effects", "held_out", "chosen_on",
                "fitted_on", "tests")

log = logging.getLogger("loop_measured")


def run_one(name: str, folder: Path) -> dict:
    """Run the loop on data set ``name`` into ``folder`` (fresh); its report and wall time."""
    command = ["hysteresis-lab-loop", f"data={name}", *QUIET]
    cpu = time.process_time()  # one thread (OMP_NUM_THREADS=1): what a shared CPU does not skew
    try:
        report, seconds = run_fresh_loop(command[1:], folder)
    except RuntimeError as exc:
        raise SystemExit(str(exc)) from None
    round_0 = RunFolder(LoopFolder(folder).round_dir(0)).read_metrics()
    return {"command": " ".join(command), "report": table_report(report),
            "seconds": seconds, "cpu_seconds": time.process_time() - cpu,
            "round_0_train_s": round_0.get("train_seconds")}


def collect_one(name: str, folder: Path) -> dict:
    """The row of a loop that ran into ``folder`` with this script's command (a benchmark
    stopped after some data sets keeps theirs): its report, and its wall time from the first
    and last lines of its ``loop.log``; no CPU time."""
    report = json.loads(LoopFolder(folder).report_json.read_text())
    stamps = [datetime.datetime.strptime(line[1:24], "%Y-%m-%d %H:%M:%S,%f")
              for line in (folder / "loop.log").read_text().splitlines()
              if line.startswith("[20")]
    round_0 = RunFolder(LoopFolder(folder).round_dir(0)).read_metrics()
    return {"command": " ".join(["hysteresis-lab-loop", f"data={name}", *QUIET]),
            "report": table_report(report),
            "seconds": (stamps[-1] - stamps[0]).total_seconds(),
            "round_0_train_s": round_0.get("train_seconds")}


def table_report(report: dict[str, Any]) -> dict[str, Any]:
    """The parts of a ``loop_report.json`` the table shows: units, roles, the result and per
    round its error, effects, decision, held-out loss and the three best-scored effects."""
    rounds = []
    for entry in report["rounds"]:
        kept = {key: entry[key] for key in ROUND_FIELDS if key in entry}
        kept["diagnosis"] = [d for d in entry.get("diagnosis") or [] if d["tested"]][:3]
        rounds.append(kept)
    return {"units": report["units"], "roles": report["roles"], "result": report["result"],
            "rounds": rounds}


def load_kept(path: Path = KEPT) -> dict[str, dict]:
    """The rows kept so far, data set -> row (command, commit, date, report, times)."""
    return json.loads(path.read_text()) if path.is_file() else {}


def keep(runs: dict[str, dict], path: Path = KEPT) -> dict[str, dict]:
    """Merge ``runs`` into the kept rows (a data set run again replaces its row); all rows in
    `TARGETS`' order, then any other."""
    kept = {**load_kept(path), **runs}
    order = [name for name in TARGETS if name in kept] + sorted(set(kept) - set(TARGETS))
    kept = {name: kept[name] for name in order}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(kept, indent=1) + "\n")
    return kept


def row(name: str, run: dict) -> str:
    """One table line: start and result RMSE, the cut, what each round did, the time."""
    report = run["report"]
    rounds, unit = report["rounds"], report["units"]["y"]
    result = report["result"] if report["result"] is not None else 0
    before, after = rounds[0]["mean_rmse_free_run"], rounds[result]["mean_rmse_free_run"]
    steps = round_steps(rounds)
    kept = rounds[result]["effects"]
    named, target = TARGETS.get(name, (None, ""))
    return (f"| {name} | {before:.4g} {unit} | {after:.4g} {unit} | "
            f"{100 * (after - before) / before:+.1f} % | {'; '.join(steps) or 'nothing named'} | "
            f"[{', '.join(kept)}] | {target}"
            + (f" (named: {'yes' if named in _named(rounds) else 'no'})" if named else "")
            + f" | {run['round_0_train_s']:.0f} s / {run['seconds']:.0f} s{_cpu(run, rounds)} |")


def round_steps(rounds: list[dict]) -> list[str]:
    """What each round after the start tried and whether the folds kept it; where the folds
    kept a confounded alternative, the effect the diagnosis named first too."""
    steps, standing = [], list(rounds[0]["effects"])
    for before, entry in zip(rounds, rounds[1:], strict=False):
        new = [e for e in entry["effects"] if e not in standing]
        named = before.get("added")
        tried = new[0] if new else named
        label = tried if named in (None, tried) else f"{tried} (diagnosis named {named})"
        if entry.get("rejected"):
            steps.append(f"{label} rejected")
        else:
            steps.append(f"{label} kept")
            standing = list(entry["effects"])
    return steps


def _cpu(run: dict, rounds: list[dict]) -> str:
    """The command's CPU time and its mean per round (rows measured before it was: none)."""
    cpu = run.get("cpu_seconds")
    return "" if cpu is None else f" ({cpu:.0f} s CPU, {cpu / len(rounds):.0f} s a round)"


def _named(rounds: list[dict]) -> set[str]:
    return {entry["added"] for entry in rounds if entry.get("added")}


def roles_lines(name: str, run: dict) -> list[str]:
    """Which data chose (the folds' held-out stretches; rows measured before the folds: one
    held-out stretch) and which fitted the result."""
    roles = run["report"]["roles"]
    if "folds" in roles:
        return [f"- **{name}**: chosen on {len(roles['folds'])} folds holding out "
                f"{'; '.join(roles['folds'])}; the result fitted on {', '.join(roles['train'])}"
                f"{_length(run)}; test {', '.join(roles['test'])}"]
    return [f"- **{name}** (one held-out stretch): trained on {', '.join(roles['train'])}; "
            f"diagnosis and validation {', '.join(roles['diagnosis'])} / "
            f"{', '.join(roles['validation'])}; test {', '.join(roles['test'])}"]


def _length(run: dict) -> str:
    """How long the result's whole-record refit trained (rows measured before the folds set
    it: nothing)."""
    report = run["report"]
    fitted = report["rounds"][report["result"] or 0].get("fitted_on") or {}
    return f" (every sample, trained {fitted['length']})" if fitted.get("length") else ""


def _votes(score: dict[str, Any]) -> str:
    """How the effect's held-out blocks voted (rows measured before votes were kept: none)."""
    blocks = score.get("blocks")
    if not blocks:
        return ""
    return f", {blocks['gaining']} of {blocks['held_out']} blocks gain, {blocks['losing']} lose"


def diagnosis_lines(name: str, run: dict) -> list[str]:
    """Round 0's three best-scored effects, the evidence behind the first choice."""
    lines = []
    for i, entry in enumerate(run["report"]["rounds"]):
        if not entry["diagnosis"]:
            continue
        best = [f"{d['effect']} {100 * d['score']:.1f} % (p {d['p_value']:.2g}"
                f"{_votes(d)}{', significant' if d['significant'] else ''})"
                for d in entry["diagnosis"][:3]]
        held = entry["held_out"]
        lines.append(f"- {name} round {i} {entry['effects']}: held-out loss "
                     f"{held['loss']:.4g}; best scores {', '.join(best)}")
    return lines


def render(kept: dict[str, dict]) -> str:
    """The page from all kept rows."""
    lines = [
        "# The loop on measured data, before and after",
        "",
        "Written by `python benchmarks/loop_measured.py --data <data sets>`, which reruns the "
        "given data sets and keeps the other rows (`loop_measured.json`); each row's commit "
        "and date are listed below it. Shared 2-core CPU (OMP_NUM_THREADS=1; other jobs ran "
        "beside it, so the wall time runs high: the command's CPU time, one thread, is its "
        "cost). One command per "
        "data set, default settings: the start is `model=linear effects=[]` (on EMPS with "
        "the integrator its data set declares: its position integrates the force). The loop "
        "chooses on `loop.folds` folds of the identification record and reports the model "
        "refitted on all of it; the test recordings are never used for a choice. Free runs "
        "start from rest (`evaluation.initial_state=rest`).",
        "",
        "| data | start (round 0) free-run RMSE | result | change | rounds | result's effects "
        "| target | round 0 train / whole command (wall; CPU) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    lines += [row(name, run) for name, run in kept.items()]
    lines += ["", "Commands, with the commit and date each row was measured at:", ""]
    lines += [f"- `{run['command']}` at {run['commit']}, {run['date']}" for run in kept.values()]
    lines += ["", "Which recordings played which role:", ""]
    for name, run in kept.items():
        lines += roles_lines(name, run)
    lines += ["", "Diagnosis per round (held-out residual, every fold's blocks together; score "
              "= share of its variance explained beyond the input and the declared effects):",
              ""]
    for name, run in kept.items():
        lines += diagnosis_lines(name, run)
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", nargs="+", default=["cascaded_tanks", "bouc_wen"])
    parser.add_argument("--runs", type=Path, default=REPO / "outputs" / "loop_measured")
    parser.add_argument("--collect", metavar="COMMIT",
                        help="run nothing: take the rows of --data from the loops that "
                             "finished under --runs, measured at COMMIT")
    parser.add_argument("--render", action="store_true",
                        help="run nothing: rewrite the page from the kept rows")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.render:
        OUT.write_text(render(keep({})))
        log.info("wrote %s", OUT)
        return
    commit = args.collect or commit_stamp(REPO)
    runs = {}
    for name in args.data:
        if args.collect:
            folder = args.runs / name
            stamp = datetime.datetime.fromtimestamp(
                LoopFolder(folder).report_json.stat().st_mtime, datetime.UTC)
            runs[name] = {**collect_one(name, folder), "commit": commit,
                          "date": f"{stamp:%Y-%m-%d %H:%M} UTC"}
            continue
        log.info("running the loop on %s ...", name)
        runs[name] = {**run_one(name, args.runs / name), "commit": commit,
                      "date": f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC"}
        log.info("%s done in %.0f s", name, runs[name]["seconds"])
    OUT.write_text(render(keep(runs)))
    log.info("wrote %s", OUT)


if __name__ == "__main__":
    main()
