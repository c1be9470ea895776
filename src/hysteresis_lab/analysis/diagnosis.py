"""Rank candidate effects by how much of a model's residual each explains on held-out data.

An omitted-variable test per effect: regress the residual on the effect's candidate signals
(plus the input itself and a constant, which any model already has) with blocked
cross-validation inside each recording, and score the *gain* in held-out explained variance
over the input-only baseline. Significance comes from circularly shifted copies of the
candidate signals (which keep their autocorrelation but lose their alignment with the
residual): p = share of shifted gains at least as large as the real one. Nothing here looks
at the name or origin of the data.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.effects.registry import available_effects, get_effect

log = logging.getLogger(__name__)


@dataclass
class EffectScore:
    """Evidence for one candidate effect."""

    effect: str
    score: float  # held-out explained share of the residual variance beyond the input
    p_value: float
    significant: bool
    evidence: str
    predictable: bool = True

    def to_dict(self) -> dict:
        return {
            "effect": self.effect,
            "score": self.score,
            "p_value": self.p_value,
            "significant": self.significant,
            "evidence": self.evidence,
            "predictable": self.predictable,
        }


def _design(features: np.ndarray, u: np.ndarray) -> np.ndarray:
    return np.column_stack([np.ones(len(u)), u, features])


def _blocked_cv_sse(x: np.ndarray, e: np.ndarray, folds: int, ridge: float = 1e-6) -> float:
    """Held-out SSE of a ridge regression of ``e`` on ``x`` over contiguous blocks."""
    n = len(e)
    edges = np.linspace(0, n, folds + 1).astype(int)
    mean = x.mean(0)
    scale = x.std(0)
    scale[scale == 0] = 1.0
    z = (x - mean) / scale
    z[:, 0] = 1.0
    sse = 0.0
    for k in range(folds):
        test = slice(edges[k], edges[k + 1])
        train = np.ones(n, bool)
        train[test] = False
        a = z[train]
        gram = a.T @ a + ridge * len(a) * np.eye(a.shape[1])
        coef = np.linalg.solve(gram, a.T @ e[train])
        sse += float(np.sum((e[test] - z[test] @ coef) ** 2))
    return sse


def _gain(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]], folds: int) -> float:
    """Summed over recordings: (SSE_input_only - SSE_with_effect) / SST."""
    sst = sum(float(np.sum((e - e.mean()) ** 2)) for e, _, _ in parts)
    base = sum(_blocked_cv_sse(_design(np.zeros((len(u), 0)), u), e, folds) for e, u, _ in parts)
    full = sum(_blocked_cv_sse(_design(f, u), e, folds) for e, u, f in parts)
    return (base - full) / sst if sst > 0 else 0.0


def diagnose(
    recordings: list[Recording],
    residuals: list[np.ndarray],
    context: FeatureContext,
    declared: list[str],
    candidates: list[str] | None = None,
    min_score: float = 0.05,
    alpha: float = 0.05,
    n_shifts: int = 39,
    folds: int = 5,
    max_points: int = 20_000,
    seed: int = 0,
) -> list[EffectScore]:
    """Score every candidate effect not yet declared; best first."""
    names = [n for n in (candidates or available_effects()) if n not in declared]
    rng = np.random.default_rng(seed)
    results = []
    for name in names:
        effect = get_effect(name)
        parts = []
        for rec, residual in zip(recordings, residuals, strict=True):
            features = effect.evidence(rec.u, context)
            step = max(1, rec.n_samples // max_points)
            e = np.asarray(residual, dtype=float)[:, 0]
            keep = np.isfinite(e)
            sel = np.flatnonzero(keep)[::step]
            parts.append((e[sel], rec.u[sel], features[sel]))
        score = _gain(parts, folds)
        null = []
        for _ in range(n_shifts):
            shifted = []
            for e, u, f in parts:
                offset = int(
                    rng.integers(len(e) // 10, max(len(e) - len(e) // 10, len(e) // 10 + 1))
                )
                shifted.append((e, u, np.roll(f, offset, axis=0)))
            null.append(_gain(shifted, folds))
        p_value = (1 + sum(v >= score for v in null)) / (n_shifts + 1)
        significant = score >= min_score and p_value <= alpha
        evidence = (
            f"{effect.description}: explains {100 * score:.1f} % of the held-out residual "
            f"variance beyond the input (p = {p_value:.3f}, {n_shifts} shifted copies)"
        )
        results.append(
            EffectScore(
                name, float(score), float(p_value), bool(significant), evidence, effect.predictable
            )
        )
        log.info("%s", evidence)
    results.sort(key=lambda r: (-r.significant, -r.score))
    return results
