"""The closed loop: fit -> residuals -> diagnose -> add the top significant effect -> refit.

Each round trains the model with the effects declared so far, scores it on the test
recordings in both modes, analyses the free-run residuals and ranks the effects the model
does not declare yet (`hysteresis_lab.loop.diagnosis.ranking`). The top significant one is added
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
from hysteresis_lab._console import SUMMARY
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.effects.base import MODEL_OUTPUT_BLOCKS, FeatureContext
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.errors import ConfigError, DivergedError, HysteresisLabError
from hysteresis_lab.evaluation.evaluate import scoring_start
from hysteresis_lab.evaluation.plots import loops_figure, save_figure
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.evaluation.report import write_json
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.loop.advice import excitation_advice
from hysteresis_lab.loop.data import LoopData, Stretch, loop_data
from hysteresis_lab.loop.diagnosis.excitation import operator_excitation
from hysteresis_lab.loop.diagnosis.ranking import TESTS, EffectScore, diagnose, evidence_lags
from hysteresis_lab.loop.diagnosis.residuals import diagnostics_figure, residual_analysis
from hysteresis_lab.loop.figures import ResidualEvidence
from hysteresis_lab.loop.report import (
    loop_markdown,
    result_line,
    round_line,
    start_label,
    write_round_figures,
)
from hysteresis_lab.models.augment import SETTING as BASELINE_SETTING
from hysteresis_lab.models.augment import feature_context, for_model
from hysteresis_lab.models.settings import TrainingSettings
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.run_folder import LoopFolder, RunFolder
from hysteresis_lab.workflows.grow import REFIT_LR_FACTORS, refit_mode, refit_rates
from hysteresis_lab.workflows.pipeline import (
    RunConfig,
    RunResult,
    RunSettings,
    run_model,
)

log = logging.getLogger(__name__)

REFITS = ("new_inputs", "full")

#: the residual analysis' figure in the folder of each diagnosed round's fit
DIAGNOSTICS_FIGURE = "residual_diagnostics.png"

#: a free run that leaves the measured output's range by more than this many times its
#: span (or is not finite) diverges: such a model is never the loop's result
DIVERGED_SPANS = 10.0


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
    #: a refit runs at each of these multiples of ``training.lr`` and the one with the lowest
    #: validation free-run loss goes on to the keep-or-reject test (``training.refit_lr``,
    #: when set, is the only rate tried)
    refit_lr_factors: tuple[float, ...] = REFIT_LR_FACTORS
    #: run again in the folder of a stopped loop (``hydra.run.dir``), each fit that finished
    #: there with the same settings, data and start is reused, not trained again
    resume: bool = True
    #: share at the end of every training recording held out to validate on and diagnose
    #: from, when the data set has no validation recordings (`hysteresis_lab.loop.data`)
    holdout: float = 0.25
    #: the diagnosis drops each residual's start transient and also reads the input-side
    #: effects through the model's own dynamics (`hysteresis_lab.loop.diagnosis.ranking`): a
    #: recording that starts with a jump from rest rings, and filters of the input started
    #: from rest fit that ring whatever its cause (off: an effect seen only in start
    #: transients, a mode far above the input's band, stays visible)
    diagnosis_through_dynamics: bool = True

    def __post_init__(self) -> None:
        if not 0.0 < self.holdout < 1.0:
            raise ConfigError(
                f"loop.holdout={self.holdout} must lie in (0, 1): it is the share of every "
                "training recording held out. Fix: e.g. loop.holdout=0.25."
            )
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


@dataclass
class HeldOut:
    """A round's model on the loop's held-out data (`hysteresis_lab.loop.data`)."""

    #: mean over the validation stretches (and outputs) of the free-run MSE over the
    #: variance of the measured output there: unit-free, each stretch weighing the same
    loss: float
    rmse: dict[str, float]  # free-run RMSE per validation stretch
    #: every recording (validation, diagnosis, test) on which the free run diverges
    diverging: list[str]
    #: the free run of each diagnosis stretch (whole recording)
    diagnosis_predictions: list[np.ndarray]

    def to_dict(self) -> dict[str, Any]:
        return {"loss": self.loss, "rmse": self.rmse, "diverging": self.diverging}


@dataclass(frozen=True)
class _LoopRun:
    """What every round of one loop run shares."""

    model: ModelSpec
    #: how the start model trains (a refit: at its refit rate)
    training: TrainingSettings
    settings: LoopSettings
    data: LoopData
    context: FeatureContext
    #: `fit_model` with the run's data, trainer and bookkeeping settings bound
    fit_model: Callable[..., RunResult]
    #: `held_out` with the run's data and device bound
    judge: Callable[[RunResult], HeldOut]
    folder: LoopFolder
    use_tensorboard: bool
    #: the data config (the advice on recordings to add names its overrides)
    data_spec: DataSpec


@dataclass
class _LoopState:
    """What the loop carries from round to round."""

    #: the effects the standing model declares
    effects: list[str]
    rounds: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    #: the rounds whose model stands, with their held-out scores
    kept: list[tuple[RunResult, HeldOut]] = dataclasses.field(default_factory=list)
    diagnosis: list[EffectScore] = dataclasses.field(default_factory=list)
    #: effects tried on the standing model
    tried: set[str] = dataclasses.field(default_factory=set)
    #: the effect the next round adds
    trying: str | None = None
    #: the standing model's free run on the diagnosis recordings (the report's figures)
    evidence: ResidualEvidence | None = None


def run_loop(
    model_cfg: Mapping[str, Any] | ModelSpec,
    data_spec: DataSpec,
    trainer: TrainerSettings,
    splits: DatasetSplits,
    output_dir: Path,
    settings: LoopSettings,
    seed: int = 0,
    use_tensorboard: bool = True,
    training: Mapping[str, Any] | TrainingSettings | None = None,
) -> dict[str, Any]:
    """Run the loop on ``splits``, the data set of ``data_spec``, from the model
    ``model_cfg`` trained with ``training`` (the ``training`` config, or settings; unset
    values: the model's own); write ``loop_report.json``, ``loop_report.md`` and figures."""
    model = model_cfg if isinstance(model_cfg, ModelSpec) else ModelSpec.from_config(model_cfg)
    if not isinstance(training, TrainingSettings):
        training = model.training_settings(training)
    if model.settings.get(BASELINE_SETTING):
        raise ConfigError(
            "the loop grows a model from its residual; a start with model.baseline would add "
            "effects in front of the baseline's channels. Fix: run the loop without "
            "model.baseline, then give the run folder of its result round to a network as "
            "model.baseline=<that folder>."
        )
    start = {"model": model.name, "effects": model.effects}
    log.info("loop start: %s", start_label(start))
    data = loop_data(splits, data_spec, settings.holdout)
    log.info("loop data roles: %s", data.roles())
    bookkeeping = RunSettings(seed=seed, use_tensorboard=use_tensorboard,
                              min_refit_gain=settings.min_refit_gain, reuse=settings.resume,
                              resume=settings.resume)
    run = _LoopRun(
        model=model,
        training=training,
        settings=settings,
        data=data,
        context=feature_context(data.fit.train),
        fit_model=functools.partial(
            fit_model, RunConfig(model, data_spec, trainer, output_dir, bookkeeping, training),
            data.fit),
        judge=functools.partial(held_out, data=data, device=trainer.evaluation_device()),
        folder=LoopFolder(output_dir),
        use_tensorboard=use_tensorboard,
        data_spec=data_spec,
    )
    state = _LoopState(effects=list(start["effects"]))
    try:
        _run_rounds(run, state)
    except HysteresisLabError as exc:
        if state.rounds:  # the rounds done are reported; their fits resume on a rerun
            _write_report(run, state, _report(run, state, splits.name, start, stopped=str(exc)))
            log.error("the loop stopped in round %d: %s. The rounds done are in %s",
                      len(state.rounds), exc, run.folder.report_md)
        raise
    report = _report(run, state, splits.name, start)
    _write_report(run, state, report)
    return report


def _run_rounds(run: _LoopRun, state: _LoopState) -> None:
    """Fit, judge and diagnose round after round until the loop ends."""
    for number in itertools.count():
        entry, goes_on = _fit_round_and_decide(run, state, number)
        goes_on = goes_on and _choose_next_effect(run, state, entry)
        write_round_figures(run.folder, number, entry, state.evidence, run.context,
                            run.settings.min_score)
        report = {"units": {"y": run.data.fit.test[0].y_units}, "rounds": state.rounds}
        log.info("%s", round_line(report, number), extra=SUMMARY)
        if not goes_on:
            return


def _report(
    run: _LoopRun, state: _LoopState, data_name: str, start: dict[str, Any],
    stopped: str | None = None,
) -> dict[str, Any]:
    """``loop_report.json``'s document; ``stopped``: why the loop stopped before its end."""
    report = {
        "units": {"y": run.data.fit.test[0].y_units},
        "data": data_name,
        "model": run.model.name,
        "start": start,
        "settings": dataclasses.asdict(run.settings),
        "roles": run.data.roles(),
        "result": _result_round(state.rounds, state.kept),
        "rounds": state.rounds,
    }
    if stopped is not None:
        report["stopped"] = stopped
    return report


def _fit_round_and_decide(
    run: _LoopRun, state: _LoopState, number: int
) -> tuple[dict[str, Any], bool]:
    """Round ``number``: fit (a refit when an effect is being tried), judge it on held-out
    data, keep or reject it, and diagnose a kept model's residual. Returns the round's
    report entry and False when the loop cannot go on (the start diverges)."""
    settings, trying = run.settings, state.trying
    round_effects = state.effects + ([trying] if trying else [])
    log.info("=== loop round %d: effects %s ===", number, round_effects or "none")
    warm_start = (_previous_network([k[0] for k in state.kept])
                  if settings.warm_start else None)
    model = run.model.with_settings({**run.model.settings, "effects": round_effects})
    variants = _refit_variants(model, warm_start, trying)
    result, round_dir, refit_lr, losses, check = _fit_round(
        run.fit_model,
        run.judge,
        model,
        run.training,
        run.folder.round_dir(number),
        _refit_rates(run.training, settings) if warm_start is not None else [None],
        variants=variants,
        warm_start=warm_start,
        refit=_refit_mode(settings.refit, trying, run.model.cls),
    )
    if trying is not None and warm_start is None:
        result = judge_cold_refit(result, state.kept[-1][0], settings.min_refit_gain)
        if not result.improved:
            _set_aside_rejected_files(result.rejected_refit)
    if trying is not None and result.improved:
        result, check = _judge_held_out(result, check, state.kept[-1], settings.min_refit_gain)
    entry = _round_entry(round_effects, result)
    entry["held_out"] = check.to_dict()
    if refit_lr is not None:
        entry["refit_lr"] = refit_lr
        entry["refit_candidates"] = losses
    if len(variants) > 1:
        entry["refit_settings"] = {k: result.model.hparams.get(k) for k in variants[0]}
    if trying is not None:
        entry["decision"] = _decision(trying, result, entry, state, settings.min_refit_gain)
    state.rounds.append(entry)
    if trying is not None and not result.improved:
        entry["rejected"] = trying
        where = "the held-out validation data" if "held_out" in (
            result.rejected_refit or {}) else "validation"
        entry["note"] = (
            f"the refit with '{trying}' did not beat the last model on {where}: "
            f"'{trying}' dropped, the last model stands"
        )
    elif check.diverging:
        entry["note"] = (
            f"the start model's free run diverges on {check.diverging}: it is no result, "
            "and nothing is diagnosed from it. Fix: another start (model=linear is stable "
            "by construction) or other training settings"
        )
        log.error("%s", entry["note"])
        return entry, False
    else:
        state.effects, state.tried = round_effects, set()
        state.kept.append((result, check))
        state.diagnosis, state.evidence = _diagnose_round(
            result, check, run.data, run.context, held_effects(run.model, state.effects),
            settings, round_dir,
            run.use_tensorboard, number,
        )
        entry["diagnosis"] = [d.to_dict() for d in state.diagnosis]
        advice = excitation_advice(state.diagnosis, run.data, run.data_spec, run.context,
                                   settings.min_score, settings.holdout)
        if advice:
            entry["under_excited"] = advice
        entry["figures"] = {
            "diagnostics": run.folder.relative(round_dir / DIAGNOSTICS_FIGURE)}
    return entry, True


def _choose_next_effect(run: _LoopRun, state: _LoopState, entry: dict[str, Any]) -> bool:
    """Pick the effect the next round adds from the standing diagnosis (recorded in
    ``entry``); False when the loop ends here (nothing significant, or enough rounds)."""
    uncarried = _not_carried(run.model, state.diagnosis, state.tried)
    if uncarried:
        entry["not_carried"] = uncarried
        log.info("model '%s' has no block for the significant effect(s) %s: not added",
                 run.model.name, uncarried)
    top, reported = next_effect(state.diagnosis, state.tried | set(uncarried))
    if reported:
        entry["reported"] = reported
    if top is None:
        entry.setdefault("note", "no significant missing effect" + (
            " that depends on the input" if reported else ""))
        return False
    if len(state.kept) > run.settings.max_rounds:
        entry.setdefault(
            "note", f"loop.max_rounds={run.settings.max_rounds} reached; next: {top.effect}"
        )
        return False
    entry["added"] = state.trying = top.effect
    state.tried.add(top.effect)
    if get_effect(top.effect).block in MODEL_OUTPUT_BLOCKS:  # no input operators to compare
        log.info("'%s' added (it acts on the model's output)", top.effect)
        return True
    fit = run.data.fit
    excitation = operator_excitation(top.effect, [*fit.train, *fit.val], fit.test, run.context)
    entry["added_excitation"] = excitation.to_dict()
    log.info("'%s' added: %s", top.effect, excitation.reading())
    return True


def _write_report(run: _LoopRun, state: _LoopState, report: dict[str, Any]) -> None:
    """``loop_report.json`` / ``.md`` and the before/after figure; the result and where the
    report is, in the log."""
    write_json(report, run.folder.report_json)
    run.folder.report_md.write_text(loop_markdown(report))
    if state.kept:
        _before_after_figure(run.data.fit, state.kept[0][0], state.kept[-1][0], state.rounds,
                             state.effects, run.folder.before_after_figure)
    log.info("%s", result_line(report), extra=SUMMARY)
    log.info("report: %s (beside it: %s, each round's fit in round_<n>/)",
             run.folder.report_md, run.folder.REPORT_JSON, extra=SUMMARY)


def _decision(
    trying: str, result: RunResult, entry: dict[str, Any], state: _LoopState, min_gain: float
) -> dict[str, Any]:
    """Why round ``entry``'s refit with ``trying`` was kept or dropped: the round it was
    judged against (the standing model's) and both held-out validation losses (the refit's
    is None when it lost already on the training validation data)."""
    against = max(i for i, r in enumerate(state.rounds) if not r.get("rejected"))
    before = state.kept[-1][1].loss
    refit = entry["held_out"] if result.improved else (
        (result.rejected_refit or {}).get("held_out"))
    after = None if refit is None else refit["loss"]
    return {
        "effect": trying,
        "kept": bool(result.improved),
        "against_round": against,
        "held_out_loss": {"before": before, "after": after},
        "reason": _decision_reason(result, entry, refit, against, before, min_gain),
    }


def _decision_reason(
    result: RunResult, entry: dict[str, Any], refit: dict[str, Any] | None, against: int,
    before: float, min_gain: float,
) -> str:
    """The keep-or-drop rule that decided, with its numbers."""
    gain = f" by more than loop.min_refit_gain={min_gain:g} of it" if min_gain else ""
    if refit is None:
        loss = entry.get("refit_validation_loss") or {}
        numbers = (f" (loss {loss['refit']:.4g} against {loss['start']:.4g}, scaled)"
                   if loss else "")
        return (f"the refit did not beat its start on the training validation data{gain}"
                f"{numbers}, so it was not judged on the held-out data")
    if refit["diverging"]:
        return f"the refit's free run diverges on {', '.join(refit['diverging'])}"
    verb = "beats" if result.improved else "does not beat"
    return (f"the refit's held-out validation loss {refit['loss']:.4g} {verb} round "
            f"{against}'s {before:.4g}{gain}")


def _result_round(
    rounds: list[dict[str, Any]], kept: list[tuple[RunResult, HeldOut]]
) -> int | None:
    """The round whose model is the loop's result: the last one kept (None: none stands)."""
    if not kept:
        return None
    standing = [i for i, r in enumerate(rounds) if not r.get("rejected")
                and not r["held_out"]["diverging"]]
    return standing[-1] if standing else None


def _before_after_figure(
    fit: DatasetSplits, before: RunResult, after: RunResult, rounds: list[dict[str, Any]],
    effects: list[str], path: Path,
) -> None:
    """The test recordings' free run before (the start) and after (the result)."""
    predictions = {
        rec.name: {
            "before": before.evaluation.predictions[rec.name]["free_run"],
            "after": after.evaluation.predictions[rec.name]["free_run"],
        }
        for rec in fit.test
    }
    save_figure(
        loops_figure(
            fit.test,
            predictions,
            title=f"free run before ({rounds[0]['effects'] or 'no effects'}) and "
            f"after ({effects})",
        ),
        path,
    )


def held_out(result: RunResult, data: LoopData, device: str) -> HeldOut:
    """``result``'s model on the loop's validation and diagnosis stretches (each recording
    simulated end to end, scored from its stretch's start), and where its free run diverges
    (those recordings and the test recordings)."""
    stretches = list(data.validation) + [s for s in data.diagnosis if s not in data.validation]
    recordings = [s.recording for s in stretches]
    predictions = free_run(result.model, for_model(result.model, recordings), result.window,
                           device=device)
    n_skip = scoring_start(result.window, data.fit.n_init)
    by_stretch = dict(zip(map(id, stretches), predictions, strict=True))
    losses, rmse = [], {}
    for stretch in data.validation:
        first = max(stretch.start, n_skip)
        y = stretch.recording.y[first:]
        error = y - by_stretch[id(stretch)][first:]
        mse = np.mean(error**2, axis=0)
        losses.append(float(np.mean(mse / np.maximum(np.var(y, axis=0), 1e-300))))
        rmse[stretch.describe()] = float(np.sqrt(np.mean(mse)))
    runs = [(s.name, s.recording.y, p) for s, p in zip(stretches, predictions, strict=True)]
    runs += [(rec.name, rec.y, result.evaluation.predictions[rec.name]["free_run"])
             for rec in data.fit.test]
    diverging = sorted({name for name, y, p in runs if _diverges(y, p)})
    loss = float(np.mean(losses)) if not diverging else float("inf")
    return HeldOut(loss, rmse, diverging, [by_stretch[id(s)] for s in data.diagnosis])


def _diverges(y: np.ndarray, prediction: np.ndarray) -> bool:
    """Whether a free run is not finite or leaves the measured output's range by more than
    `DIVERGED_SPANS` times its span."""
    prediction = np.asarray(prediction, dtype=float)
    if not np.all(np.isfinite(prediction)):
        return True
    low, high = np.min(y, axis=0), np.max(y, axis=0)
    margin = DIVERGED_SPANS * np.maximum(high - low, 1e-12)
    return bool(np.any(prediction < low - margin) or np.any(prediction > high + margin))


def _judge_held_out(
    refit: RunResult, check: HeldOut, last: tuple[RunResult, HeldOut], min_gain: float
) -> tuple[RunResult, HeldOut]:
    """Keep a refit only when its free run on the held-out validation data is stable and
    beats the last kept model's by more than the share ``min_gain``; otherwise the last
    model stands, the refit's scores kept as what it would have done."""
    last_result, last_check = last
    if not check.diverging and check.loss < (1.0 - min_gain) * last_check.loss:
        return refit, check
    why = f"diverges on {check.diverging}" if check.diverging else (
        f"held-out validation loss {check.loss:.4g} against the last model's {last_check.loss:.4g}")
    log.info("refit rejected on the held-out validation data: %s", why)
    document = {**refit.document, "held_out": check.to_dict()}
    _set_aside_rejected_files(document)
    return dataclasses.replace(
        last_result, improved=False, refit_validation=refit.refit_validation,
        rejected_refit=document,
    ), last_check


def next_effect(
    diagnosis: Sequence[EffectScore], tried: set[str]
) -> tuple[EffectScore | None, list[str]]:
    """The significant effect to add next (best first, not yet tried on this model) and the
    significant ones that do not depend on the input: free run cannot predict those, so
    they are reported, never added, and the loop goes on with the next."""
    candidates = [d for d in diagnosis if d.significant and d.effect not in tried]
    reported = [d.effect for d in candidates if not d.predictable]
    return next((d for d in candidates if d.predictable), None), reported


def held_effects(model: ModelSpec, effects: Sequence[str]) -> list[str]:
    """The effects a model holds: those declared and those its structure always has (a
    grey-box's hysteresis cell, `built_in_effects`); the diagnosis looks beyond them."""
    extra = model.cls.built_in_effects(model.settings)
    return [*effects, *(e for e in extra if e not in effects)]


def _not_carried(
    model: ModelSpec, diagnosis: Sequence[EffectScore], tried: set[str]
) -> list[str]:
    """Significant, input-driven effects the start model's class cannot take (a grey-box
    carries only the effects it has physical blocks for; a network every effect that reaches
    it through its inputs, none that acts on its output)."""
    carried = model.cls.carried_effects

    def carries(effect: str) -> bool:
        if carried is not None:
            return effect in carried
        return get_effect(effect).block not in MODEL_OUTPUT_BLOCKS

    return [d.effect for d in diagnosis
            if d.significant and d.predictable and d.effect not in tried
            and not carries(d.effect)]


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
    aside = RunFolder(model_path.parent).set_model_aside_as_rejected(model_path)
    document["model_path"] = str(aside)


def fit_model(base: RunConfig, splits: DatasetSplits, model: ModelSpec,
              training: TrainingSettings, output_dir: Path, warm_start: Any | None,
              refit: str) -> RunResult:
    """One fit of the loop: ``base`` (the loop's data, trainer and bookkeeping) with a
    round's ``model`` and ``training`` settings, in ``output_dir``, started from
    ``warm_start`` (None: from the data) with that ``refit`` mode."""
    config = dataclasses.replace(base, model=model, training=training, output_dir=output_dir,
                                 settings=dataclasses.replace(base.settings, refit=refit))
    return run_model(config, splits=splits, warm_start=warm_start)


def _round_entry(effects: list[str], result: RunResult) -> dict[str, Any]:
    """A round of ``loop_report.json``: its effects and errors (diagnosis and decision follow).
    A refit that lost to its start adds ``rejected_refit``: what it would have scored."""
    entry: dict[str, Any] = {"effects": list(effects), **_scores(result.document)}
    entry.update(diagnosis=[], added=None)
    if result.refit_validation is not None:
        entry["refit_validation_loss"] = result.refit_validation
    if result.rejected_refit is not None:
        entry["rejected_refit"] = _scores(result.rejected_refit)
        if "held_out" in result.rejected_refit:
            entry["rejected_refit"]["held_out"] = result.rejected_refit["held_out"]
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
    check: HeldOut,
    data: LoopData,
    context: FeatureContext,
    effects: list[str],
    settings: LoopSettings,
    round_dir: Path,
    use_tensorboard: bool,
    number: int,
) -> tuple[list[EffectScore], ResidualEvidence]:
    """Residual analysis (JSON, figure, TensorBoard) and the ranked diagnosis of a round, on
    the diagnosis recordings (never the test recordings: `hysteresis_lab.loop.data`),
    and the free run they were read from (for the report's figures)."""
    n_skip = scoring_start(result.window, data.fit.n_init)
    recordings, residuals, shown, predictions, starts = [], [], [], {}, []
    for stretch, prediction in zip(data.diagnosis, check.diagnosis_predictions, strict=True):
        first = max(stretch.start, n_skip)
        starts.append(first)
        e = stretch.recording.y - prediction
        e[:first] = np.nan
        recordings.append(stretch.recording)
        residuals.append(e)
        part = _from(stretch, first)
        shown.append(part)
        predictions[part.name] = {"free_run": prediction[first:]}
    diagnosis = diagnose(
        recordings,
        residuals,
        context,
        declared=effects,
        min_score=settings.min_score,
        alpha=settings.alpha,
        lags=evidence_lags(result.window.nb),
        test=settings.significance,
        predictions=list(check.diagnosis_predictions),
        through_dynamics=settings.diagnosis_through_dynamics,
    )
    write_json(residual_analysis(shown, predictions, 0), round_dir / "residual_analysis.json")
    figure = diagnostics_figure(shown, predictions, 0)
    save_figure(figure, round_dir / DIAGNOSTICS_FIGURE)
    if use_tensorboard:
        _log_round_to_tensorboard(round_dir / "tensorboard", figure, diagnosis, number)
    evidence = ResidualEvidence(recordings, list(check.diagnosis_predictions), starts,
                                [part.name for part in shown])
    return diagnosis, evidence


def _from(stretch: Stretch, first: int) -> Recording:
    """The scored part of a diagnosis stretch, named as the report names it."""
    rec = stretch.recording
    if first == 0:
        return rec
    return dataclasses.replace(rec, u=rec.u[first:], y=rec.y[first:], name=stretch.describe())


def _fit_round(
    fit_model: Callable[..., RunResult],
    judge: Callable[[RunResult], HeldOut],
    model: ModelSpec,
    training: TrainingSettings,
    round_dir: Path,
    rates: list[float] | list[None],
    variants: Sequence[Mapping[str, Any]] = ({},),
    **fit_options: Any,
) -> tuple[RunResult, Path, float | None, list[dict[str, Any]], HeldOut]:
    """Fit a round's ``model`` with ``fit_model`` (`fit_model` bound to the loop's data and
    settings) once per refit learning rate in ``rates`` (``[None]``: no refit, one fit),
    each in its own folder when there are several, and score each on the held-out data with
    ``judge``; the one with the lowest held-out validation loss (then training validation
    loss) is returned with its folder, its rate, every rate's losses and its held-out scores
    (the test recordings play no part in the choice). A refit that diverges in training is
    no candidate (recorded with ``diverged``); when every one does, `DivergedError`.
    ``variants``: model settings each rate is fitted with (the model class's
    ``refit_variants``: a law's place), each in its own folder when there are several."""
    runs, diverged = [], []
    for variant, rate in itertools.product(variants, rates):
        base = round_dir / _variant_label(variant) if len(variants) > 1 else round_dir
        run_dir = LoopFolder.refit_dir(base, rate, several=len(rates) > 1)
        refit_lr = {"refit_lr": rate} if rate is not None else {}
        try:
            result = fit_model(model=model.with_settings({**model.settings, **variant}),
                               training=training.with_changes(**refit_lr),
                               output_dir=run_dir, **fit_options)
        except DivergedError as exc:
            if rate is None and len(variants) == 1:
                raise
            log.warning("the refit %s at learning rate %s diverged: not a candidate (%s)",
                        dict(variant), rate, exc)
            diverged.append({**variant, "refit_lr": rate, "validation_loss": float("inf"),
                             "held_out_loss": float("inf"), "diverged": str(exc)})
            continue
        runs.append((result, run_dir, rate, judge(result), dict(variant)))
    if not runs:
        raise DivergedError(
            f"every refit diverged in training (learning rates "
            f"{', '.join(f'{r:.3g}' for r in rates if r is not None)}). Fix: smaller rates, "
            "e.g. loop.refit_lr_factors=[0.1] or a smaller training.lr."
        )
    result, run_dir, rate, check, _ = min(runs, key=lambda run: (run[3].loss,
                                                                 _refit_loss(run[0])))
    losses = [
        {**v, "refit_lr": r, "validation_loss": _refit_loss(res), "held_out_loss": c.loss}
        for res, _, r, c, v in runs if r is not None
    ] + diverged
    return result, run_dir, rate, losses, check


def _variant_label(variant: Mapping[str, Any]) -> str:
    """A folder name for a refit's model settings (``feedback_on_output_stage``)."""
    return "_".join(f"{key}_{value}" for key, value in variant.items()) or "default"


def _refit_variants(model: ModelSpec, previous: Any | None,
                    added: str | None) -> list[dict[str, Any]]:
    """The model settings a round fits, each a candidate the held-out loss chooses among
    (the class's ``refit_variants``; ``[{}]``: the round's settings alone)."""
    return model.cls.refit_variants(model.to_config(), previous, added) or [{}]


def _refit_rates(training: TrainingSettings, settings: LoopSettings) -> list[float]:
    """The learning rates a refit runs at: ``training.refit_lr`` if set, else the loop's
    multiples of ``training.lr`` (`grow.refit_rates`)."""
    return refit_rates(training, settings.refit_lr_factors)


def _refit_loss(result: RunResult) -> float:
    """The validation loss a refit reached (its own weights, kept or not)."""
    loss = result.refit_validation
    return float(loss["refit"]) if loss else float("inf")


def _refit_mode(refit: str, added: str | None, model_cls: type) -> str:
    """How a round's refit trains (`grow.refit_mode`: the whole model where the added
    effect changes what the fitted part was fitted to)."""
    return refit_mode(added, model_cls, refit)


def _previous_network(results: list[RunResult]) -> Any | None:
    """The last round's fitted network to start the refit from (None: first round, or SVM)."""
    if not results or not results[-1].model.warm_starts:
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
