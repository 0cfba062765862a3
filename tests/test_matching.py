"""Hungarian (lapjv cost_limit semantics) and greedy assignment (tracker.matching)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

import tracker.matching
from tracker.config import GreedyOrder
from tracker.matching import Matches, _solve_edges, greedy, hungarian

INF = np.inf


def pair_set(matches: Matches) -> set[tuple[int, int]]:
    return {(int(r), int(c)) for r, c in matches.pairs}


def lapjv_extended(cost: np.ndarray, thr: float) -> set[tuple[int, int]]:
    """``lap.lapjv(cost, extend_cost=True, cost_limit=thr)`` rebuilt literally (spec §2.4).

    The matrix is padded to (M + N)² with thr/2 for "unassigned" and 0 in the dummy block.
    """
    m, n = cost.shape
    big = np.full((m + n, n + m), thr / 2.0)
    big[:m, :n] = np.where(np.isfinite(cost), cost, 1e12)
    big[m:, n:] = 0.0
    rows, cols = linear_sum_assignment(big)
    return {(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if r < m and c < n}


def per_category_reference(cost, row_cat, col_cat, thr_per_cat) -> set[tuple[int, int]]:
    """The reference's per-class layers: one lapjv per category on that category's sub-matrix."""
    pairs: set[tuple[int, int]] = set()
    for cat, thr in enumerate(thr_per_cat):
        rows, cols = np.flatnonzero(row_cat == cat), np.flatnonzero(col_cat == cat)
        sub = lapjv_extended(cost[np.ix_(rows, cols)], thr)
        pairs |= {(int(rows[r]), int(cols[c])) for r, c in sub}
    return pairs


def sparse_problem(m: int, n: int, seed: int, *, n_categories: int = 3, density: float = 0.08):
    """Random cost matrix shaped like a tracking frame: +inf across categories, mostly far pairs."""
    rng = np.random.default_rng(seed)
    row_cat, col_cat = rng.integers(0, n_categories, m), rng.integers(0, n_categories, n)
    thr_per_cat = rng.uniform(0.8, 2.0, n_categories)
    cost = rng.uniform(0.0, 2.0, (m, n))
    cost[rng.random((m, n)) > density] = rng.choice([5.0, INF])  # gated out or hopeless
    cost[row_cat[:, None] != col_cat[None, :]] = INF
    return cost, row_cat, col_cat, thr_per_cat


# --- Matches ------------------------------------------------------------------------------------


def test_matches_empty_and_layout() -> None:
    empty = Matches.empty(2, 3)
    assert empty.pairs.shape == (0, 2) and empty.pairs.dtype == np.int64
    assert empty.costs.shape == (0,)
    np.testing.assert_array_equal(empty.unmatched_rows, [0, 1])
    np.testing.assert_array_equal(empty.unmatched_cols, [0, 1, 2])
    assert len(empty) == 0
    m = Matches.from_pairs([2, 0], [1, 3], np.arange(20.0).reshape(4, 5))
    np.testing.assert_array_equal(m.pairs, [[0, 3], [2, 1]])  # sorted by row
    np.testing.assert_array_equal(m.costs, [3.0, 11.0])
    np.testing.assert_array_equal(m.rows, [0, 2])
    np.testing.assert_array_equal(m.cols, [3, 1])
    np.testing.assert_array_equal(m.unmatched_rows, [1, 3])
    np.testing.assert_array_equal(m.unmatched_cols, [0, 2, 4])
    assert m.unmatched_rows.dtype == m.unmatched_cols.dtype == np.int64
    with pytest.raises(ValueError):
        m.pairs[0, 0] = 5  # read-only


def test_matches_subset_keeps_layout_and_frees_dropped_pairs() -> None:
    m = Matches.from_pairs([3, 0, 1], [0, 4, 2], np.arange(20.0).reshape(4, 5))
    kept = m.subset(np.array([True, False, True]))  # drops (1, 2)
    np.testing.assert_array_equal(kept.pairs, [[0, 4], [3, 0]])
    np.testing.assert_array_equal(kept.costs, [4.0, 15.0])
    np.testing.assert_array_equal(kept.unmatched_rows, [1, 2])
    np.testing.assert_array_equal(kept.unmatched_cols, [1, 2, 3])
    none = m.subset(np.zeros(3, dtype=bool))
    assert len(none) == 0 and none.pairs.shape == (0, 2)
    np.testing.assert_array_equal(none.unmatched_rows, np.arange(4))
    np.testing.assert_array_equal(none.unmatched_cols, np.arange(5))
    with pytest.raises(ValueError):
        kept.unmatched_cols[0] = 7  # read-only


# --- Hungarian ----------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(40))
def test_hungarian_fast_paths_equal_lapjv_on_tiny_sparse_problems(seed) -> None:
    """Frames with 0, 1 or only uncontested feasible pairs skip the solver: same answer."""
    rng = np.random.default_rng(300 + seed)
    m, n = rng.integers(0, 7, 2)
    cost = np.where(rng.random((m, n)) < 0.25, rng.uniform(0.0, 2.0, (m, n)), INF)
    thr = 1.4
    matches = hungarian(cost, max_cost_per_row=np.full(m, thr))
    assert pair_set(matches) == lapjv_extended(cost, thr)
    assert np.all(np.diff(matches.rows) > 0)
    every_row = np.sort(np.r_[matches.rows, matches.unmatched_rows])
    every_col = np.sort(np.r_[matches.cols, matches.unmatched_cols])
    np.testing.assert_array_equal(every_row, np.arange(m))
    np.testing.assert_array_equal(every_col, np.arange(n))


def test_hungarian_lapjv_example_is_not_assign_then_threshold() -> None:
    """Spec §2.4: C = [[0.1, 0.2], [0.2, 5.0]], thr 1.4 -> {(0, 1), (1, 0)} (not (0, 0))."""
    matches = hungarian([[0.1, 0.2], [0.2, 5.0]], max_cost_per_row=[1.4, 1.4])
    assert pair_set(matches) == {(0, 1), (1, 0)}
    np.testing.assert_array_equal(matches.costs, [0.2, 0.2])
    assert matches.unmatched_rows.size == 0 and matches.unmatched_cols.size == 0
    assert lapjv_extended(np.array([[0.1, 0.2], [0.2, 5.0]]), 1.4) == {(0, 1), (1, 0)}


def test_hungarian_threshold_is_inclusive_and_strict_above() -> None:
    assert pair_set(hungarian([[1.4]], max_cost_per_row=[1.4])) == {(0, 0)}
    assert pair_set(hungarian([[1.4 + 1e-12]], max_cost_per_row=[1.4])) == set()
    # Two tied pairs at the threshold: both matched (more matches win a tie in gain).
    tied = hungarian([[1.0, INF], [INF, 1.0]], max_cost_per_row=1.0)
    assert pair_set(tied) == {(0, 0), (1, 1)}


def test_hungarian_never_matches_inf_or_nan() -> None:
    cost = np.array([[INF, np.nan], [np.nan, 0.5]])
    assert pair_set(hungarian(cost, max_cost_per_row=[INF, INF])) == {(1, 1)}
    assert len(hungarian(np.full((3, 2), INF), max_cost_per_row=np.full(3, INF))) == 0


def test_hungarian_per_row_thresholds() -> None:
    cost = np.array([[0.9, INF], [INF, 0.9]])
    matches = hungarian(cost, max_cost_per_row=[1.0, 0.5])
    assert pair_set(matches) == {(0, 0)}
    np.testing.assert_array_equal(matches.unmatched_rows, [1])
    np.testing.assert_array_equal(matches.unmatched_cols, [1])


@pytest.mark.parametrize(("m", "n"), [(0, 0), (0, 4), (3, 0)])
def test_hungarian_empty(m, n) -> None:
    matches = hungarian(np.zeros((m, n)), max_cost_per_row=np.ones(m))
    assert len(matches) == 0
    np.testing.assert_array_equal(matches.unmatched_rows, np.arange(m))
    np.testing.assert_array_equal(matches.unmatched_cols, np.arange(n))


@pytest.mark.parametrize("seed", range(6))
def test_hungarian_matches_lapjv_extension_on_dense_problems(seed) -> None:
    rng = np.random.default_rng(100 + seed)
    m, n = rng.integers(1, 9, 2)
    cost = rng.uniform(0.0, 2.5, (m, n))
    thr = float(rng.uniform(0.5, 2.0))
    matches = hungarian(cost, max_cost_per_row=np.full(m, thr))
    assert pair_set(matches) == lapjv_extended(cost, thr)
    assert np.all(matches.costs <= thr)


@pytest.mark.parametrize("split", [True, False], ids=["components", "one-solve"])
@pytest.mark.parametrize("seed", range(5))
def test_hungarian_components_equal_reference_and_undecomposed(seed, split, monkeypatch) -> None:
    monkeypatch.setattr(tracker.matching, "_SPLIT_MIN_PAIRS", 0 if split else 10**9)
    m, n = (200, 200) if seed == 0 else (60, 70)
    cost, row_cat, col_cat, thr_per_cat = sparse_problem(m, n, seed)
    thr_rows = thr_per_cat[row_cat]
    matches = hungarian(cost, max_cost_per_row=thr_rows)
    assert pair_set(matches) == per_category_reference(cost, row_cat, col_cat, thr_per_cat)
    # One assignment over every feasible pair at once: the same optimum.
    rows, cols = np.nonzero(np.isfinite(cost) & (cost <= thr_rows[:, None]))
    whole_rows, whole_cols = _solve_edges(rows, cols, thr_rows[rows] - cost[rows, cols] + 1e-9)
    assert pair_set(matches) == set(zip(whole_rows.tolist(), whole_cols.tolist(), strict=True))
    assert len(matches) > 10


def test_hungarian_is_deterministic() -> None:
    cost, row_cat, _, thr_per_cat = sparse_problem(50, 50, seed=7)
    first = hungarian(cost, max_cost_per_row=thr_per_cat[row_cat])
    again = hungarian(cost.copy(), max_cost_per_row=thr_per_cat[row_cat])
    np.testing.assert_array_equal(first.pairs, again.pairs)
    np.testing.assert_array_equal(first.costs, again.costs)


def test_hungarian_rejects_bad_shapes() -> None:
    with pytest.raises(ValueError, match="max_cost_per_row"):
        hungarian(np.zeros((2, 2)), max_cost_per_row=np.ones(3))
    with pytest.raises(ValueError, match="cost"):
        hungarian(np.zeros(4), max_cost_per_row=1.0)


# --- Greedy -------------------------------------------------------------------------------------


def test_greedy_detection_order_is_the_reference() -> None:
    """Detections take their cheapest free track in column order, whatever comes later."""
    cost = np.array([[0.1, 0.05], [0.2, 0.3]])
    by_detection = greedy(cost, max_cost_per_row=[1.0, 1.0])
    assert pair_set(by_detection) == {(0, 0), (1, 1)}
    by_cost = greedy(cost, max_cost_per_row=[1.0, 1.0], order=GreedyOrder.COST)
    assert pair_set(by_cost) == {(0, 1), (1, 0)}
    assert pair_set(greedy(cost, max_cost_per_row=[1.0, 1.0], order="cost")) == pair_set(by_cost)
    # Reordering the detections changes the reference's result.
    swapped = greedy(cost[:, ::-1], max_cost_per_row=[1.0, 1.0])
    assert pair_set(swapped) == {(0, 0), (1, 1)}  # i.e. det 1 -> track 0, det 0 -> track 1


def test_greedy_threshold_applies_to_the_argmin_row() -> None:
    # The cheapest free track (row 0) fails its own threshold: the detection stays unmatched,
    # even though row 1 would have accepted it.
    matches = greedy([[0.8], [1.0]], max_cost_per_row=[0.5, 2.0])
    assert len(matches) == 0
    assert pair_set(greedy([[1.3]], max_cost_per_row=[1.3])) == {(0, 0)}  # tie accepted


def test_greedy_skips_used_rows_and_bad_values() -> None:
    cost = np.array([[0.1, 0.2, np.nan], [INF, 0.9, 0.4]])
    matches = greedy(cost, max_cost_per_row=[1.0, 1.0])
    assert pair_set(matches) == {(0, 0), (1, 1)}  # det 2 finds only used row 1
    np.testing.assert_array_equal(matches.unmatched_cols, [2])
    only_used = greedy([[0.1, 0.2]], max_cost_per_row=[1.0])
    assert pair_set(only_used) == {(0, 0)}
    np.testing.assert_array_equal(only_used.unmatched_cols, [1])
    assert len(greedy([[np.nan, INF]], max_cost_per_row=[INF])) == 0


def test_greedy_cost_order_ties_are_deterministic() -> None:
    matches = greedy(np.full((2, 2), 0.5), max_cost_per_row=1.0, order=GreedyOrder.COST)
    assert pair_set(matches) == {(0, 0), (1, 1)}


@pytest.mark.parametrize("order", list(GreedyOrder))
@pytest.mark.parametrize(("m", "n"), [(0, 0), (0, 3), (2, 0)])
def test_greedy_empty(order, m, n) -> None:
    matches = greedy(np.zeros((m, n)), max_cost_per_row=np.ones(m), order=order)
    assert len(matches) == 0 and matches.pairs.shape == (0, 2)
    np.testing.assert_array_equal(matches.unmatched_cols, np.arange(n))


@pytest.mark.parametrize("order", list(GreedyOrder))
def test_greedy_respects_thresholds_on_random_problems(order) -> None:
    cost, row_cat, _, thr_per_cat = sparse_problem(40, 45, seed=3, density=0.3)
    thr_rows = thr_per_cat[row_cat]
    matches = greedy(cost, max_cost_per_row=thr_rows, order=order)
    assert np.all(matches.costs <= thr_rows[matches.rows])
    assert len(np.unique(matches.rows)) == len(np.unique(matches.cols)) == len(matches)
    # Hungarian is optimal for the same objective: it never gains less.
    best = hungarian(cost, max_cost_per_row=thr_rows)
    gain = np.sum(thr_rows[matches.rows] - matches.costs)
    assert np.sum(thr_rows[best.rows] - best.costs) >= gain - 1e-9


def reference_greedy(cost, row_cat, col_cat, thr_per_cat) -> set[tuple[int, int]]:
    """The reference's ``Greedy`` transcribed: per class layer, det × track, used tracks = 1e18."""
    pairs: set[tuple[int, int]] = set()
    for cat, thr in enumerate(thr_per_cat):
        layer = cost.T.copy()
        layer[~((col_cat[:, None] == cat) & (row_cat[None, :] == cat))] = INF
        for det in range(layer.shape[0]):
            track = int(layer[det].argmin())
            if layer[det, track] <= thr:
                layer[:, track] = 1e18
                pairs.add((track, det))
    return pairs


@pytest.mark.parametrize("seed", range(4))
def test_greedy_detection_order_equals_reference_transcription(seed) -> None:
    cost, row_cat, col_cat, thr_per_cat = sparse_problem(50, 60, seed, density=0.4)
    matches = greedy(cost, max_cost_per_row=thr_per_cat[row_cat])
    assert pair_set(matches) == reference_greedy(cost, row_cat, col_cat, thr_per_cat)
    assert len(matches) > 10
