"""Undeclared-effect check of the closed loop on the simulator (issue #23 item 4).

    python experiments/undeclared_effects.py                        # all cases, then the table
    python experiments/undeclared_effects.py --cases creep          # one case (rows are kept)
    python experiments/undeclared_effects.py --table-only           # the table from kept rows
    python experiments/undeclared_effects.py --cases saturation --recommended  # and again with
                                                   # the recordings its first run's report names

For each case the simulator switches one effect on that the start model does not declare.
The start is the loop's own, ``model=linear effects=[]``; the simulator's always-on
nonlinear blocks (Bouc–Wen hysteresis, creep) are switched off, so the effect under test is
the only one beyond linear dynamics (amplifier, delay, first bending mode). Rate dependence
modulates the Bouc–Wen loop, so there the hysteresis stays on and the start declares it.
Everything else is the loop's default but ``loop.max_rounds=1``: only round 0's diagnosis
and the refit it leads to are judged here (the loop tries the significant effects best first
and keeps the first refit that wins on held-out validation; `judged_refit`). The drift case also
diagnoses a 10 s recording that holds the input at 0 V (``data.splits.test_hold_s=10
data.diagnose=[hold_10s]``): on a moving input a trend cannot be told apart from slow
input-driven error.

Reported per case: the top significant effect of round 0 and its score; the share of the
round-0 diagnosis residual that the effect's own output explains (``effect_share``: where it
is below ``loop.min_score`` the rule does not ask for the effect to be named); per test where
the effect acts (its own output > 0.05 µm RMS) the free-run RMSE before and after the refit
and the ceiling (``hysteresis_lab.loop.checks.ceiling``: the cut that taking the
effect's own output off the round-0 error would give); and the verdict of the rule: named as
the top significant effect (or its catalogue stand-in); the refit takes at least half the
ceiling off where the effect acts; no other test more than 5 % worse; an input-independent
effect (drift) named and no gain claimed for it. Each case's row is kept as JSON under
``--root`` and merged into ``docs/results/undeclared_effects.json`` (a case run again replaces
its rows, the others stay); the table of all kept rows goes to
``docs/results/undeclared_effects.md``.

Where round 0 could not judge an effect for lack of excitation, the loop's report names the
recordings to add (``under_excited``: simulator overrides). ``--recommended`` runs such a
case again with them added, nothing else changed, into ``<root>/<case>+recommended``; its
row follows the first run's, whose verdict stands.
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
from pathlib import Path

from hysteresis_lab.cli.loop import run_fresh_loop
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.loop.checks import ceiling, effect_share

log = logging.getLogger("undeclared_effects")

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "undeclared_effects.md"
#: case -> (simulator block, effects the start declares, catalogue effects that name it)
CASES: dict[str, tuple[str, list[str], tuple[str, ...]]] = {
    "creep": ("creep", [], ("creep",)),
    "mode2": ("mode2", [], ("resonance",)),
    "drift": ("drift", [], ("drift",)),
    "saturation": ("saturation", [], ("saturation",)),
    # a play operator is a backlash: the hysteresis's play operators model it as well
    "backlash": ("backlash", [], ("backlash", "hysteresis")),
    "dead_zone": ("dead_zone", [], ("dead_zone",)),
    # creep again, its slow test diagnosed: the 1 s validation multisine cannot show it
    "creep_1hz": ("creep", [], ("creep",)),
    # rate dependence modulates the Bouc–Wen loop: the hysteresis stays on and is declared; a
    # loop that widens with the rate lowers the gain at high frequencies, which the
    # resonance's filters (a frequency-dependent gain) model
    "rate_dependence": ("rate_dependence", ["hysteresis"], ("rate", "resonance")),
}
#: the simulator's always-on nonlinear blocks, switched off unless the case needs them
NONLINEAR = ("hysteresis", "creep")
#: extra data overrides per case (drift: a held input, diagnosed)
CASE_DATA = {"drift": ["data.splits.test_hold_s=10", "data.diagnose=[hold_10s]"],
             "creep_1hz": ["data.diagnose=[sine_1Hz]"]}
QUIET = ["trainer.enable_progress_bar=false", "logger=none"]
ACTS_UM = 0.05  # an effect "acts" on a test where it moves the noise-free output by more (RMS)
WORSE_PCT = 5.0  # no other test may get worse than this
CEILING_SHARE = 0.5  # the share of the ceiling the refit must take off where the effect acts
MIN_SCORE = 0.05  # loop.min_score's default
#: the start holds the effect where taking its own output off would cut no test's error more
HELD_PCT = 10.0


def command_for(name: str, rounds: int, extra: tuple[str, ...] = ()) -> list[str]:
    """The hysteresis-lab-loop command of case ``name`` (``extra``: data overrides added)."""
    block, declared, _ = CASES[name]
    off = [f"data.effects.{b}.enabled=false" for b in NONLINEAR
           if b != block and b not in declared]
    start = [f"model.effects=[{','.join(declared)}]"] if declared else []
    return [
        "hysteresis-lab-loop", *start, *off,
        f"data.effects.{block}.enabled=true", *CASE_DATA.get(name, []), *extra,
        f"loop.max_rounds={rounds}", *QUIET,
    ]


def change_pct(before: dict, after: dict) -> dict[str, float]:
    """Free-run RMSE change per test recording, in percent."""
    return {
        test: 100 * (after["tests"][test]["rmse_free_run"] / m["rmse_free_run"] - 1)
        for test, m in before["tests"].items()
    }


def verdict(row: dict) -> str:
    """Does the case meet the rule (named where it shows; half the ceiling off where it acts;
    no other test > 5 % worse; an input-independent effect named, no gain claimed)?"""
    shows = row["effect_share_max"] >= MIN_SCORE
    named = row["top"] in row["expected"] and row["significant"]
    if not named:
        if shows:
            return "FAIL: not named as the top significant effect"
        share = (f"the effect holds {100 * row['effect_share_max']:.1f} % < "
                 f"{100 * MIN_SCORE:g} % of the residual")
        held = max(row["ceiling_pct"].values(), default=0.0)
        if held < HELD_PCT:  # a linear effect the linear start fits: nothing left to name
            return (f"PASS: the start holds it ({share}; taking it off would cut no test's "
                    f"error by more than {held:.0f} %)")
        return f"n/a: {share}; not named"
    if not row["predictable"]:
        claimed = row.get("change_pct") is not None
        return "FAIL: a gain is claimed" if claimed else "PASS: named, reported, not added"
    if row.get("change_pct") is None:
        return f"named; not refitted ({row.get('why_not_refitted', 'no refit')})"
    acting = row["ceiling_pct"]
    missed = [t for t, top in acting.items() if -row["change_pct"][t] < CEILING_SHARE * top]
    worse = [t for t, c in row["change_pct"].items() if t not in acting and c > WORSE_PCT]
    failures = ([f"less than half the ceiling off {missed}"] if missed else []) + (
        [f"> {WORSE_PCT:.0f} % worse on {worse}"] if worse else [])
    return "FAIL: " + "; ".join(failures) if failures else "PASS"


def judged_refit(rounds: list[dict]) -> dict:
    """The refit that round 0's diagnosis led to: the loop tries its significant effects best
    first, dropping each refit that loses on held-out validation, and keeps the first that
    wins; that one is judged, or, where none won, the first (rejected) refit."""
    refits = rounds[1:]
    return next((r for r in refits if not r.get("rejected")), refits[0])


def _why_not_refitted(first: dict, report: dict) -> str:
    if first.get("not_carried"):
        return f"model=linear has no block for {first['not_carried']}"
    return first.get("note", "no refit")


def recommended_recordings(report: dict, expected: tuple[str, ...]) -> list[str] | None:
    """The overrides round 0's report recommends for the case's effect (None: it could judge
    the effect, or recommends no override)."""
    advice = [a for a in report["rounds"][0].get("under_excited") or []
              if a["effect"] in expected]
    return advice[0].get("override") if advice else None


def run_case(name: str, root: Path, rounds: int, extra: tuple[str, ...] = ()) -> dict:
    """Run one case's loop (fresh) and read its row; ``extra``: the recordings recommended
    by its first run (their row is the case's ``+recommended`` one)."""
    block, _, expected = CASES[name]
    folder = root / (f"{name}+recommended" if extra else name)
    try:
        row = case_row(command_for(name, rounds, extra), folder, block, expected)
    except RuntimeError as exc:
        raise SystemExit(str(exc)) from None
    row = {"case": f"{name} + recommended recordings" if extra else name,
           "added_recordings": list(extra), **row}
    if extra:
        row["verdict"] = _with_recommended(row["verdict"])
    return row


def case_row(command: list[str], folder: Path, block: str, expected: tuple[str, ...]) -> dict:
    """Run the loop of ``command`` (fresh, into ``folder``) whose data switch simulator
    ``block`` on, undeclared, and judge round 0 by the rule (``expected``: the catalogue
    effects that name the block): the row the table shows. A config or data error is a
    RuntimeError (`run_fresh_loop`)."""
    report, seconds = run_fresh_loop(command[1:], folder)
    first = report["rounds"][0]
    significant = [d for d in first["diagnosis"] if d["significant"]]
    top = significant[0] if significant else (first["diagnosis"] or [{}])[0]
    scores = {d["effect"]: d["score"] for d in first["diagnosis"]}
    shares = effect_share(folder, block, 0)
    row = {
        "block": block, "expected": list(expected),
        "recommends": recommended_recordings(report, expected),
        "command": " ".join(command),
        "commit": commit_stamp(REPO, ("src", "experiments")),
        "date": f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M}",
        "seconds": seconds, "top": top.get("effect"), "top_score": top.get("score"),
        "significant": bool(top.get("significant")),
        "expected_score": max(scores.get(e, float("nan")) for e in expected),
        "predictable": get_effect(expected[0]).predictable,
        "added": first.get("added"), "effect_share": shares,
        "effect_share_max": max(shares.values()),
        "before": {t: m["rmse_free_run"] for t, m in first["tests"].items()},
    }
    if len(report["rounds"]) > 1 and first.get("added"):
        after = judged_refit(report["rounds"])
        refit = after.get("rejected_refit", after) if after.get("rejected") else after
        row["rejected"] = bool(after.get("rejected"))
        row["kept_effect"] = (after["effects"] or [None])[-1] if not row["rejected"] else None
        row["tried"] = [r["rejected"] if r.get("rejected") else r["effects"][-1]
                        for r in report["rounds"][1:] if r["effects"]]
        row["after"] = {t: m["rmse_free_run"] for t, m in refit["tests"].items()}
        # a rejected refit claims no gain: the last model stands
        row["change_pct"] = (change_pct(first, after) if not after.get("rejected")
                             else dict.fromkeys(first["tests"], 0.0))
        row["refit_change_pct"] = change_pct(first, refit)
    else:
        row["why_not_refitted"] = _why_not_refitted(first, report)
    acting = [r for r in ceiling(folder, block, 0) if r["effect_size_um"] > ACTS_UM
              and r["test"] in first["tests"]]
    row["ceiling_pct"] = {r["test"]: r["max_cut_pct"] for r in acting}
    row["effect_size_um"] = {r["test"]: r["effect_size_um"] for r in acting}
    row["verdict"] = verdict(row)
    return row


def _with_recommended(plain: str) -> str:
    """A rerun's verdict says that it ran with the recommended recordings."""
    head, _, rest = plain.partition(":")
    said = f"{head} with the recommended recordings"
    return f"{said}:{rest}" if rest else said


def _verdict_cell(row: dict) -> str:
    """The verdict, and the recordings the report recommends (a first run's)."""
    if row.get("recommends") and not row.get("added_recordings"):
        return (f"{row['verdict']}; not judged for lack of excitation, the report "
                f"recommends `{' '.join(row['recommends'])}`")
    if row.get("added_recordings"):
        return f"{row['verdict']} (added: `{' '.join(row['added_recordings'])}`)"
    return row["verdict"]


def _tests_cell(row: dict) -> str:
    """Per acting test: before -> after (change; ceiling)."""
    if not row["ceiling_pct"]:
        return "acts on no test (> 0.05 µm)"
    after = row.get("after", {})
    cells = []
    for test, top in row["ceiling_pct"].items():
        before = row["before"][test]
        if test in after:
            cells.append(f"{test}: {before:.3f} → {after[test]:.3f} "
                         f"({row['refit_change_pct'][test]:+.0f} %; ceiling −{top:.0f} %)")
        else:
            cells.append(f"{test}: {before:.3f} (ceiling −{top:.0f} %)")
    return "<br>".join(cells)


def _others_cell(row: dict) -> str:
    """The worst change on the tests where the effect does not act."""
    change = row.get("refit_change_pct")
    if change is None:
        return "–"
    others = {t: c for t, c in change.items() if t not in row["ceiling_pct"]}
    if not others:
        return "–"
    worst = max(others, key=others.get)
    return f"{others[worst]:+.1f} % ({worst})"


def table(rows: list[dict]) -> str:
    """The markdown page of all kept rows."""
    lines = [
        "# Undeclared effects on the simulator: does the loop name and fix them?",
        "",
        "Written by `python experiments/undeclared_effects.py` (the cases one after another; "
        "`--cases <name>` reruns one, `--table-only` rewrites this page from the kept rows) "
        "on a shared 2-core CPU (OMP_NUM_THREADS=1). "
        "Start `model=linear effects=[]` (rate dependence: `effects=[hysteresis]`); the "
        "simulator's hysteresis and creep off but where under test (rate: hysteresis on), "
        "so each case has one effect beyond linear dynamics; default loop settings but "
        "`loop.max_rounds=1` (round 0's "
        "diagnosis and the refit it leads to are what is judged: the loop tries the "
        "significant effects best first and keeps the first refit that wins on held-out "
        "validation). Rule: named as the top significant "
        "effect where its own output holds ≥ 5 % (`loop.min_score`) of the round-0 "
        "diagnosis residual; the refit takes at least half the ceiling off every test "
        "where the effect acts (> 0.05 µm RMS); no other test > 5 % worse; drift named, "
        "no gain claimed; an effect below 5 % of the residual whose own output is < 10 % of "
        "every test's error (its ceiling) is held by the start: nothing to name, PASS. "
        "Free-run RMSE in µm, from rest (`evaluation.initial_state=rest`, the default); "
        "'after' is the refit's, also when the loop "
        "rejected it (then the loop claims no gain). Where round 0 could not judge an effect "
        "for lack of excitation its report names recordings to add; a '+ recommended "
        "recordings' row is the case run again with them (`--recommended`), nothing else "
        "changed, below the first run's row, whose verdict stands.",
        "",
        "| case | top significant (score) | expected's score | effect share of residual "
        "| tests where it acts: before → after (refit; ceiling) | worst other test "
        "| refit kept | verdict |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        top = (f"{r['top']} ({100 * r['top_score']:.1f} %)" if r["significant"]
               else "none significant")
        kept = ("–" if "after" not in r else "no (rejected)" if r["rejected"] else "yes")
        dropped = [e for e in r.get("tried", []) if e != r.get("kept_effect")]
        if r.get("kept_effect") and dropped:
            kept = f"yes: {r['kept_effect']} ({', '.join(dropped)} dropped)"
        lines.append(
            f"| {r['case']} | {top} | {'/'.join(r['expected'])} "
            f"{100 * r['expected_score']:.1f} % | {100 * r['effect_share_max']:.1f} % "
            f"| {_tests_cell(r)} | {_others_cell(r)} | {kept} | {_verdict_cell(r)} |"
        )
    lines += ["", "Per case: command, commit, date, wall time:", ""]
    lines += [f"- {r['case']}: `{r['command']}` at {r['commit']}, {r['date']} UTC, "
              f"{r['seconds']:.0f} s" for r in rows]
    return "\n".join(lines) + "\n"


def _run_and_keep(name: str, root: Path, rounds: int, recommended: bool) -> None:
    """Run case ``name`` (its first run reused with ``recommended`` where kept) and keep its
    row; with ``recommended`` also the rerun with the recordings its report names."""
    first = root / name / "row.json"
    kept = first.is_file() and "recommends" in json.loads(first.read_text())
    if not (recommended and kept):  # (a row from before the advice is run again)
        log.info("case %s ...", name)
        _keep(run_case(name, root, rounds), first)
    rerun = root / f"{name}+recommended" / "row.json"
    extra = json.loads(first.read_text()).get("recommends")
    if rerun.is_file() and json.loads(rerun.read_text())["added_recordings"] != extra:
        rerun.unlink()  # a rerun with what the first run's report no longer recommends
    if not extra:
        if recommended:
            log.info("case %s: its report recommends no recordings", name)
        return
    if not recommended:
        return
    log.info("case %s with the recommended recordings %s ...", name, extra)
    _keep(run_case(name, root, rounds, tuple(extra)), rerun)


def merged_rows(root: Path) -> dict[str, dict]:
    """The rows under ``root`` over those kept in ``undeclared_effects.json``, case by case
    in `CASES`' order: a case with a row under ``root`` takes its rows (first run and
    ``+recommended`` rerun) from there only."""
    kept_path = OUT.with_suffix(".json")
    kept = json.loads(kept_path.read_text()) if kept_path.is_file() else {}
    rows = {}
    for name in CASES:
        fresh = (root / name / "row.json").is_file()
        for key in (name, f"{name}+recommended"):
            path = root / key / "row.json"
            if path.is_file():
                rows[key] = json.loads(path.read_text())
            elif not fresh and key in kept:
                rows[key] = kept[key]
    return rows


def _keep(row: dict, path: Path) -> None:
    path.write_text(json.dumps(row, indent=1))
    log.info("%s", json.dumps(row, indent=1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--rounds", type=int, default=1, help="loop.max_rounds")
    parser.add_argument("--root", type=Path, default=REPO / "outputs" / "undeclared")
    parser.add_argument("--table-only", action="store_true",
                        help="write the table from the rows kept under --root")
    parser.add_argument("--recommended", action="store_true",
                        help="run each case again with the recordings its first run's report "
                        "recommends (the first run is reused when its row is kept)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if not args.table_only:
        for name in args.cases:
            _run_and_keep(name, args.root, args.rounds, args.recommended)
    rows = merged_rows(args.root)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.with_suffix(".json").write_text(json.dumps(rows, indent=1) + "\n")
    OUT.write_text(table(list(rows.values())))
    log.info("wrote %s", OUT)


if __name__ == "__main__":
    main()
