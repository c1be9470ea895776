"""The cascaded tanks' loop at several fold counts: what ``loop.folds`` decides.

The tanks have one identification record of 1024 samples. The loop cuts it into ``loop.folds``
contiguous blocks; each fold trains on the others and holds one out, and the held-out blocks
of all folds choose the next effect (diagnosis) and judge every refit (stable on every fold,
better pooled and on a majority). This runs the loop from ``model=linear effects=[]`` at
several fold counts, nothing else changed, and lists per count:

* the rounds: the effect each round added and whether its refit was kept;
* the block votes of ``nonlinear_feedback`` (the tanks' outflow law, which the loop needs
  after the overflow: `docs/results/tanks_structure.md`) in the last diagnosis that had it
  untried: held-out blocks that gain, lose, carry no evidence, and its p;
* the result's free-run RMSE on the test record;
* the structure the tanks need declared (``model.effects=[overflow,nonlinear_feedback]
  model.feedback_on=output_stage loop.max_rounds=0``) and trained on the whole record, with
  the loop's default training: what the loop could reach had it named both.

The test record chooses nothing here. Writes ``docs/results/tanks_loop_folds.md``.

    OMP_NUM_THREADS=1 python experiments/tanks_loop_folds.py --root /tmp/tanks-folds
    OMP_NUM_THREADS=1 python experiments/tanks_loop_folds.py \
        --explain outputs/loop_measured/cascaded_tanks
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from hysteresis_lab.cli.loop import run_fresh_loop
from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.loop.diagnosis.ranking import BlockCounts

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "tanks_loop_folds.md"
FOLDS = (2, 3, 4)
COMMON = ("data=cascaded_tanks", "trainer.enable_progress_bar=false", "logger=none")
DECLARED = ("model.effects=[overflow,nonlinear_feedback]", "model.feedback_on=output_stage",
            "loop.max_rounds=0")
LAW = "nonlinear_feedback"

log = logging.getLogger("tanks_loop_folds")


def _rounds(report: dict[str, Any]) -> str:
    """Each round after the start: the effect it tried and whether it stood."""
    parts = []
    for entry in report["rounds"][1:]:
        decision = entry.get("decision") or {}
        verdict = "kept" if decision.get("kept") else "dropped"
        parts.append(f"+{decision.get('effect')} {verdict}")
    return ", ".join(parts) or "none added"


def _law_votes(report: dict[str, Any]) -> str:
    """The outflow law's score, votes and p in the last diagnosis that scored it."""
    for number in reversed(range(len(report["rounds"]))):
        entry = next((d for d in report["rounds"][number]["diagnosis"] if d["effect"] == LAW),
                     None)
        if entry is None or "blocks" not in entry:
            continue
        b = BlockCounts(**entry["blocks"])
        return (f"round {number}: {100 * entry['score']:.1f} %, {b.gaining} gain / "
                f"{b.losing} lose / {b.silent} silent of {b.held_out}, "
                f"p {entry['p_value']:.2g}")
    return "not scored"


def _measure(folds: int, root: Path) -> dict[str, Any]:
    setting = f"loop.folds={folds}"
    loop, seconds = run_fresh_loop([*COMMON, setting], root / f"loop_{folds}")
    declared, _ = run_fresh_loop([*COMMON, setting, *DECLARED], root / f"declared_{folds}")
    if loop["result"] is None:
        raise SystemExit(f"the loop at {setting} has no standing model: see "
                         f"{root / f'loop_{folds}'}/loop_report.md")
    result = loop["rounds"][loop["result"]]
    log.info("%d folds: %.4f V (%s) in %.0f s", folds, result["mean_rmse_free_run"],
             _rounds(loop), seconds)
    return {
        "folds": folds,
        "roles": loop["roles"],
        "rounds": _rounds(loop),
        "effects": result["effects"],
        "law": _law_votes(loop),
        "start": loop["rounds"][0]["mean_rmse_free_run"],
        "result": result["mean_rmse_free_run"],
        "declared": declared["rounds"][0]["mean_rmse_free_run"],
        "seconds": seconds,
    }


def _written_by(command: str) -> str:
    """A page's provenance: the command, the time (UTC) and the commit."""
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return f"Written by `{command}` on {stamp}, commit {commit_stamp(REPO)}"


def _page(rows: list[dict[str, Any]], jobs: int) -> str:
    lines = [
        "# The cascaded tanks' loop: what the number of folds decides",
        "",
        _written_by("python experiments/tanks_loop_folds.py")
        + f"; 2-core CPU, {jobs} loop(s) side by side. Each row runs "
        "`hysteresis-lab-loop data=cascaded_tanks loop.folds=<k>` from `model=linear "
        "effects=[]`, nothing else changed; `loop.folds=3` is the default. The last "
        "column trains the structure the tanks need, declared (`"
        + " ".join(DECLARED) + "`), with the loop's default training. "
        "Free-run RMSE on the test record (tanks_test); target 0.25 V.",
        "",
        "| folds | held out per fold | rounds after the start | result's effects | "
        "nonlinear feedback's votes (last diagnosis scoring it) | start | result | "
        "declared structure | loop time |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['folds']} | {'; '.join(r['roles']['folds'])} | {r['rounds']} | "
            f"{r['effects']} | "
            f"{r['law']} | {r['start']:.4f} V | {r['result']:.4f} V | {r['declared']:.4f} V | "
            f"{r['seconds']:.0f} s |"
        )
    lines += [
        "",
        "A held-out block is one vote of the diagnosis' significance test "
        "(`hysteresis_lab.loop.diagnosis.ranking.BlockCounts`); a silent block is one neither fit "
        "predicts better than nothing. More folds give more votes on the keep rule's "
        "majority, and one more fit per candidate.",
        "",
    ]
    return "\n".join(lines)


def _decisions(report: dict[str, Any]) -> list[str]:
    """Per round after the start: each refit candidate (effect, place, rate) with its
    pooled and per-fold held-out losses, the standing model's, and the keep rule's reason."""
    lines = ["| round | effect tried | place | refit rate | pooled held-out loss | per fold | "
             "verdict |", "|---|---|---|---|---|---|---|"]
    start = report["rounds"][0]["held_out"]
    lines.append(f"| 0 | (start) | | | {start['loss']:.4g} | "
                 f"{', '.join(f'{x:.4g}' for x in start['folds'])} | stands |")
    for number, entry in enumerate(report["rounds"][1:], start=1):
        decision = entry.get("decision") or {}
        effect = decision.get("effect")
        for c in entry.get("refit_candidates", []):
            tried = c.get("effect", effect)  # a compared alternative names its own
            chosen = (tried == effect and c.get("refit_lr") == entry.get("refit_lr")
                      and c.get("feedback_on") == (entry.get("refit_settings") or {}).get(
                          "feedback_on"))
            verdict = ("kept" if decision.get("kept") else "dropped") if chosen else "not best"
            lines.append(
                f"| {number} | {tried} | {c.get('feedback_on', '')} | {c.get('refit_lr')} | "
                f"{c['held_out_loss']:.4g} | "
                f"{', '.join(f'{x:.4g}' for x in c['fold_losses'])} | {verdict} |")
        if decision:
            lines.append(f"| {number} | | | | | | {decision['reason']} |")
    return lines


def explain(folder: Path, root: Path) -> str:
    """The page for a finished default loop in ``folder``: its decisions with every fold's
    numbers, and the declared structure trained with the loop's settings (in ``root``)."""
    report = json.loads((folder / "loop_report.json").read_text())
    declared, _ = run_fresh_loop([*COMMON, *DECLARED], root / "declared_3")
    result = report["rounds"][report["result"] or 0]
    lines = [
        "# The cascaded tanks' loop: what the folds decided, and why",
        "",
        _written_by(f"python experiments/tanks_loop_folds.py --explain {folder}")
        + ", from the default loop's report "
        "(`hysteresis-lab-loop data=cascaded_tanks`, `loop.folds=3`). Held-out loss: the "
        "free-run MSE over the measured variance on each fold's held-out third, pooled by "
        "samples; a refit stands when it is lower pooled and on a majority of folds.",
        "",
        *_decisions(report),
        "",
        f"- Test free-run RMSE (tanks_test): start {report['rounds'][0]['mean_rmse_free_run']:.4f}"
        f" V, result {result['mean_rmse_free_run']:.4f} V ({result['effects']}); target 0.25 V.",
        f"- Nonlinear feedback (the outflow law) in the diagnoses: {_law_votes(report)}.",
        f"- The structure the tanks need, declared (`{' '.join(DECLARED)}`), trained with the "
        f"loop's settings on the whole record: {declared['rounds'][0]['mean_rmse_free_run']:.4f}"
        f" V; its pooled held-out loss on the same folds "
        f"{declared['rounds'][0]['held_out']['loss']:.4g} (folds "
        f"{', '.join(f'{x:.4g}' for x in declared['rounds'][0]['held_out']['folds'])}).",
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path("outputs/tanks_loop_folds"))
    parser.add_argument("--folds", type=int, nargs="+", default=list(FOLDS))
    parser.add_argument("--jobs", type=int, default=2, help="loops run side by side")
    parser.add_argument("--explain", type=Path, default=None, metavar="LOOP_FOLDER",
                        help="run no fold counts: explain the finished default loop in "
                             "LOOP_FOLDER (e.g. outputs/loop_measured/cascaded_tanks) and train "
                             "the declared structure")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    if args.explain is not None:
        OUT.write_text(explain(args.explain, args.root))
        log.info("wrote %s", OUT)
        return
    with ThreadPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(lambda folds: _measure(folds, args.root), args.folds))
    OUT.write_text(_page(rows, args.jobs))
    log.info("wrote %s", OUT)


if __name__ == "__main__":
    main()
