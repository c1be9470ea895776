"""The closed loop: fit -> residuals -> diagnose -> add the top significant effect -> refit.

Each round fits the model with the effects declared so far on every fold of the
identification record (`hysteresis_lab.loop.data`), scores each fold's model on the fold's
held-out stretches, and ranks the effects the model does not declare yet from those
held-out residuals, every fold's blocks voting together
(`hysteresis_lab.loop.diagnosis.ranking`). The top significant one is added and the next
round refits it on every fold: the refit stands only when its free run is stable on every
fold, its pooled held-out loss beats the standing model's and it is better on a majority of
the folds (`hysteresis_lab.loop.crossval.keep_refit`); the refit's learning rate and the
effect's place are the candidates' with the lowest pooled held-out loss. The structure the
folds chose is then refitted on the whole identification record, every sample training, for
the epochs the folds' fits of it needed (`hysteresis_lab.loop.length`), its last weights
kept: that model is the round's result, the one reported on the tests and saved in
``round_<n>/``.

With ``warm_start`` every refit (each fold's and the whole record's) starts from the same
lane's previous model with the new effect's input weights at zero; with
``refit="new_inputs"`` (the default) it trains only those weights, so a fold's refit costs
little more than the new block's fit.
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

from hysteresis_lab._console import SUMMARY
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.effects.base import MODEL_OUTPUT_BLOCKS, FeatureContext
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.errors import ConfigError, DivergedError, HysteresisLabError
from hysteresis_lab.evaluation.evaluate import scoring_start
from hysteresis_lab.evaluation.plots import loops_figure, save_figure
from hysteresis_lab.evaluation.report import write_json
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.loop.advice import excitation_advice
from hysteresis_lab.loop.crossval import FoldsCheck, HeldOut, held_out, keep_refit
from hysteresis_lab.loop.data import LoopData, Stretch, loop_data
from hysteresis_lab.loop.diagnosis.excitation import operator_excitation, under_excited
from hysteresis_lab.loop.diagnosis.ranking import TESTS, EffectScore, diagnose, evidence_lags
from hysteresis_lab.loop.diagnosis.residuals import diagnostics_figure, residual_analysis
from hysteresis_lab.loop.figures import ResidualEvidence
from hysteresis_lab.loop.length import (
    FINE_TUNE,
    TRAINER_STAGES,
    TrainingLength,
    configured_length,
    final_length,
)
from hysteresis_lab.loop.plant import fits_plant, prefer_plant, with_plant_prior
from hysteresis_lab.loop.report import (
    loop_markdown,
    result_line,
    round_line,
    start_label,
    write_round_figures,
)
from hysteresis_lab.models.augment import SETTING as BASELINE_SETTING
from hysteresis_lab.models.augment import feature_context
from hysteresis_lab.models.settings import TrainingSettings
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.run_folder import LoopFolder
from hysteresis_lab.workflows.grow import (
    POLISHED_REFIT_LR_FACTORS,
    REFIT_LR_FACTORS,
    growth_stages,
    polishes_fits,
    refit_mode,
    refit_rates,
)
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

#: a round's fits on fold j land in ``round_<n>/fold_<j>``
FOLD_DIR = "fold_{}"


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
    #: when set, is the only rate tried); None: `POLISHED_REFIT_LR_FACTORS` one after the
    #: other (the next where the refit fails the folds) for a model whose fits end with the
    #: L-BFGS polish, else `REFIT_LR_FACTORS`
    refit_lr_factors: tuple[float, ...] | None = None
    #: run again in the folder of a stopped loop (``hydra.run.dir``), each fit that finished
    #: there with the same settings, data and start is reused, not trained again
    resume: bool = True
    #: folds of the identification record that choose the effect, its place and whether a
    #: refit stands (`hysteresis_lab.loop.data`); the result is refitted on all of it
    folds: int = 3
    #: significant effects scoring within this share of the top score are confounded with
    #: it: each is refitted and the folds keep the best (`confounded`)
    confounded_margin: float = 0.2
    #: at most this many effects refitted in one round (the top one included)
    max_alternatives: int = 3
    #: add an effect foreign to the declared ``data.plant`` (`hysteresis_lab.loop.plant`)
    #: whose operators the test recordings' inputs drive beyond twice (RMS) what the
    #: identification data do (`beyond_identification`); false: such an effect is reported
    #: with the recordings that would show it, and the next one is tried (an effect that
    #: fits the plant, or any effect where no plant is declared, is added as before)
    add_under_excited: bool = False
    #: significance level of the effects whose physics fits the declared ``data.plant``
    #: (`hysteresis_lab.loop.plant.with_plant_prior`); 1: such an effect needs only reach
    #: ``min_score`` and the folds alone judge its refit; None: ``alpha``, as every effect
    plant_alpha: float | None = 1.0
    #: the diagnosis drops each residual's start transient and also reads the input-side
    #: effects through the model's own dynamics (`hysteresis_lab.loop.diagnosis.ranking`): a
    #: recording that starts with a jump from rest rings, and filters of the input started
    #: from rest fit that ring whatever its cause (off: an effect seen only in start
    #: transients, a mode far above the input's band, stays visible)
    diagnosis_through_dynamics: bool = True

    def __post_init__(self) -> None:
        if not 0.0 <= self.confounded_margin < 1.0 or self.max_alternatives < 1:
            raise ConfigError(
                f"loop.confounded_margin={self.confounded_margin} must lie in [0, 1) and "
                f"loop.max_alternatives={self.max_alternatives} be at least 1. Fix: e.g. "
                "loop.confounded_margin=0.2 loop.max_alternatives=3."
            )
        if self.plant_alpha is not None and not 0.0 < self.plant_alpha <= 1.0:
            raise ConfigError(
                f"loop.plant_alpha={self.plant_alpha} must lie in (0, 1], or be null (loop.alpha "
                "for every effect). Fix: e.g. loop.plant_alpha=0.05."
            )
        if self.folds < 2:
            raise ConfigError(
                f"loop.folds={self.folds} must be at least 2: each fold holds out a share of "
                "the identification record. Fix: e.g. loop.folds=3."
            )
        if self.refit_lr_factors is not None:
            self.refit_lr_factors = tuple(float(f) for f in self.refit_lr_factors)
            if not self.refit_lr_factors or min(self.refit_lr_factors) <= 0:
                raise ConfigError(
                    f"loop.refit_lr_factors={list(self.refit_lr_factors)} must be a non-empty "
                    "list of positive numbers, or null (automatic). Fix: e.g. "
                    "loop.refit_lr_factors=[0.1,1.0]."
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


@dataclass(frozen=True)
class _Lane:
    """Fits of the loop on one set of training data: the whole identification record or
    one fold's share of it."""

    config: RunConfig  # the loop's trainer and bookkeeping settings
    splits: DatasetSplits

    def fit(self, **options: Any) -> RunResult:
        """`fit_model` on this lane's data (``options``: its model, training, folder, warm
        start and refit mode)."""
        return fit_model(self.config, self.splits, **options)

    @property
    def samples(self) -> int:
        """Training samples of this lane."""
        return sum(rec.n_samples for rec in self.splits.train)


@dataclass(frozen=True)
class _LoopRun:
    """What every round of one loop run shares."""

    model: ModelSpec
    #: how the start model trains (a refit: at its refit rate)
    training: TrainingSettings
    settings: LoopSettings
    data: LoopData
    context: FeatureContext
    #: fits on the whole identification record (the result's)
    whole: _Lane
    #: fits on each fold's training data (no figures: nobody reads them)
    folds: list[_Lane]
    #: `held_out` on each fold's held-out stretches, with the device bound
    fold_judges: list[Callable[[RunResult], HeldOut]]
    folder: LoopFolder
    use_tensorboard: bool
    #: the data config (the advice on recordings to add names its overrides)
    data_spec: DataSpec
    device: str

    @property
    def plots(self) -> bool:
        """Whether the report's figures are drawn (PNG, and the diagnostics in TensorBoard):
        the config's ``plots``, as the whole record's fits draw theirs."""
        return self.whole.config.settings.plots


@dataclass
class _Standing:
    """A structure that stands: fitted on the whole identification record (the result) and
    on every fold (what the next refit of each fold starts from), with its fold scores."""

    final: RunResult
    folds: list[RunResult]
    check: FoldsCheck


@dataclass
class _Candidate:
    """A round's structure at one place (``variant``) and refit rate, fitted on every fold
    (None: that fold's fit diverged in training)."""

    variant: dict[str, Any]
    rate: float | None
    folds: list[RunResult | None]
    check: FoldsCheck
    model: ModelSpec | None = None  # the round's model (its effects) before the variant
    effect: str | None = None  # the effect it adds (None: the start)

    def refit_loss(self) -> float:
        """The folds' mean training validation loss of the refit (inf: none)."""
        losses = [_refit_loss(r) for r in self.folds if r is not None]
        return float(np.mean(losses)) if losses else float("inf")


@dataclass
class _LoopState:
    """What the loop carries from round to round."""

    #: the effects the standing model declares
    effects: list[str]
    rounds: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    #: the rounds whose model stands
    kept: list[_Standing] = dataclasses.field(default_factory=list)
    diagnosis: list[EffectScore] = dataclasses.field(default_factory=list)
    #: effects tried on the standing model
    tried: set[str] = dataclasses.field(default_factory=set)
    #: effects the folds rejected on any model: not tried again (on plants where one came
    #: back after another effect was kept, the folds rejected it again, at a refit per fold
    #: and rate each time)
    rejected: set[str] = dataclasses.field(default_factory=set)
    #: the effects the next round refits, one at a time (the top one and those the evidence
    #: does not tell apart from it); the folds keep at most one
    trying: list[str] = dataclasses.field(default_factory=list)
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
    plots: bool = True,
) -> dict[str, Any]:
    """Run the loop on ``splits``, the data set of ``data_spec``, from the model
    ``model_cfg`` trained with ``training`` (the ``training`` config, or settings; unset
    values: the model's own); write ``loop_report.json``, ``loop_report.md`` and, with
    ``plots``, the figures."""
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
    data = loop_data(splits, data_spec, settings.folds)
    log.info("loop data roles: %s", data.roles())
    bookkeeping = RunSettings(seed=seed, use_tensorboard=use_tensorboard, plots=plots,
                              min_refit_gain=settings.min_refit_gain, reuse=settings.resume,
                              resume=settings.resume)
    base = RunConfig(model, data_spec, trainer, output_dir, bookkeeping, training)
    quiet = dataclasses.replace(base, settings=dataclasses.replace(
        bookkeeping, plots=False, use_tensorboard=False))
    device = trainer.evaluation_device()
    run = _LoopRun(
        model=model,
        training=training,
        settings=settings,
        data=data,
        context=feature_context(data.fit.train),
        whole=_Lane(base, data.whole),
        folds=[_Lane(quiet, fold.fit) for fold in data.folds],
        fold_judges=[functools.partial(held_out, stretches=fold.held_out,
                                       n_init=data.fit.n_init, device=device)
                     for fold in data.folds],
        folder=LoopFolder(output_dir),
        use_tensorboard=use_tensorboard,
        data_spec=data_spec,
        device=device,
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
        if run.plots:
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
        "plots": run.plots,
    }
    if stopped is not None:
        report["stopped"] = stopped
    return report


def _fit_round_and_decide(
    run: _LoopRun, state: _LoopState, number: int
) -> tuple[dict[str, Any], bool]:
    """Round ``number``: fit the round's structure on every fold (each place and refit rate
    when an effect is being tried), keep or reject it on the folds, refit what stands on the
    whole identification record and diagnose its residual on the folds. Returns the round's
    report entry and False when the loop cannot go on (the start diverges)."""
    settings, trying = run.settings, state.trying
    log.info("=== loop round %d: effects %s%s ===", number, state.effects or "none",
             f" + one of {trying}" if trying else "")
    standing = state.kept[-1] if state.kept else None
    warm = (settings.warm_start and standing is not None
            and bool(standing.final.model.warm_starts))
    stages: list[list[float]] | list[list[None]] = (
        _refit_rate_stages(run.model, run.training, settings) if warm else [[None]])
    rates = [rate for stage in stages for rate in stage]
    round_dir = run.folder.round_dir(number)
    candidates: list[_Candidate] = []
    for stage in stages:  # a later stage's rates only where the earlier ones' refit fails
        candidates += _fit_candidates(run, state, standing if warm else None, stage, rates,
                                      round_dir)
        best = min(candidates, key=lambda c: (c.check.loss, c.refit_loss()))
        if standing is None:
            kept, reason = True, ""
        else:
            kept, reason = keep_refit(best.check, standing.check, settings.min_refit_gain,
                                      start=state.kept[0].check)
        if kept:
            break
    model, round_effects = best.model, best.model.effects
    refit = _refit_mode(settings.refit, best.effect, run.model.cls)
    variants = {tuple(sorted(c.variant.items())) for c in candidates if c.effect == best.effect}
    fitted_on = None
    if kept:
        final, samples, length = _fit_final(run, model, best, round_dir,
                                            standing if warm else None, refit)
        fitted_on = {"samples": samples, "recordings": [r.name for r in run.data.fit.train],
                     "training_length": length.to_dict(), "length": length.describe()}
    else:
        final = standing.final
    entry = _round_entry(round_effects, final)
    entry["chosen_on"] = {"folds": len(run.data.folds),
                          "samples": [lane.samples for lane in run.folds],
                          "held_out": [fold.describe() for fold in run.data.folds]}
    entry["fitted_on"] = fitted_on
    entry["held_out"] = (best.check if kept else standing.check).to_dict()
    if warm:
        entry["refit_lr"] = best.rate
        entry["refit_candidates"] = [_candidate_entry(c) for c in candidates]
    if len(variants) > 1 or best.variant:
        entry["refit_settings"] = dict(best.variant)
    if kept and standing is not None and final.refit_validation is not None:
        entry["refit_validation_loss"] = final.refit_validation
    if trying:
        entry["decision"] = _decision(best.effect, kept, reason, best, state)
    if len(trying) > 1:
        entry["compared"] = compared_effects(candidates)
    state.rounds.append(entry)
    if trying and not kept:
        state.rejected |= set(trying)
        entry["rejected"] = best.effect
        entry["rejected_held_out"] = best.check.to_dict()
        entry["note"] = (f"the refit with '{best.effect}' did not pass the folds: "
                         f"'{best.effect}' dropped, the last model stands")
        return entry, True
    if best.check.diverging:
        entry["note"] = (
            f"the start model's free run diverges on {best.check.diverging}: it is no result, "
            "and nothing is diagnosed from it. Fix: another start (model=linear is stable "
            "by construction) or other training settings"
        )
        log.error("%s", entry["note"])
        return entry, False
    if standing is not None and not final.improved:
        entry["final_refit"] = (
            "the whole-record refit did not beat its start on its training validation "
            "windows: the result keeps the last model's weights, the new block at no effect")
        log.warning("round %d: %s", number, entry["final_refit"])
    state.effects, state.tried = round_effects, set()
    fold_results = [r for r in best.folds if r is not None]
    state.kept.append(_Standing(final, fold_results, best.check))
    state.diagnosis, state.evidence = _diagnose_round(
        run, final, best.check, held_effects(run.model, state.effects), round_dir, number)
    entry["diagnosis"] = [d.to_dict() for d in state.diagnosis]
    # every sample of an added recording is held out by one fold: the diagnosis reads all
    advice = excitation_advice(state.diagnosis, run.data, run.data_spec, run.context,
                               settings.min_score, 1.0)
    if advice:
        entry["under_excited"] = advice
    if run.plots:
        entry["figures"] = {"diagnostics": run.folder.relative(round_dir / DIAGNOSTICS_FIGURE)}
    return entry, True


def _fit_candidates(run: _LoopRun, state: _LoopState, standing: _Standing | None,
                    rates: Sequence[float] | Sequence[None], all_rates: Sequence[Any],
                    round_dir: Path) -> list[_Candidate]:
    """The round's model with each effect it tries, at each place and each of ``rates``,
    fitted on the folds (warm from ``standing`` where given); ``all_rates``: every rate the
    round may fit (their folders)."""
    candidates = []
    trying = state.trying
    for effect in trying or [None]:
        effects = state.effects + ([effect] if effect else [])
        model = run.model.with_settings({**run.model.settings, "effects": effects})
        variants = _refit_variants(model, standing.final.model if standing else None, effect)
        refit = _refit_mode(run.settings.refit, effect, run.model.cls)
        folder = round_dir / effect if len(trying) > 1 else round_dir
        candidates += [
            _fit_on_folds(run, model, variant, rate,
                          _candidate_dir(folder, variant, rate, variants, all_rates),
                          standing, refit, effect)
            for variant, rate in itertools.product(variants, rates)
        ]
    return candidates


def _candidate_dir(round_dir: Path, variant: Mapping[str, Any], rate: float | None,
                   variants: Sequence[Mapping[str, Any]],
                   rates: Sequence[float | None]) -> Path:
    """Where a candidate's fold fits land (below it: ``fold_<j>``)."""
    base = round_dir / _variant_label(variant) if len(variants) > 1 else round_dir
    return LoopFolder.refit_dir(base, rate, several=len(rates) > 1)


def _fit_on_folds(
    run: _LoopRun, model: ModelSpec, variant: Mapping[str, Any], rate: float | None,
    folder: Path, standing: _Standing | None, refit: str, effect: str | None = None,
) -> _Candidate:
    """``model`` at place ``variant`` and refit rate ``rate`` fitted on every fold (from the
    fold's standing model when ``standing`` is given) and scored on its held-out stretches."""
    spec = model.with_settings({**model.settings, **variant})
    training = run.training.with_changes(**({"refit_lr": rate} if rate is not None else {}))
    results: list[RunResult | None] = []
    checks: list[HeldOut | None] = []
    for j, (lane, judge) in enumerate(zip(run.folds, run.fold_judges, strict=True)):
        try:
            result = lane.fit(model=spec, training=training,
                         output_dir=folder / FOLD_DIR.format(j),
                         warm_start=None if standing is None else standing.folds[j].model,
                         refit=refit)
        except DivergedError as exc:
            log.warning("the fit %s at learning rate %s diverged on fold %d (%s)",
                        dict(variant), rate, j, exc)
            results.append(None)
            checks.append(None)
            continue
        results.append(result)
        checks.append(judge(result))
    candidate = _Candidate(dict(variant), rate, results, FoldsCheck(checks), model, effect)
    log.info("%s %s at rate %s: pooled held-out loss %.4g (folds %s)", model.effects,
             dict(variant), rate, candidate.check.loss,
             ", ".join(f"{x:.4g}" for x in candidate.check.fold_losses()))
    return candidate


def _fit_final(run: _LoopRun, model: ModelSpec, chosen: _Candidate, round_dir: Path,
               standing: _Standing | None,
               refit: str) -> tuple[RunResult, int, TrainingLength]:
    """The structure the folds chose (its place and rate) refitted on the whole
    identification record, from the standing result when ``standing`` is given, for the
    folds' length (`training_length`; its last weights kept); with the samples it trained on
    and that length."""
    spec = model.with_settings({**model.settings, **chosen.variant})
    training = run.training.with_changes(
        **({"refit_lr": chosen.rate} if chosen.rate is not None else {}))
    lane = run.whole
    length = training_length(run, spec, chosen, grows=standing is None)
    trainer = lane.config.trainer
    if length.from_folds:
        stages = length.epochs
        trainer = trainer.with_changes(max_epochs=next(
            (stages[s] for s in TRAINER_STAGES if s in stages), trainer.max_epochs))
        if FINE_TUNE in stages:
            training = training.with_changes(simulation_epochs=stages[FINE_TUNE])
    log.info("the final refit on the whole identification record trains %s",
             length.describe())
    result = lane.fit(model=spec, training=training, output_dir=round_dir,
                      warm_start=None if standing is None else standing.final.model,
                      refit=refit, trainer=trainer, keep_last=length.from_folds)
    return result, lane.samples, length


def training_length(run: _LoopRun, model: ModelSpec, chosen: _Candidate,
                    grows: bool) -> TrainingLength:
    """How long the final refit of ``chosen`` trains: the folds' median best epoch per
    stage (`hysteresis_lab.loop.length`), or the configured length where the folds cannot
    say (not a network; a model that ``grows`` through stages from the data, each stage
    its own length)."""
    configured = configured_length(run.whole.config.trainer.max_epochs,
                                   run.training.simulation_epochs)
    if not model.is_network:
        return TrainingLength(configured=configured, fallback="not a network: no epochs")
    if grows and len(growth_stages(model)) > 1:
        return TrainingLength(configured=configured,
                              fallback="the model grows through stages, each its own length")
    return final_length([None if r is None else r.document for r in chosen.folds],
                        configured)


def _candidate_entry(candidate: _Candidate) -> dict[str, Any]:
    """A refit candidate in the report: the effect it adds, place, rate, losses (and where
    it diverged)."""
    entry = {**({"effect": candidate.effect} if candidate.effect else {}),
             **candidate.variant, "refit_lr": candidate.rate,
             "validation_loss": candidate.refit_loss(), "held_out_loss": candidate.check.loss,
             "fold_losses": candidate.check.fold_losses()}
    if any(r is None for r in candidate.folds):
        entry["diverged"] = "in training on " + ", ".join(
            f"fold {j}" for j, r in enumerate(candidate.folds) if r is None)
    return entry


def _choose_next_effect(run: _LoopRun, state: _LoopState, entry: dict[str, Any]) -> bool:
    """Pick the effect the next round adds from the standing diagnosis (recorded in
    ``entry``); False when the loop ends here (nothing significant, or enough rounds)."""
    uncarried = _not_carried(run.model, state.diagnosis, state.tried | state.rejected,
                             run.data.fit.output_integrates)
    if uncarried:
        entry["not_carried"] = uncarried
        log.info("model '%s' has no block for the significant effect(s) %s: not added",
                 run.model.name, uncarried)
    excluded = state.tried | state.rejected | set(uncarried)
    top, reported = next_effect(state.diagnosis, excluded)
    plant = run.data_spec.plant
    while top is not None and not run.settings.add_under_excited:
        if plant is None or fits_plant(top.effect, plant):
            break  # only an effect foreign to the declared plant must show on the data
        unseen = beyond_identification(top.effect, [*run.data.fit.train, *run.data.fit.val],
                                       run.data.fit.test, run.context)
        if unseen is None:
            break
        unseen["plant"] = plant
        entry.setdefault("not_added_under_excited", []).append(unseen)
        log.warning("'%s' not added: its physics is foreign to data.plant=%s and %s "
                    "(loop.add_under_excited=false)", top.effect, plant, unseen["reading"])
        excluded.add(top.effect)
        top, reported = next_effect(state.diagnosis, excluded)
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
    group = named_group(state.diagnosis, top, excluded, run.settings.confounded_margin,
                        run.settings.max_alternatives, plant)
    if group[0] != top.effect:
        entry["named_for_plant"] = {"plant": plant, "top_score": top.effect}
        log.info("'%s' scores highest, but the evidence does not tell it from '%s', whose "
                 "physics fits the declared data.plant=%s: '%s' is named", top.effect,
                 group[0], plant, group[0])
    entry["added"], state.trying = group[0], group
    if len(group) > 1:
        entry["alternatives"] = group[1:]
        log.info("'%s' is confounded with %s (scores within loop.confounded_margin=%g of "
                 "its): each is refitted and the folds keep the best", group[0], group[1:],
                 run.settings.confounded_margin)
    state.tried |= set(group)
    if get_effect(group[0]).block in MODEL_OUTPUT_BLOCKS:  # no input operators to compare
        log.info("'%s' added (it acts on the model's output)", group[0])
        return True
    fit = run.data.fit
    excitation = operator_excitation(group[0], [*fit.train, *fit.val], fit.test, run.context)
    entry["added_excitation"] = excitation.to_dict()
    log.info("'%s' added: %s", group[0], excitation.reading())
    return True


def beyond_identification(effect: str, identification: Sequence[Recording],
                          tests: Sequence[Recording],
                          context: FeatureContext) -> dict[str, Any] | None:
    """Where the ``tests``' inputs (never their outputs) drive an operator of ``effect`` more
    than `UNDER_EXCITED_RATIO` times as hard (RMS) as the ``identification`` data do: the
    ratios and a reading; None where they do not, or the effect has no input operators. A
    refit learns such an effect from data that show little of it, and the folds, cut from
    those data, cannot see the extrapolation."""
    if get_effect(effect).block in MODEL_OUTPUT_BLOCKS:
        return None
    excitation = operator_excitation(effect, identification, tests, context)
    if not under_excited(excitation):
        return None
    return {**excitation.to_dict(), "reading": excitation.reading()}


def _write_report(run: _LoopRun, state: _LoopState, report: dict[str, Any]) -> None:
    """``loop_report.json`` / ``.md`` and the before/after figure (``plots``); the result and
    where the report is, in the log."""
    write_json(report, run.folder.report_json)
    run.folder.report_md.write_text(loop_markdown(report))
    if state.kept and run.plots:
        _before_after_figure(run.data.fit, state.kept[0].final, state.kept[-1].final,
                             state.rounds, state.effects, run.folder.before_after_figure)
    log.info("%s", result_line(report), extra=SUMMARY)
    log.info("report: %s (beside it: %s, each round's fit in round_<n>/)",
             run.folder.report_md, run.folder.REPORT_JSON, extra=SUMMARY)


def _decision(trying: str, kept: bool, reason: str, refit: _Candidate,
              state: _LoopState) -> dict[str, Any]:
    """Why a round's refit with ``trying`` was kept or dropped: the round it was judged
    against (the standing model's) and both pooled held-out losses, per fold too."""
    against = max(i for i, r in enumerate(state.rounds) if not r.get("rejected"))
    before = state.kept[-1].check
    return {
        "effect": trying,
        "kept": kept,
        "against_round": against,
        "held_out_loss": {"before": before.loss, "after": refit.check.loss},
        "fold_losses": {"before": before.fold_losses(), "after": refit.check.fold_losses()},
        "reason": reason,
    }


def _result_round(rounds: list[dict[str, Any]], kept: list[_Standing]) -> int | None:
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


def next_effect(
    diagnosis: Sequence[EffectScore], tried: set[str]
) -> tuple[EffectScore | None, list[str]]:
    """The significant effect to add next (best first, not yet tried on this model) and the
    significant ones that do not depend on the input: free run cannot predict those, so
    they are reported, never added, and the loop goes on with the next."""
    candidates = [d for d in diagnosis if d.significant and d.effect not in tried]
    reported = [d.effect for d in candidates if not d.predictable]
    return next((d for d in candidates if d.predictable), None), reported


def confounded(diagnosis: Sequence[EffectScore], top: EffectScore, tried: set[str],
               margin: float, most: int) -> list[str]:
    """``top`` and the significant, input-driven effects not yet tried whose score lies
    within the share ``margin`` of its (best first, ``most`` in all): the evidence does not
    tell them apart, so each is refitted and the folds choose."""
    close = [d.effect for d in diagnosis
             if d is not top and d.significant and d.predictable and d.effect not in tried
             and d.score >= (1.0 - margin) * top.score]
    return [top.effect, *close][:most]


def named_group(diagnosis: Sequence[EffectScore], top: EffectScore, tried: set[str],
                margin: float, most: int, plant: str | None) -> list[str]:
    """The effects the next round refits, the named one first: ``top`` and those the evidence
    does not tell apart from it (`confounded`), those whose physics fits the declared kind of
    ``plant`` first (`hysteresis_lab.loop.plant`; None: in the order of their scores)."""
    return prefer_plant(confounded(diagnosis, top, tried, margin, most), plant)


def compared_effects(candidates: Sequence[_Candidate]) -> list[dict[str, Any]]:
    """Per effect refitted in a round: its best place and rate on the folds, the pooled and
    per-fold held-out losses, and whether the folds tell it from the best one (lower on a
    majority of them); best first."""
    best: dict[str | None, _Candidate] = {}
    for c in candidates:
        if c.effect not in best or c.check.loss < best[c.effect].check.loss:
            best[c.effect] = c
    ranked = sorted(best.values(), key=lambda c: c.check.loss)
    winner = ranked[0].check.fold_losses()
    rows = []
    for c in ranked:
        losses = c.check.fold_losses()
        wins = sum(w < x for w, x in zip(winner, losses, strict=True))
        rows.append({"effect": c.effect, **c.variant, "refit_lr": c.rate,
                     "held_out_loss": c.check.loss, "fold_losses": losses,
                     "told_apart": c is ranked[0] or 2 * wins > len(losses)})
    return rows


def held_effects(model: ModelSpec, effects: Sequence[str]) -> list[str]:
    """The effects a model holds: those declared and those its structure always has (a
    grey-box's hysteresis cell, `built_in_effects`); the diagnosis looks beyond them."""
    extra = model.cls.built_in_effects(model.settings)
    return [*effects, *(e for e in extra if e not in effects)]


def _not_carried(
    model: ModelSpec, diagnosis: Sequence[EffectScore], tried: set[str],
    output_integrates: bool = False,
) -> list[str]:
    """Significant, input-driven effects the start model's class cannot take (a grey-box
    carries only the effects it has physical blocks for; a network every effect that reaches
    it through its inputs, none that acts on its output; ``model=linear`` a law of the
    velocity, friction, only where its output integrates: ``model.integrator``, by default
    ``output_integrates``, the data set's word)."""
    carried = model.cls.carried_effects
    setting = model.settings.get("integrator")
    integrates = output_integrates if setting is None else bool(setting)

    def carries(effect: str) -> bool:
        if getattr(get_effect(effect), "linear_needs_integrator", False) and not integrates \
                and model.name == "linear":
            return False
        if carried is not None:
            return effect in carried
        return get_effect(effect).block not in MODEL_OUTPUT_BLOCKS

    return [d.effect for d in diagnosis
            if d.significant and d.predictable and d.effect not in tried
            and not carries(d.effect)]


def fit_model(base: RunConfig, splits: DatasetSplits, model: ModelSpec,
              training: TrainingSettings, output_dir: Path, warm_start: Any | None,
              refit: str, trainer: TrainerSettings | None = None,
              keep_last: bool = False) -> RunResult:
    """One fit of the loop: ``base`` (the loop's data, trainer and bookkeeping) with a
    round's ``model`` and ``training`` settings, in ``output_dir``, started from
    ``warm_start`` (None: from the data) with that ``refit`` mode; ``trainer``: another
    length, ``keep_last``: its last weights kept (`hysteresis_lab.fitting.fit`)."""
    config = dataclasses.replace(base, model=model, training=training, output_dir=output_dir,
                                 trainer=trainer or base.trainer,
                                 settings=dataclasses.replace(base.settings, refit=refit,
                                                              keep_last=keep_last))
    return run_model(config, splits=splits, warm_start=warm_start)


def _round_entry(effects: list[str], result: RunResult) -> dict[str, Any]:
    """A round of ``loop_report.json``: its effects and the test errors of the model that
    stands after it (diagnosis and decision follow)."""
    entry: dict[str, Any] = {"effects": list(effects), **_scores(result.document)}
    entry.update(diagnosis=[], added=None)
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
    run: _LoopRun, final: RunResult, check: FoldsCheck, effects: list[str], round_dir: Path,
    number: int,
) -> tuple[list[EffectScore], ResidualEvidence]:
    """Residual analysis (JSON, figure, TensorBoard) and the ranked diagnosis of a round, on
    the diagnosis stretches: by default every fold's held-out stretches, each read from its
    fold's model (which did not train on it), their blocks voting together; recordings named
    in ``data.diagnose`` are read from the result (`hysteresis_lab.loop.data`). Never the
    test recordings. Also the free run they were read from (for the report's figures)."""
    data, settings = run.data, run.settings
    if data.diagnosis == data.validation:
        stretches = data.validation
        predictions = [p for fold in check.folds if fold is not None for p in fold.predictions]
    else:
        stretches = data.diagnosis
        predictions = held_out(final, stretches, data.fit.n_init, run.device).predictions
    n_skip = scoring_start(final.window, data.fit.n_init)
    recordings, residuals, shown, shown_predictions, starts, kept = [], [], [], {}, [], []
    for stretch, prediction in zip(stretches, predictions, strict=True):
        first, stop = max(stretch.start, n_skip), stretch.stop
        rec = _until(stretch.recording, stop)
        prediction = np.asarray(prediction)[:stop]
        e = rec.y - prediction
        e[:first] = np.nan
        starts.append(first)
        recordings.append(rec)
        residuals.append(e)
        kept.append(prediction)
        part = _from(stretch, first)
        shown.append(part)
        shown_predictions[part.name] = {"free_run": prediction[first:]}
    diagnosis = diagnose(
        recordings,
        residuals,
        run.context,
        declared=effects,
        min_score=settings.min_score,
        alpha=settings.alpha,
        lags=evidence_lags(final.window.nb),
        test=settings.significance,
        predictions=kept,
        through_dynamics=settings.diagnosis_through_dynamics,
    )
    if settings.plant_alpha is not None:
        diagnosis = with_plant_prior(diagnosis, run.data_spec.plant, settings.plant_alpha,
                                     settings.min_score)
    write_json(residual_analysis(shown, shown_predictions, 0),
               round_dir / "residual_analysis.json")
    figure = diagnostics_figure(shown, shown_predictions, 0) if run.plots else None
    if figure is not None:
        save_figure(figure, round_dir / DIAGNOSTICS_FIGURE)
    if run.use_tensorboard:
        _log_round_to_tensorboard(round_dir / "tensorboard", figure, diagnosis, number)
    evidence = ResidualEvidence(recordings, kept, starts, [part.name for part in shown])
    return diagnosis, evidence


def _until(rec: Recording, stop: int) -> Recording:
    """``rec`` up to sample ``stop`` (a held-out block's end)."""
    if stop >= rec.n_samples:
        return rec
    return dataclasses.replace(rec, u=rec.u[:stop], y=rec.y[:stop])


def _from(stretch: Stretch, first: int) -> Recording:
    """The scored part of a diagnosis stretch, named as the report names it."""
    rec = stretch.recording
    if first == 0 and stretch.stop == rec.n_samples:
        return rec
    return dataclasses.replace(rec, u=rec.u[first:stretch.stop], y=rec.y[first:stretch.stop],
                               name=stretch.describe())


def _variant_label(variant: Mapping[str, Any]) -> str:
    """A folder name for a refit's model settings (``feedback_on_output_stage``)."""
    return "_".join(f"{key}_{value}" for key, value in variant.items()) or "default"


def _refit_variants(model: ModelSpec, previous: Any | None,
                    added: str | None) -> list[dict[str, Any]]:
    """The model settings a round fits, each a candidate the held-out loss chooses among
    (the class's ``refit_variants``; ``[{}]``: the round's settings alone)."""
    return model.cls.refit_variants(model.to_config(), previous, added) or [{}]


def _refit_rate_stages(model: ModelSpec, training: TrainingSettings,
                       settings: LoopSettings) -> list[list[float]]:
    """The learning rates a refit runs at, in stages: a later stage runs only where the
    refit at the earlier ones does not pass the folds. ``training.refit_lr`` if set, else
    ``loop.refit_lr_factors`` of ``training.lr`` (`grow.refit_rates`), all in one stage;
    where those are null, `POLISHED_REFIT_LR_FACTORS` one after the other for a model whose
    fits the L-BFGS polish ends (a second rate rarely helps a polished refit, but where the
    first fails it can: zoo plant 4), else `REFIT_LR_FACTORS` in one stage."""
    factors = settings.refit_lr_factors
    if factors is None and polishes_fits(model.settings, training):
        rates = refit_rates(training, POLISHED_REFIT_LR_FACTORS)
        return [[rate] for rate in dict.fromkeys(rates)]
    return [refit_rates(training, REFIT_LR_FACTORS if factors is None else factors)]


def _refit_loss(result: RunResult) -> float:
    """The validation loss a refit reached (its own weights, kept or not)."""
    loss = result.refit_validation
    return float(loss["refit"]) if loss else float("inf")


def _refit_mode(refit: str, added: str | None, model_cls: type) -> str:
    """How a round's refit trains (`grow.refit_mode`: the whole model where the added
    effect changes what the fitted part was fitted to)."""
    return refit_mode(added, model_cls, refit)


def _log_round_to_tensorboard(
    log_dir: Path, figure: Any | None, diagnosis: list[Any], number: int
) -> None:
    """Residual diagnostics figure (where drawn) and every tested effect's score, beside the
    round's training logs."""
    from torch.utils.tensorboard import SummaryWriter

    with SummaryWriter(log_dir=str(log_dir)) as writer:
        if figure is not None:
            writer.add_figure("loop/residual_diagnostics", figure, global_step=number,
                              close=False)
        for d in (d for d in diagnosis if d.tested):
            writer.add_scalar(f"loop/diagnosis_score/{d.effect}", d.score, global_step=number)
