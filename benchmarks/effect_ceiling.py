"""How much of a fitted model's free-run error is an undeclared simulator effect's own output?

    python benchmarks/effect_ceiling.py outputs/undeclared/drift --block drift
    python benchmarks/effect_ceiling.py outputs/undeclared/saturation --block saturation \
        --clip-input 90

The ceiling of the closed loop on one undeclared-effect case (``benchmarks/undeclared_effects.py``
writes the run folders). The run's own Hydra config rebuilds its test recordings; the effect's
contribution ``d`` is the noise-free output with ``--block`` switched on minus the same with it
off. For every test recording the script reports the model's free-run RMSE, the RMS of ``d`` and
the correlation of the de-meaned residual ``e`` with ``d``: subtracting the best multiple of the
true contribution would cut the RMSE by ``1 - sqrt(1 - corr²)``, the part of the error that is
the effect as it reaches the output (a refit beats that figure only by also changing the rest of
the model's error; where ``d`` is below 1 % of ``e`` no share is given). ``--clip-input V`` also
runs the same model on the test inputs clipped at +-V: for amplifier clipping, the free-run RMSE
that the exact clipping block ahead of the fitted network would give.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import OmegaConf

from hysteresis_lab.analysis.loop import refit_dir
from hysteresis_lab.data.factory import build_splits
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.augment import for_model
from hysteresis_lab.evaluation.evaluate import scoring_start
from hysteresis_lab.evaluation.metrics import rmse
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.models.io import load_model

log = logging.getLogger("effect_ceiling")
NEGLIGIBLE = 0.01  # effect RMS below this share of the residual RMS: no share reported


def round_model(run: Path, number: int) -> Path:
    """The model a loop round kept: ``round_N/model.ckpt``, or the refit whose rate the loop
    chose (named in ``loop_report.json``)."""
    folder = run / f"round_{number}"
    if (folder / "model.ckpt").exists():
        return folder / "model.ckpt"
    rounds = json.loads((run / "loop_report.json").read_text())["rounds"]
    if not 0 <= number < len(rounds):
        raise SystemExit(f"{run} has rounds 0-{len(rounds) - 1}; --round {number} is not one.")
    entry = rounds[number]
    several = len(entry.get("refit_candidates") or []) > 1
    path = refit_dir(folder, entry.get("refit_lr"), several) / "model.ckpt"
    if not path.exists():
        raise SystemExit(f"no model.ckpt for round {number} under {folder}")
    return path


def effect_contribution(data_cfg: dict[str, Any], block: str) -> dict[str, np.ndarray]:
    """Noise-free output with ``block`` on minus with it off, per test recording."""
    quiet = {"noise": {"enabled": False}, "quantisation": {"enabled": False}}

    def outputs(enabled: bool) -> dict[str, np.ndarray]:
        effects = {
            **data_cfg["effects"],
            **quiet,
            block: {**data_cfg["effects"][block], "enabled": enabled},
        }
        splits = build_splits(
            {**data_cfg, "effects": effects, "splits": {**data_cfg["splits"], "effects": effects}}
        )
        return {r.name: r.y[:, 0] for r in splits.test}

    on, off = outputs(True), outputs(False)
    return {name: on[name] - off[name] for name in on}


def run_data_config(run: Path) -> dict[str, Any]:
    """The ``data`` config of a hysteresis-lab-loop run folder."""
    config = run / ".hydra" / "config.yaml"
    if not config.is_file():
        raise SystemExit(
            f"{run} is not a hysteresis-lab-loop run folder (no {config}). Fix: pass the folder "
            "a loop run wrote, e.g. outputs/undeclared/drift from benchmarks/undeclared_effects.py."
        )
    return OmegaConf.to_container(OmegaConf.load(config), resolve=True)["data"]


def free_run_rmse(model: Any, recordings: list[Recording], n_init: int) -> dict[str, float]:
    """Free-run RMSE per recording, scored from `scoring_start` as the tests are."""
    predictions = free_run(model, for_model(model, recordings), model.window)
    skip = scoring_start(model.window, n_init)
    return {
        rec.name: rmse(rec.y[skip:], p[skip:])
        for rec, p in zip(recordings, predictions, strict=True)
    }


def ceiling(
    run: Path, block: str, number: int, clip_input: float | None = None
) -> list[dict[str, float | str]]:
    """Per test recording: the model's free-run error and the effect's share of it."""
    data_cfg = run_data_config(run)
    if block not in data_cfg["effects"]:
        raise SystemExit(f"unknown simulator block '{block}': one of {list(data_cfg['effects'])}")
    splits = build_splits(data_cfg)
    model = load_model(round_model(run, number))
    predictions = free_run(model, for_model(model, splits.test), model.window)
    clipped_rmse = {}
    if clip_input is not None:
        clipped = [
            dataclasses.replace(r, u=np.clip(r.u, -clip_input, clip_input)) for r in splits.test
        ]
        clipped_rmse = free_run_rmse(model, clipped, splits.n_init)
    contribution = effect_contribution(data_cfg, block)
    skip = scoring_start(model.window, splits.n_init)
    rows = []
    for rec, prediction in zip(splits.test, predictions, strict=True):
        e = (rec.y - prediction)[skip:, 0]
        whole = contribution[rec.name]
        d = whole[skip:]
        e, d = e - e.mean(), d - d.mean()
        norm = float(np.sqrt((e @ e) * (d @ d)))
        # an effect below 1 % of the error does not act there: its correlation would be chance
        acts = norm > 0 and np.std(d) > NEGLIGIBLE * np.std(e)
        corr = float(e @ d) / norm if acts else float("nan")
        row = {
            "test": rec.name,
            "rmse_free_run": rmse(rec.y[skip:], prediction[skip:]),
            "effect_rms": float(np.sqrt(np.mean(d**2))),
            # RMS over the whole recording, not de-meaned: where the effect acts (> 0.05 um)
            "effect_size_um": float(np.sqrt(np.mean(whole**2))),
            "corr": corr,
            "max_cut_pct": float(100 * (1 - np.sqrt(1 - corr**2))),
        }
        if clip_input is not None:
            row["rmse_clipped_input"] = clipped_rmse[rec.name]
        rows.append(row)
    return rows


def _change(row: dict) -> float:
    return 100 * (row["rmse_clipped_input"] / row["rmse_free_run"] - 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a hysteresis-lab-loop run folder")
    parser.add_argument("--block", required=True, help="the simulator block left undeclared")
    parser.add_argument("--round", type=int, default=0, help="the loop round whose model to use")
    parser.add_argument(
        "--clip-input", type=float, default=None, help="volts: also run on inputs clipped here"
    )
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    rows = ceiling(args.run, args.block, args.round, args.clip_input)
    clipped = args.clip_input is not None
    log.info(
        "%-12s %9s %11s %6s %10s%s",
        "test",
        "RMSE [um]",
        "effect [um]",
        "corr",
        "max cut %",
        f" {'clipped input':>14s}" if clipped else "",
    )
    for row in rows:
        log.info(
            "%-12s %9.3f %11.3f %6.2f %10.1f%s",
            row["test"],
            row["rmse_free_run"],
            row["effect_rms"],
            row["corr"],
            row["max_cut_pct"],
            f" {row['rmse_clipped_input']:9.3f} ({_change(row):+.0f} %)" if clipped else "",
        )


if __name__ == "__main__":
    main()
