"""How hard the test recordings drive an effect's operators, against the identification data.

A refit learns an added effect's weights from the training data. Where the test recordings
drive the effect's operators far beyond anything those data showed (amplifier clipping
identified inside the linear range, play operators of wide thresholds under a multisine that
rarely turns at full amplitude), the refit learns the effect from data that show little of
it, and a small gain says more about the data than about the effect. The loop reports this
ratio for every effect it adds.

The same ratio tells why an effect may go unjudged: where the residual of the diagnosis
recordings holds a share of the effect (its score reaches ``loop.min_score``) but too few of
its moments to be significant, and the tests drive its operators far harder, the data cannot
say. `recommend_recordings` then names recordings that would: sines at the amplitude of the
tests that drive the operators, at frequencies between theirs (never a test's), for training
and for validation, with the ratios they would give. Only the test recordings' *inputs* are
read, never their residual: the advice chooses no effect.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.effects.registry import get_effect

#: above this ratio the report says the identification data show little of the effect
UNDER_EXCITED_RATIO = 2.0


@dataclass(frozen=True)
class Excitation:
    """Per operator channel of an effect: RMS about the mean on the tests over the same on
    the identification data (None: the operator moves on the tests but never moved there)."""

    effect: str
    ratios: dict[str, float | None]

    @property
    def worst(self) -> tuple[str, float | None]:
        """The channel the tests drive hardest beyond the identification data."""
        return max(self.ratios.items(), key=lambda item: np.inf if item[1] is None else item[1])

    def reading(self) -> str:
        """One line for the report."""
        channel, ratio = self.worst
        if not under_excited_ratio(ratio):
            return (
                f"the tests drive no operator of '{self.effect}' more than {ratio:.2g}x as "
                f"hard (RMS) as the identification data ({channel})"
            )
        if ratio is None:
            return (
                f"'{channel}' never moves in the identification data but does on the tests: "
                f"the refit cannot learn '{self.effect}' there; identification data that "
                "drive it as the tests do would"
            )
        return (
            f"'{channel}' moves {ratio:.3g}x less (RMS) in the identification data than on "
            f"the tests: the refit learns '{self.effect}' from data that show little of it; "
            "identification data that drive it as the tests do would show more"
        )

    def to_dict(self) -> dict[str, object]:
        channel, ratio = self.worst
        return {
            "effect": self.effect,
            "worst_channel": channel,
            "worst_ratio": ratio,
            "ratios": self.ratios,
            "reading": self.reading(),
        }


def operator_excitation(
    effect: str,
    identification: Sequence[Recording],
    tests: Sequence[Recording],
    ctx: FeatureContext,
) -> Excitation:
    """Compare how much ``effect``'s operators move on ``tests`` and on ``identification``."""
    return _from_spreads(effect, _spread(effect, [r.u for r in identification], ctx),
                         _spread(effect, [r.u for r in tests], ctx))


def _spread(effect: str, inputs: Sequence[np.ndarray], ctx: FeatureContext) -> np.ndarray:
    """RMS about the mean of each of ``effect``'s operator channels over ``inputs``."""
    operator = get_effect(effect)
    values = np.concatenate([operator.features(u, ctx) for u in inputs])
    return np.sqrt(np.mean((values - values.mean(axis=0)) ** 2, axis=0))


def _from_spreads(effect: str, train: np.ndarray, test: np.ndarray) -> Excitation:
    """The ratios of the operator spreads ``test`` over ``train`` (`_spread`)."""
    ratios: dict[str, float | None] = {}
    for j, (on_train, on_test) in enumerate(zip(train, test, strict=True)):
        if on_train > 0:
            ratios[f"{effect}_{j}"] = float(on_test / on_train)
        else:  # never moved while identifying: None if the tests move it, else no contrast
            ratios[f"{effect}_{j}"] = None if on_test > 0 else 1.0
    return Excitation(effect, ratios)


def under_excited(excitation: Excitation) -> bool:
    """Whether the tests drive some operator more than `UNDER_EXCITED_RATIO` times as hard."""
    return under_excited_ratio(excitation.worst[1])


#: at most this many added sines between two neighbouring test frequencies
MAX_PER_GAP = 3

#: makes the input of an added sine recording: (frequency in Hz, amplitude per input) -> u
SineMaker = Callable[[float, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class RecordingAdvice:
    """Recordings that would drive an effect's operators as the tests do.

    ``identification`` / ``diagnosis``: the worst ratio (tests over those data; None: never
    moved there) now and with the recommended sines added (``*_after``; None when no input
    could be made for them). ``train_hz`` go to training, ``val_hz`` to the validation and
    diagnosis recordings; ``amplitude``: their peak per input (that of the tests that drive
    the operators, ``driving``, whose frequencies span ``band_hz``)."""

    effect: str
    identification: float | None
    diagnosis: float | None
    driving: list[str]
    amplitude: list[float]
    band_hz: tuple[float, float]
    train_hz: list[float]
    val_hz: list[float]
    identification_after: float | None = None
    diagnosis_after: float | None = None

    def to_dict(self) -> dict[str, object]:
        return dataclasses.asdict(self)


def dominant_frequency(u: np.ndarray, fs: float) -> float:
    """The frequency (Hz) of the strongest line of ``u``'s spectrum (all inputs summed);
    0 for an input that does not move."""
    x = np.asarray(u, dtype=float).reshape(len(u), -1)
    power = np.sum(np.abs(np.fft.rfft(x - x.mean(axis=0), axis=0)) ** 2, axis=1)
    if len(power) < 2 or not np.any(power[1:] > 0):
        return 0.0
    return float((1 + np.argmax(power[1:])) * fs / len(x))


def _round(f: float) -> float:
    """Two significant digits."""
    return float(f"{f:.2g}")


def between_frequencies(
    tests_hz: Sequence[float], driving_hz: Sequence[float], per_gap: int = 1
) -> list[float]:
    """Frequencies beside the ``driving_hz`` tests and apart from every test's (two
    significant digits): ``per_gap`` evenly spaced on a log scale between each pair of
    neighbouring test frequencies one of which drives (1: their geometric midpoint); where
    that gives fewer than two, also the lowest driving frequency ÷ sqrt(2) and the highest
    x sqrt(2)."""
    tests = sorted({f for f in tests_hz if f > 0})
    driving = sorted({f for f in driving_hz if f > 0})
    picked = {
        _round(low * (high / low) ** (j / (per_gap + 1)))
        for low, high in itertools.pairwise(tests) if low in driving or high in driving
        for j in range(1, per_gap + 1)
    }
    if len(picked) < 2 and driving:
        picked |= {_round(driving[0] / np.sqrt(2)), _round(driving[-1] * np.sqrt(2))}
    return sorted(picked - set(tests))


def _split_roles(
    candidates: list[float], for_training: bool, for_diagnosis: bool, held_out: bool
) -> tuple[list[float], list[float]]:
    """Candidates to training and to validation: all to training where the loop diagnoses
    held-out ends of the training recordings (``held_out``); else every other one to each
    where both need them (training the first, so the lowest frequencies are learnt from)."""
    if held_out:
        return candidates, []
    if for_training and for_diagnosis and len(candidates) > 1:
        return candidates[0::2], candidates[1::2]
    if for_diagnosis and not for_training:
        return [], candidates
    return candidates, []


def under_excited_ratio(ratio: float | None) -> bool:
    """Whether a worst ratio (None: never moved) is above `UNDER_EXCITED_RATIO`."""
    return ratio is None or ratio > UNDER_EXCITED_RATIO


def _worst_after(after: dict[str, float | None]) -> float:
    """The largest ratio the added sines leave (inf: an operator still never moves); 0
    where no ratio could be computed, or where every one is within the ratio (the first
    such attempt is taken)."""
    ratios = [np.inf if r is None else r for r in after.values()]
    return 0.0 if not ratios or max(ratios) <= UNDER_EXCITED_RATIO else float(max(ratios))


def _added_inputs(
    make_sine: SineMaker, amplitude: np.ndarray, train_hz: list[float], val_hz: list[float],
    held_out: float | None,
) -> dict[str, list[np.ndarray]]:
    """The added sines' inputs as the identification data and the diagnosis would hold
    them (where the loop holds out the end of each training recording: those ends)."""
    def sines(frequencies: list[float]) -> list[np.ndarray]:
        return [np.reshape(make_sine(f, amplitude), (-1, len(amplitude))) for f in frequencies]

    train, val = sines(train_hz), sines(val_hz)
    diagnosed = val if held_out is None else [
        u[int(round((1.0 - held_out) * len(u))):] for u in train]
    return {"identification": [*train, *val], "diagnosis": diagnosed}


def recommend_recordings(
    effect: str,
    identification: Sequence[Recording],
    diagnosis: Sequence[Recording],
    tests: Sequence[Recording],
    ctx: FeatureContext,
    make_sine: SineMaker | None = None,
    held_out: float | None = None,
) -> RecordingAdvice | None:
    """Recordings to add where the tests drive ``effect``'s operators more than
    `UNDER_EXCITED_RATIO` times as hard as the ``identification`` (training and validation)
    or the ``diagnosis`` recordings do; None where neither is the case. ``make_sine`` gives
    an added sine's input (e.g. the simulator's): with it the ratios the added sines would
    give are computed too. ``held_out``: the share at the end of every training recording
    that is validated and diagnosed on (data without validation recordings; then every
    added recording is a training one)."""
    on_tests = _spread(effect, [r.u for r in tests], ctx)
    on_identification = _spread(effect, [r.u for r in identification], ctx)
    now = {
        "identification": _from_spreads(effect, on_identification, on_tests),
        "diagnosis": _from_spreads(effect, _spread(effect, [r.u for r in diagnosis], ctx),
                                   on_tests),
    }
    lacking = {role: under_excited(e) for role, e in now.items()}
    if not any(lacking.values()):
        return None
    driving = [t for t in tests if under_excited(
        _from_spreads(effect, on_identification, _spread(effect, [t.u], ctx)))]
    driving = driving or list(tests)
    hz = {t.name: dominant_frequency(t.u, t.fs) for t in tests}
    amplitude = np.atleast_1d(np.max([np.max(np.abs(t.u), axis=0) for t in driving], axis=0))
    roles = {"identification": identification, "diagnosis": diagnosis}
    attempts = []
    for per_gap in range(1, MAX_PER_GAP + 1):  # denser until the added sines suffice
        candidates = between_frequencies(list(hz.values()), [hz[t.name] for t in driving],
                                         per_gap)
        train_hz, val_hz = _split_roles(candidates, lacking["identification"],
                                        lacking["diagnosis"], held_out is not None)
        if make_sine is None or not candidates:
            attempts.append((train_hz, val_hz, {}))
            break
        added = _added_inputs(make_sine, amplitude, train_hz, val_hz, held_out)
        after = {
            f"{role}_after": _from_spreads(
                effect, _spread(effect, [*(r.u for r in recordings), *added[role]], ctx),
                on_tests).worst[1]
            for role, recordings in roles.items()
        }
        attempts.append((train_hz, val_hz, after))
        if not any(under_excited_ratio(r) for r in after.values()):
            break
    # the first that suffices, else the one that comes closest
    train_hz, val_hz, after = min(attempts, key=lambda a: _worst_after(a[2]))
    driving_hz = [hz[t.name] for t in driving]
    return RecordingAdvice(
        effect=effect,
        identification=now["identification"].worst[1],
        diagnosis=now["diagnosis"].worst[1],
        driving=[t.name for t in driving],
        amplitude=[float(a) for a in amplitude],
        band_hz=(min(driving_hz), max(driving_hz)),
        train_hz=train_hz,
        val_hz=val_hz,
        **after,
    )
