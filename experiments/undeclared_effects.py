"""Undeclared-effect check of the closed loop on the simulator (issue: the closed loop).

    python experiments/undeclared_effects.py                       # all cases
    python experiments/undeclared_effects.py --cases creep --epochs 100

For each case the simulator switches one effect on that the model does not declare, while
the model declares the other effects present (the first bending mode, always on, counts as
"resonance"); `hysteresis-lab-loop` runs one round (fit, diagnose, add the top significant
effect, refit). Reported per case: the top-ranked effect, whether it is significant and the
expected one, the free-run RMSE change per test recording, the effect's own size per test
(RMS change of the noise-free output when it is switched on) and the verdict of the issue's
rule: named as the top significant effect; where it acts (> 0.05 µm) the free-run RMSE cut by
>= 30 %; no other test more than 5 % worse (an input-independent effect only has to be named).

The test set is the study's twelve sines plus 10 s with the input held at 0 V (drift, which
does not depend on the input, can only be told apart from slow input-driven error where the
input does not move). The identification data is the study's multisine plus full-amplitude
sines between the test frequencies (``--train-sines``; the multisine alone never drives the
full-amplitude loops of the test sines, so a model trained on it mostly shows its own
extrapolation error), and the networks are fine-tuned on their free-run error (``--horizon``).
Each case also reports, per test where the effect acts, the RMSE cut that taking the effect's
own output off the round-0 error would give (``experiments/effect_ceiling.py``).
"""

from __future__ import annotations

import argparse
import json
import logging
import subprocess
import time
from pathlib import Path

from hysteresis_lab.analysis.diagnosis import TESTS
from hysteresis_lab.analysis.loop_checks import ceiling
from hysteresis_lab.effects.registry import get_effect

log = logging.getLogger("undeclared_effects")

#: case -> (simulator block, effects the model declares, catalogue effect expected)
CASES: dict[str, tuple[str, list[str], str]] = {
    "creep": ("creep", ["hysteresis", "resonance"], "creep"),
    "mode2": ("mode2", ["hysteresis", "creep"], "resonance"),
    "drift": ("drift", ["hysteresis", "creep", "resonance"], "drift"),
    "saturation": ("saturation", ["hysteresis", "creep", "resonance"], "saturation"),
}
#: every case's test set ends with 10 s of the input held at 0 V: the metrology test for
#: drift, the one recording on which an input-independent effect can be told apart
TEST_HOLD = "data.splits.test_hold_s=10"
#: extra data overrides per case: identification inside the amplifier's linear range (80 V
#: sines; the multisine's rare peaks still reach the clipping level), tested at full range
CASE_DATA = {"saturation": ["data.splits.train_sine_amplitude=80"]}
TRAIN_SINES = "[0.3,3,30,75,125,175,225,275,350,425,475]"
ACTS_UM = 0.05  # an effect "acts" on a test where it moves the noise-free output by more (RMS)
WORSE_PCT = 5.0  # no other test may get worse than this
CUT_PCT = 30.0  # the gain required where the effect acts


def verdict(row: dict, sizes: dict[str, float], predictable: bool) -> str:
    """Does the case meet the issue's rule (named; cut where it acts; nothing else worse)?"""
    if row["top"] != row["expected"] or not row["significant"]:
        return "FAIL: not named as the top significant effect"
    if not predictable:
        return "PASS: named (an input-independent effect is reported, not added)"
    change = row.get("change_pct")
    if change is None:
        return "FAIL: named but not refitted"
    acting = [t for t, size in sizes.items() if size > ACTS_UM]
    missed = [t for t in acting if change[t] > -CUT_PCT]
    worse = [t for t in change if t not in acting and change[t] > WORSE_PCT]
    failures = ([f"cut < {CUT_PCT:.0f} % on {missed}"] if missed else []) + (
        [f"> {WORSE_PCT:.0f} % worse on {worse}"] if worse else [])
    if failures:
        return "FAIL: " + "; ".join(failures)
    return f"PASS: cut >= {CUT_PCT:.0f} % on {acting}; no other test > {WORSE_PCT:.0f} % worse"


def change_pct(before: dict, after: dict) -> dict[str, float]:
    """Free-run RMSE change per test recording, in percent."""
    return {
        test: 100 * (after["tests"][test]["rmse_free_run"] / m["rmse_free_run"] - 1)
        for test, m in before["tests"].items()
    }


def run_case(name: str, args: argparse.Namespace) -> dict:
    block, declared, expected = CASES[name]
    overrides = [f"data.effects.{block}.enabled=true", TEST_HOLD, *CASE_DATA.get(name, [])]
    out = args.root / name
    command = [
        "hysteresis-lab-loop", "model=ffnn", f"model.effects=[{','.join(declared)}]",
        "loop.max_rounds=1", f"trainer.max_epochs={args.epochs}",
        "model.objective=simulation", f"model.horizon={args.horizon}",
        f"model.simulation_epochs={args.simulation_epochs}",
        f"data.splits.train_sines={args.train_sines}", f"model.effect_path={args.effect_path}",
        f"loop.significance={args.significance}", f"loop.resume={str(args.resume).lower()}",
        "trainer.enable_progress_bar=false",
        "logger=none", f"hydra.run.dir={out}", *overrides,
    ]
    start = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    report = json.loads((out / "loop_report.json").read_text())
    first = report["rounds"][0]
    top = first["diagnosis"][0] if first["diagnosis"] else {"effect": None, "significant": False}
    row = {"case": name, "expected": expected, "top": top["effect"],
           "significant": top["significant"], "added": first["added"], "seconds": seconds}
    if len(report["rounds"]) > 1:
        after = report["rounds"][1]
        row["change_pct"] = change_pct(first, after)
        if after.get("rejected"):  # the loop kept round 0; what the refit would have done:
            row["rejected"] = after["rejected"]
            row["rejected_refit_change_pct"] = change_pct(first, after["rejected_refit"])
    # per test: the effect's size and the cut that taking its own output off the round-0
    # error would give
    shares = ceiling(out, block, 0)
    sizes = {r["test"]: r["effect_size_um"] for r in shares}
    row["effect_size_um"] = sizes
    row["effect_share_max_cut_pct"] = {
        r["test"]: r["max_cut_pct"] for r in shares if sizes[r["test"]] > ACTS_UM
    }
    row["verdict"] = verdict(row, sizes, get_effect(expected).predictable)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument(
        "--epochs", type=int, default=20,
        help="one-step epochs of each fit (20 for speed; the study's 100 leave the round-0 "
        "network holding more of creep and the second mode: see experiments/README.md)",
    )
    parser.add_argument("--horizon", type=int, default=200)
    parser.add_argument("--simulation-epochs", type=int, default=5)
    parser.add_argument("--train-sines", default=TRAIN_SINES, help="Hydra list, or [] for none")
    parser.add_argument("--effect-path", default="network", choices=["network", "linear"],
                        help="how effect operators enter the network (model.effect_path)")
    parser.add_argument("--significance", default="pooled", choices=list(TESTS),
                        help="how the diagnosis tests significance (loop.significance)")
    parser.add_argument("--root", type=Path, default=Path("outputs/undeclared"))
    parser.add_argument(
        "--resume", action="store_true",
        help="reuse the fits a stopped run finished under --root (their seconds are then not "
        "training times); by default every fit trains, so the figures come from this code",
    )
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for name in args.cases:
        row = run_case(name, args)
        log.info("%s", json.dumps(row, indent=1))


if __name__ == "__main__":
    main()
