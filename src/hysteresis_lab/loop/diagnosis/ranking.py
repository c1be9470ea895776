"""Rank candidate effects by how much of a model's residual each explains on held-out data.

An omitted-variable test per effect. The residual of every test recording is regressed on the
effect's candidate signals *beyond* what the model already has: the input itself and the
operators of every effect it declares (the baseline design). One set of coefficients serves
all recordings, so an effect counts only when one law explains the residual everywhere; an
effect that does not depend on the input (drift) gets coefficients per recording instead. Each
recording is cut into contiguous blocks; every block is predicted by the fit on all the other
blocks (of every recording), and the gain in held-out explained variance over the baseline is
the evidence. A missing effect reaches the output through the system's dynamics, so the
baseline and each input-dependent candidate enter with a few lags (``lags``, a distributed-lag
regression; the loop spans twice the model's input window): the test then sees an effect with
the phase the dynamics give it, and the baseline gets the same freedom. Every recording
weighs the same, however long; the score is the mean over recordings of the held-out gain.
A recording with several outputs (a MIMO system) counts as one recording per output, and
each output gets coefficients of its own (one law per output, shared by the recordings).

An output-side effect (``Effect.block == "output"``: overflow, output clipping) acts after the
dynamics on what the model puts out (a ``"feedback"`` one, a static law of the output fed back
into the dynamics, is read the same way), so its candidate signals come from the model's own
free-run output (``predictions``), not from the input: a model that does not clip overshoots
where the system clips, and its residual follows those excesses. Their baseline also holds
the model's output (a gain error is no overflow). An effect that also acts inside the
dynamics (`Effect.state_evidence`: hysteresis in the feedback, as a Bouc–Wen restoring
force) adds signals of the model's output to its input-side ones. An effect whose evidence
overlaps a simpler one's (`Effect.beyond`: a law in the feedback overlaps a clip at the
output) is significant only when it is also significant beyond that one's signals (its score
stays its own), unless the model already carries the simpler one: a clip is not named a
feedback law.

Each effect is tested on the recordings that can show it. An input-dependent effect: those
whose input moves. An input-independent one (drift): those that hold the input constant — on
a moving input a trend per recording cannot be told apart from slow input-driven error (a
creep transient, a slow hysteresis error) and held out it takes up whichever is there. With no
such recording the effect is reported as not tested, with what to record.

``through_dynamics`` (the loop's default, `loop.diagnosis_through_dynamics`; off in a bare
`diagnose` call): a missing input-side block leaves a residual
of about G(q)·Δ(u), G the model's dynamics; through a lightly damped mode that ring lasts far
longer than the regression's lags. With it, an ARX fit of the model's own free run
(``predictions``) on the baseline signals gives the denominator of its dynamics
(`_model_dynamics`), and every nonlinear input-side effect (its evidence of twice the input is
not twice its evidence; not on the model's output) adds its signals through ``1 / A(q)`` (the
lags give the numerator) and is tested against a baseline that also holds the input and
declared operators through it (so a linear dynamics error stays in the baseline). Effects
linear in the input (resonance, creep) are themselves a change of the dynamics and keep the
plain baseline. For every effect the first rows of each residual are dropped, `SETTLE_FACTOR`
times as many as the slowest pole takes to decay to 1 % (`_settling`), at most
`MAX_SKIPPED_SHARE` of them: a recording that starts
with a jump from rest has a start transient that can outweigh the rest of the residual, and
filters of the input started from rest (the resonance's) fit it whatever its cause. The cost:
an effect that shows only in that start transient (a mode far above the band of a
band-limited input) is no longer seen. Without ``predictions``, or where the fit is unstable,
nothing changes.

Significance: a one-sided Wilcoxon signed-rank test that the held-out block gains are positive
(spurious signals make held-out predictions worse, not better). A block that neither fit
predicts better than nothing carries no evidence and the test leaves it out, so few
informative blocks bound the p-value from below: `BlockCounts` keeps each effect's votes.
``test="pooled"`` (the default) tests all blocks of all recordings at once and asks the mean
gain to reach ``min_score``. ``test="per_recording"`` tests each recording's blocks on their own
(`BLOCKS_PER_RECORDING` of them), adjusts the p-values for the number of recordings (Holm) and
calls an effect significant when one recording's gain reaches ``min_score`` at that adjusted
p: an effect that acts in one regime only (creep on the slowest test, a resonance on the
fastest) is then not diluted by the recordings it cannot act on. Circularly shifted copies of
the candidate signals are no null here: the study's test signals are periodic, and a shifted
copy of a periodic signal is as good a regressor as the original. Nothing here looks at the
name or origin of the data.

The held-out fits are computed from normal equations accumulated block by block, one series
at a time (`normal_equations`): never a stacked design, whose zeros of the other outputs'
coefficients made it gigabytes on a long MIMO data set.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy import signal, stats

from hysteresis_lab.blocks.sections import arx_least_squares
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.base import MODEL_OUTPUT_BLOCKS, Effect, FeatureContext
from hysteresis_lab.effects.registry import available_effects, get_effect
from hysteresis_lab.loop.diagnosis.normal_equations import (
    BlockSums,
    Design,
    Segment,
    accumulate,
    block_edges,
    held_out_sse,
)

log = logging.getLogger(__name__)

#: an input whose peak-to-peak stays within this share of its amplitude counts as held
HELD_SPAN = 1e-3
#: how the held-out block gains are tested (see the module docstring)
TESTS = ("pooled", "per_recording")
#: blocks per recording of the per-recording test (its smallest one-sided p is 2**-blocks)
BLOCKS_PER_RECORDING = 20
#: fewer nonzero block gains than this give no signed-rank test (p = 1)
MIN_RANKED_BLOCKS = 6
#: a block gain within this of zero carries no evidence (the signed-rank test drops it)
ZERO_GAIN = 1e-12
#: orders of the ARX fit of the model's own dynamics (denominator, input lags; `_model_dynamics`)
DYNAMICS_ORDER = (4, 8)
#: the start skipped: this many times the samples the slowest pole of the model's dynamics
#: takes to decay to 1 % (so to 1e-6) ...
SETTLE_FACTOR = 3
#: ... but never more than this share of a residual's scored rows: dynamics that settle over
#: most of a short record (the cascaded tanks' 1024 samples) would take its evidence with them
MAX_SKIPPED_SHARE = 0.1


@dataclass
class EffectScore:
    """Evidence for one candidate effect."""

    effect: str
    #: mean over the recordings it is tested on: held-out share of the residual variance
    #: beyond the baseline
    score: float
    p_value: float
    significant: bool
    evidence: str
    predictable: bool = True
    tested: bool = True  # False: no recording can show the effect (see ``evidence``)
    #: how the held-out blocks voted (None: not tested)
    blocks: BlockCounts | None = None
    #: significant by the declared plant's prior (``loop.plant_alpha``), not at ``loop.alpha``:
    #: tried, but the data alone did not decide it (`hysteresis_lab.loop.plant`)
    by_plant_prior: bool = False

    def to_dict(self) -> dict:
        out = {
            "effect": self.effect,
            "score": self.score,
            "p_value": self.p_value,
            "significant": self.significant,
            "evidence": self.evidence,
            "predictable": self.predictable,
            "tested": self.tested,
        }
        if self.blocks is not None:
            out["blocks"] = dataclasses.asdict(self.blocks)
        if self.by_plant_prior:
            out["by_plant_prior"] = True
        return out


@dataclass(frozen=True)
class BlockCounts:
    """How an effect's held-out blocks voted: those its signals predict better than the
    baseline does (``gaining``), worse (``losing``), and all of them (``held_out``). The rest
    carry no evidence (neither fit predicts them better than nothing) and the signed-rank
    test leaves them out, so the pooled test's p can be no smaller than
    ``2 ** -(gaining + losing)``."""

    held_out: int
    gaining: int
    losing: int

    @property
    def informative(self) -> int:
        return self.gaining + self.losing

    @property
    def silent(self) -> int:
        """The blocks that carry no evidence either way."""
        return self.held_out - self.informative

    @property
    def smallest_p(self) -> float:
        """The smallest one-sided signed-rank p the informative blocks can give (all gaining)."""
        return 2.0 ** -self.informative

    @classmethod
    def of(cls, gains: np.ndarray) -> BlockCounts:
        return cls(len(gains), int(np.sum(gains > ZERO_GAIN)), int(np.sum(gains < -ZERO_GAIN)))


@dataclass
class _Prepared:
    """A recording's residual and baseline regressors (subsampled, de-meaned), both scaled so
    that the residual's sum of squares is 1: every recording, long or short, counts the same in
    the shared fit, and the law residual = regressors @ coef is unchanged by the scaling."""

    e: np.ndarray
    base: np.ndarray
    keep: np.ndarray  # the rows kept (finite residual, subsampled)
    weight: float
    #: the model's free run (lagged, de-meaned, scaled), in the baseline of output-side
    #: effects only (None: not given)
    model_output: np.ndarray | None = None
    #: the baseline signals through the model's dynamics (lagged, de-meaned, scaled), in the
    #: baseline of nonlinear input-side effects only (None: no dynamics; `_model_dynamics`)
    through: np.ndarray | None = None


def _centre(x: np.ndarray) -> np.ndarray:
    """``x`` less its mean; a column that is constant (to round-off: a play operator the
    recording never moves) becomes exactly zero, not round-off that standardising would
    blow up."""
    centred = x - x.mean(axis=0)
    if centred.ndim == 2 and len(centred):
        span = np.ptp(x, axis=0)
        centred[:, span <= 1e-12 * np.max(np.abs(x), axis=0)] = 0.0
    return centred


def _lagged_rows(x: np.ndarray, keep: np.ndarray, lags: Sequence[int]) -> np.ndarray:
    """The rows ``keep`` of ``x`` (N x k) and of its copies delayed by each lag (zeros before
    the start): (len(keep) x k * len(lags))."""
    x = np.asarray(x, dtype=float).reshape(len(x), -1)
    columns = []
    for lag in lags:
        rows = keep - lag
        columns.append(np.where((rows >= 0)[:, None], x[np.maximum(rows, 0)], 0.0))
    return np.column_stack(columns)


def _prepare(
    recording: Recording,
    residual: np.ndarray,
    context: FeatureContext,
    declared: Sequence[str],
    max_points: int,
    lags: Sequence[int],
    held: bool = False,
    model_output: np.ndarray | None = None,
    dynamics: np.ndarray | None = None,
) -> _Prepared:
    """``held``: the input is constant, so the baseline has nothing to regress on and gets no
    columns (de-meaned, they would be round-off, which standardising would blow up).
    ``model_output``: the model's free run, which joins the baseline of output-side effects
    (a gain or level error of the model's output is no overflow). ``dynamics``: the
    denominator of the model's own dynamics (`_model_dynamics`): the rows within its settling
    time of the start are dropped and the baseline signals also enter through it."""
    e_all = np.asarray(residual, dtype=float)[:, 0]  # one output's (see `_one_output_each`)
    keep = np.flatnonzero(np.isfinite(e_all))
    if dynamics is not None and len(keep):
        keep = keep[keep >= keep[0] + _skipped_start(dynamics, len(keep))]
    keep = keep[:: max(1, len(keep) // max_points)]
    e = _centre(e_all[keep])
    weight = 1.0 / (float(np.sqrt(e @ e)) or 1.0)
    if held:
        return _Prepared(e * weight, np.empty((len(keep), 0)), keep, weight)
    base = _baseline_signals(recording.u, context, declared)
    design = _centre(_lagged_rows(base, keep, lags))
    through = None
    if dynamics is not None:
        through = _centre(_lagged_rows(_through_dynamics(base, dynamics), keep, lags)) * weight
    output = None
    if model_output is not None:
        y_model = np.nan_to_num(np.asarray(model_output, dtype=float).reshape(len(e_all), -1))
        output = _centre(_lagged_rows(y_model, keep, lags)) * weight
    return _Prepared(e * weight, design * weight, keep, weight, output, through)


def _baseline_signals(u: np.ndarray, context: FeatureContext,
                      declared: Sequence[str]) -> np.ndarray:
    """The baseline's signals of one recording: its input and the declared effects'
    operators (N x k)."""
    return np.column_stack([u] + [get_effect(name).features(u, context) for name in declared])


def _through_dynamics(x: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The columns of ``x`` (less their first row: at rest before the start) through the
    all-pole filter ``1 / a``; the regression's lags give it its numerator."""
    x = np.asarray(x, dtype=float).reshape(len(x), -1)
    return signal.lfilter([1.0], a, x - x[:1], axis=0)


def _settling(a: np.ndarray) -> int:
    """Samples the start transient of the dynamics ``1 / a`` takes to die out (to 1e-6):
    `SETTLE_FACTOR` times the slowest pole's decay to 1 %."""
    radius = float(np.max(np.abs(np.roots(a)))) if len(a) > 1 else 0.0
    if radius <= 1e-12:
        return 0
    return int(np.ceil(SETTLE_FACTOR * np.log(0.01) / np.log(radius)))


def _skipped_start(a: np.ndarray, scored: int) -> int:
    """The rows left out at the start of a residual with ``scored`` scored rows: the
    settling time of the dynamics ``1 / a`` (`_settling`), at most `MAX_SKIPPED_SHARE` of
    those rows."""
    return min(_settling(a), int(MAX_SKIPPED_SHARE * scored))


def _skipped_report(a: np.ndarray, recordings: Sequence[Recording],
                    residuals: Sequence[np.ndarray]) -> str:
    """What `_prepare` leaves out at the start of each of ``recordings``' residuals, in
    words: the rows of each, and the settling time where the cap cuts it."""
    settling = _settling(a)
    scored = [int(np.isfinite(np.asarray(e, dtype=float).reshape(len(e), -1)[:, 0]).sum())
              for e in residuals]
    skipped = [_skipped_start(a, n) for n in scored]
    parts = ", ".join(f"{left} of {n} on {rec.name}"
                      for rec, left, n in zip(recordings, skipped, scored, strict=True))
    note = (f" (its start transient settles in {settling} samples; at most "
            f"{MAX_SKIPPED_SHARE:.0%} of a residual's scored samples are left out)"
            if any(left < settling for left in skipped) else "")
    return f"scored samples left out at the start: {parts}{note}"


def _model_dynamics(
    recordings: Sequence[Recording],
    residuals: Sequence[np.ndarray],
    model_outputs: Sequence[np.ndarray] | None,
    held: Sequence[bool],
    context: FeatureContext,
    declared: Sequence[str],
) -> list[np.ndarray | None]:
    """Per single-output series, the denominator of the model's own dynamics: a least-squares
    ARX fit (`DYNAMICS_ORDER`) of its free run on the baseline signals (the input and the
    declared operators), from the rows its residual is scored on, pooled over the series of
    that output that move the input. None everywhere when there is no free run, an output
    has no such series, or a fit is unstable."""
    none: list[np.ndarray | None] = [None] * len(recordings)
    if model_outputs is None:
        return none
    na, nb = DYNAMICS_ORDER
    fits: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {}
    for k, (rec, e, y) in enumerate(zip(recordings, residuals, model_outputs, strict=True)):
        scored = np.flatnonzero(np.isfinite(np.asarray(e, dtype=float).reshape(-1)))
        if held[k] or len(scored) <= 2 * (na + nb):
            continue
        base = _baseline_signals(rec.u, context, declared)
        inputs, outputs = fits.setdefault(rec.y_names[0], ([], []))
        inputs.append(base[scored[0]:])
        outputs.append(np.nan_to_num(np.asarray(y, dtype=float).reshape(-1)[scored[0]:]))
    names = {rec.y_names[0] for rec in recordings}
    if not fits or set(fits) != names:
        return none
    found = {}
    for name, (inputs, outputs) in fits.items():
        _, a = arx_least_squares(inputs, outputs, na=na, nb=nb, nk=0)
        if not np.all(np.isfinite(a)) or np.max(np.abs(np.roots(a))) >= 1.0:
            log.info("diagnosis: the ARX fit of the model's dynamics of output %s is unstable; "
                     "the evidence does not pass through it", name)
            return none
        found[name] = a
        of_output = [k for k, rec in enumerate(recordings) if rec.y_names[0] == name]
        log.info("diagnosis through the model's dynamics: output %s, slowest pole |p| = %.4f; "
                 "%s", name, float(np.max(np.abs(np.roots(a)))),
                 _skipped_report(a, [recordings[k] for k in of_output],
                                 [residuals[k] for k in of_output]))
    return [found[rec.y_names[0]] for rec in recordings]


def evidence_lags(nb: int) -> tuple[int, ...]:
    """Lags (samples) of the distributed-lag diagnosis for a model with ``nb`` input lags:
    0 to twice the input window, denser at the start."""
    return tuple(sorted({0, nb // 5, nb // 2, nb, 2 * nb}))


@dataclass
class _Gains:
    """One candidate's evidence: its score and the signed-rank p-values of its block gains."""

    score: float  # mean over recordings of the held-out gain
    p_value: float  # all blocks pooled
    recording_gains: np.ndarray  # held-out gain per recording
    recording_p: np.ndarray  # per recording, Holm-adjusted over the recordings
    block_gains: np.ndarray  # held-out gain per block (of every recording)


def _signed_rank_p(gains: np.ndarray) -> float:
    """One-sided Wilcoxon p that the gains are positive (1 with fewer than
    `MIN_RANKED_BLOCKS` nonzero ones)."""
    nonzero = gains[np.abs(gains) > ZERO_GAIN]
    if len(nonzero) < MIN_RANKED_BLOCKS:
        return 1.0
    return float(stats.wilcoxon(nonzero, alternative="greater").pvalue)


def _holm(p: np.ndarray) -> np.ndarray:
    """Holm's step-down adjustment of the p-values ``p`` for their number."""
    order = np.argsort(p)
    factors = len(p) - np.arange(len(p))
    adjusted = np.empty_like(p)
    adjusted[order] = np.minimum(1.0, np.maximum.accumulate(p[order] * factors))
    return adjusted


def _gains(base_design: Design, full_design: Design) -> _Gains:
    base, full = held_out_sse(base_design), held_out_sse(full_design)
    sst = np.array([max(b.sst, 1e-12) for b in base_design.blocks])
    owner = np.array([b.series for b in base_design.blocks])
    block_gains = (base - full) / sst
    recordings = np.unique(owner)
    per_recording = np.array([
        np.sum(base[owner == r] - full[owner == r]) / np.sum(sst[owner == r]) for r in recordings
    ])
    recording_p = _holm(np.array([_signed_rank_p(block_gains[owner == r]) for r in recordings]))
    return _Gains(
        float(np.mean(per_recording)), _signed_rank_p(block_gains), per_recording, recording_p,
        block_gains,
    )


def _verdict(
    gains: _Gains, test: str, min_score: float, alpha: float, names: Sequence[str]
) -> tuple[bool, float, str]:
    """(significant, the p-value reported, how it was tested) under ``test``."""
    if test == "pooled":
        significant = gains.score >= min_score and gains.p_value <= alpha
        return significant, gains.p_value, "one-sided Wilcoxon over all held-out blocks"
    strong = np.flatnonzero(gains.recording_gains >= min_score)
    if not len(strong):
        best = int(np.argmax(gains.recording_gains))
        return False, 1.0, (
            f"no recording reaches {100 * min_score:g} %; at most "
            f"{100 * gains.recording_gains[best]:.1f} % on {names[best]}"
        )
    best = int(strong[np.argmin(gains.recording_p[strong])])
    p = float(gains.recording_p[best])
    return p <= alpha, p, (
        f"on {names[best]} {100 * gains.recording_gains[best]:.1f} %; one-sided Wilcoxon over "
        f"its blocks, Holm-adjusted over {len(names)} recordings"
    )


def _warn_too_short(blocks: Sequence[BlockSums], names: Sequence[str], alpha: float) -> None:
    """Log the recordings too short for the per-recording test ever to reach ``alpha``."""
    counts = np.bincount([b.series for b in blocks], minlength=len(names))
    # the smallest one-sided signed-rank p of n blocks is 2**-n, times Holm's factor
    ranked = counts >= MIN_RANKED_BLOCKS
    floor = np.where(ranked, 2.0 ** -counts.astype(float), 1.0) * len(names)
    short = [f"{names[i]} ({counts[i]} blocks)" for i in np.flatnonzero(floor > alpha)]
    if short:
        log.warning(
            "per-recording significance cannot reach p <= %g on %s: too short to cut into "
            "enough blocks, so an effect acting only there goes unseen. Fix: longer "
            "recordings, or loop.significance=pooled",
            alpha,
            ", ".join(short),
        )


def _one_output_each(
    recordings: Sequence[Recording], residuals: Sequence[np.ndarray]
) -> tuple[list[Recording], list[np.ndarray], list[int]]:
    """Every output of a recording as a series of its own (named by `Recording.output_label`),
    each weighing as much as a single-output recording; also which output each series is (its
    coefficients are that output's)."""
    singles, columns, outputs = [], [], []
    for rec, residual in zip(recordings, residuals, strict=True):
        residual = np.asarray(residual, dtype=float).reshape(len(residual), -1)
        if residual.shape[1] != rec.ny:
            raise ValueError(
                f"the residual of '{rec.name}' has {residual.shape[1]} column(s), the recording "
                f"{rec.ny} output(s)."
            )
        for j, output in enumerate(rec.y_names):
            singles.append(replace(
                rec, name=rec.output_label(j), y=rec.y[:, [j]], y_names=(output,)
            ))
            columns.append(residual[:, [j]])
            outputs.append(j)
    return singles, columns, outputs


def _holds_input(recording: Recording, context: FeatureContext) -> bool:
    """Whether the recording holds every input constant: its peak-to-peak within 0.1 % of the
    training input's amplitude (a measured hold keeps a little noise)."""
    span = np.ptp(np.asarray(recording.u, dtype=float), axis=0)
    return bool(np.all(span <= HELD_SPAN * np.maximum(context.u_amplitude, 1e-12)))


def _not_tested(
    name: str, description: str, predictable: bool, why: str | None = None
) -> EffectScore:
    """The entry of an effect no recording can show (``why``: the reason, if not the input)."""
    if why is None and predictable:
        why = "no recording diagnosed moves the input"
    elif why is None:
        why = (
            "no recording diagnosed holds the input constant; on a moving input a trend cannot be "
            "told from slow input-driven error. Fix: diagnose a recording with the input held "
            "(data.diagnose=[...]; on the simulator: data.splits.test_hold_s=10 "
            "data.diagnose=[hold_10s])"
        )
    evidence = f"{description}: not tested: {why}"
    return EffectScore(name, 0.0, 1.0, False, evidence, predictable, tested=False)


def _passes_dynamics(effect: Effect, u: np.ndarray, context: FeatureContext) -> bool:
    """Whether the effect's evidence also enters through the model's dynamics: a nonlinear
    operator of the input (its evidence of twice the input is not twice its evidence; ``u``
    one recording's input) that acts ahead of the dynamics (not on the model's output). An
    effect linear in the input (a resonance, creep) is itself a change of the dynamics: the
    filtered baseline would take it up."""
    if not effect.predictable or effect.block in MODEL_OUTPUT_BLOCKS:
        return False
    once, twice = effect.evidence(u, context), effect.evidence(2.0 * u, context)
    return not np.allclose(twice, 2.0 * once, rtol=1e-6, atol=1e-9 * np.max(np.abs(once)))


def _has_state_evidence(effect: Effect) -> bool:
    """Whether the effect also acts inside the dynamics (`Effect.state_evidence`)."""
    return type(effect).state_evidence is not Effect.state_evidence


def _output_evidence(
    effect: Effect, model_outputs: Sequence[np.ndarray], outputs: Sequence[int],
    state: bool = False,
) -> Callable[[int], np.ndarray]:
    """An output-side effect's signals on recording ``k`` from the model's free-run output
    (``state``: its state-side ones), read when asked; the span its levels are set in is
    that output's over all the recordings (one law)."""
    spans = {}
    for j in set(outputs):
        pooled = np.concatenate([
            np.asarray(y, dtype=float).reshape(-1)
            for y, o in zip(model_outputs, outputs, strict=True) if o == j
        ])
        pooled = pooled[np.isfinite(pooled)]
        spans[j] = (float(pooled.min()), float(pooled.max())) if len(pooled) else (0.0, 1.0)
    read = effect.state_evidence if state else effect.output_evidence

    def signals(k: int) -> np.ndarray:
        return read(np.asarray(model_outputs[k], dtype=float).reshape(-1), spans[outputs[k]])

    return signals


@dataclass(frozen=True)
class DiagnosisSettings:
    """How `diagnose` tests: the significance rule (``min_score``, ``alpha``, ``test``, one
    of `TESTS`), the held-out blocks (``folds``), the subsampling (``max_points``) and the
    sample delays of the distributed-lag regression (``lags``, see `evidence_lags`);
    ``through_dynamics``: the start skipped and the evidence also through the model's own
    dynamics (see the module docstring)."""

    min_score: float = 0.05
    alpha: float = 0.01
    folds: int = 5
    max_points: int = 20_000
    lags: tuple[int, ...] = (0,)
    test: str = "pooled"
    through_dynamics: bool = False

    def __post_init__(self) -> None:
        if not self.lags or min(self.lags) < 0:
            raise ValueError(f"lags must be non-negative sample delays, got {list(self.lags)}.")
        if self.test not in TESTS:
            raise ValueError(f"unknown test '{self.test}': one of {list(TESTS)}.")


@dataclass
class _Evidence:
    """The diagnosed recordings, one output each, prepared once for every candidate."""

    recordings: list[Recording]
    outputs: list[int]  # which output of its recording each one is
    prepared: list[_Prepared]
    held: list[bool]  # whether each holds the input constant
    model_outputs: list[np.ndarray] | None
    #: baseline designs (their held-out blocks) per (tested recordings, output-side, through
    #: the model's dynamics), built on first use
    baselines: dict[tuple, Design]
    declared: tuple[str, ...] = ()  # the effects the model carries
    #: per series, the denominator of the model's own dynamics (`_model_dynamics`), or None
    dynamics: list[np.ndarray | None] | None = None


def diagnose(
    recordings: list[Recording],
    residuals: list[np.ndarray],
    context: FeatureContext,
    declared: list[str],
    candidates: list[str] | None = None,
    min_score: float = 0.05,
    alpha: float = 0.01,
    folds: int = 5,
    max_points: int = 20_000,
    lags: Sequence[int] = (0,),
    test: str = "pooled",
    predictions: list[np.ndarray] | None = None,
    through_dynamics: bool = False,
) -> list[EffectScore]:
    """Score every candidate effect not yet declared; best first. ``lags``: delays (samples)
    with which the baseline and the input-dependent candidates enter (see `evidence_lags`);
    ``test``: how significance is tested, one of `TESTS` (see the module docstring);
    ``predictions``: the model's free-run output per recording (``residuals`` is the
    measurement minus it), the evidence of output-side effects (without it they are
    reported as not tested); ``through_dynamics``: drop the start transient and pass the
    input-side evidence through the model's own dynamics, read from ``predictions`` (see
    the module docstring; off by default)."""
    settings = DiagnosisSettings(min_score, alpha, folds, max_points, tuple(lags), test,
                                 through_dynamics)
    if settings.test == "per_recording":
        settings = replace(settings, folds=max(settings.folds, BLOCKS_PER_RECORDING))
    names = [n for n in (candidates or available_effects()) if n not in declared]
    evidence = _prepare_evidence(recordings, residuals, context, declared, predictions, settings)
    results = [_score_effect(get_effect(name), name, evidence, context, settings)
               for name in names]
    results.sort(key=lambda r: (-r.significant, -r.score))
    return results


def _prepare_evidence(
    recordings: list[Recording],
    residuals: list[np.ndarray],
    context: FeatureContext,
    declared: list[str],
    predictions: list[np.ndarray] | None,
    settings: DiagnosisSettings,
) -> _Evidence:
    """Split recordings into one output each and prepare their residuals and baselines."""
    model_outputs = (
        _one_output_each(recordings, predictions)[1] if predictions is not None else None
    )
    recordings, residuals, outputs = _one_output_each(recordings, residuals)
    held = [_holds_input(rec, context) for rec in recordings]
    dynamics = (
        _model_dynamics(recordings, residuals, model_outputs, held, context, declared)
        if settings.through_dynamics else [None] * len(recordings)
    )
    prepared = [
        _prepare(rec, res, context, declared, settings.max_points, settings.lags, hold,
                 None if model_outputs is None else model_outputs[i], dynamics[i])
        for i, (rec, res, hold) in enumerate(zip(recordings, residuals, held, strict=True))
    ]
    return _Evidence(recordings, outputs, prepared, held, model_outputs, {}, tuple(declared),
                     dynamics)


def _baseline_segment(
    evidence: _Evidence, tested: tuple[int, ...], output_side: bool, through: bool = False,
) -> Segment:
    """The baseline's columns (the input and the declared effects; for an output-side effect
    also the model's output; ``through``: also those signals through the model's dynamics)
    on the ``tested`` recordings, coefficients per output."""
    shown = [evidence.prepared[i] for i in tested]

    def columns(k: int) -> np.ndarray:
        p = shown[k]
        parts = [p.base]
        if output_side and p.model_output is not None:
            parts.append(p.model_output)
        if through:
            parts.append(p.through)
        return np.column_stack(parts) if len(parts) > 1 else p.base

    return Segment(tuple(evidence.outputs[i] for i in tested), columns)


def _design(evidence: _Evidence, tested: tuple[int, ...], segments: Sequence[Segment],
            settings: DiagnosisSettings) -> Design:
    """The held-out blocks of the ``tested`` recordings' residuals regressed on
    ``segments``."""
    shown = [evidence.prepared[i] for i in tested]
    edges = block_edges([len(p.e) for p in shown], settings.folds)
    return accumulate([p.e for p in shown], segments, edges)


def _baseline(
    evidence: _Evidence, tested: tuple[int, ...], output_side: bool, settings: DiagnosisSettings,
    through: bool = False,
) -> Design:
    """The baseline design of the ``tested`` recordings (`_baseline_segment`) and its held-out
    blocks."""
    key = (tested, output_side, through)
    if key not in evidence.baselines:
        segment = _baseline_segment(evidence, tested, output_side, through)
        evidence.baselines[key] = _design(evidence, tested, [segment], settings)
        if settings.test == "per_recording" and not output_side:
            _warn_too_short(evidence.baselines[key].blocks,
                            [evidence.recordings[i].name for i in tested], settings.alpha)
    return evidence.baselines[key]


def _signal_reader(
    effect: Effect,
    recordings: Sequence[Recording],
    outputs: Sequence[int],
    model_outputs: Sequence[np.ndarray] | None,
    context: FeatureContext,
    dynamics: Sequence[np.ndarray] | None = None,
) -> Callable[[int], np.ndarray]:
    """The effect's candidate signals on single-output series ``k``, read when asked: from
    its input, or for an output-side effect from the model's output (plus the state-side
    ones from it); ``dynamics`` (per series, an input-side effect's): its input signals also
    through them."""
    if effect.block in MODEL_OUTPUT_BLOCKS:
        assert model_outputs is not None
        return _output_evidence(effect, model_outputs, outputs)
    state = (_output_evidence(effect, model_outputs, outputs, state=True)
             if model_outputs is not None and _has_state_evidence(effect) else None)

    def read(k: int) -> np.ndarray:
        raw = effect.evidence(recordings[k].u, context)
        parts = [raw] if state is None else [raw, state(k)]
        if dynamics is not None:
            parts.append(_through_dynamics(raw, dynamics[k]))
        return parts[0] if len(parts) == 1 else np.column_stack(parts)

    return read


def _signals_of(
    effect: Effect,
    recordings: Sequence[Recording],
    outputs: Sequence[int],
    model_outputs: Sequence[np.ndarray] | None,
    context: FeatureContext,
) -> list[np.ndarray]:
    """The effect's candidate signals on each single-output series (`_signal_reader`)."""
    read = _signal_reader(effect, recordings, outputs, model_outputs, context)
    return [read(k) for k in range(len(recordings))]


def effect_signals(
    name: str,
    recordings: Sequence[Recording],
    context: FeatureContext,
    predictions: Sequence[np.ndarray] | None = None,
) -> list[np.ndarray]:
    """The signals `diagnose` regresses the residual on for effect ``name`` (before its lags):
    one (N x k) array per recording and output, in the order `diagnose` takes them apart
    (every output of a recording in turn). ``predictions``: the model's free run per
    recording, which an output-side effect's signals are read from."""
    effect = get_effect(name)
    if effect.block in MODEL_OUTPUT_BLOCKS and predictions is None:
        raise ValueError(f"effect '{name}' acts on the model's output: pass its free run.")
    singles, _, outputs = _one_output_each(recordings, [r.y for r in recordings])
    model_outputs = (
        None if predictions is None else _one_output_each(recordings, predictions)[1]
    )
    return _signals_of(effect, singles, outputs, model_outputs, context)


def _effect_segment(
    effect: Effect, evidence: _Evidence, tested: tuple[int, ...], context: FeatureContext,
    settings: DiagnosisSettings, through: bool = False,
) -> Segment:
    """An effect's candidate signals on the ``tested`` recordings, lagged and weighted like
    the residual, coefficients per output (per recording for an input-independent one);
    ``through``: its input-side ones also through the model's dynamics. Each recording's
    are computed when the design reads them."""
    shown = [evidence.prepared[i] for i in tested]
    # an input-independent trend gains nothing from delayed copies of itself
    own_lags = settings.lags if effect.predictable else (0,)
    if through:
        assert evidence.dynamics is not None
    read = _signal_reader(
        effect,
        [evidence.recordings[i] for i in tested],
        [evidence.outputs[i] for i in tested],
        None if evidence.model_outputs is None else [evidence.model_outputs[i] for i in tested],
        context,
        dynamics=[evidence.dynamics[i] for i in tested] if through else None,
    )

    def columns(k: int) -> np.ndarray:
        return _centre(_lagged_rows(read(k), shown[k].keep, own_lags)) * shown[k].weight

    groups = (tuple(evidence.outputs[i] for i in tested) if effect.predictable
              else tuple(range(len(tested))))
    return Segment(groups, columns)


def _score_effect(
    effect: Effect, name: str, evidence: _Evidence, context: FeatureContext,
    settings: DiagnosisSettings,
) -> EffectScore:
    """One candidate's held-out gain over the baseline, its significance and its evidence."""
    # input-dependent: where the input moves; input-independent: where it is held
    tested = tuple(i for i, h in enumerate(evidence.held) if h != effect.predictable)
    if not tested:
        return _not_tested(name, effect.description, effect.predictable)
    if effect.block in MODEL_OUTPUT_BLOCKS and evidence.model_outputs is None:
        return _not_tested(name, effect.description, True, why=(
            "acts on the model's output: no free-run prediction was given to read it from"
        ))
    shown_names = [evidence.recordings[i].name for i in tested]
    through = (evidence.dynamics is not None
               and all(evidence.dynamics[i] is not None for i in tested)
               and _passes_dynamics(effect, evidence.recordings[tested[0]].u, context))
    output_side = effect.block in MODEL_OUTPUT_BLOCKS
    base = _baseline(evidence, tested, output_side, settings, through)
    base_columns = _baseline_segment(evidence, tested, output_side, through)
    signals = _effect_segment(effect, evidence, tested, context, settings, through)
    gains = _gains(base, _design(evidence, tested, [base_columns, signals], settings))
    significant, p_value, how = _verdict(gains, settings.test, settings.min_score,
                                         settings.alpha, shown_names)
    blocks = BlockCounts.of(gains.block_gains)
    simpler_names = [other for other in effect.beyond if other not in evidence.declared]
    if simpler_names and significant:  # and beyond the simpler explanation's signals too
        simpler = [_effect_segment(get_effect(other), evidence, tested, context, settings,
                                   through and _passes_dynamics(
                                       get_effect(other), evidence.recordings[tested[0]].u,
                                       context))
                   for other in simpler_names]
        with_it = _design(evidence, tested, [base_columns, *simpler, signals], settings)
        left = _gains(with_it.select(range(1 + len(simpler))), with_it)
        significant, p_left, _ = _verdict(left, settings.test, settings.min_score,
                                          settings.alpha, shown_names)
        if p_left > p_value:  # the test that decided: its blocks' votes go with its p
            p_value, blocks = p_left, BlockCounts.of(left.block_gains)
        how += (f"; beyond the signals of {', '.join(simpler_names)} "
                f"{100 * left.score:.1f} % (p = {p_left:.2g})")
    n_all = len(evidence.recordings)
    where = "" if len(tested) == n_all else (
        f" on the {len(tested)} of {n_all} recordings that "
        + ("move the input" if effect.predictable else "hold the input constant")
    )
    text = (
        f"{effect.description}: explains {100 * gains.score:.1f} % of the residual variance "
        f"of held-out blocks beyond the input and the declared effects{where}"
        f"{' (also through the model dynamics)' if through else ''} "
        f"({how}; {blocks.held_out} blocks, {blocks.gaining} gaining and {blocks.losing} "
        f"losing: p = {p_value:.2g})"
    )
    log.info("%s", text)
    return EffectScore(name, gains.score, p_value, bool(significant), text, effect.predictable,
                       blocks=blocks)
