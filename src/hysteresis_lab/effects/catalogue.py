"""The built-in effects. Each is small: its operators and a line on the physics it stands for."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy import signal

from hysteresis_lab.effects.base import Effect, FeatureContext
from hysteresis_lab.physics.filters import lowpass_bank, resonator_bank
from hysteresis_lab.physics.play import play_operators
from hysteresis_lab.physics.static import dead_zone, rate


def _seconds(taus: np.ndarray) -> str:
    """Time constants as ``0.1, 1 s``."""
    return ", ".join(f"{t:.3g}" for t in taus) + " s"


def _per_input(u: np.ndarray, make) -> np.ndarray:
    return np.column_stack([make(u[:, i], i) for i in range(u.shape[1])])


class Hysteresis(Effect):
    """Rate-independent hysteresis memory: Prandtl–Ishlinskii play operators (8 thresholds)
    of the input, and of the model's own output as state evidence (in the dynamics'
    feedback)."""

    name = "hysteresis"
    description = "hysteresis memory (Prandtl-Ishlinskii play operators)"
    fractions = np.array([0.02, 0.05, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8])

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        return _per_input(
            u,
            lambda x, i: play_operators(
                np.ascontiguousarray(x), self.fractions * ctx.u_amplitude[i]
            ),
        )

    def state_evidence(self, y_model: np.ndarray, span: tuple[float, float]) -> np.ndarray:
        """Play operators of the model's output (thresholds 2-40 % of its span): hysteresis
        in the feedback of the dynamics, such as a Bouc–Wen restoring force."""
        width = max(span[1] - span[0], 1e-12)
        y = np.ascontiguousarray(np.nan_to_num(np.asarray(y_model, dtype=float).reshape(-1)))
        return play_operators(y, np.array([0.02, 0.05, 0.1, 0.2, 0.4]) * width)


class Creep(Effect):
    """Creep: slow first-order filter bank of the input (time constants 0.1 s ... 100 s).

    Creep is the slow drift after a step, counted from 0.1 s on (the manufacturers' law
    ``x(t) = x(0.1 s) * (1 + gamma * log10(t / 0.1 s))``); faster memory is the actuator's
    dynamics, which the network's lags and the resonance effect cover. Only time constants
    the training data can show are used: at least 20 samples and at most half the longest
    training recording (a slower filter never moves during training, and on a long test
    signal its output would lie far outside what the model was fitted on).
    """

    name = "creep"
    description = "creep (slow first-order filter bank, 0.1-100 s)"
    time_constants_s = np.array([0.1, 1.0, 10.0, 100.0])

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        return _per_input(u, lambda x, i: lowpass_bank(x, ctx.fs, self.usable(ctx)))

    #: a filter is used where the training data hold this many samples of its time constant…
    MIN_SAMPLES_PER_TAU = 20.0
    #: … and their longest recording is at least this many of its time constants
    MIN_DURATION_PER_TAU = 2.0

    def _bounds(self, ctx: FeatureContext) -> tuple[float, float]:
        """The fastest and the slowest time constant (s) the training data can show."""
        fastest = self.MIN_SAMPLES_PER_TAU / ctx.fs
        return fastest, max(ctx.duration_s / self.MIN_DURATION_PER_TAU, fastest)

    def usable(self, ctx: FeatureContext) -> np.ndarray:
        taus = self.time_constants_s
        fastest, slowest = self._bounds(ctx)
        usable = taus[(taus >= fastest) & (taus <= slowest)]
        # training data too short for any of them: the slowest filter it can still show
        return usable if len(usable) else np.array([min(slowest, taus[-1])])

    def unshown(
        self, ctx: FeatureContext, settings: Mapping[str, Any] | None = None
    ) -> str | None:
        """The filters the training data are too short (or too coarsely sampled) for: the
        operators leave them out; a model with filters of its own (``settings``'
        ``creep_time_constants_s``: the linear and grey-box models) keeps them, unidentified."""
        own = (settings or {}).get("creep_time_constants_s")
        taus = np.sort(np.asarray(own if own else self.time_constants_s, dtype=float))
        fastest, slowest = self._bounds(ctx)
        fate = "never move over it" if own else "are left out"
        parts = []
        too_slow = taus[taus > slowest]
        if len(too_slow):
            parts.append(
                f"its slowest filter is {taus[-1]:g} s but the longest training record is "
                f"{ctx.duration_s:.3g} s, so the filters of {_seconds(too_slow)} {fate} "
                f"(a filter needs a record {self.MIN_DURATION_PER_TAU:g}x its time constant); "
                f"record at least {self.MIN_DURATION_PER_TAU * taus[-1]:g} s, or drop creep "
                "from model.effects"
            )
        too_fast = taus[taus < fastest]
        if len(too_fast):
            parts.append(
                f"its filters of {_seconds(too_fast)} span fewer than "
                f"{self.MIN_SAMPLES_PER_TAU:g} samples at {ctx.fs:g} Hz"
                + ("" if own else " and are left out")
                + f"; sample at {self.MIN_SAMPLES_PER_TAU / too_fast[0]:g} Hz or faster to "
                "show them"
            )
        if not parts:
            return None
        used = "" if own else f" (used: {_seconds(self.usable(ctx))})"
        return f"creep: {'; '.join(parts)}{used}."


class Resonance(Effect):
    """Unmodelled structural dynamics: resonant filters of the input on a log frequency grid."""

    name = "resonance"
    description = "resonance / unmodelled dynamics (band-pass filters of the input)"

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        grid = np.geomspace(0.01 * ctx.fs, 0.4 * ctx.fs, 12)
        return _per_input(u, lambda x, i: resonator_bank(x, ctx.fs, grid))


class RateDependence(Effect):
    """Rate-dependent behaviour: input rate and its magnitude-weighted input."""

    name = "rate"
    description = "rate dependence (input-rate features)"

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        def make(x: np.ndarray, i: int) -> np.ndarray:
            r = rate(x, ctx.fs) / (2 * np.pi * 100.0 * max(ctx.u_amplitude[i], 1e-12))
            return np.column_stack([r, np.abs(r) * x / max(ctx.u_amplitude[i], 1e-12)])

        return _per_input(u, make)


class Drift(Effect):
    """Drift / offset: a slow trend that does not depend on the input (time ramps)."""

    name = "drift"
    description = "drift / offset (slow trend, independent of the input)"
    predictable = False

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        t = np.arange(len(u)) / ctx.fs
        scale = max(ctx.duration_s, 1e-9)
        return np.column_stack([t / scale, (t / scale) ** 2])


class Saturation(Effect):
    """Saturation: the clipped-off excess of the input over 70-95 % of its range.

    Amplifier clipping happens ahead of the actuator's dynamics, so a network takes it in
    through the input block: ``u - 1 * excess`` is the clipped input.
    """

    name = "saturation"
    description = "saturation (clipped-input features)"
    block = "input"
    fractions = np.array([0.7, 0.8, 0.9, 0.95])

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        def make(x: np.ndarray, i: int) -> np.ndarray:
            limits = self.fractions * ctx.u_amplitude[i]
            return np.column_stack([x - np.clip(x, -c, c) for c in limits])

        return _per_input(u, make)


class DeadZone(Effect):
    """Dead zone: the input with a band around zero removed (2-20 % of its range)."""

    name = "dead_zone"
    description = "dead zone (input with a band around zero removed)"
    fractions = np.array([0.02, 0.05, 0.1, 0.2])

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        return _per_input(
            u,
            lambda x, i: np.column_stack(
                [dead_zone(x, f * ctx.u_amplitude[i]) for f in self.fractions]
            ),
        )


class Backlash(Effect):
    """Backlash: single wide play operators (gear/clamp play, 5-15 % of the range)."""

    name = "backlash"
    description = "backlash (wide play operators)"
    fractions = np.array([0.05, 0.1, 0.15])

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        return _per_input(
            u,
            lambda x, i: play_operators(
                np.ascontiguousarray(x), self.fractions * ctx.u_amplitude[i]
            ),
        )


class _ReadFromModelOutput(Effect):
    """An effect with no input operators whose evidence is the model's own free-run output
    (`Effect.output_evidence`), placed on its training range."""

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        return np.zeros((len(u), 0))

    @staticmethod
    def _on_range(y_model: np.ndarray, span: tuple[float, float]) -> tuple[np.ndarray, float,
                                                                            float]:
        """The output as a 1-D array, the range's low end and its width."""
        low, high = span
        return np.asarray(y_model, dtype=float).reshape(-1), low, max(high - low, 1e-12)


class Overflow(_ReadFromModelOutput):
    """Output saturation / overflow: the output cannot pass a level (a tank overflows, a
    sensor or an amplifier stage clips), after the dynamics.

    It has no input operators: a model carries it as an output block (``model=linear``:
    ``y - w_hi relu(y - c_hi) + w_lo relu(c_lo - y)``). Its evidence is the model's own
    free-run output beyond 70-95 % of its range on either side: a model that does not clip
    overshoots where the system clips, so its residual follows those excesses.
    """

    name = "overflow"
    description = "output saturation / overflow (the model's own output clipped near its extremes)"
    block = "output"
    fractions = np.array([0.7, 0.8, 0.9, 0.95])
    #: an upstream storage held at its rim: the excesses through a first-order storage
    poles = (0.9,)

    def output_evidence(self, y_model: np.ndarray, span: tuple[float, float]) -> np.ndarray:
        y, low, width = self._on_range(y_model, span)
        high = low + width
        upper = [np.maximum(y - (low + f * width), 0.0) for f in self.fractions]
        lower = [np.minimum(y - (high - f * width), 0.0) for f in self.fractions]
        clips = np.column_stack(upper + lower)
        stored = [signal.lfilter([1.0 - p], [1.0, -p], clips, axis=0) for p in self.poles]
        return np.nan_to_num(np.column_stack([clips, *stored]))


class NonlinearFeedback(_ReadFromModelOutput):
    """A static nonlinearity in the dynamics' feedback (a Lur'e system): what leaves or
    restores the system depends on its own output level as no linear law does — a tank's
    outflow through an orifice (Torricelli, ``sqrt`` of the level), a hardening or softening
    spring.

    It has no input operators: a model carries it as the dynamics in a closed loop with a
    function of their output (``model=linear``: piecewise linear, weights from zero, knots
    ``model.feedback_knots``). Its evidence is the model's own free-run output's distance
    from the middle of its range, squared and cubed (a linear law fitted to a curved one
    leaves a residual that follows the curvature, over the whole range), a sample late and
    smoothed by first-order filters (time constants of about 2 and 10 samples): what is fed
    back reaches the output through the dynamics. A clip at the output (`Overflow`) bends
    the output sharply at one level and at once; these smooth curves do not. Where the two
    overlap the clip is the simpler explanation: this effect is significant only where it is
    also significant beyond the overflow's signals (`beyond`).
    """

    name = "nonlinear_feedback"
    description = ("nonlinear feedback / level-dependent outflow (a static law of the "
                   "model's own output inside its dynamics)")
    block = "feedback"
    #: a clip at the output is the simpler explanation of a bent output: this effect is
    #: significant only beyond it too
    beyond = ("overflow",)
    #: powers of the output's distance from the middle of its range
    powers = (2, 3)
    #: first-order smoothing of the law (time constants of about 2 and 10 samples)
    poles = (0.6, 0.9)

    def output_evidence(self, y_model: np.ndarray, span: tuple[float, float]) -> np.ndarray:
        y, low, width = self._on_range(y_model, span)
        level = (y - low) / width
        law = (level - 0.5)[:, None] ** np.asarray(self.powers)
        law = np.vstack([np.zeros((1, law.shape[1])), law[:-1]])  # fed back: a sample late
        smoothed = [signal.lfilter([1.0 - p], [1.0, -p], law, axis=0) for p in self.poles]
        return np.nan_to_num(np.column_stack(smoothed))
