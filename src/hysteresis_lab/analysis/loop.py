"""The closed loop: fit -> residuals -> diagnose -> add the top significant effect -> refit.

Each round trains the model with the effects declared so far, scores it on the test
recordings in both modes, analyses the free-run residuals and ranks the effects the model
does not declare yet (`hysteresis_lab.analysis.diagnosis`). The top significant one is added
and the next round refits, until nothing significant remains or ``max_rounds`` effects are
added. A refit that does not beat the model it started from on validation is rejected: the
effect is dropped, the last model stands and the next significant effect is tried (a model
refitted from scratch, the SVM, meets the last kept one on its validation MSE).
With ``warm_start`` a refit starts from the previous round's network with the new effect's
input weights at zero (nested models: it begins exactly where the last round ended); with
``refit="new_inputs"`` (the default) it trains only those weights, so everything the last
round fitted stays exactly as it was and the before/after difference is what the added
effect brings, not the spread between two fits.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hysteresis_lab import fit_record
from hysteresis_lab.analysis.diagnosis import TESTS, EffectScore, diagnose, evidence_lags
from hysteresis_lab.analysis.excitation import operator_excitation
from hysteresis_lab.analysis.report import diagnostics_figure, residual_analysis
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.effects.augment import feature_context
from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.evaluate import scoring_start
from hysteresis_lab.evaluation.plots import loops_figure, save_figure
from hysteresis_lab.evaluation.report import write_json
from hysteresis_lab.models.base import NarxModule
from hysteresis_lab.models.registry import get_model_class
from hysteresis_lab.pipeline import (
    REJECTED_REFIT_METRICS,
    REJECTED_REFIT_MODEL,
    RunResult,
    train_and_evaluate,
)

log = logging.getLogger(__name__)

#: model settings only networks take
NETWORK_ONLY = ("effect_path", "refit_lr", "objective", "horizon", "simulation_epochs",
                "simulation_lr", "patience")

REFITS = ("new_inputs", "full")


@dataclass
class LoopSettings:
    """``loop.*`` config: rounds and the significance rule of the diagnosis."""

    max_rounds: int = 3
    min_score: float = 0.05
    alpha: float = 0.01
    #: how the diagnosis tests significance: "pooled" or "per_recording" (`diagnosis.TESTS`)
    significance: str = "pooled"
    warm_start: bool = True  # refit from the previous round's network (new inputs at zero)
    #: after a warm start: "new_inputs" trains only the added effect's input weights, "full" all
    refit: str = "new_inputs"
    #: share of the validation loss a refit must take off to be kept (0: any improvement)
    min_refit_gain: float = 0.0
    #: a refit runs at each of these multiples of ``model.lr`` and the one with the lowest
    #: validation free-run loss goes on to the keep-or-reject test (``model.refit_lr``, when
    #: set, is the only rate tried)
    refit_lr_factors: tuple[float, ...] = (0.1, 1.0)
    #: run again in the folder of a stopped loop (``hydra.run.dir``), each fit that finished
    #: there with the same settings, data and start is reused, not trained again
    resume: bool = True

    def __post_init__(self) -> None:
        self.refit_lr_factors = tuple(float(f) for f in self.refit_lr_factors)
        if not self.refit_lr_factors or min(self.refit_lr_factors) <= 0:
            raise ConfigError(
                f"loop.refit_lr_factors={list(self.refit_lr_factors)} must be a non-empty list "
                "of positive numbers. Fix: e.g. loop.refit_lr_factors=[0.1,1.0]."
            )
        if self.refit not in REFITS:
            raise ConfigError(
                f"unknown loop.refit '{self.refit}'. Fix: loop.refit=one of {list(REFITS)}."
            )
        if not 0.0 <= self.min_refit_gain < 1.0:
            raise ConfigError(
                f"loop.min_refit_gain={self.min_refit_gain} must lie in [0, 1). Fix: e.g. "
                "loop.min_refit_gain=0.02 (a refit must take 2 % off the validation loss)."
            )
        if not 0.0 < self.alpha < 1.0:
            raise ConfigError(
                f"loop.alpha={self.alpha} must lie in (0, 1): it is the significance level of "
                "the diagnosis. Fix: e.g. loop.alpha=0.01."
            )
        if not 0.0 <= self.min_score < 1.0:
            raise ConfigError(
                f"loop.min_score={self.min_score} must lie in [0, 1): it is a share of the "
                "residual variance. Fix: e.g. loop.min_score=0.05."
            )
        if self.significance not in TESTS:
            raise ConfigError(
                f"unknown loop.significance '{self.significance}'. Fix: loop.significance=one "
                f"of {list(TESTS)}."
            )
        if self.max_rounds < 0:
            raise ConfigError(f"loop.max_rounds={self.max_rounds} must be >= 0.")


def run_loop(
    model_cfg: Mapping[str, Any],
    data_cfg: Mapping[str, Any],
    trainer_cfg: Mapping[str, Any],
    splits: DatasetSplits,
    output_dir: Path,
    settings: LoopSettings,
    seed: int = 0,
    use_tensorboard: bool = True,
) -> dict[str, Any]:
    """Run the loop; write ``loop_report.json``, ``loop_report.md`` and figures."""
    model_cfg = _without_network_only_settings(model_cfg)
    effects = list(model_cfg.get("effects") or [])
    context = feature_context(splits.train)
    rounds: list[dict[str, Any]] = []
    kept: list[RunResult] = []  # the rounds whose model stands
    diagnosis: list[EffectScore] = []
    tried: set[str] = set()  # effects tried on the current model
    trying: str | None = None
    fit_model = functools.partial(
        train_and_evaluate,
        data_cfg=data_cfg,
        trainer_cfg=trainer_cfg,
        seed=seed,
        splits=splits,
        use_tensorboard=use_tensorboard,
        min_refit_gain=settings.min_refit_gain,
        reuse=settings.resume,
    )
    for number in itertools.count():
        round_effects = effects + ([trying] if trying else [])
        log.info("=== loop round %d: effects %s ===", number, round_effects or "none")
        warm_start = _previous_network(kept) if settings.warm_start else None
        result, round_dir, refit_lr, losses = _fit_round(
            fit_model,
            {**model_cfg, "effects": round_effects},
            output_dir / f"round_{number}",
            _refit_rates(model_cfg, settings) if warm_start is not None else [None],
            warm_start=warm_start,
            refit=_refit_mode(settings.refit, trying),
        )
        if trying is not None and warm_start is None:
            result = judge_cold_refit(result, kept[-1], settings.min_refit_gain)
            if not result.improved:
                _set_aside_rejected_files(result.rejected_refit)
        entry = _round_entry(round_effects, result)
        if refit_lr is not None:
            entry["refit_lr"] = refit_lr
            entry["refit_candidates"] = losses
        rounds.append(entry)
        if trying is not None and not result.improved:
            entry["rejected"] = trying
            entry["note"] = (
                f"the refit with '{trying}' did not beat the last model on validation: "
                f"'{trying}' dropped, the last model stands"
            )
        else:
            effects, tried = round_effects, set()
            kept.append(result)
            diagnosis = _diagnose_round(
                result, splits, context, effects, settings, round_dir, use_tensorboard, number
            )
            entry["diagnosis"] = [d.to_dict() for d in diagnosis]
        uncarried = _not_carried(model_cfg, diagnosis, tried)
        if uncarried:
            entry["not_carried"] = uncarried
            log.info("model '%s' has no block for the significant effect(s) %s: not added",
                     model_cfg.get("name"), uncarried)
        top, reported = next_effect(diagnosis, tried | set(uncarried))
        if reported:
            entry["reported"] = reported
        if top is None:
            entry.setdefault("note", "no significant missing effect" + (
                " that depends on the input" if reported else ""))
            break
        if len(kept) > settings.max_rounds:
            entry.setdefault(
                "note", f"loop.max_rounds={settings.max_rounds} reached; next: {top.effect}"
            )
            break
        entry["added"] = trying = top.effect
        tried.add(top.effect)
        excitation = operator_excitation(
            top.effect, [*splits.train, *splits.val], splits.test, context
        )
        entry["added_excitation"] = excitation.to_dict()
        log.info("'%s' added: %s", top.effect, excitation.reading())
    report = {
        "units": {"y": splits.test[0].y_units},
        "data": splits.name,
        "model": str(model_cfg.get("name")),
        "rounds": rounds,
    }
    write_json(report, output_dir / "loop_report.json")
    (output_dir / "loop_report.md").write_text(loop_markdown(report))
    before, after = kept[0], kept[-1]
    predictions = {
        rec.name: {
            "before": before.evaluation.predictions[rec.name]["free_run"],
            "after": after.evaluation.predictions[rec.name]["free_run"],
        }
        for rec in splits.test
    }
    save_figure(
        loops_figure(
            splits.test,
            predictions,
            title=f"free run before ({rounds[0]['effects'] or 'no effects'}) and "
            f"after ({effects})",
        ),
        output_dir / "loops_before_after.png",
    )
    log.info("\n%s", loop_markdown(report))
    return report


def next_effect(
    diagnosis: Sequence[EffectScore], tried: set[str]
) -> tuple[EffectScore | None, list[str]]:
    """The significant effect to add next (best first, not yet tried on this model) and the
    significant ones that do not depend on the input: free run cannot predict those, so
    they are reported, never added, and the loop goes on with the next."""
    candidates = [d for d in diagnosis if d.significant and d.effect not in tried]
    reported = [d.effect for d in candidates if not d.predictable]
    return next((d for d in candidates if d.predictable), None), reported


def _not_carried(
    model_cfg: Mapping[str, Any], diagnosis: Sequence[EffectScore], tried: set[str]
) -> list[str]:
    """Significant, input-driven effects the start model's class cannot take (a grey-box
    carries only the effects it has physical blocks for)."""
    carried = getattr(get_model_class(str(model_cfg.get("name"))), "carried_effects", None)
    if carried is None:
        return []
    return [d.effect for d in diagnosis
            if d.significant and d.predictable and d.effect not in tried
            and d.effect not in carried]


def judge_cold_refit(refit: RunResult, last: RunResult, min_gain: float) -> RunResult:
    """Keep a refit trained from scratch (the SVM, or ``loop.warm_start=false``) only when its
    validation MSE beats the last kept model's by more than the share ``min_gain``; otherwise
    the last model stands, with the refit's scores kept as what it would have done (as a
    warm-started refit that lost to its start is reported)."""
    losses = {"start": last.val_mse, "refit": refit.val_mse}
    if refit.val_mse < (1.0 - min_gain) * last.val_mse:
        return dataclasses.replace(refit, refit_validation=losses)
    log.info(
        "refit did not beat the last model on validation (%.4e vs %.4e, scaled): kept that model",
        refit.val_mse,
        last.val_mse,
    )
    return dataclasses.replace(
        last, improved=False, refit_validation=losses, rejected_refit=refit.document
    )


def _set_aside_rejected_files(document: dict[str, Any]) -> None:
    """A rejected refit trained from scratch leaves its model and metrics under the names a
    rejected warm-started refit uses, so a round folder's ``model.*`` is always a model that
    stands (the one it lost to is the last kept round's)."""
    model_path = Path(document["model_path"])
    fit_record.forget(model_path.parent)  # its files move: a resumed loop refits it
    aside = model_path.with_name(REJECTED_REFIT_MODEL + model_path.suffix)
    model_path.replace(aside)
    (model_path.parent / "metrics.json").replace(model_path.parent / REJECTED_REFIT_METRICS)
    document["model_path"] = str(aside)


def _without_network_only_settings(model_cfg: Mapping[str, Any]) -> dict[str, Any]:
    """Free-run fine-tuning (on by default in the loop), ``effect_path`` and ``refit_lr`` are
    network settings; a model that is no network (the SVM) skips them."""
    cfg = dict(model_cfg)
    network_only = [k for k in cfg if k in NETWORK_ONLY]
    if network_only and not issubclass(get_model_class(str(cfg.get("name"))), NarxModule):
        log.info("model '%s' is no network: %s ignored", cfg.get("name"), network_only)
        cfg = {k: v for k, v in cfg.items() if k not in network_only}
    return cfg


def _round_entry(effects: list[str], result: RunResult) -> dict[str, Any]:
    """A round of ``loop_report.json``: its effects and errors (diagnosis and decision follow).
    A refit that lost to its start adds ``rejected_refit``: what it would have scored."""
    entry: dict[str, Any] = {"effects": list(effects), **_scores(result.document)}
    entry.update(diagnosis=[], added=None)
    if result.refit_validation is not None:
        entry["refit_validation_loss"] = result.refit_validation
    if result.rejected_refit is not None:
        entry["rejected_refit"] = _scores(result.rejected_refit)
    return entry


def _scores(document: Mapping[str, Any]) -> dict[str, Any]:
    """Per-test and mean errors of a metrics document, as the report shows them."""
    tests = {
        name: {k: m[k] for k in ("rmse_free_run", "rmse_one_step", "r2_free_run")}
        for name, m in document["tests"].items()
    }
    return {
        "tests": tests,
        "mean_rmse_free_run": document["mean"]["rmse_free_run"],
        "mean_rmse_one_step": document["mean"]["rmse_one_step"],
    }


def _diagnose_round(
    result: RunResult,
    splits: DatasetSplits,
    context: FeatureContext,
    effects: list[str],
    settings: LoopSettings,
    round_dir: Path,
    use_tensorboard: bool,
    number: int,
) -> list[EffectScore]:
    """Residual analysis (JSON, figure, TensorBoard) and the ranked diagnosis of a round."""
    n_skip = scoring_start(result.window, splits.n_init)
    residuals = []
    for rec in splits.test:
        e = rec.y - result.evaluation.predictions[rec.name]["free_run"]
        e[:n_skip] = np.nan
        residuals.append(e)
    diagnosis = diagnose(
        splits.test,
        residuals,
        context,
        declared=effects,
        min_score=settings.min_score,
        alpha=settings.alpha,
        lags=evidence_lags(result.window.nb),
        test=settings.significance,
    )
    write_json(
        residual_analysis(splits.test, result.evaluation.predictions, n_skip),
        round_dir / "residual_analysis.json",
    )
    figure = diagnostics_figure(splits.test, result.evaluation.predictions, n_skip)
    save_figure(figure, round_dir / "residual_diagnostics.png")
    if use_tensorboard:
        _log_round_to_tensorboard(round_dir / "tensorboard", figure, diagnosis, number)
    return diagnosis


def _fit_round(
    fit_model: Callable[..., RunResult],
    model_cfg: dict[str, Any],
    round_dir: Path,
    rates: list[float] | list[None],
    **fit_options: Any,
) -> tuple[RunResult, Path, float | None, list[dict[str, float]]]:
    """Fit a round's model with ``fit_model`` (`train_and_evaluate` bound to the loop's data
    and settings) once per refit learning rate in ``rates`` (``[None]``: no refit, one fit),
    each in its own folder when there are several; the one with the lowest validation loss
    is returned with its folder, its rate and every rate's loss (the test recordings play no
    part in the choice)."""
    runs = []
    for rate in rates:
        run_dir = refit_dir(round_dir, rate, several=len(rates) > 1)
        refit_lr = {"refit_lr": rate} if rate is not None else {}
        result = fit_model(model_cfg={**model_cfg, **refit_lr}, output_dir=run_dir, **fit_options)
        runs.append((result, run_dir, rate))
    result, run_dir, rate = min(runs, key=lambda run: _refit_loss(run[0]))
    losses = [
        {"refit_lr": r, "validation_loss": _refit_loss(res)} for res, _, r in runs if r is not None
    ]
    return result, run_dir, rate, losses


def refit_dir(round_dir: Path, rate: float | None, several: bool) -> Path:
    """Where a round's fit at ``rate`` lands: its own ``refit_lr_<rate>`` folder when the round
    tried ``several`` rates, else the round's folder."""
    return round_dir / f"refit_lr_{rate:.3g}" if several else round_dir


def _refit_rates(model_cfg: Mapping[str, Any], settings: LoopSettings) -> list[float]:
    """The learning rates a refit runs at: ``model.refit_lr`` if set, else the loop's
    multiples of ``model.lr``."""
    if model_cfg.get("refit_lr") is not None:
        return [float(model_cfg["refit_lr"])]
    lr = float(model_cfg.get("lr", 1e-3))
    return [factor * lr for factor in settings.refit_lr_factors]


def _refit_loss(result: RunResult) -> float:
    """The validation loss a refit reached (its own weights, kept or not)."""
    loss = result.refit_validation
    return float(loss["refit"]) if loss else float("inf")


def _refit_mode(refit: str, added: str | None) -> str:
    """``refit``, except for an effect that enters through the input block: it changes what
    the fitted network sees (the corrected input), so the network refits with it."""
    if refit == "new_inputs" and added is not None and get_effect(added).block == "input":
        log.info("'%s' corrects the network's input: the whole network refits", added)
        return "full"
    return refit


def _previous_network(results: list[RunResult]) -> Any | None:
    """The last round's fitted network to start the refit from (None: first round, or SVM)."""
    if not results or not hasattr(results[-1].model, "warm_start_from"):
        return None
    return results[-1].model


def _log_round_to_tensorboard(
    log_dir: Path, figure: Any, diagnosis: list[Any], number: int
) -> None:
    """Residual diagnostics figure and every tested effect's score, beside the round's
    training logs."""
    from torch.utils.tensorboard import SummaryWriter

    with SummaryWriter(log_dir=str(log_dir)) as writer:
        writer.add_figure("loop/residual_diagnostics", figure, global_step=number, close=False)
        for d in (d for d in diagnosis if d.tested):
            writer.add_scalar(f"loop/diagnosis_score/{d.effect}", d.score, global_step=number)


def loop_markdown(report: dict[str, Any]) -> str:
    """Readable report: per round the effects, errors per test and the ranked diagnosis."""
    unit = report["units"]["y"]
    rounds = report["rounds"]
    tests = list(rounds[0]["tests"])
    lines = [
        f"# Residual loop: {report['model']} on {report['data']}",
        "",
        f"Free-run RMSE [{unit}] per test recording and round (effects declared):",
        "",
    ]
    header = ["test"] + [f"round {i}: {r['effects'] or '[]'}" for i, r in enumerate(rounds)]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for name in tests:
        cells = [name] + [f"{r['tests'][name]['rmse_free_run']:.4g}" for r in rounds]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append(
        "| **mean** | " + " | ".join(f"{r['mean_rmse_free_run']:.4g}" for r in rounds) + " |"
    )
    if len(rounds) > 1:
        first, last = rounds[0]["mean_rmse_free_run"], rounds[-1]["mean_rmse_free_run"]
        change = _change(first, last)
        lines += ["", f"Mean free-run RMSE {first:.4g} -> {last:.4g} {unit} ({change})."]
    for i, r in enumerate(rounds):
        if r.get("rejected"):
            lines += ["", f"## Round {i}: {r['rejected']} rejected", "", f"- {r['note']}"]
            lines += _refit_rate_lines(r) + _rejected_refit_lines(r, unit)
            lines.append(f"- next: {r['added']}" if r["added"] else "- nothing else to try")
            lines += _excitation_lines(r)
            continue
        lines += ["", f"## Round {i}: diagnosis", ""] + _refit_rate_lines(r)
        lines += [_diagnosis_line(d) for d in r["diagnosis"]]
        if r.get("reported"):
            lines.append(
                f"- reported, not added: {', '.join(r['reported'])} (does not depend on the "
                "input: free run cannot predict it; no gain is claimed)"
            )
        lines.append(f"- added: {r['added']}" + (f" ({r['note']})" if r.get("note") else ""))
        lines += _excitation_lines(r)
    return "\n".join(lines) + "\n"


def _excitation_lines(entry: Mapping[str, Any]) -> list[str]:
    """How hard the tests drive the added effect's operators beyond the identification data."""
    excitation = entry.get("added_excitation")
    return [f"  - {excitation['reading']}"] if excitation else []


def _diagnosis_line(d: Mapping[str, Any]) -> str:
    """One effect of a round's diagnosis: its score and p-value, or why it was not tested."""
    if not d["tested"]:
        return f"- {d['effect']} (not tested): {d['evidence']}"
    bold = "**" if d["significant"] else ""
    return f"- {bold}{d['effect']}{bold}: score {d['score']:.3f}, p {d['p_value']:.3g}"


def _refit_rate_lines(entry: Mapping[str, Any]) -> list[str]:
    """The learning rate a refit was chosen at and every tried rate's validation loss."""
    if entry.get("refit_lr") is None:
        return []
    tried = ", ".join(
        f"{c['refit_lr']:.0e}: {c['validation_loss']:.4g}" for c in entry["refit_candidates"]
    )
    return [f"- refit learning rate {entry['refit_lr']:.0e} (validation loss per rate: {tried})"]


def _rejected_refit_lines(entry: Mapping[str, Any], unit: str) -> list[str]:
    """What a rejected refit would have done: its validation loss and free-run test errors
    beside those of the model that stands."""
    refit = entry.get("rejected_refit")
    if refit is None:
        return []
    lines = []
    loss = entry.get("refit_validation_loss")
    if loss:
        lines.append(
            f"- validation loss (scaled): last model {loss['start']:.4g}, refit {loss['refit']:.4g}"
        )
    lines.append(f"- the refit's free-run RMSE [{unit}] beside the last model's (not kept):")
    for name, stands in entry["tests"].items():
        before, after = stands["rmse_free_run"], refit["tests"][name]["rmse_free_run"]
        lines.append(f"  - {name}: {before:.4g} -> {after:.4g} ({_change(before, after)})")
    before, after = entry["mean_rmse_free_run"], refit["mean_rmse_free_run"]
    lines.append(f"  - mean: {before:.4g} -> {after:.4g} ({_change(before, after)})")
    return lines


def _change(before: float, after: float) -> str:
    """Relative change as a signed percentage."""
    return f"{100 * (after - before) / before:+.1f} %" if before else "n/a"
