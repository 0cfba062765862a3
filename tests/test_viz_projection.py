"""Projection for drawing: batched over frames, equal to tracker.camera, and true to the labels."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tracker.boxes import Boxes
from tracker.camera import box_wireframes_image, project_boxes, project_boxes_batched
from tracker.io.baseversion import read_baseversion
from tracker.io.convert.kitti import read_kitti_labels
from tracker.io.synthetic import front_camera
from viz.projection import drawable_segments

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"


def _random_boxes(rng: np.random.Generator, n: int) -> Boxes:
    """Boxes around a camera at the origin looking along +x: in front, behind, straddling."""
    return Boxes.create(
        xyz=np.column_stack(
            [rng.uniform(-10, 60, n), rng.uniform(-30, 30, n), rng.uniform(0, 2, n)]
        ),
        lwh=rng.uniform(0.5, 6, (n, 3)),
        yaw=rng.uniform(-np.pi, np.pi, n),
        category=np.zeros(n, dtype=int),
    )


def test_batched_projection_equals_tracker_camera() -> None:
    rng = np.random.default_rng(7)
    boxes = _random_boxes(rng, 300)
    cam = front_camera()
    # a second camera per row: shifted and turned, to check each box uses its own matrix
    turn = np.array(
        [[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    )
    cam2 = type(cam)("B", cam.image_from_camera, cam.camera_from_world @ turn, 800, 600)
    which = rng.integers(0, 2, len(boxes)).astype(bool)
    m = np.where(which[:, None, None], cam2.image_from_world, cam.image_from_world)
    size = np.where(which[:, None], [800, 600], [cam.width_px, cam.height_px])
    seg, xyxy, visible = project_boxes_batched(boxes.xyz, boxes.lwh, boxes.yaw, m, size)
    for flag, camera in ((False, cam), (True, cam2)):
        rows = which == flag
        ref_xyxy, ref_visible = project_boxes(boxes[rows], camera)
        np.testing.assert_array_equal(visible[rows], ref_visible)
        np.testing.assert_allclose(xyxy[rows], ref_xyxy, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(
            seg[rows], box_wireframes_image(boxes[rows], camera), rtol=1e-9, atol=1e-9
        )
    assert visible.any() and not visible.all()


def test_empty_batches() -> None:
    seg, xyxy, visible = project_boxes_batched(
        np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3, 4)), np.zeros((0, 2))
    )
    assert seg.shape == (0, 12, 2, 2) and xyxy.shape == (0, 4) and visible.shape == (0,)
    strips, rows = drawable_segments(seg, np.zeros((0, 2)))
    assert strips.shape == (0, 2, 2) and rows.shape == (0,)


def test_drawable_segments_drop_what_is_behind_or_far_off() -> None:
    cam = front_camera()
    boxes = Boxes.create(
        xyz=[[20.0, 0.0, 0.8], [-20.0, 0.0, 0.8], [0.3, 40.0, 0.8]],  # ahead, behind, beside
        lwh=[[4.0, 2.0, 1.6]] * 3,
        yaw=[0.0, 0.0, 0.0],
        category=[0, 0, 0],
    )
    seg = box_wireframes_image(boxes, cam)
    strips, rows = drawable_segments(seg, np.tile([cam.width_px, cam.height_px], (3, 1)))
    assert set(rows.tolist()) == {0}
    assert len(strips) == 12


def test_gt_wireframes_fall_inside_the_image_where_labels_say_visible() -> None:
    """Where the label says the object is wholly in the image (truncation 0 and a 2D box that
    does not touch the border: KITTI marks many border-clipped cars as untruncated), the
    projected 3D box is inside the image too (a few pixels of slack: the label box is annotated
    in the camera's axes, ours is z-up), and its 2D box overlaps the annotated one."""
    if not (SAMPLE / "gt.json.gz").is_file():
        pytest.skip("sample data missing")
    gt = read_baseversion(SAMPLE / "gt.json.gz", fallback_frame_rate_hz=10.0)["0001"]
    labels = read_kitti_labels(SAMPLE / "raw" / "training" / "label_02" / "0001.txt")
    by_frame = {f.frame_id: f for f in gt}
    checked, overlaps, excess_px = 0, [], []
    box = labels.xyxy_image
    inside = (box[:, 0] >= 2) & (box[:, 1] >= 2) & (box[:, 2] <= 1239) & (box[:, 3] <= 372)
    for i in np.flatnonzero((labels.truncated == 0) & inside & (labels.track_id >= 0)):
        frame = by_frame[int(labels.frame[i])]
        rows = np.flatnonzero(frame.boxes.track_id == labels.track_id[i])
        if not len(rows):
            continue
        cam = frame.cameras[0]
        gt_box = frame.boxes[rows[:1]]
        m = cam.image_from_world[None]
        size = np.array([[cam.width_px, cam.height_px]])
        seg, xyxy, visible = project_boxes_batched(gt_box.xyz, gt_box.lwh, gt_box.yaw, m, size)
        assert visible[0]
        assert not np.isnan(seg).any(), "a wholly visible object has no edge behind the camera"
        lo, hi = seg.reshape(-1, 2).min(axis=0), seg.reshape(-1, 2).max(axis=0)
        excess = max(-lo[0], -lo[1], hi[0] - cam.width_px, hi[1] - cam.height_px)
        # the 3D box may reach past the tight 2D annotation (wheels, rear corners), never far
        assert excess <= 0.3 * (box[i, 3] - box[i, 1]), (int(labels.frame[i]), excess)
        excess_px.append(excess)
        a, b = xyxy[0], labels.xyxy_image[i]
        inter = np.prod(np.clip(np.minimum(a[2:], b[2:]) - np.maximum(a[:2], b[:2]), 0, None))
        union = np.prod(a[2:] - a[:2]) + np.prod(b[2:] - b[:2]) - inter
        overlaps.append(inter / union)
        checked += 1
    assert checked > 1500
    assert np.mean(np.array(excess_px) <= 8.0) > 0.99
    assert np.median(overlaps) > 0.7
