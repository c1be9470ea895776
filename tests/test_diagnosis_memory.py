"""The effect ranking's held-out fits come from normal equations accumulated block by block
(`normal_equations`); they must equal the plain computation: every series stacked into one
design (zeros in the other groups' columns), standardised by np.std, and each block predicted
by a direct least-squares ridge fit on the stacked rows of all the others."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal, stats

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.loop.diagnosis.normal_equations import (
    Design,
    Segment,
    accumulate,
    block_edges,
    held_out_sse,
)
from hysteresis_lab.loop.diagnosis.ranking import (
    DiagnosisSettings,
    _baseline_segment,
    _effect_segment,
    _passes_dynamics,
    _prepare_evidence,
    diagnose,
    evidence_lags,
)
from hysteresis_lab.models.augment import feature_context
from hysteresis_lab.physics.play import play_operators

RIDGE = 1e-4


def _stacked(columns: list[list[np.ndarray]], groups: list[tuple[int, ...]]) -> np.ndarray:
    """The plain design: per segment, each group's columns of their own (zeros in the rows
    of the other groups' series), all series' rows stacked, each column divided by its std."""
    parts = []
    for s, segment_groups in enumerate(groups):
        keys = sorted(set(segment_groups))
        rows = []
        for i, group in enumerate(segment_groups):
            x = columns[i][s]
            block = np.zeros((len(x), x.shape[1] * len(keys)))
            start = keys.index(group) * x.shape[1]
            block[:, start : start + x.shape[1]] = x
            rows.append(block)
        parts.append(np.vstack(rows))
    design = np.hstack(parts)
    scale = np.std(design, axis=0)
    scale[scale == 0] = 1.0
    return design / scale


def _direct_held_out_sse(design: np.ndarray, e: np.ndarray, edges: list[np.ndarray]
                         ) -> np.ndarray:
    """Each block's SSE under the ridge fit on the other blocks' stacked rows (an augmented
    least-squares problem, no normal equations), capped at its SST."""
    offsets = np.cumsum([0] + [int(k[-1]) for k in edges])
    bounds = [(offsets[i] + a, offsets[i] + b)
              for i, k in enumerate(edges) for a, b in zip(k[:-1], k[1:], strict=True)]
    root = np.sqrt(RIDGE * len(e)) * np.eye(design.shape[1])
    sse = []
    for start, stop in bounds:
        train = np.r_[0:start, stop:len(e)]
        coef, *_ = np.linalg.lstsq(np.vstack([design[train], root]),
                                   np.concatenate([e[train], np.zeros(design.shape[1])]),
                                   rcond=None)
        held = e[start:stop]
        sse.append(min(float(np.sum((held - design[start:stop] @ coef) ** 2)),
                       float(held @ held)))
    return np.array(sse)


def _random_series(seed: int) -> tuple[list[np.ndarray], list[list[np.ndarray]]]:
    """Residuals of five series of different lengths and their columns of three segments
    (widths 3, 2, 2); the first segment's last column is zero on every series."""
    rng = np.random.default_rng(seed)
    residuals, columns = [], []
    for n in (130, 95, 160, 70, 120):
        x = [rng.normal(size=(n, 3)) * [1.0, 3.0, 0.0], rng.normal(size=(n, 2)),
             rng.normal(size=(n, 2)) + 0.5]
        residuals.append(x[0][:, :1] @ [0.7] + x[1] @ [0.2, -0.4] + rng.normal(size=n))
        columns.append(x)
    return residuals, columns


#: per segment, the group of each of the five series: per output (two outputs), per series
#: (a drift's), one for all
GROUPS = [(0, 1, 0, 1, 1), (0, 1, 2, 3, 4), (0, 0, 0, 0, 0)]


@pytest.mark.parametrize("segments", [[0], [0, 1], [0, 2], [0, 1, 2]])
def test_accumulated_held_out_sse_equals_the_stacked_least_squares(segments):
    residuals, columns = _random_series(0)
    edges = block_edges([len(e) for e in residuals], folds=3)
    design = accumulate(
        residuals,
        [Segment(GROUPS[s], lambda i, s=s: columns[i][s]) for s in segments],
        edges,
    )
    assert sum(b.rows for b in design.blocks) == sum(len(e) for e in residuals)
    stacked = _stacked([[c[s] for s in segments] for c in columns],
                       [GROUPS[s] for s in segments])
    expected = _direct_held_out_sse(stacked, np.concatenate(residuals), edges)
    np.testing.assert_allclose(held_out_sse(design, RIDGE), expected, rtol=1e-9)


def test_a_selection_of_segments_equals_the_design_of_those_alone():
    residuals, columns = _random_series(1)
    edges = block_edges([len(e) for e in residuals], folds=4)

    def design(segments: list[int]) -> Design:
        return accumulate(residuals, [Segment(GROUPS[s], lambda i, s=s: columns[i][s])
                                      for s in segments], edges)

    np.testing.assert_allclose(held_out_sse(design([0, 1, 2]).select([0, 2])),
                               held_out_sse(design([0, 2])), rtol=1e-10)


def _mimo_recordings() -> tuple[list[Recording], list[np.ndarray], list[np.ndarray]]:
    """Two recordings of a two-input, two-output plant whose outputs carry a hysteresis the
    linear model lacks: the recordings, the model's free run and its residual."""
    rng = np.random.default_rng(3)
    fs, recordings, predictions, residuals = 1000.0, [], [], []
    for k, n in enumerate((1500, 1100)):
        t = np.arange(n) / fs
        u = np.column_stack([np.sin(2 * np.pi * (3 + k) * t), np.sin(2 * np.pi * 7 * t + k)])
        linear = signal.lfilter([0.2], [1.0, -0.8], u @ [[1.0, 0.3], [0.2, 1.0]], axis=0)
        memory = np.column_stack([play_operators(np.ascontiguousarray(u[:, 0]),
                                                 np.array([0.3]))[:, 0],
                                  play_operators(np.ascontiguousarray(u[:, 1]),
                                                 np.array([0.5]))[:, 0]])
        y = linear + 0.3 * memory + 0.01 * rng.normal(size=(n, 2))
        recordings.append(Recording(u=u, y=y, fs=fs, name=f"rec{k}", u_names=("u1", "u2"),
                                    y_names=("y1", "y2")))
        predictions.append(linear)
        e = y - linear
        e[:20] = np.nan
        residuals.append(e)
    return recordings, predictions, residuals


def test_the_ranking_equals_the_stacked_computation_on_a_mimo_data_set():
    recordings, predictions, residuals = _mimo_recordings()
    context = feature_context(recordings)
    candidates = ["hysteresis", "overflow", "saturation"]
    lags = evidence_lags(4)
    scores = {s.effect: s for s in diagnose(
        recordings, residuals, context, [], candidates=candidates, lags=lags,
        predictions=predictions, through_dynamics=True)}
    settings = DiagnosisSettings(lags=lags, through_dynamics=True)
    evidence = _prepare_evidence(recordings, residuals, context, [], predictions, settings)
    assert evidence.dynamics is not None and evidence.dynamics[0] is not None
    assert len(evidence.prepared) == 4  # two recordings x two outputs, coefficients per output
    tested = (0, 1, 2, 3)
    e = np.concatenate([p.e for p in evidence.prepared])
    edges = block_edges([len(p.e) for p in evidence.prepared], settings.folds)
    owner = np.repeat(np.arange(4), [len(k) - 1 for k in edges])
    sst = np.array([float(p.e[a:b] @ p.e[a:b])
                    for p, k in zip(evidence.prepared, edges, strict=True)
                    for a, b in zip(k[:-1], k[1:], strict=True)])
    for name in candidates:
        effect = get_effect(name)
        output_side = effect.block in ("output", "feedback")
        through = _passes_dynamics(effect, recordings[0].u, context)
        segments = [_baseline_segment(evidence, tested, output_side, through),
                    _effect_segment(effect, evidence, tested, context, settings, through)]
        series = [[s.columns(i) for s in segments] for i in range(4)]
        groups = [s.groups for s in segments]
        base = _direct_held_out_sse(_stacked([c[:1] for c in series], groups[:1]), e, edges)
        full = _direct_held_out_sse(_stacked(series, groups), e, edges)
        gains = (base - full) / np.maximum(sst, 1e-12)
        score = np.mean([np.sum(base[owner == r] - full[owner == r]) / np.sum(sst[owner == r])
                         for r in range(4)])
        nonzero = gains[np.abs(gains) > 1e-12]
        p = float(stats.wilcoxon(nonzero, alternative="greater").pvalue)
        got = scores[name]
        assert got.score == pytest.approx(score, rel=1e-9), name
        assert got.p_value == pytest.approx(p, rel=1e-9), name
        assert (got.blocks.gaining, got.blocks.losing) == (int(np.sum(gains > 1e-12)),
                                                           int(np.sum(gains < -1e-12))), name
    # the case is one the ranking can tell: the missing hysteresis comes first
    assert next(iter(sorted(scores.values(), key=lambda s: (-s.significant, -s.score)))).effect \
        == "hysteresis"
