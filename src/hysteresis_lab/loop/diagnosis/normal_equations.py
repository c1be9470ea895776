"""Held-out ridge fits of a shared regression from normal equations accumulated per block.

The effect ranking (`ranking`) fits one law to many series (every output of every recording)
and scores each contiguous block of a series by the fit on all the other blocks. Stacked into
one design matrix, the series cost rows x columns, and with coefficients per group (per output
of a MIMO system, per recording for a drift) most of that matrix is zeros: every series has
non-zero columns only in its own group's slot. Here a design is read one series at a time and
kept as each block's cross-products in the columns the series has (``X'X``, ``X'e`` and
``e'e``), from which every held-out fit follows exactly; memory grows with the blocks times
the columns squared, not with the samples.

A design is a list of `Segment`s side by side, each giving every series' own columns and the
group whose coefficients they take. Columns are standardised by their pooled std over all
rows (the zeros of the other groups' rows included), as the stacked design would be.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


@dataclass(frozen=True)
class Segment:
    """Regressors of a design: ``columns(i)`` gives series ``i``'s (its rows x the segment's
    width, the same for every series); series of one group share coefficients, every group
    has its own."""

    groups: tuple[int, ...]  # per series
    columns: Callable[[int], np.ndarray]


@dataclass
class BlockSums:
    """One held-out block: the series it cuts, its rows, its residual's sum of squares and the
    cross-products of its standardised regressors (its series' columns only)."""

    series: int
    rows: int
    sst: float
    gram: np.ndarray
    moment: np.ndarray


@dataclass
class Design:
    """The blocks of a design and its segments' widths and groups (where each series'
    columns sit among the design's)."""

    blocks: list[BlockSums]
    widths: tuple[int, ...]
    groups: tuple[tuple[int, ...], ...]

    def slots(self) -> list[np.ndarray]:
        """Per series, the design's columns its own columns are, in order."""
        n_series = len(self.groups[0]) if self.groups else 1 + max(
            (b.series for b in self.blocks), default=-1)
        per_series: list[list[np.ndarray]] = [[] for _ in range(n_series)]
        offset = 0
        for width, groups in zip(self.widths, self.groups, strict=True):
            keys = sorted(set(groups))
            for i, group in enumerate(groups):
                start = offset + keys.index(group) * width
                per_series[i].append(np.arange(start, start + width))
            offset += width * len(keys)
        return [np.concatenate(s) if s else np.empty(0, dtype=int) for s in per_series]

    @property
    def n_columns(self) -> int:
        return sum(w * len(set(g)) for w, g in zip(self.widths, self.groups, strict=True))

    def select(self, segments: Sequence[int]) -> Design:
        """The design of some of its segments only (their columns as standardised here)."""
        starts = np.concatenate([[0], np.cumsum(self.widths)])
        kept = np.concatenate([np.arange(starts[s], starts[s + 1]) for s in segments]
                              or [np.empty(0, dtype=int)]).astype(int)
        blocks = [BlockSums(b.series, b.rows, b.sst, b.gram[np.ix_(kept, kept)], b.moment[kept])
                  for b in self.blocks]
        return Design(blocks, tuple(self.widths[s] for s in segments),
                      tuple(self.groups[s] for s in segments))


def block_edges(lengths: Sequence[int], folds: int, min_blocks: int = 20,
                min_rows: int = 20) -> list[np.ndarray]:
    """Every series cut into contiguous blocks of ``min_rows`` rows or more: ``folds`` each,
    more when there are few series (``min_blocks`` in all, for the signed-rank test)."""
    per_series = max(folds, -(-min_blocks // len(lengths)))
    return [np.linspace(0, n, max(1, min(per_series, n // min_rows)) + 1).astype(int)
            for n in lengths]


def accumulate(residuals: Sequence[np.ndarray], segments: Sequence[Segment],
               edges: Sequence[np.ndarray]) -> Design:
    """The blocks (cut at ``edges``) of the regression of ``residuals`` (one per series) on
    ``segments``, standardised; one series' regressors in memory at a time."""
    n_series = len(residuals)
    widths: list[int] = []
    blocks: list[BlockSums] = []
    sums: np.ndarray | None = None
    squares: np.ndarray | None = None
    slots: list[np.ndarray] = []
    for i, e in enumerate(residuals):
        parts = [np.asarray(s.columns(i), dtype=float).reshape(len(e), -1) for s in segments]
        if i == 0:
            widths = [p.shape[1] for p in parts]
            layout = Design([], tuple(widths), tuple(tuple(s.groups) for s in segments))
            slots = layout.slots() if segments else [np.empty(0, dtype=int)] * n_series
            sums, squares = np.zeros(layout.n_columns), np.zeros(layout.n_columns)
        if [p.shape[1] for p in parts] != widths:
            raise ValueError(f"series {i} has {[p.shape[1] for p in parts]} columns per "
                             f"segment, series 0 {widths}: a segment's width is one for all.")
        x = np.column_stack(parts) if parts else np.empty((len(e), 0))
        assert sums is not None and squares is not None
        sums[slots[i]] += x.sum(axis=0)
        squares[slots[i]] += np.einsum("ij,ij->j", x, x)
        for start, stop in zip(edges[i][:-1], edges[i][1:], strict=True):
            rows, part = x[start:stop], e[start:stop]
            blocks.append(BlockSums(i, int(stop - start), float(part @ part), rows.T @ rows,
                                    rows.T @ part))
    total = max(sum(len(e) for e in residuals), 1)
    if sums is None or squares is None:
        return Design(blocks, (), ())
    mean = sums / total
    scale = np.sqrt(np.maximum(squares / total - mean**2, 0.0))
    scale[scale == 0] = 1.0
    for block in blocks:
        own = scale[slots[block.series]]
        block.gram /= np.outer(own, own)
        block.moment /= own
    return Design(blocks, tuple(widths), tuple(tuple(s.groups) for s in segments))


def held_out_sse(design: Design, ridge: float = 1e-4) -> np.ndarray:
    """SSE of each block under the shared ridge fit on all the other blocks, capped at its SST
    (a held-out fit worse than predicting nothing explains nothing). The normal equations
    fall apart into independent sets of columns that no series links (a MIMO system's
    outputs): each block's fit solves only its own set's."""
    slots = design.slots()
    n = design.n_columns
    gram_all, moment_all = np.zeros((n, n)), np.zeros(n)
    for block in design.blocks:
        own = slots[block.series]
        gram_all[np.ix_(own, own)] += block.gram
        moment_all[own] += block.moment
    penalty = ridge * sum(block.rows for block in design.blocks)
    members = _linked_columns(slots, n)
    sst = np.array([block.sst for block in design.blocks])
    sse = sst.copy()
    for k, block in enumerate(design.blocks):
        own = slots[block.series]
        if not len(own):
            continue
        linked = members[int(own[0])]
        where = np.searchsorted(linked, own)
        system = gram_all[np.ix_(linked, linked)]
        system[np.ix_(where, where)] -= block.gram
        system[np.diag_indices_from(system)] += penalty
        rhs = moment_all[linked]
        rhs[where] -= block.moment
        coef = np.linalg.solve(system, rhs)[where]
        sse[k] = block.sst - 2 * coef @ block.moment + coef @ block.gram @ coef
    return np.minimum(sse, sst)


def _linked_columns(slots: Sequence[np.ndarray], n: int) -> dict[int, np.ndarray]:
    """Column -> the sorted columns it shares a set of normal equations with: those linked
    to it through the columns of some series."""
    heads = np.concatenate([s[:-1] for s in slots] + [np.empty(0, dtype=int)]).astype(int)
    tails = np.concatenate([s[1:] for s in slots] + [np.empty(0, dtype=int)]).astype(int)
    graph = coo_matrix((np.ones(len(heads)), (heads, tails)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    sets = {int(c): np.flatnonzero(label == c) for c in np.unique(label)}
    return {column: sets[int(label[column])] for column in range(n)}
