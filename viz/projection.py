"""Box projection batched over many frames at once (each box with its own camera matrix).

:mod:`tracker.camera` projects one batch of boxes into one camera. The observer buffers a few
hundred frames and projects them in one call here, which removes the per-frame numpy overhead
(the dominant cost of drawing wireframes every frame). The maths is the same: every edge is
clipped against the near plane in homogeneous image coordinates before the perspective division,
and the 2D box is the clipped image extent; tests/test_viz_projection.py checks equality with
:func:`tracker.camera.project_boxes` and :func:`tracker.camera.box_wireframes_image`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from tracker.boxes import FloatArray
from tracker.camera import NEAR_PLANE_M, clip_edges_px
from tracker.geometry import corners_3d


def project_boxes_batched(
    xyz: FloatArray,
    lwh: FloatArray,
    yaw_rad: FloatArray,
    image_from_world: FloatArray,
    size_px: NDArray[np.integer],
    *,
    near_m: float = NEAR_PLANE_M,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Projected edges and 2D boxes of N boxes, each in its own camera.

    Parameters
    ----------
    xyz, lwh, yaw_rad : (N, 3), (N, 3), (N,) world boxes (metres, radians).
    image_from_world : (N, 3, 4) the camera matrix of each box.
    size_px : (N, 2) image width and height of each box's camera.

    Returns
    -------
    segments_px : (N, 12, 2, 2) edge end points; NaN for edges entirely behind the near plane.
    xyxy_image : (N, 4) image extent clipped to the image; NaN where not visible.
    visible : (N,) part of the box is in front of the near plane and inside the image.
    """
    n = len(yaw_rad)
    if n == 0:
        return np.zeros((0, 12, 2, 2)), np.zeros((0, 4)), np.zeros(0, dtype=bool)
    corners = corners_3d(xyz, lwh, yaw_rad)  # (N, 8, 3)
    m = np.asarray(image_from_world, dtype=np.float64)
    h = np.einsum("nij,nkj->nki", m[:, :, :3], corners) + m[:, None, :, 3]  # (N, 8, 3)
    seg = clip_edges_px(h, near_m=near_m)  # the same clipping as tracker.camera

    pts = seg.reshape(n, -1, 2)
    missing = np.isnan(pts)
    lo = np.where(missing, np.inf, pts).min(axis=1)
    hi = np.where(missing, -np.inf, pts).max(axis=1)
    max_xy = np.asarray(size_px, dtype=np.float64) - 1.0
    lo_clip = np.clip(lo, 0.0, max_xy)
    hi_clip = np.clip(hi, 0.0, max_xy)
    visible = ~missing[..., 0].all(axis=1) & (hi_clip > lo_clip).all(axis=1)
    xyxy = np.concatenate([lo_clip, hi_clip], axis=1)
    xyxy[~visible] = np.nan
    return seg, xyxy, visible


def drawable_segments(
    segments_px: FloatArray, size_px: NDArray[np.integer], *, margin_px: float = 2000.0
) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
    """The segments worth drawing, ``(S, 2, 2)`` float32, and the box row of each.

    Edges behind the camera are dropped, and so are whole boxes far outside the image
    (projected from beside the camera): their huge coordinates only confuse a 2D view.
    """
    n = len(segments_px)
    if n == 0:
        return np.zeros((0, 2, 2), np.float32), np.zeros(0, np.int64)
    ok = ~np.isnan(segments_px).any(axis=(2, 3))  # (N, 12)
    size = np.asarray(size_px, dtype=np.float64)[:, None, None, :]
    with np.errstate(invalid="ignore"):
        inside = ((segments_px >= -margin_px) & (segments_px <= size + margin_px)).all(axis=(2, 3))
    keep = ok & (ok & inside).any(axis=1)[:, None]
    rows = np.broadcast_to(np.arange(n)[:, None], keep.shape)[keep]
    return segments_px[keep].astype(np.float32), rows
