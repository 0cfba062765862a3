"""Pairwise BEV and image-plane similarities (tracker.cost) against the reference's values."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest
import shapely

from tracker.boxes import Boxes
from tracker.cost import (
    back_predict,
    diou_bev,
    giou_bev,
    iou_bev,
    ro_gdiou_bev,
    ro_gdiou_terms_bev,
    sdiou_image,
)
from tracker.geometry import corners_bev

# The spec's golden values are rounded to 4 decimals and came from cv2's float32 geometry.
GOLDEN_ABS = 1e-4


def boxes(*rows: tuple[float, ...], category: int = 0) -> Boxes:
    """Boxes from (x, y, yaw) or (x, y, yaw, length, width) rows; z = 0, height 1.5."""
    full = [(*r, 4.0, 2.0) if len(r) == 3 else r for r in rows]
    arr = np.array(full, dtype=np.float64).reshape(-1, 5)
    n = len(arr)
    return Boxes.create(
        xyz=np.column_stack([arr[:, :2], np.zeros(n)]),
        lwh=np.column_stack([arr[:, 3:5], np.full(n, 1.5)]),
        yaw=arr[:, 2],
        category=np.full(n, category),
    )


def random_boxes(n: int, rng: np.random.Generator, *, spread_m: float) -> Boxes:
    return Boxes.create(
        xyz=np.column_stack([rng.uniform(-spread_m, spread_m, (n, 2)), rng.normal(0, 1, n)]),
        lwh=rng.uniform(0.4, 8.0, (n, 3)),
        yaw=rng.uniform(-np.pi, np.pi, n),
        category=rng.integers(0, 3, n),
    )


def reference_ro_gdiou(a: Boxes, i: int, b: Boxes, j: int, w1: float, w2: float) -> float:
    """One pair, the way ``cal_rotation_gdiou_inbev`` does it (shapely for the intersection)."""
    corners_a = corners_bev(a.xyz[i, :2], a.lwh[i, :2], a.yaw[i])[0]
    corners_b = corners_bev(b.xyz[j, :2], b.lwh[j, :2], b.yaw[j])[0]
    inter = shapely.Polygon(corners_a).intersection(shapely.Polygon(corners_b)).area
    union = a.lwh[i, 0] * a.lwh[i, 1] + b.lwh[j, 0] * b.lwh[j, 1] - inter
    points = np.concatenate([corners_a, corners_b]) - a.xyz[i, :2]
    _, (rect_w, rect_h), _ = cv2.minAreaRect(points.astype(np.float32))
    enclosing = rect_w * rect_h
    centre_dist_sq = float(np.sum((a.xyz[i, :2] - b.xyz[j, :2]) ** 2))
    return (
        inter / union
        - w1 * (enclosing - union) / enclosing
        - w2 * centre_dist_sq / (rect_w**2 + rect_h**2)
    )


# --- Ro_GDIoU golden values (spec §8, KITTI weights w1 = w2 = 1) ---------------------------------

GOLDEN_KITTI = [
    # track (x, y, yaw [, l, w]), detection, IoU (None: not given), Ro_GDIoU
    ((0, 0, 0), (0, 0, 0), 1.0, 1.0000),
    ((0, 0, 0), (1, 0, 0), 0.6, 0.5655),
    ((0, 0, 0), (0, 1, 0), 0.3333, 0.2933),
    ((0, 0, 0), (3, 0, 0), 0.1429, -0.0270),
    ((0, 0, 0), (5, 0, 0), 0.0, -0.4052),
    ((0, 0, 0), (20, 0, 0), 0.0, -1.3563),
    ((0, 0, 0), (0, 0, np.pi / 2), 0.3333, 0.0833),
    ((0, 0, 0), (0, 0, np.pi), 1.0, 1.0000),
    ((0, 0, 0.3), (0.5, 0.5, 0.2), 0.5342, 0.3928),
    ((10, 5, 1.0), (11, 6, 1.2), 0.3530, 0.0900),
    ((0, 0, 0, 4.0, 2.0), (0.3, 0, 0, 4.5, 1.8), None, 0.7751),
]


@pytest.mark.parametrize(("track", "det", "iou", "ro_gdiou"), GOLDEN_KITTI)
def test_ro_gdiou_golden_kitti(track, det, iou, ro_gdiou) -> None:
    a, b = boxes(track), boxes(det)
    got = ro_gdiou_bev(a, b, w1=1.0, w2=1.0)
    assert got.shape == (1, 1) and got.dtype == np.float64
    assert got[0, 0] == pytest.approx(ro_gdiou, abs=GOLDEN_ABS)
    assert 1.0 - got[0, 0] == pytest.approx(1.0 - ro_gdiou, abs=GOLDEN_ABS)  # the cost column
    if iou is not None:
        assert iou_bev(a, b)[0, 0] == pytest.approx(iou, abs=GOLDEN_ABS)


@pytest.mark.parametrize(
    ("det", "ro_gdiou"),
    [
        ((1, 0, 0), 0.5483),
        ((0, 1, 0), 0.2733),
        ((3, 0, 0), -0.1119),
        ((5, 0, 0), -0.4967),
        ((20, 0, 0), -1.3678),
    ],
)
def test_ro_gdiou_golden_nuscenes_car_weights(det, ro_gdiou) -> None:
    got = ro_gdiou_bev(boxes((0, 0, 0)), boxes(det), w1=0.5, w2=1.5)
    assert got[0, 0] == pytest.approx(ro_gdiou, abs=GOLDEN_ABS)


def test_golden_table_in_one_call_with_exact_values() -> None:
    """All rows at once (rows = tracks) and a few values known in closed form."""
    tracks = boxes(*(row[0] for row in GOLDEN_KITTI))
    dets = boxes(*(row[1] for row in GOLDEN_KITTI))
    diagonal = np.diag(ro_gdiou_bev(tracks, dets, w1=1.0, w2=1.0))
    np.testing.assert_allclose(diagonal, [row[3] for row in GOLDEN_KITTI], atol=GOLDEN_ABS)
    terms = ro_gdiou_terms_bev(tracks, dets)
    assert terms.iou[0, 0] == 1.0 and terms.iou[7, 7] == pytest.approx(1.0, abs=1e-15)
    assert terms.iou[1, 1] == pytest.approx(0.6, abs=1e-15)  # 6 / (8 + 8 - 6)
    assert terms.iou[4, 4] == 0.0 and terms.iou[5, 5] == 0.0  # pre-gated: exactly 0
    # Rotated 90°: IoU = 4 / 12, C = 4 × 4, U = 12, c = 0.
    assert terms.iou[6, 6] == pytest.approx(1 / 3, abs=1e-15)
    assert terms.enclosure[6, 6] == pytest.approx(0.25, abs=1e-15)
    assert terms.distance[6, 6] == 0.0
    # 20 m apart along x: C = 24 × 2, U = 16, c² = 400, d² = 24² + 2².
    assert terms.enclosure[5, 5] == pytest.approx(32 / 48, abs=1e-15)
    assert terms.distance[5, 5] == pytest.approx(400 / 580, abs=1e-15)


def test_matches_per_pair_reference_loop_on_random_pairs() -> None:
    rng = np.random.default_rng(7)
    a, b = random_boxes(15, rng, spread_m=6.0), random_boxes(14, rng, spread_m=6.0)
    w1 = rng.uniform(0.2, 1.5, 15)  # per-row weights, as the tracker passes them
    got = ro_gdiou_bev(a, b, w1=w1, w2=0.7)
    expected = np.array(
        [[reference_ro_gdiou(a, i, b, j, w1[i], 0.7) for j in range(14)] for i in range(15)]
    )
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-5)  # cv2 float32 vs float64
    iou = iou_bev(a, b)
    assert (iou > 0).sum() > 40  # overlaps are well represented among the 210 pairs


def test_giou_diou_and_terms_are_the_same_computation() -> None:
    rng = np.random.default_rng(8)
    a, b = random_boxes(9, rng, spread_m=5.0), random_boxes(11, rng, spread_m=5.0)
    terms = ro_gdiou_terms_bev(a, b)
    np.testing.assert_array_equal(iou_bev(a, b), terms.iou)
    np.testing.assert_allclose(giou_bev(a, b), terms.iou - terms.enclosure, atol=1e-15)
    np.testing.assert_allclose(diou_bev(a, b), terms.iou - terms.distance, atol=1e-15)
    np.testing.assert_allclose(
        ro_gdiou_bev(a, b, w1=0.5, w2=1.5),
        terms.iou - 0.5 * terms.enclosure - 1.5 * terms.distance,
        atol=1e-15,
    )
    assert np.all(terms.enclosure >= -1e-12) and np.all(terms.distance >= 0)
    assert np.all(giou_bev(a, b) <= 1 + 1e-12) and np.all(giou_bev(a, b) > -1)


def test_mask_semantics() -> None:
    rng = np.random.default_rng(9)
    a, b = random_boxes(8, rng, spread_m=5.0), random_boxes(6, rng, spread_m=5.0)
    mask = a.category[:, None] == b.category[None, :]
    full = ro_gdiou_bev(a, b, w1=1.0, w2=1.0)
    masked = ro_gdiou_bev(a, b, w1=1.0, w2=1.0, mask=mask)
    np.testing.assert_array_equal(masked[mask], full[mask])
    assert np.all(masked[~mask] == -np.inf)
    assert np.all(iou_bev(a, b, mask=mask)[~mask] == -np.inf)
    terms = ro_gdiou_terms_bev(a, b, mask=mask)
    assert np.all(np.isnan(terms.iou[~mask])) and np.all(np.isnan(terms.distance[~mask]))
    nothing = ro_gdiou_bev(a, b, w1=1.0, w2=1.0, mask=np.zeros((8, 6), dtype=bool))
    assert np.all(nothing == -np.inf)
    with pytest.raises(ValueError, match="mask"):
        iou_bev(a, b, mask=np.ones((6, 8), dtype=bool))


def test_per_row_weights() -> None:
    tracks = boxes((0, 0, 0), (0, 0, 0))
    dets = boxes((1, 0, 0))
    got = ro_gdiou_bev(tracks, dets, w1=np.array([1.0, 0.5]), w2=np.array([1.0, 1.5]))
    assert got[0, 0] == pytest.approx(0.5655, abs=GOLDEN_ABS)
    assert got[1, 0] == pytest.approx(0.5483, abs=GOLDEN_ABS)


def test_heading_enters_only_through_geometry() -> None:
    square = (0.0, 0.0, 0.0, 2.0, 2.0)
    for yaw in (np.pi / 2, np.pi, -np.pi / 2, 2 * np.pi):
        turned = (0.0, 0.0, yaw, 2.0, 2.0)
        assert ro_gdiou_bev(boxes(square), boxes(turned), w1=1, w2=1)[0, 0] == pytest.approx(1.0)
    car = ro_gdiou_bev(boxes((3, 4, 0.2)), boxes((3, 4, 0.2 + np.pi)), w1=1.0, w2=1.0)
    assert car[0, 0] == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize(
    "fn",
    [iou_bev, giou_bev, diou_bev, lambda a, b: ro_gdiou_bev(a, b, w1=1.0, w2=np.ones(len(a)))],
)
def test_empty_inputs(fn) -> None:
    some = boxes((0, 0, 0), (1, 1, 0), (2, 2, 0))
    assert fn(Boxes.empty(), some).shape == (0, 3)
    assert fn(some, Boxes.empty()).shape == (3, 0)
    assert fn(Boxes.empty(), Boxes.empty()).shape == (0, 0)


def test_nan_box_never_matches() -> None:
    good = boxes((0, 0, 0))
    bad = Boxes.create(xyz=[[np.nan, 0, 0]], lwh=[[4, 2, 1.5]], yaw=[0.0], category=[0])
    no_size = Boxes.create(xyz=[[0, 0, 0]], lwh=[[np.nan, 2, 1.5]], yaw=[0.0], category=[0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for other in (bad, no_size):
            assert ro_gdiou_bev(good, other, w1=1, w2=1)[0, 0] == -np.inf
            assert ro_gdiou_bev(other, good, w1=1, w2=1)[0, 0] == -np.inf
            assert iou_bev(good, other)[0, 0] == -np.inf


def test_back_predict_moves_detections_back_by_velocity() -> None:
    dets = Boxes.create(
        xyz=[[10.0, 5.0, 1.0], [0.0, 0.0, 0.0]],
        lwh=[[4, 2, 1.5]] * 2,
        yaw=[0.3, 0.0],
        category=[0, 1],
        velocity=[[2.0, -4.0], [0.0, 0.0]],
    )
    moved = back_predict(dets, 0.5)
    np.testing.assert_array_equal(moved.xyz, [[9.0, 7.0, 1.0], [0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(moved.yaw, dets.yaw)
    np.testing.assert_array_equal(moved.velocity, dets.velocity)
    np.testing.assert_array_equal(dets.xyz[0], [10.0, 5.0, 1.0])  # input untouched


def test_back_predict_leaves_a_detection_without_velocity_in_place() -> None:
    """An unknown velocity (NaN: BaseVersion null) moves nothing, as the 0 it used to be read
    as; a NaN position would fail every cost."""
    dets = Boxes.create(
        xyz=[[10.0, 5.0, 1.0], [3.0, 4.0, 0.0]],
        lwh=[[4, 2, 1.5]] * 2,
        yaw=[0.3, 0.0],
        category=[0, 0],
        velocity=[[np.nan, np.nan], [2.0, -4.0]],
    )
    moved = back_predict(dets, 0.5)
    np.testing.assert_array_equal(moved.xyz, [[10.0, 5.0, 1.0], [2.0, 6.0, 0.0]])
    assert np.isnan(moved.velocity[0]).all()  # still unknown, not made 0


# --- SDIoU (spec §2.5) ---------------------------------------------------------------------------


def reference_sdiou(box_a, box_b) -> float:
    """``cal_sdiou_inrv`` transcribed for one pair (without the camera check)."""
    ax1, ay1, ax2, ay2 = box_a
    bx1, by1, bx2, by2 = box_b
    inter = max(0, min(ax2, bx2) - max(ax1, bx1) + 1) * max(0, min(ay2, by2) - max(ay1, by1) + 1)
    area_a = (ax2 - ax1 + 1) * (ay2 - ay1 + 1)
    area_b = (bx2 - bx1 + 1) * (by2 - by1 + 1)
    area_ratio = area_a / area_b if area_b > area_a else area_b / area_a
    out_w, out_h = max(ax2, bx2) - min(ax1, bx1), max(ay2, by2) - min(ay1, by1)
    if area_a + area_b - inter == 0 or out_w**2 + out_h**2 == 0 or area_ratio == 0:
        return 0.0
    centre_dist = np.hypot((bx1 + bx2) / 2 - (ax1 + ax2) / 2, (by1 + by2) / 2 - (ay1 + ay2) / 2)
    distance = 1 - centre_dist / np.hypot(out_w, out_h)
    aspect_a, aspect_b = (ax2 - ax1) / (ay2 - ay1), (bx2 - bx1) / (by2 - by1)
    aspect = aspect_a / aspect_b if aspect_b > aspect_a else aspect_b / aspect_a
    return inter / (area_a + area_b - inter) + area_ratio * distance * aspect


SDIOU_A = (100, 100, 200, 180)


@pytest.mark.parametrize(
    ("box_b", "expected"),
    [
        pytest.param((100, 100, 200, 180), 2.0, id="identical"),
        pytest.param((110, 105, 210, 185), 1.6517, id="shifted-10-5"),
        pytest.param((150, 100, 250, 180), 1.0436, id="shifted-50"),
        pytest.param((300, 100, 400, 180), 0.3558, id="disjoint"),
        pytest.param((120, 110, 180, 170), 0.8187, id="contained"),
    ],
)
def test_sdiou_golden(box_b, expected) -> None:
    got = sdiou_image([SDIOU_A], [box_b])
    assert got.shape == (1, 1)
    assert got[0, 0] == pytest.approx(expected, abs=GOLDEN_ABS)
    assert sdiou_image([box_b], [SDIOU_A])[0, 0] == pytest.approx(got[0, 0], abs=1e-12)


def test_sdiou_matches_reference_loop() -> None:
    rng = np.random.default_rng(10)

    def random_xyxy(n: int) -> np.ndarray:
        x1, y1 = rng.uniform(0, 1000, n), rng.uniform(0, 300, n)
        return np.column_stack([x1, y1, x1 + rng.uniform(2, 300, n), y1 + rng.uniform(2, 200, n)])

    a, b = random_xyxy(12), random_xyxy(9)
    b[:3] = a[:3] + rng.normal(0, 5, (3, 4))  # some strongly overlapping pairs
    got = sdiou_image(a, b)
    expected = [[reference_sdiou(a[i], b[j]) for j in range(9)] for i in range(12)]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    assert np.all((got >= 0) & (got <= 2))


def test_sdiou_missing_and_degenerate_boxes() -> None:
    a = np.array([[100, 100, 200, 180], [np.nan] * 4])
    b = np.array([[100, 100, 200, 100], [100, 100, 200, 180], [50, 60, 50, 60]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # zero heights/widths: no division warnings
        got = sdiou_image(a, b)
    assert np.all(got[1] == -np.inf)  # a box that is not in the image never matches
    # Zero height: the aspect term is 0 (the reference divides by zero), IoU term stays.
    assert got[0, 0] == pytest.approx(reference_iou_plus1(a[0], b[0]), abs=1e-12)
    assert got[0, 1] == 2.0
    assert np.isfinite(got[0, 2])
    assert sdiou_image(np.zeros((0, 4)), b).shape == (0, 3)
    assert sdiou_image(a, np.zeros((0, 4))).shape == (2, 0)


def reference_iou_plus1(box_a, box_b) -> float:
    ax1, ay1, ax2, ay2 = box_a
    bx1, by1, bx2, by2 = box_b
    inter = max(0, min(ax2, bx2) - max(ax1, bx1) + 1) * max(0, min(ay2, by2) - max(ay1, by1) + 1)
    union = (ax2 - ax1 + 1) * (ay2 - ay1 + 1) + (bx2 - bx1 + 1) * (by2 - by1 + 1) - inter
    return inter / union
