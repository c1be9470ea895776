"""Why the cascaded tanks' loop stops short of its target: the held-out share it reads and
trains without.

The tanks have one identification record of 1024 samples. Without validation recordings the
loop trains on the first ``1 - loop.holdout`` of it and both chooses the next effect
(diagnosis) and judges every refit on the rest. This runs the loop from ``model=linear
effects=[]`` at several held-out shares, nothing else changed, and lists per share:

* the rounds: the effect each round added and whether its refit was kept;
* the block votes of ``nonlinear_feedback`` (the tanks' outflow law, which the loop needs
  after the overflow: `docs/results/tanks_structure.md`) in the last diagnosis that had it
  untried: held-out blocks that gain, lose, carry no evidence, and its p;
* the result's free-run RMSE on the test record;
* the structure the tanks need declared (``model.effects=[overflow,nonlinear_feedback]
  model.feedback_on=output_stage loop.max_rounds=0``) and trained on the same share, with the
  loop's default training: what the loop could reach on that share had it named both.

The test record chooses nothing here. Writes ``docs/results/tanks_loop_holdout.md``.

    OMP_NUM_THREADS=1 python experiments/tanks_loop_holdout.py --root /tmp/tanks-holdout
"""

from __future__ import annotations

import argparse
import datetime
import logging
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from hysteresis_lab.cli.loop import run_fresh_loop
from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.loop.diagnosis.ranking import BlockCounts

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "tanks_loop_holdout.md"
SHARES = (0.25, 0.35, 0.5)
COMMON = ("data=cascaded_tanks", "trainer.enable_progress_bar=false", "logger=none")
DECLARED = ("model.effects=[overflow,nonlinear_feedback]", "model.feedback_on=output_stage",
            "loop.max_rounds=0")
LAW = "nonlinear_feedback"

log = logging.getLogger("tanks_loop_holdout")


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


def _measure(share: float, root: Path) -> dict[str, Any]:
    holdout = f"loop.holdout={share}"
    loop, seconds = run_fresh_loop([*COMMON, holdout], root / f"loop_{share}")
    declared, _ = run_fresh_loop([*COMMON, holdout, *DECLARED], root / f"declared_{share}")
    if loop["result"] is None:
        raise SystemExit(f"the loop at loop.holdout={share} has no standing model: see "
                         f"{root / f'loop_{share}'}/loop_report.md")
    result = loop["rounds"][loop["result"]]
    log.info("holdout %g: %.4f V (%s) in %.0f s", share, result["mean_rmse_free_run"],
             _rounds(loop), seconds)
    return {
        "share": share,
        "roles": loop["roles"],
        "rounds": _rounds(loop),
        "effects": result["effects"],
        "law": _law_votes(loop),
        "start": loop["rounds"][0]["mean_rmse_free_run"],
        "result": result["mean_rmse_free_run"],
        "declared": declared["rounds"][0]["mean_rmse_free_run"],
        "seconds": seconds,
    }


def _page(rows: list[dict[str, Any]], jobs: int) -> str:
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        "# The cascaded tanks' loop: what the held-out share decides",
        "",
        f"Written by `python experiments/tanks_loop_holdout.py` on {stamp}, commit "
        f"{commit_stamp(REPO)}; 2-core CPU, {jobs} loop(s) side by side. Each row runs "
        "`hysteresis-lab-loop data=cascaded_tanks loop.holdout=<share>` from `model=linear "
        "effects=[]`, nothing else changed; `loop.holdout=0.25` is the default. The last "
        "column trains the structure the tanks need, declared (`"
        + " ".join(DECLARED) + "`), on the same share with the loop's default training. "
        "Free-run RMSE on the test record (tanks_test); target 0.25 V.",
        "",
        "| held out | trained on / held out | rounds after the start | result's effects | "
        "nonlinear feedback's votes (last diagnosis scoring it) | start | result | "
        "declared structure | loop time |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['share']:g} | {', '.join(r['roles']['train'])} / "
            f"{', '.join(r['roles']['validation'])} | {r['rounds']} | {r['effects']} | "
            f"{r['law']} | {r['start']:.4f} V | {r['result']:.4f} V | {r['declared']:.4f} V | "
            f"{r['seconds']:.0f} s |"
        )
    lines += [
        "",
        "A held-out block is one vote of the diagnosis' significance test "
        "(`hysteresis_lab.loop.diagnosis.ranking.BlockCounts`); a silent block is one neither fit "
        "predicts better than nothing. More held-out samples give more votes, and fewer "
        "samples to train on.",
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path("outputs/tanks_loop_holdout"))
    parser.add_argument("--shares", type=float, nargs="+", default=list(SHARES))
    parser.add_argument("--jobs", type=int, default=2, help="loops run side by side")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    with ThreadPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(lambda share: _measure(share, args.root), args.shares))
    OUT.write_text(_page(rows, args.jobs))
    log.info("wrote %s", OUT)


if __name__ == "__main__":
    main()
