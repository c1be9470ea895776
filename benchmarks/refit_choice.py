"""Would held-out sines have chosen the loop's refits the way its validation data did?

    python benchmarks/refit_choice.py outputs/loop/ffnn_default/<run>
    python benchmarks/refit_choice.py <run> --frequencies 0.2 2 20 200

A loop round keeps a refit only if it beats its start on the validation free-run loss (held-out
segments of the training data), at the rate whose loss is lowest. This script checks those
choices against signals like the tests: full-amplitude sines at frequencies that are neither
test nor training frequencies, simulated with the run's own simulator settings and scored in
free run over the whole recording. Per refit round it scores the start (the model that stood
before the round) and every rate's refit — also those the loop rejected
(``rejected_refit_model.ckpt``) — and says which one the check sines prefer. Simulator runs
only: measured data have no such extra recordings.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
from effect_ceiling import free_run_rmse, run_data_config  # the script beside this one

from hysteresis_lab.analysis.loop import refit_dir
from hysteresis_lab.data.factory import build_splits
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.models.io import load_model
from hysteresis_lab.pipeline import REJECTED_REFIT_MODEL

log = logging.getLogger("refit_choice")

#: between the study's test frequencies (0.1 ... 500 Hz) and apart from the training sines
#: of benchmarks/undeclared_effects.py
CHECK_FREQUENCIES = (0.2, 2.0, 20.0, 70.0, 120.0, 170.0, 220.0, 270.0, 340.0, 420.0, 470.0)


def check_splits(data_cfg: dict[str, Any], frequencies: list[float]) -> DatasetSplits:
    """The run's simulator, its test sines replaced by sines at ``frequencies``."""
    splits_cfg = data_cfg.get("splits") or {}
    if not str(splits_cfg.get("_target_", "")).endswith("make_default_dataset"):
        raise SystemExit(
            "refit_choice needs a loop run on the simulator (data=default): measured data have "
            "no extra recordings to check against."
        )
    used = {float(f) for f in splits_cfg.get("train_sines") or []}
    clash = sorted(used & set(frequencies))
    if clash:
        raise SystemExit(
            f"{clash} Hz are training sines of this run. Fix: --frequencies without them."
        )
    splits_cfg = {**splits_cfg, "test_frequencies": frequencies, "test_hold_s": 0}
    return build_splits({**data_cfg, "splits": splits_cfg})


def round_candidates(run: Path, number: int, entry: dict[str, Any]) -> list[dict[str, Any]]:
    """Every refit a round ran: its rate, validation loss, weights and whether it was kept.

    A rate's folder holds the refit as ``model.ckpt`` when it beat its start, else the start
    there and the refit as ``rejected_refit_model.ckpt``."""
    if "refit_candidates" not in entry:
        raise SystemExit(
            f"round {number} is no warm-started refit (e.g. the SVM refits from scratch): "
            "there is no refit choice to check."
        )
    losses = {c["refit_lr"]: c["validation_loss"] for c in entry["refit_candidates"]}
    start_loss = entry["refit_validation_loss"]["start"]
    folder = run / f"round_{number}"
    candidates = []
    for rate, loss in losses.items():
        rate_folder = refit_dir(folder, rate, several=len(losses) > 1)
        rejected = rate_folder / f"{REJECTED_REFIT_MODEL}.ckpt"
        if not rejected.exists() and not loss < start_loss:
            raise SystemExit(
                f"the refit at lr {rate:g} in {rate_folder} lost to its start and its weights "
                "were not saved (a run from before they were): rerun the loop."
            )
        candidates.append({
            "refit_lr": rate,
            "validation_loss": loss,
            "kept": rate == entry["refit_lr"] and not entry.get("rejected"),
            "model": rejected if rejected.exists() else rate_folder / "model.ckpt",
        })
    return candidates


def refit_choices(run: Path, frequencies: list[float]) -> list[dict[str, Any]]:
    """Per refit round: the start and every refit, scored on the check sines."""
    report = run / "loop_report.json"
    data_cfg = run_data_config(run)  # says plainly when the folder is no loop run at all
    if not report.is_file():
        raise SystemExit(f"{run} has no loop_report.json: the loop did not finish. Rerun it.")
    check = check_splits(data_cfg, frequencies)
    rounds = json.loads(report.read_text())["rounds"]
    standing = run / "round_0" / "model.ckpt"
    results = []
    for number, entry in enumerate(rounds[1:], start=1):
        candidates = round_candidates(run, number, entry)
        start = {"refit_lr": None, "validation_loss": entry["refit_validation_loss"]["start"],
                 "kept": bool(entry.get("rejected")), "model": standing}
        everything = [start, *candidates]
        for candidate in everything:
            model = load_model(candidate["model"])
            candidate["check_rmse"] = free_run_rmse(model, check.test, check.n_init)
            candidate["check_mean"] = float(np.mean(list(candidate["check_rmse"].values())))
        results.append({
            "round": number,
            "effects": entry["effects"],
            "candidates": everything,
            "loop_keeps": next(c["refit_lr"] for c in everything if c["kept"]),
            "check_prefers": min(everything, key=lambda c: c["check_mean"])["refit_lr"],
        })
        if not entry.get("rejected"):
            standing = next(c["model"] for c in candidates if c["kept"])
    return results


def _name(rate: float | None) -> str:
    return "start" if rate is None else f"refit lr {rate:.0e}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished hysteresis-lab-loop run folder")
    parser.add_argument("--frequencies", type=float, nargs="+", default=list(CHECK_FREQUENCIES))
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    results = refit_choices(args.run, args.frequencies)
    for result in results:
        log.info("round %d, effects %s:", result["round"], result["effects"])
        for c in result["candidates"]:
            sines = " ".join(f"{v:.3f}" for v in c["check_rmse"].values())
            log.info("  %-14s validation %.3e  check mean %.4f  [%s]%s", _name(c["refit_lr"]),
                     c["validation_loss"], c["check_mean"], sines, "  <- loop" if c["kept"] else "")
        agree = "agree" if result["loop_keeps"] == result["check_prefers"] else "DISAGREE"
        log.info("  check sines prefer %s: %s", _name(result["check_prefers"]), agree)
    (args.run / "refit_choice.json").write_text(json.dumps(results, indent=1, default=str))


if __name__ == "__main__":
    main()
