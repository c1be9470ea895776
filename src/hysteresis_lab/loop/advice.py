"""The loop's advice where an effect cannot be judged for lack of excitation: what to record.

An effect whose residual score reaches ``loop.min_score`` but is not significant on the data
alone (``loop.plant_alpha`` aside), and whose operators the test recordings drive more than
twice as hard as the identification data or the diagnosis recordings
(`hysteresis_lab.loop.diagnosis.excitation`), is reported as not judged:
the data show too little of it to tell. The advice names the recordings that would show it
(`recommend_recordings`): for the simulator (``data=default``) the overrides that add them
(``data.splits.train_sines=[...] data.splits.val_sines=[...]``, and ``data.diagnose`` where
it names the diagnosis recordings), for recorded data a sentence on what to record and where
to pass it. It reads the test recordings' inputs only, never their residual, and changes
no decision of the loop.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.effects.base import MODEL_OUTPUT_BLOCKS, FeatureContext
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.loop.data import LoopData, Stretch
from hysteresis_lab.loop.diagnosis.excitation import (
    UNDER_EXCITED_RATIO,
    RecordingAdvice,
    SineMaker,
    recommend_recordings,
    under_excited_ratio,
)
from hysteresis_lab.loop.diagnosis.ranking import EffectScore
from hysteresis_lab.sim.default_dataset import sine_name, sine_signal

log = logging.getLogger(__name__)

#: the simulator's test amplitude when its config does not set one (`make_default_dataset`)
SIM_AMPLITUDE = 100.0


def unjudged_effects(diagnosis: Sequence[EffectScore], min_score: float) -> list[EffectScore]:
    """Input-driven effects with a score at or above ``min_score`` that the data alone do not
    make significant (one the declared plant's prior made significant is tried, but more
    excitation would still decide it)."""
    return [
        d for d in diagnosis
        if d.tested and d.predictable and (not d.significant or d.by_plant_prior)
        and d.score >= min_score
        and get_effect(d.effect).block not in MODEL_OUTPUT_BLOCKS
    ]


def excitation_advice(
    diagnosis: Sequence[EffectScore],
    data: LoopData,
    data_spec: DataSpec,
    context: FeatureContext,
    min_score: float,
    holdout: float,
) -> list[dict[str, Any]]:
    """Per effect not judged for lack of excitation: the numbers, the recordings to add and
    how (``override``: the simulator's overrides; ``advice``: one sentence). Logged.
    ``holdout``: the share of an added identification recording the diagnosis reads (1: the
    folds hold out every block of it once)."""
    fit = data.fit
    held = holdout if _holds_out(data) and not data_spec.diagnose else None
    make_sine = _sine_maker(fit.test[0].fs) if fit.test and fit.test[0].nu == 1 else None
    advice = []
    for score in unjudged_effects(diagnosis, min_score):
        found = recommend_recordings(
            score.effect, [*fit.train, *fit.val], _scored_parts(data.diagnosis), fit.test,
            context, make_sine, held,
        )
        if found is None:
            continue
        override = (simulator_override(found, data_spec) if is_simulator(data_spec) else None)
        entry = {**found.to_dict(), "score": score.score, "p_value": score.p_value,
                 "override": override,
                 "advice": _sentence(found, score, override, _where(data, data_spec),
                                     len(fit.test), fit.test[0].u_units)}
        log.warning("%s", entry["advice"])
        advice.append(entry)
    return advice


def _holds_out(data: LoopData) -> bool:
    """Whether the folds hold out blocks of the identification recordings (not whole ones)."""
    return any(s.start > 0 or s.stop < s.recording.n_samples for s in data.validation)


def _scored_parts(stretches: Sequence[Stretch]) -> list[Recording]:
    """The part of each diagnosis stretch that is scored (a held-out block)."""
    return [s.scored() for s in stretches]


def _sine_maker(fs: float) -> SineMaker:
    """The simulator's added sine (two periods, one below 1 Hz) at ``fs``."""
    return lambda frequency, amplitude: sine_signal(frequency, fs, float(amplitude[0]))


def is_simulator(data_spec: DataSpec) -> bool:
    """Whether the data set is the built-in simulator's (``data=default``)."""
    splits = data_spec.config.get("splits") or {}
    return str(splits.get("_target_", "")).endswith("make_default_dataset")


def _hz(values: Sequence[float]) -> str:
    return ",".join(f"{float(f):g}" for f in values)


def simulator_override(advice: RecordingAdvice, data_spec: DataSpec) -> list[str]:
    """The simulator overrides that add ``advice``'s sines to the run's own (training,
    validation, and the diagnosis recordings where ``data.diagnose`` names them)."""
    splits = data_spec.config.get("splits") or {}
    train = [float(f) for f in splits.get("train_sines") or []]
    val = [float(f) for f in splits.get("val_sines") or []]
    new_train = [f for f in advice.train_hz if f not in train and f not in val]
    new_val = [f for f in advice.val_hz if f not in val and f not in train]
    override = []
    if new_train:
        override.append(f"data.splits.train_sines=[{_hz(sorted(train + new_train))}]")
    if new_val:
        override.append(f"data.splits.val_sines=[{_hz(sorted(val + new_val))}]")
    if new_val and data_spec.diagnose:
        names = [*data_spec.diagnose, *(f"val_{sine_name(f)}" for f in new_val)]
        override.append(f"data.diagnose=[{','.join(names)}]")
    amplitude = advice.amplitude[0]
    test_amplitude = float(splits.get("amplitude", SIM_AMPLITUDE))
    wanted = None if np.isclose(amplitude, test_amplitude) else float(f"{amplitude:.3g}")
    current = splits.get("train_sine_amplitude")
    if (new_train or new_val) and wanted != (None if current is None else float(current)):
        override.append(f"data.splits.train_sine_amplitude={'null' if wanted is None else wanted}")
    return override


def _ratio(value: float | None) -> str:
    return "never moved there" if value is None else f"{value:.3g}x"


def _tests(driving: Sequence[str], n_tests: int) -> str:
    """The tests that drive the operators: all of them, or their names."""
    if len(driving) == n_tests > 1:
        return f"all {n_tests} tests"
    return f"the test recordings ({', '.join(driving)})"


def _where(data: LoopData, data_spec: DataSpec) -> str:
    """Which recordings the diagnosis reads: ``"diagnose"`` (named in data.diagnose),
    ``"holdout"`` (blocks of the identification recordings) or ``"val"`` (whole ones)."""
    if data_spec.diagnose:
        return "diagnose"
    return "holdout" if _holds_out(data) else "val"


def _sentence(
    advice: RecordingAdvice, score: EffectScore, override: list[str] | None, where: str,
    n_tests: int, u_units: str,
) -> str:
    """What the report and the log say: not judged, why, and what to record (``where``: see
    `_where`; ``n_tests``: how many test recordings there are)."""
    why = (
        f"'{advice.effect}' not judged for lack of excitation: score {score.score:.3f} reaches "
        f"loop.min_score but p = {score.p_value:.4g}; {_tests(advice.driving, n_tests)} "
        f"drive its operators beyond the identification data ({_ratio(advice.identification)}"
        f" RMS) and the diagnosis recordings ({_ratio(advice.diagnosis)}; above "
        f"{UNDER_EXCITED_RATIO:g}x the data show too little of it)"
    )
    after = ""
    if advice.identification_after is not None:
        still = [advice.identification_after, advice.diagnosis_after]
        short = ("; still above the ratio: longer recordings would show more"
                 if any(under_excited_ratio(r) for r in still) else "")
        after = (f" (with them: {_ratio(still[0])} and {_ratio(still[1])}{short})")
    if override:
        return f"{why}. Add these recordings and run the loop again: {' '.join(override)}{after}"
    peak = "/".join(f"{a:.3g}" for a in advice.amplitude)
    low, high = advice.band_hz
    sines = _hz([*advice.train_hz, *advice.val_hz])
    band = f"at {low:g} Hz" if low == high else f"in {low:g}-{high:g} Hz"
    what = (f"record inputs of ±{peak} {u_units} peak {band}, as the tests "
            f"that drive it, at frequencies of their own"
            + (f" (e.g. sines at {sines} Hz)" if sines else ""))
    some = f"those at {_hz(advice.val_hz) or 'other frequencies'} Hz"
    place = {
        "holdout": " and pass them as extra data.train files (the loop's folds hold out a "
                   "block of each)",
        "val": f" and pass them as extra data.train files, {some} among them (the loop's "
               "folds hold out whole recordings)",
        "diagnose": f" and pass them as extra data.train files, and {some} in data.diagnose "
                    "(the recordings the diagnosis reads)",
    }[where] if advice.val_hz or where == "holdout" else " and pass them as extra data.train files"
    return f"{why}. {what[0].upper()}{what[1:]}{place}{after}"

