"""Assignment of tracks (rows) to detections (columns) from an (M, N) cost matrix.

A pair is only ever accepted when its cost is finite and <= the threshold of its row
(``max_cost_per_row``; the tracker fills it from the track's category). Cross-category pairs
carry +inf cost, so one call serves every category at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from tracker.boxes import FloatArray, IntArray
from tracker.config import GreedyOrder

# Hungarian tie-break: each match earns this much extra gain, so a pair whose cost equals its
# threshold (zero gain) is still matched, as lapjv does. Relative to the largest gain; far above
# float64 rounding of a sum of gains and far below any meaningful cost difference.
_TIE_BONUS_REL = 1e-12

# Splitting the feasible graph into connected components pays off only for large problems:
# below this many contested pairs one solver call is faster than the per-component overhead.
_SPLIT_MIN_PAIRS = 1500


def _readonly(array: ArrayLike, dtype: type) -> np.ndarray:
    out = np.array(array, dtype=dtype)
    out.flags.writeable = False
    return out


@dataclass(frozen=True, slots=True)
class Matches:
    """The result of one assignment.

    Attributes
    ----------
    pairs : (K, 2) int64 [row, col] (track row, detection column), sorted by row.
    costs : (K,) cost of each pair.
    unmatched_rows : sorted int64 rows without a pair.
    unmatched_cols : sorted int64 columns without a pair.
    """

    pairs: IntArray
    costs: FloatArray
    unmatched_rows: IntArray
    unmatched_cols: IntArray

    @classmethod
    def empty(cls, m: int, n: int) -> Matches:
        """No pair: every one of ``m`` rows and ``n`` columns is unmatched."""
        return cls._trusted(
            np.zeros((0, 2), dtype=np.int64),
            np.zeros(0),
            np.arange(m, dtype=np.int64),
            np.arange(n, dtype=np.int64),
        )

    @classmethod
    def from_pairs(cls, rows: ArrayLike, cols: ArrayLike, cost: FloatArray) -> Matches:
        """Matches for parallel ``rows``/``cols`` index arrays into the (M, N) ``cost``."""
        rows = np.asarray(rows, dtype=np.int64)
        cols = np.asarray(cols, dtype=np.int64)
        if len(rows) > 1:
            order = np.argsort(rows, kind="stable")
            rows, cols = rows[order], cols[order]
        return cls._sorted(rows, cols, cost)

    @classmethod
    def _sorted(cls, rows: IntArray, cols: IntArray, cost: FloatArray) -> Matches:
        """Internal :meth:`from_pairs` for int64 ``rows`` already sorted (and ours to keep)."""
        m, n = cost.shape
        pairs = np.empty((len(rows), 2), dtype=np.int64)
        pairs[:, 0], pairs[:, 1] = rows, cols
        return cls._trusted(pairs, cost[rows, cols], _complement(rows, m), _complement(cols, n))

    @classmethod
    def _trusted(
        cls, pairs: IntArray, costs: FloatArray, unmatched_rows: IntArray, unmatched_cols: IntArray
    ) -> Matches:
        """Internal: Matches from fresh arrays we own (made read-only here, not copied)."""
        for array in (pairs, costs, unmatched_rows, unmatched_cols):
            array.flags.writeable = False
        return cls(pairs, costs, unmatched_rows, unmatched_cols)

    def subset(self, keep: ArrayLike) -> Matches:
        """The pairs where ``keep`` (K,) is True; the rows and columns of the others become
        unmatched."""
        n_rows = len(self.unmatched_rows) + len(self.pairs)
        n_cols = len(self.unmatched_cols) + len(self.pairs)
        pairs = self.pairs[keep]
        return Matches._trusted(
            pairs,
            self.costs[keep],
            _complement(pairs[:, 0], n_rows),
            _complement(pairs[:, 1], n_cols),
        )

    def __len__(self) -> int:
        return len(self.pairs)

    @property
    def rows(self) -> IntArray:
        return self.pairs[:, 0]

    @property
    def cols(self) -> IntArray:
        return self.pairs[:, 1]


def _complement(index: IntArray, size: int) -> IntArray:
    """Sorted ``arange(size)`` without ``index`` (``np.setdiff1d``, without its sorts)."""
    free = np.ones(size, dtype=bool)
    free[index] = False
    return np.flatnonzero(free)


def _prepare(cost: ArrayLike, max_cost_per_row: ArrayLike) -> tuple[FloatArray, FloatArray]:
    cost_arr = np.asarray(cost, dtype=np.float64)
    if cost_arr.ndim != 2:
        raise ValueError(f"cost: expected an (M, N) matrix, got shape {cost_arr.shape}")
    m = cost_arr.shape[0]
    threshold = np.asarray(max_cost_per_row, dtype=np.float64)
    if threshold.shape == (m,):
        return cost_arr, threshold
    if threshold.shape != ():
        raise ValueError(f"max_cost_per_row: expected shape ({m},), got {threshold.shape}")
    return cost_arr, np.broadcast_to(threshold, (m,))


def _feasible(cost: FloatArray, threshold: FloatArray) -> np.ndarray:
    """Pairs that may be matched: finite cost <= the row's threshold (a tie is accepted)."""
    return np.isfinite(cost) & (cost <= threshold[:, None])


def hungarian(cost: ArrayLike, *, max_cost_per_row: ArrayLike) -> Matches:
    """Optimal assignment under per-row cost limits: the reference's lapjv with ``cost_limit``.

    ``lap.lapjv(cost, extend_cost=True, cost_limit=thr)`` (mctrack_reference.md §2.4) pads the
    matrix to (M + N)² with thr/2 for "unassigned", so it maximises Σ_matched (thr - cost). That is
    not "assign, then threshold": C = [[0.1, 0.2], [0.2, 5.0]] with thr 1.4 gives (0, 1), (1, 0),
    not (0, 0). Here a pair gains thr_row - cost: a cost above thr_row, inf or NaN is never
    matched, and among optimal assignments the one with more pairs wins, so a pair whose cost
    equals its threshold is matched (as lapjv does). Only feasible pairs reach the solver: rows
    and columns without one are unmatched, a pair alone in its row and column is matched
    directly, and a large remainder is split into the connected components of the feasible
    graph, each solved on its own. The optimum is the same; it is just cheaper.

    Parameters
    ----------
    cost : (M, N) array
        Cost of matching row i (track) to column j (detection); +inf forbids the pair.
    max_cost_per_row : (M,) array or float
        Largest accepted cost of each row (cross-category costs are +inf, so per-category
        thresholds work in one call).

    Returns
    -------
    Matches, deterministic for a given input.
    """
    cost_arr, threshold = _prepare(cost, max_cost_per_row)
    m, n = cost_arr.shape
    rows, cols = np.nonzero(_feasible(cost_arr, threshold))  # rows/cols without one: unmatched
    if len(rows) == 0:
        return Matches.empty(m, n)
    if len(rows) == 1:  # one feasible pair: matched
        return Matches._sorted(rows, cols, cost_arr)
    # A pair whose row and column have no other feasible pair is a component of its own, and
    # matched (the usual case in tracking: a track with one nearby detection). No solver needed.
    row_count, col_count = np.bincount(rows, minlength=m), np.bincount(cols, minlength=n)
    if row_count.max() == 1 and col_count.max() == 1:  # every pair alone: no contest at all
        return Matches._sorted(rows, cols, cost_arr)  # np.nonzero lists rows in order
    alone = (row_count[rows] == 1) & (col_count[cols] == 1)
    # maximise Σ_matched gain, gain = thr_row - cost >= 0 (lapjv's objective), + a tie bonus
    gain = threshold[rows] - cost_arr[rows, cols]
    gain += _TIE_BONUS_REL * max(1.0, float(gain.max()))
    matched_rows, matched_cols = [rows[alone]], [cols[alone]]
    rows, cols, gain = rows[~alone], cols[~alone], gain[~alone]
    if len(rows) > _SPLIT_MIN_PAIRS:
        # Connected components of the feasible bipartite graph, each solved on its own.
        graph = coo_matrix((np.ones(len(rows)), (rows, m + cols)), shape=(m + n, m + n))
        _, label = connected_components(graph, directed=False)
        by_component = np.argsort(label[rows], kind="stable")
        starts = np.flatnonzero(np.diff(label[rows][by_component]))
        groups = np.split(by_component, starts + 1)
    else:
        groups = [np.arange(len(rows))] if len(rows) else []
    for edges in groups:
        r, c = _solve_edges(rows[edges], cols[edges], gain[edges])
        matched_rows.append(r)
        matched_cols.append(c)
    return Matches.from_pairs(np.concatenate(matched_rows), np.concatenate(matched_cols), cost_arr)


def _solve_edges(rows: IntArray, cols: IntArray, gain: FloatArray) -> tuple[IntArray, IntArray]:
    """Maximum-gain matching over the feasible pairs (edges) given, every gain > 0."""
    if len(rows) == 1:
        return rows, cols
    sub_rows, r = np.unique(rows, return_inverse=True)
    sub_cols, c = np.unique(cols, return_inverse=True)
    if len(sub_rows) == 1 or len(sub_cols) == 1:
        # A star: the single best edge wins (argmax takes the lowest index on ties).
        best = int(np.argmax(gain))
        return rows[best : best + 1], cols[best : best + 1]
    # Rows choose a column or one of len(sub_rows) "unmatched" dummies (cost 0); every gain is
    # > 0, so a feasible pair always beats leaving both ends unmatched, as with lapjv's thr/2.
    n_rows, n_cols = len(sub_rows), len(sub_cols)
    dense = np.full((n_rows, n_cols + n_rows), np.inf)
    dense[:, n_cols:] = 0.0
    dense[r, c] = -gain
    assigned_rows, assigned_cols = linear_sum_assignment(dense)
    real = assigned_cols < n_cols
    return sub_rows[assigned_rows[real]], sub_cols[assigned_cols[real]]


def greedy(
    cost: ArrayLike,
    *,
    max_cost_per_row: ArrayLike,
    order: GreedyOrder | str = GreedyOrder.DETECTION,
) -> Matches:
    """Greedy assignment with a per-row cost limit (the reference's RV-stage ``Greedy``).

    Parameters
    ----------
    cost : (M, N) array
        Cost of matching row i (track) to column j (detection); +inf forbids the pair.
    max_cost_per_row : (M,) array or float
        Largest accepted cost of each row.
    order : GreedyOrder or its value
        ``DETECTION`` (the reference): columns in index order each take the cheapest still
        unused row, accepted iff its cost <= that row's threshold; the result depends on the
        detection order. ``COST``: feasible pairs in ascending cost (ties by column, then row)
        are taken while both ends are free.

    Returns
    -------
    Matches, deterministic for a given input.
    """
    order = GreedyOrder(order)
    cost_arr, threshold = _prepare(cost, max_cost_per_row)
    m, n = cost_arr.shape
    if m == 0 or n == 0:
        return Matches.empty(m, n)
    feasible = _feasible(cost_arr, threshold)
    matched_rows: list[int] = []
    matched_cols: list[int] = []
    if order is GreedyOrder.DETECTION:
        # NaN would win np.argmin. Each column's cheapest row is found once; only when that row
        # has been taken is the argmin redone over the free rows (the reference sets taken rows
        # to 1e18: the same outcome).
        cost_arr = np.where(np.isnan(cost_arr), np.inf, cost_arr)
        best_row = np.argmin(cost_arr, axis=0).tolist()
        used = np.zeros(m, dtype=bool)
        for col in np.flatnonzero(feasible.any(axis=0)).tolist():
            row = best_row[col]
            if used[row]:
                row = int(np.argmin(np.where(used, np.inf, cost_arr[:, col])))
            if feasible[row, col] and not used[row]:
                used[row] = True
                matched_rows.append(row)
                matched_cols.append(col)
    else:
        rows, cols = np.nonzero(feasible)
        by_cost = np.lexsort((rows, cols, cost_arr[rows, cols]))
        row_used = np.zeros(m, dtype=bool)
        col_used = np.zeros(n, dtype=bool)
        for row, col in zip(rows[by_cost].tolist(), cols[by_cost].tolist(), strict=True):
            if not (row_used[row] or col_used[col]):
                row_used[row] = col_used[col] = True
                matched_rows.append(row)
                matched_cols.append(col)
    return Matches.from_pairs(matched_rows, matched_cols, cost_arr)


__all__ = ["Matches", "greedy", "hungarian"]
