"""Compiled stage-1 assignment for the uncontested case (numpy reference:
:func:`tracker.matching.hungarian`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from tracker.boxes import FloatArray
from tracker.kernels._common import _F1, _F2


@numba.njit((_F2, _F1), cache=True, error_model="numpy", nogil=True)
def isolated_pairs_kernel(cost: FloatArray, threshold: FloatArray) -> tuple:  # pragma: no cover
    """Stage 1's assignment when no feasible pair is contested, the usual case in tracking.

    A pair is feasible when its cost is finite and <= its row's ``threshold``. When no row and
    no column has two feasible pairs, every feasible pair is matched (the optimum of
    :func:`tracker.matching.hungarian`, which this returns without a solver): the pairs (K, 2)
    sorted by row, their costs, the unmatched rows and columns, and True. Otherwise the arrays
    are empty and the flag is False: the caller runs the solver.
    """
    m, n = cost.shape
    row_count = np.zeros(m, dtype=np.int64)
    col_count = np.zeros(n, dtype=np.int64)
    row_col = np.full(m, -1, dtype=np.int64)
    total = 0
    for i in range(m):
        for j in range(n):
            c = cost[i, j]
            if math.isfinite(c) and c <= threshold[i]:
                row_count[i] += 1
                col_count[j] += 1
                row_col[i] = j
                total += 1
    contested = False
    for i in range(m):
        contested = contested or row_count[i] > 1
    for j in range(n):
        contested = contested or col_count[j] > 1
    if contested:
        none = np.zeros(0, dtype=np.int64)
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0), none, none.copy(), False
    pairs = np.empty((total, 2), dtype=np.int64)
    costs = np.empty(total)
    free_rows = np.empty(m - total, dtype=np.int64)
    free_cols = np.empty(n - total, dtype=np.int64)
    p = f = 0
    for i in range(m):
        if row_col[i] >= 0:
            pairs[p, 0], pairs[p, 1] = i, row_col[i]
            costs[p] = cost[i, row_col[i]]
            p += 1
        else:
            free_rows[f] = i
            f += 1
    f = 0
    for j in range(n):
        if col_count[j] == 0:
            free_cols[f] = j
            f += 1
    return pairs, costs, free_rows, free_cols, True
