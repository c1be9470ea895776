"""Checks of a finished ``hysteresis-lab-loop`` run against what only a simulator knows.

- `ceiling`: how much of a round's free-run error is an undeclared simulator effect's own
  output (the most a refit that models the effect could take off);
- `refit_choices`: whether held-out sines, like the tests but at other frequencies, would have
  chosen each round's refit the way its validation data did.

Both read the run folder the loop wrote (``.hydra/config.yaml``, ``loop_report.json``,
``round_<n>/``; a study runs its loop with `hysteresis_lab.cli.loop.run_fresh_loop`); the
studies in ``experiments/`` print their results. Nothing here runs a loop or a command.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import OmegaConf

from hysteresis_lab.data.factory import build_splits
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import ConfigError, DataError
from hysteresis_lab.evaluation.evaluate import scoring_start
from hysteresis_lab.evaluation.metrics import rmse
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.models.augment import for_model
from hysteresis_lab.models.io import load_model
from hysteresis_lab.run_folder import LoopFolder, RunFolder

log = logging.getLogger(__name__)

#: the fold whose fits `refit_choices` scores (the loop's fits of fold 0)
FIRST_FOLD = "fold_0"

#: effect RMS below this share of the residual RMS: the effect does not act there
NEGLIGIBLE = 0.01
#: check sines between the study's test frequencies (0.1 ... 500 Hz), apart from the training
#: sines of experiments/undeclared_effects.py
CHECK_FREQUENCIES = (0.2, 2.0, 20.0, 70.0, 120.0, 170.0, 220.0, 270.0, 340.0, 420.0, 470.0)


# ---------------------------------------------------------------------------- the run folder
def run_data_config(run: Path) -> dict[str, Any]:
    """The resolved ``data`` config of a hysteresis-lab-loop run folder."""
    config = Path(run) / ".hydra" / "config.yaml"
    if not config.is_file():
        raise DataError(
            f"not a hysteresis-lab-loop run folder (no {config})", source=str(run),
            fix="pass the folder a loop run wrote (its hydra.run.dir).",
        )
    return OmegaConf.to_container(OmegaConf.load(config), resolve=True)["data"]


def loop_rounds(run: Path) -> list[dict[str, Any]]:
    """The rounds of a finished loop run's ``loop_report.json``."""
    report = LoopFolder(run).report_json
    if not report.is_file():
        raise DataError("no loop_report.json: the loop did not finish", source=str(run),
                        fix="rerun the loop in this folder.")
    return json.loads(report.read_text())["rounds"]


def round_model(run: Path, number: int) -> Path:
    """The model a loop round kept: ``round_N/model.ckpt``, or the refit whose rate the loop
    chose (named in ``loop_report.json``)."""
    folder = LoopFolder(run).round_dir(number)
    kept = RunFolder(folder).model_file()
    if kept is not None:
        return kept
    rounds = loop_rounds(run)
    if not 0 <= number < len(rounds):
        raise ConfigError(f"{run} has rounds 0-{len(rounds) - 1}; round {number} is not one.")
    entry = rounds[number]
    several = len(entry.get("refit_candidates") or []) > 1
    path = RunFolder(LoopFolder.refit_dir(folder, entry.get("refit_lr"), several)).model_file()
    if path is None:
        raise DataError(f"no saved model for round {number}", source=str(folder))
    return path


# ---------------------------------------------------------------------------- scoring
def free_run_rmse(model: Any, recordings: list[Recording], n_init: int) -> dict[str, float]:
    """Free-run RMSE per recording, scored from `scoring_start` as the tests are."""
    predictions = free_run(model, for_model(model, recordings), model.window)
    skip = scoring_start(model.window, n_init)
    return {
        rec.name: rmse(rec.y[skip:], p[skip:])
        for rec, p in zip(recordings, predictions, strict=True)
    }


# ---------------------------------------------------------------------------- effect ceiling
def _quiet_outputs(data_cfg: dict[str, Any], block: str, enabled: bool) -> DatasetSplits:
    """The run's simulated data without noise or quantisation, ``block`` switched as given."""
    quiet = {"noise": {"enabled": False}, "quantisation": {"enabled": False}}
    effects = {
        **data_cfg["effects"],
        **quiet,
        block: {**data_cfg["effects"][block], "enabled": enabled},
    }
    return build_splits(
        {**data_cfg, "effects": effects, "splits": {**data_cfg["splits"], "effects": effects}}
    )


def effect_contribution(
    data_cfg: dict[str, Any], block: str, role: str = "test"
) -> dict[str, np.ndarray]:
    """Noise-free output with simulator ``block`` on minus with it off, per recording of
    ``role`` (``"test"``, or ``"diagnosis"``: those the loop diagnoses, `diagnosis_recordings`)."""
    pick = (lambda s: s.test) if role == "test" else (
        lambda s: diagnosis_recordings(s, data_cfg))
    on = {r.name: r.y[:, 0] for r in pick(_quiet_outputs(data_cfg, block, True))}
    off = {r.name: r.y[:, 0] for r in pick(_quiet_outputs(data_cfg, block, False))}
    return {name: on[name] - off[name] for name in on}


def diagnosis_recordings(splits: DatasetSplits, data_cfg: dict[str, Any]) -> list[Recording]:
    """The whole recordings a loop run diagnoses (``data.diagnose``, else the validation
    recordings); a loop without validation recordings diagnoses held-out stretches, which
    this check does not rebuild."""
    named = list(data_cfg.get("diagnose") or [])
    chosen = [r for r in [*splits.val, *splits.test] if r.name in named]
    if named or splits.val:
        return chosen or list(splits.val)
    raise ConfigError("the run diagnoses held-out stretches of its training recordings: give "
                      "it validation recordings (the simulator's data.splits.val_samples > 0).")


def effect_share(run: Path, block: str, number: int) -> dict[str, float]:
    """Per diagnosis recording of a loop run on the simulator: the share of round
    ``number``'s de-meaned free-run residual variance that ``block``'s own contribution
    explains (its squared correlation with the residual), scored from `scoring_start`. What
    the diagnosis could find of the effect at most, with no lags."""
    data_cfg = run_data_config(run)
    splits = build_splits(data_cfg)
    recordings = diagnosis_recordings(splits, data_cfg)
    model = load_model(round_model(run, number))
    predictions = free_run(model, for_model(model, recordings), model.window)
    contribution = effect_contribution(data_cfg, block, role="diagnosis")
    skip = scoring_start(model.window, splits.n_init)
    shares = {}
    for rec, prediction in zip(recordings, predictions, strict=True):
        e = (rec.y - prediction)[skip:, 0]
        d = contribution[rec.name][skip:]
        e, d = e - e.mean(), d - d.mean()
        norm = float((e @ e) * (d @ d))
        shares[rec.name] = float((e @ d) ** 2 / norm) if norm > 0 else 0.0
    return shares


def _ceiling_row(rec: Recording, prediction: np.ndarray, whole: np.ndarray, skip: int) -> dict:
    """One test's free-run RMSE, the effect's size and its share of the residual."""
    e = (rec.y - prediction)[skip:, 0]
    d = whole[skip:]
    e, d = e - e.mean(), d - d.mean()
    norm = float(np.sqrt((e @ e) * (d @ d)))
    # an effect below 1 % of the error does not act there: its correlation would be chance
    acts = norm > 0 and np.std(d) > NEGLIGIBLE * np.std(e)
    corr = float(e @ d) / norm if acts else float("nan")
    return {
        "test": rec.name,
        "rmse_free_run": rmse(rec.y[skip:], prediction[skip:]),
        "effect_rms": float(np.sqrt(np.mean(d**2))),
        # RMS over the whole recording, not de-meaned: where the effect acts (> 0.05 um)
        "effect_size_um": float(np.sqrt(np.mean(whole**2))),
        "corr": corr,
        "max_cut_pct": float(100 * (1 - np.sqrt(1 - corr**2))),
    }


def ceiling(
    run: Path, block: str, number: int, clip_input: float | None = None
) -> list[dict[str, float | str]]:
    """Per test recording of a loop run on the simulator: round ``number``'s free-run RMSE,
    the RMS of ``block``'s own contribution ``d`` and the correlation of the de-meaned residual
    with ``d``; subtracting the best multiple of ``d`` would cut the RMSE by ``max_cut_pct``.
    With ``clip_input`` (volts) also the free-run RMSE on test inputs clipped at ±clip_input.
    """
    data_cfg = run_data_config(run)
    if block not in data_cfg["effects"]:
        raise ConfigError(f"unknown simulator block '{block}': one of {list(data_cfg['effects'])}")
    splits = build_splits(data_cfg)
    model = load_model(round_model(run, number))
    predictions = free_run(model, for_model(model, splits.test), model.window)
    contribution = effect_contribution(data_cfg, block)
    skip = scoring_start(model.window, splits.n_init)
    rows = [
        _ceiling_row(rec, prediction, contribution[rec.name], skip)
        for rec, prediction in zip(splits.test, predictions, strict=True)
    ]
    if clip_input is not None:
        clipped = [
            dataclasses.replace(r, u=np.clip(r.u, -clip_input, clip_input)) for r in splits.test
        ]
        clipped_rmse = free_run_rmse(model, clipped, splits.n_init)
        for row in rows:
            row["rmse_clipped_input"] = clipped_rmse[row["test"]]
    return rows


# ---------------------------------------------------------------------------- refit choice
def check_splits(data_cfg: dict[str, Any], frequencies: list[float]) -> DatasetSplits:
    """The run's simulator, its test sines replaced by sines at ``frequencies``."""
    splits_cfg = data_cfg.get("splits") or {}
    if not str(splits_cfg.get("_target_", "")).endswith("make_default_dataset"):
        raise ConfigError(
            "the refit-choice check needs a loop run on the simulator (data=default): measured "
            "data have no extra recordings to check against."
        )
    used = {float(f) for key in ("train_sines", "val_sines") for f in splits_cfg.get(key) or []}
    clash = sorted(used & set(frequencies))
    if clash:
        raise ConfigError(
            f"{clash} Hz are training or validation sines of this run. Fix: check frequencies "
            "without them."
        )
    splits_cfg = {**splits_cfg, "test_frequencies": frequencies, "test_hold_s": 0}
    return build_splits({**data_cfg, "splits": splits_cfg})


def round_candidates(run: Path, number: int, entry: dict[str, Any]) -> list[dict[str, Any]]:
    """Every refit a round ran: its rate, validation loss, weights and whether it was kept.

    Each rate is read as the loop's first fold fitted it (``<rate folder>/fold_0``): its
    folder holds the refit as ``model.ckpt`` when it beat its start, else the start there and
    the refit as ``rejected_refit_model.ckpt``."""
    if "refit_candidates" not in entry:
        raise ConfigError(
            f"round {number} is no warm-started refit (e.g. the SVM refits from scratch): "
            "there is no refit choice to check."
        )
    losses = {c["refit_lr"]: c["validation_loss"] for c in entry["refit_candidates"]}
    folder = LoopFolder(run).round_dir(number)
    candidates = []
    for rate, loss in losses.items():
        rate_folder = RunFolder(
            LoopFolder.refit_dir(folder, rate, several=len(losses) > 1) / FIRST_FOLD)
        rejected = rate_folder.rejected_refit_model_file()
        candidates.append({
            "refit_lr": rate,
            "validation_loss": loss,
            "kept": rate == entry["refit_lr"] and not entry.get("rejected"),
            "model": rejected if rejected is not None else rate_folder.model_file(),
        })
    return candidates


def _score_candidates(candidates: list[dict[str, Any]], check: DatasetSplits) -> None:
    """Add each candidate's free-run RMSE per check sine and their mean."""
    for candidate in candidates:
        model = load_model(candidate["model"])
        candidate["check_rmse"] = free_run_rmse(model, check.test, check.n_init)
        candidate["check_mean"] = float(np.mean(list(candidate["check_rmse"].values())))


def refit_choices(run: Path, frequencies: list[float]) -> list[dict[str, Any]]:
    """Per refit round: the start (``refit_lr`` None) and every refit, scored on check sines
    at ``frequencies``; ``loop_keeps`` and ``check_prefers`` name the chosen rate."""
    run = Path(run)
    data_cfg = run_data_config(run)  # says plainly when the folder is no loop run at all
    rounds = loop_rounds(run)
    check = check_splits(data_cfg, frequencies)
    standing = RunFolder(LoopFolder(run).round_dir(0) / FIRST_FOLD).model_file()
    results = []
    for number, entry in enumerate(rounds[1:], start=1):
        candidates = round_candidates(run, number, entry)
        start = {"refit_lr": None, "validation_loss": float("nan"),
                 "kept": bool(entry.get("rejected")), "model": standing}
        everything = [start, *candidates]
        _score_candidates(everything, check)
        results.append({
            "round": number,
            "effects": entry["effects"],
            "candidates": everything,
            "loop_keeps": next(c["refit_lr"] for c in everything if c["kept"]),
            "check_prefers": min(everything, key=lambda c: c["check_mean"])["refit_lr"],
        })
        if not entry.get("rejected"):
            standing = next(c["model"] for c in candidates if c["kept"])
    log.info("scored %d refit round(s) of %s on %d check sines", len(results), run,
             len(frequencies))
    return results

