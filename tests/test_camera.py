"""tracker.camera on a synthetic pinhole camera looking along world +x (z up)."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.boxes import Boxes
from tracker.camera import (
    NEAR_PLANE_M,
    _clipped_edges_px,
    box_wireframes_image,
    in_front,
    in_image_fraction,
    project_boxes,
    project_points,
)
from tracker.frame import Camera
from tracker.geometry import corners_3d

# Camera axes (x right, y down, z forward) from world (x forward, y left, z up).
CAMERA_FROM_WORLD = np.array(
    [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
FOCAL_PX, CX_PX, CY_PX = 100.0, 50.0, 40.0
WIDTH_PX, HEIGHT_PX = 100, 80


@pytest.fixture
def camera() -> Camera:
    image_from_camera = np.array(
        [[FOCAL_PX, 0.0, CX_PX, 0.0], [0.0, FOCAL_PX, CY_PX, 0.0], [0.0, 0.0, 1.0, 0.0]]
    )
    return Camera("CAM_FRONT", image_from_camera, CAMERA_FROM_WORLD, WIDTH_PX, HEIGHT_PX)


def make_boxes(xyz: list[list[float]], lwh: list[list[float]], yaw: list[float]) -> Boxes:
    return Boxes.create(xyz=xyz, lwh=lwh, yaw=yaw, category=np.zeros(len(yaw), dtype=np.int64))


def test_project_points_by_hand(camera: Camera) -> None:
    uv_px, depth_m = project_points([[10.0, 0.0, 0.0], [5.0, -1.0, 0.5]], camera)
    # (5, -1, 0.5) world = (1, -0.5, 5) camera -> u = 50 + 100 * 1/5, v = 40 - 100 * 0.5/5
    np.testing.assert_allclose(uv_px, [[50.0, 40.0], [70.0, 30.0]])
    np.testing.assert_allclose(depth_m, [10.0, 5.0])


def test_in_front(camera: Camera) -> None:
    points = [[10.0, 0.0, 0.0], [-10.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.1, 3.0, 0.0]]
    np.testing.assert_array_equal(in_front(points, camera), [True, False, False, True])


def test_box_straight_ahead_by_hand(camera: Camera) -> None:
    # A 2 m cube 10 m ahead: the near face (depth 9 m) spans ±1 m -> ±100/9 px around the centre.
    boxes = make_boxes([[10.0, 0.0, 0.0]], [[2.0, 2.0, 2.0]], [0.0])
    xyxy, visible = project_boxes(boxes, camera)
    half = FOCAL_PX * 1.0 / 9.0
    np.testing.assert_allclose(xyxy, [[CX_PX - half, CY_PX - half, CX_PX + half, CY_PX + half]])
    np.testing.assert_array_equal(visible, [True])


def test_tuple_input_matches_boxes(camera: Camera) -> None:
    boxes = make_boxes([[10.0, 1.0, 0.5]], [[4.0, 2.0, 1.5]], [0.3])
    from_boxes = project_boxes(boxes, camera)[0]
    from_tuple = project_boxes((boxes.xyz, boxes.lwh, boxes.yaw), camera)[0]
    np.testing.assert_array_equal(from_boxes, from_tuple)


@pytest.mark.parametrize(
    "xyz",
    [
        [-10.0, 0.0, 0.0],  # behind
        [10.0, 60.0, 0.0],  # far to the left, outside the image
        [0.0, 0.0, -50.0],  # below the camera, every corner at depth <= 1 m but not in view
    ],
)
def test_not_visible(camera: Camera, xyz: list[float]) -> None:
    xyxy, visible = project_boxes(make_boxes([xyz], [[2.0, 2.0, 2.0]], [0.0]), camera)
    np.testing.assert_array_equal(visible, [False])
    assert np.isnan(xyxy).all()


def test_partly_behind_is_clipped_at_the_near_plane(camera: Camera) -> None:
    # x from -1 to 3 m: the part in front starts at the 0.1 m near plane, where the ±0.5 m
    # cross-section spans ±500 px; a corner-wise projection would flip the rear corners instead.
    boxes = make_boxes([[1.0, 0.0, 0.0]], [[4.0, 1.0, 1.0]], [0.0])
    raw, visible = project_boxes(boxes, camera, clip_to_image=False)
    np.testing.assert_allclose(raw, [[CX_PX - 500, CY_PX - 500, CX_PX + 500, CY_PX + 500]])
    clipped, _ = project_boxes(boxes, camera)
    np.testing.assert_allclose(clipped, [[0.0, 0.0, WIDTH_PX - 1, HEIGHT_PX - 1]])
    np.testing.assert_array_equal(visible, [True])


def test_fully_in_front_equals_corner_min_max(camera: Camera) -> None:
    """Oracle: with every corner in front, clipping changes nothing."""
    rng = np.random.default_rng(0)
    n = 50
    xyz = np.column_stack([rng.uniform(5, 40, n), rng.uniform(-3, 3, n), rng.uniform(-1, 1, n)])
    lwh = rng.uniform(0.5, 4.0, (n, 3))
    yaw = rng.uniform(-np.pi, np.pi, n)
    raw, visible = project_boxes((xyz, lwh, yaw), camera, clip_to_image=False)
    uv, depth = project_points(corners_3d(xyz, lwh, yaw).reshape(-1, 3), camera)
    assert (depth > 0.1).all()
    uv = uv.reshape(n, 8, 2)
    expected = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)
    np.testing.assert_allclose(raw[visible], expected[visible])
    assert visible.sum() > n // 2


def test_fast_path_equals_edge_clipping_bit_for_bit(camera: Camera) -> None:
    """Boxes with every corner in front skip the edge clipping: the very same numbers."""
    rng = np.random.default_rng(1)
    n = 40
    xyz = np.column_stack([rng.uniform(-3, 60, n), rng.uniform(-20, 20, n), rng.uniform(-2, 2, n)])
    lwh = rng.uniform(0.5, 6.0, (n, 3))
    yaw = rng.uniform(-np.pi, np.pi, n)
    corners = corners_3d(xyz, lwh, yaw)
    ends = _clipped_edges_px(corners, camera, NEAR_PLANE_M).reshape(n, -1, 2)
    lo = np.where(np.isnan(ends), np.inf, ends).min(axis=1)
    hi = np.where(np.isnan(ends), -np.inf, ends).max(axis=1)
    in_front = (project_points(corners.reshape(-1, 3), camera)[1] >= NEAR_PLANE_M).reshape(n, 8)
    assert in_front.all(axis=1).sum() > n // 2 and not in_front.all()  # both paths are taken
    for rows in (np.flatnonzero(in_front.all(axis=1)), np.arange(n)):
        raw, visible = project_boxes((xyz[rows], lwh[rows], yaw[rows]), camera, clip_to_image=False)
        expected = np.concatenate([lo[rows], hi[rows]], axis=1)
        np.testing.assert_array_equal(raw[visible], expected[visible])


def test_empty(camera: Camera) -> None:
    xyxy, visible = project_boxes(Boxes.empty(), camera)
    assert xyxy.shape == (0, 4) and visible.shape == (0,)
    assert box_wireframes_image(Boxes.empty(), camera).shape == (0, 12, 2, 2)
    uv, depth = project_points(np.zeros((0, 3)), camera)
    assert uv.shape == (0, 2) and depth.shape == (0,)


def test_wireframes(camera: Camera) -> None:
    boxes = make_boxes(
        [[10.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-10.0, 0.0, 0.0]],
        [[2.0, 2.0, 2.0], [4.0, 1.0, 1.0], [2.0, 2.0, 2.0]],
        [0.0, 0.0, 0.0],
    )
    segments = box_wireframes_image(boxes, camera)
    assert segments.shape == (3, 12, 2, 2)
    drawn = ~np.isnan(segments).any(axis=(2, 3))
    # ahead: all 12 edges; straddling: the rear face's 4 edges are dropped; behind: nothing.
    np.testing.assert_array_equal(drawn.sum(axis=1), [12, 8, 0])
    # The 4 length-wise edges of the straddling box cross the near plane; their clipped ends are
    # the corners of the ±500 px near-plane rectangle.
    ends = segments[1][drawn[1]].reshape(-1, 2)
    on_near_plane = np.isclose(np.abs(ends - [CX_PX, CY_PX]), 500.0).all(axis=1)
    assert on_near_plane.sum() == 4
    # Wireframe extents agree with project_boxes.
    raw, _ = project_boxes(boxes, camera, clip_to_image=False)
    ends_ahead = segments[0].reshape(-1, 2)
    np.testing.assert_allclose(raw[0], [*ends_ahead.min(axis=0), *ends_ahead.max(axis=0)])


def test_in_image_fraction_by_hand(camera: Camera) -> None:
    """Fraction of the projected width inside the image: a 2 m cube 10 m ahead (all of it),
    the same cube 6 m to the left (its near-right edge only), one behind the camera (0)."""
    xyz = np.array([[10.0, 0.0, 0.0], [10.0, 6.0, 0.0], [-10.0, 0.0, 0.0]])
    lwh = np.full((3, 3), 2.0)
    fraction = in_image_fraction(xyz, lwh, np.zeros(3), camera)
    # u = 50 - 100 y / x over x in [9, 11], y in [5, 7]: from 50 - 700/9 (< 0) to 50 - 500/11
    assert fraction[0] == pytest.approx(1.0)
    assert fraction[1] == pytest.approx((50 - 500 / 11) / (700 / 9 - 500 / 11))
    assert fraction[2] == 0.0
