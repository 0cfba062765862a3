"""The compiled pairwise BEV kernel (tracker.kernels.geometry) against its numpy reference."""

from __future__ import annotations

import numpy as np
import pytest

from tracker import geometry
from tracker.geometry import bev_pair_geometry, bev_pair_geometry_numpy

numba_kernels = pytest.importorskip("tracker.kernels.geometry")


def boxes(rng: np.random.Generator, n: int, *, origin_m: float = 0.0) -> np.ndarray:
    """(n, 5) [x, y, l, w, yaw] boxes close enough to overlap often."""
    xy = rng.uniform(-3.0, 3.0, (n, 2)) + origin_m
    return np.column_stack([xy, rng.uniform(0.2, 6.0, (n, 2)), rng.uniform(-4.0, 4.0, n)])


def all_pairs(m: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = np.divmod(np.arange(m * n, dtype=np.int64), max(n, 1))
    return rows, cols


def assert_agree(a: np.ndarray, b: np.ndarray, *, with_enclosing: bool = True) -> None:
    rows, cols = all_pairs(len(a), len(b))
    kernel = geometry._geometry_kernel()
    assert kernel is not None
    got = kernel(a, b, rows, cols, with_enclosing)
    want = bev_pair_geometry_numpy(a, b, rows, cols, with_enclosing=with_enclosing)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(np.isnan(g), np.isnan(w))
        np.testing.assert_allclose(g, w, rtol=1e-12, atol=1e-12)


def test_tolerance_matches_the_numpy_code() -> None:
    assert numba_kernels.BOUNDARY_RTOL == geometry._BOUNDARY_RTOL


@pytest.mark.parametrize("seed", range(5))
def test_kernel_equals_numpy_on_random_boxes(seed: int) -> None:
    rng = np.random.default_rng(seed)
    assert_agree(boxes(rng, 17), boxes(rng, 13))
    assert_agree(boxes(rng, 9, origin_m=4e5), boxes(rng, 11, origin_m=4e5))  # far from 0


def test_kernel_equals_numpy_on_degenerate_boxes() -> None:
    a = np.array(
        [
            [0.0, 0.0, 4.0, 2.0, 0.0],
            [0.0, 0.0, 4.0, 2.0, 0.7],
            [1.0, 1.0, 0.0, 0.0, 0.3],  # a point
            [5.0, 0.0, 4.0, 0.0, 0.0],  # a segment
            [0.0, np.nan, 4.0, 2.0, 0.0],  # missing
        ]
    )
    b = np.array(
        [
            [0.0, 0.0, 4.0, 2.0, 0.0],  # identical
            [0.0, 0.0, 4.0, 2.0, np.pi],  # flipped
            [0.0, 0.0, 4.0, 2.0, np.pi / 2],
            [4.0, 0.0, 4.0, 2.0, 0.0],  # touching along an edge
            [4.0, 2.0, 4.0, 2.0, 0.0],  # touching at a corner
            [0.5, 0.2, 1.0, 1.0, 0.0],  # nested
            [50.0, 50.0, 4.0, 2.0, 0.3],  # far apart
            [0.0, 0.0, 4.0, 2.0, np.inf],  # missing
        ]
    )
    assert_agree(a, b)
    assert_agree(a, b, with_enclosing=False)
    inter, enclosing, diag_sq, centre = bev_pair_geometry(a[:1], b[:1], *all_pairs(1, 1))
    assert (inter[0], enclosing[0], diag_sq[0], centre[0]) == pytest.approx((8.0, 8.0, 20.0, 0.0))


def test_missing_boxes_are_nan_everywhere_and_empty_input() -> None:
    a = np.array([[0.0, 0.0, 4.0, 2.0, np.nan]])
    b = np.array([[0.0, 0.0, 4.0, 2.0, 0.0]])
    for out in bev_pair_geometry(a, b, *all_pairs(1, 1)):
        assert np.isnan(out[0])
    for out in bev_pair_geometry(np.zeros((0, 5)), b, *all_pairs(0, 1)):
        assert out.shape == (0,)


def test_numpy_fallback_is_used_without_the_kernel(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(9)
    a, b = boxes(rng, 6), boxes(rng, 5)
    rows, cols = all_pairs(6, 5)
    compiled = bev_pair_geometry(a, b, rows, cols)
    monkeypatch.setattr(geometry, "_geometry_kernel", lambda: None)
    fallback = bev_pair_geometry(a, b, rows, cols)
    for g, w in zip(compiled, fallback, strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-12, atol=1e-12)
