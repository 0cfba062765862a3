"""Rotated-rectangle intersection and minimum-area enclosing rectangle (tracker.geometry)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from tracker.geometry import (
    corners_bev,
    intersection_area_bev,
    min_area_rect_bev,
    pairwise_intersection_area_bev,
)


def rect(x: float, y: float, yaw: float, length: float = 4.0, width: float = 2.0) -> np.ndarray:
    """(1, 4, 2) corners of one BEV rectangle."""
    return corners_bev([[x, y]], [[length, width]], [yaw])


def random_pairs(n: int, seed: int, *, spread_m: float = 3.0, origin_m: float = 0.0):
    """Corners of n random rectangle pairs, close enough to overlap often."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-spread_m, spread_m, (2, n, 2)) + origin_m
    lw = rng.uniform(0.3, 6.0, (2, n, 2))
    yaw = rng.uniform(-np.pi, np.pi, (2, n))
    return corners_bev(xy[0], lw[0], yaw[0]), corners_bev(xy[1], lw[1], yaw[1])


def brute_force_min_rect(points: np.ndarray) -> tuple[float, float]:
    """Min-area rectangle of (K, 2) points over every point-pair direction (hull edges included)."""
    best = (np.inf, np.inf)
    for i in range(len(points)):
        for j in range(i + 1, len(points)):
            u = points[j] - points[i]
            norm = np.hypot(*u)
            if norm == 0:
                continue
            u = u / norm
            along, across = points @ u, points @ np.array([-u[1], u[0]])
            w, h = np.ptp(along), np.ptp(across)
            best = min(best, (w * h, w * w + h * h))
    return best


# --- intersection -------------------------------------------------------------------------------

# (box a, box b, exact intersection area); boxes are (x, y, yaw, length, width).
EXACT_CASES = [
    pytest.param((0, 0, 0, 4, 2), (0, 0, 0, 4, 2), 8.0, id="identical"),
    pytest.param((0, 0, 0.7, 4, 2), (0, 0, 0.7, 4, 2), 8.0, id="identical-rotated"),
    pytest.param((0, 0, 0, 4, 2), (0, 0, np.pi, 4, 2), 8.0, id="flipped-180"),
    pytest.param((0, 0, 0, 4, 2), (0, 0, np.pi / 2, 4, 2), 4.0, id="rotated-90"),
    pytest.param((0, 0, 0, 4, 2), (0.5, 0.2, 0, 1, 1), 1.0, id="contained"),
    pytest.param((0.5, 0.2, 0.3, 1, 1), (0, 0, 0, 4, 2), 1.0, id="contained-rotated"),
    pytest.param((0, 0, 0, 4, 2), (1, 0, 0, 4, 2), 6.0, id="shifted-along"),
    pytest.param((0, 0, 0, 4, 2), (0, 1, 0, 4, 2), 4.0, id="shifted-across"),
    pytest.param((0, 0, 0, 4, 2), (4, 0, 0, 4, 2), 0.0, id="touching-edge"),
    pytest.param((0, 0, 0, 4, 2), (4, 2, 0, 4, 2), 0.0, id="touching-corner"),
    pytest.param((0, 0, 0, 4, 2), (10, 0, 0.3, 4, 2), 0.0, id="disjoint"),
    pytest.param((0, 0, 0, 4, 2), (0, 0, 0, 2, 4), 4.0, id="cross"),
    pytest.param((0, 0, 0, 2, 2), (0, 0, np.pi / 4, 2, 2), 8 * (np.sqrt(2) - 1), id="octagon"),
]


@pytest.mark.parametrize(("box_a", "box_b", "area"), EXACT_CASES)
def test_intersection_exact_cases(box_a, box_b, area) -> None:
    got = intersection_area_bev(rect(*box_a), rect(*box_b))
    assert got.shape == (1,)
    assert got[0] == pytest.approx(area, abs=1e-12)
    # Symmetric, and independent of where the pair sits in the world.
    shift = np.array([1234.5, -987.25])
    assert intersection_area_bev(rect(*box_b), rect(*box_a))[0] == pytest.approx(area, abs=1e-12)
    far = intersection_area_bev(rect(*box_a) + shift, rect(*box_b) + shift)[0]
    assert far == pytest.approx(area, abs=1e-9)


def test_intersection_matches_shapely_on_random_pairs() -> None:
    a, b = random_pairs(300, seed=1)
    expected = shapely.area(shapely.intersection(shapely.polygons(a), shapely.polygons(b)))
    np.testing.assert_allclose(intersection_area_bev(a, b), expected, rtol=0, atol=1e-10)
    assert (expected > 0).sum() > 150  # the sample really exercises overlaps


def test_intersection_far_from_origin_and_chunked() -> None:
    """World coordinates ~1e4 m, and more pairs than one internal chunk."""
    a, b = random_pairs(1500, seed=2, origin_m=1.0e4)
    expected = shapely.area(shapely.intersection(shapely.polygons(a), shapely.polygons(b)))
    np.testing.assert_allclose(intersection_area_bev(a, b), expected, rtol=0, atol=1e-8)


def test_intersection_nearly_parallel_edges() -> None:
    """Same heading up to rounding: the crossing parameter is pure noise and must not matter."""
    for yaw in np.linspace(-3.0, 3.0, 13):
        heading = np.array([np.cos(yaw), np.sin(yaw)])
        for offset_m in (0.0, 1.0, 3.0, 3.999999):
            a = rect(0, 0, yaw)
            b = rect(*(offset_m * heading), yaw + 1e-15)
            expected = 2.0 * max(0.0, 4.0 - offset_m)
            assert intersection_area_bev(a, b)[0] == pytest.approx(expected, abs=1e-9)


def test_intersection_empty_and_pairwise() -> None:
    assert intersection_area_bev(np.zeros((0, 4, 2)), np.zeros((0, 4, 2))).shape == (0,)
    a, b = random_pairs(7, seed=3)
    table = pairwise_intersection_area_bev(a, b[:5])
    assert table.shape == (7, 5)
    for i in range(7):
        for j in range(5):
            assert table[i, j] == pytest.approx(intersection_area_bev(a[i], b[j])[0], abs=1e-12)
    assert pairwise_intersection_area_bev(a, np.zeros((0, 4, 2))).shape == (7, 0)
    assert pairwise_intersection_area_bev(np.zeros((0, 4, 2)), b).shape == (0, 7)


def test_intersection_rejects_mismatched_pairs() -> None:
    with pytest.raises(ValueError, match="differ"):
        intersection_area_bev(np.zeros((2, 4, 2)), np.zeros((3, 4, 2)))


finite = st.floats(-50.0, 50.0, allow_nan=False)
size = st.floats(0.05, 20.0, allow_nan=False)
angle = st.floats(-4.0, 4.0, allow_nan=False)


@settings(max_examples=150, deadline=None)
@given(finite, finite, angle, size, size, finite, finite, angle, size, size)
def test_intersection_property_matches_shapely(x1, y1, t1, l1, w1, x2, y2, t2, l2, w2) -> None:
    a, b = rect(x1 / 10, y1 / 10, t1, l1, w1), rect(x2 / 10, y2 / 10, t2, l2, w2)
    got = intersection_area_bev(a, b)[0]
    expected = shapely.area(shapely.intersection(shapely.polygons(a), shapely.polygons(b)))[0]
    assert got == pytest.approx(expected, abs=1e-9 * max(1.0, l1 * w1, l2 * w2))
    assert got <= min(l1 * w1, l2 * w2) + 1e-9


# --- minimum-area enclosing rectangle -----------------------------------------------------------


@pytest.mark.parametrize(
    ("box_a", "box_b", "area", "diag_sq"),
    [
        pytest.param((0, 0, 0, 4, 2), (0, 0, 0, 4, 2), 8.0, 20.0, id="identical"),
        pytest.param((0, 0, 0, 4, 2), (0, 0, np.pi, 4, 2), 8.0, 20.0, id="flipped-180"),
        pytest.param((0, 0, 0, 4, 2), (0, 0, np.pi / 2, 4, 2), 16.0, 32.0, id="rotated-90"),
        pytest.param((0, 0, 0, 4, 2), (20, 0, 0, 4, 2), 48.0, 580.0, id="far-along"),
        pytest.param((0, 0, 0, 4, 2), (0.5, 0.2, 0.4, 1, 1), 8.0, 20.0, id="contained"),
        pytest.param((0, 0, 0.5, 4, 2), (0, 0, 0.5, 0, 0), 8.0, 20.0, id="point-inside"),
    ],
)
def test_min_area_rect_exact_cases(box_a, box_b, area, diag_sq) -> None:
    got_area, got_diag_sq = min_area_rect_bev(rect(*box_a), rect(*box_b))
    assert got_area[0] == pytest.approx(area, abs=1e-12)
    assert got_diag_sq[0] == pytest.approx(diag_sq, abs=1e-12)


def test_min_area_rect_matches_brute_force_and_cv2() -> None:
    a, b = random_pairs(200, seed=4, spread_m=8.0)
    area, diag_sq = min_area_rect_bev(a, b)
    points = np.concatenate([a, b], axis=1)
    for k in range(len(points)):
        brute_area, brute_diag_sq = brute_force_min_rect(points[k])
        assert area[k] == pytest.approx(brute_area, rel=1e-12)
        assert diag_sq[k] == pytest.approx(brute_diag_sq, rel=1e-9)
        # cv2 works in float32 (the reference translates by box A's centre first).
        _, (w, h), _ = cv2.minAreaRect((points[k] - a[k].mean(axis=0)).astype(np.float32))
        assert area[k] == pytest.approx(w * h, rel=1e-5)
        assert diag_sq[k] == pytest.approx(w * w + h * h, rel=1e-5)


def test_min_area_rect_matches_shapely_far_from_origin_and_chunked() -> None:
    a, b = random_pairs(1500, seed=5, spread_m=10.0, origin_m=3.0e3)
    area, _ = min_area_rect_bev(a, b)
    hull = shapely.union(shapely.multipoints(a), shapely.multipoints(b))
    np.testing.assert_allclose(
        area, shapely.area(shapely.minimum_rotated_rectangle(hull)), rtol=1e-9
    )


def test_min_area_rect_empty() -> None:
    area, diag_sq = min_area_rect_bev(np.zeros((0, 4, 2)), np.zeros((0, 4, 2)))
    assert area.shape == diag_sq.shape == (0,)


def test_non_finite_corners_give_nan() -> None:
    a = np.concatenate([rect(0, 0, 0), rect(np.nan, 0, 0), rect(0, 0, 0)])
    a[2, 1, 0] = np.inf
    b = np.concatenate([rect(1, 0, 0), rect(0, 0, 0), rect(0, 0, 0)])
    inter = intersection_area_bev(a, b)
    area, diag_sq = min_area_rect_bev(a, b)
    assert inter[0] == pytest.approx(6.0) and area[0] == pytest.approx(10.0)
    assert np.all(np.isnan(inter[1:])) and np.all(np.isnan(area[1:]))
    assert np.all(np.isnan(diag_sq[1:]))


def test_degenerate_grid_configurations_match_shapely() -> None:
    """Boxes on a half-metre grid at multiples of 45°: many shared edges, touching corners."""
    rng = np.random.default_rng(6)
    n = 3000
    xy = rng.integers(-8, 9, (2, n, 2)) * 0.5
    lw = rng.choice([1.0, 2.0, 4.0], (2, n, 2))
    yaw = rng.choice([0.0, np.pi / 4, np.pi / 2, 3 * np.pi / 4, np.pi, -np.pi / 2], (2, n))
    a, b = corners_bev(xy[0], lw[0], yaw[0]), corners_bev(xy[1], lw[1], yaw[1])
    expected = shapely.area(shapely.intersection(shapely.polygons(a), shapely.polygons(b)))
    np.testing.assert_allclose(intersection_area_bev(a, b), expected, rtol=0, atol=1e-12)
    hull = shapely.union(shapely.multipoints(a), shapely.multipoints(b))
    area, _ = min_area_rect_bev(a, b)
    np.testing.assert_allclose(
        area, shapely.area(shapely.minimum_rotated_rectangle(hull)), rtol=1e-12
    )
