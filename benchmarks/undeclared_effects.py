"""Undeclared-effect check of the closed loop on the simulator (issue: the closed loop).

    python benchmarks/undeclared_effects.py                       # all cases
    python benchmarks/undeclared_effects.py --cases creep --epochs 100

For each case the simulator switches one effect on that the model does not declare, while
the model declares the other effects present (the first bending mode, always on, counts as
"resonance"); `hysteresis-lab-loop` runs one round (fit, diagnose, add the top significant
effect, refit). Reported per case: the top-ranked effect, whether it is significant and the
expected one, and the free-run RMSE per test recording before and after.

The identification data is the study's multisine plus full-amplitude sines between the test
frequencies (``--train-sines``; the multisine alone never drives the full-amplitude loops of
the test sines, so a model trained on it mostly shows its own extrapolation error), and the
networks are fine-tuned on their free-run error (``--rollout-steps``).
"""

from __future__ import annotations

import argparse
import json
import logging
import subprocess
import time
from pathlib import Path

log = logging.getLogger("undeclared_effects")

#: case -> (simulator overrides, effects the model declares, catalogue effect expected)
CASES: dict[str, tuple[list[str], list[str], str]] = {
    "creep": ([], ["hysteresis", "resonance"], "creep"),
    "mode2": (["data.effects.mode2.enabled=true"], ["hysteresis", "creep"], "resonance"),
    "drift": (["data.effects.drift.enabled=true"], ["hysteresis", "creep", "resonance"], "drift"),
    "saturation": (["data.effects.saturation.enabled=true"],
                   ["hysteresis", "creep", "resonance"], "saturation"),
}
TRAIN_SINES = "[0.3,3,30,75,125,175,225,275,350,425,475]"


def run_case(name: str, args: argparse.Namespace) -> dict:
    overrides, declared, expected = CASES[name]
    out = args.root / name
    command = [
        "hysteresis-lab-loop", "model=ffnn", f"model.effects=[{','.join(declared)}]",
        "loop.max_rounds=1", f"trainer.max_epochs={args.epochs}",
        f"model.rollout_steps={args.rollout_steps}", f"model.rollout_epochs={args.rollout_epochs}",
        f"data.splits.train_sines={args.train_sines}", "trainer.enable_progress_bar=false",
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
        row["change_pct"] = {
            test: 100 * (after["tests"][test]["rmse_free_run"] / m["rmse_free_run"] - 1)
            for test, m in first["tests"].items()
        }
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--rollout-steps", type=int, default=200)
    parser.add_argument("--rollout-epochs", type=int, default=5)
    parser.add_argument("--train-sines", default=TRAIN_SINES, help="Hydra list, or [] for none")
    parser.add_argument("--root", type=Path, default=Path("outputs/undeclared"))
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for name in args.cases:
        row = run_case(name, args)
        log.info("%s", json.dumps(row, indent=1))


if __name__ == "__main__":
    main()
