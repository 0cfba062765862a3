"""Projection of world points and 3D boxes into a pinhole :class:`~tracker.frame.Camera`.

Everything is vectorised over boxes. Depth is the third homogeneous image coordinate
``w = (image_from_world @ [x, y, z, 1])[2]``; it is metric for KITTI ``P2`` and ``[K | 0]``
matrices (third row ``[r3ᵀ | t]`` with a unit ``r3``), which is every camera we build.

A box that straddles the camera plane cannot be projected corner by corner: a corner behind the
camera flips sign through the perspective division and lands on the wrong side of the image (the
nuScenes converter of the reference has exactly this bug). So each of the 12 edges is first
clipped against the near plane ``w = near_m`` and only the part in front of it is projected; the
2D box is the min/max over the clipped edges' end points, i.e. the exact image extent of the
visible part of the box.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tracker.boxes import Boxes, FloatArray
from tracker.frame import Camera
from tracker.geometry import BOX_EDGES, corners_3d, wrap_angle

BoolArray = NDArray[np.bool_]

#: Default near plane (metres in front of the camera) for clipping.
NEAR_PLANE_M = 0.1

#: z-up world (x forward, y left, z up) from camera axes (x right, y down, z forward).
WORLD_FROM_CAMERA_AXES: FloatArray = np.array(
    [[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)

_EDGE_START = np.array([a for a, _ in BOX_EDGES], dtype=np.int64)
_EDGE_END = np.array([b for _, b in BOX_EDGES], dtype=np.int64)
_EDGE_ENDS = np.stack([_EDGE_START, _EDGE_END], axis=1)  # (12, 2)


def _homogeneous_image(xyz_world: ArrayLike, camera: Camera) -> FloatArray:
    """(..., 3) homogeneous image coordinates (u·w, v·w, w) of (..., 3) world points."""
    p = np.asarray(xyz_world, dtype=np.float64)
    m = camera.image_from_world
    return p @ m[:, :3].T + m[:, 3]


def project_points(xyz_world: ArrayLike, camera: Camera) -> tuple[FloatArray, FloatArray]:
    """Project world points into the image.

    Parameters
    ----------
    xyz_world : (N, 3) points in the world frame, metres.
    camera : the camera (``image_from_camera @ camera_from_world``).

    Returns
    -------
    uv_px : (N, 2) pixel coordinates. Meaningless where ``depth_m <= 0`` (behind the camera);
        filter with :func:`in_front`.
    depth_m : (N,) depth along the optical axis, metres.
    """
    h = _homogeneous_image(np.asarray(xyz_world, dtype=np.float64).reshape(-1, 3), camera)
    depth_m = h[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv_px = h[:, :2] / depth_m[:, None]
    return uv_px, depth_m


def in_front(xyz_world: ArrayLike, camera: Camera, *, near_m: float = NEAR_PLANE_M) -> BoolArray:
    """(N,) True where a world point is at least ``near_m`` in front of the camera."""
    _, depth_m = project_points(xyz_world, camera)
    return depth_m >= near_m


def _corners_world(boxes: Boxes | tuple[Any, Any, Any]) -> FloatArray:
    """(N, 8, 3) world corners of a Boxes batch or of an ``(xyz, lwh, yaw)`` tuple."""
    if isinstance(boxes, Boxes):
        return corners_3d(boxes.xyz, boxes.lwh, boxes.yaw)
    xyz, lwh, yaw = boxes
    return corners_3d(xyz, lwh, yaw)


def _clipped_edges_px(
    corners_world: FloatArray, camera: Camera, near_m: float, h: FloatArray | None = None
) -> FloatArray:
    """(N, 12, 2, 2) pixel end points of each box edge clipped to ``w >= near_m``; NaN if behind.

    ``h`` : the corners' homogeneous image coordinates when already computed.
    """
    if h is None:
        h = _homogeneous_image(corners_world, camera)  # (N, 8, 3)
    return clip_edges_px(h, near_m=near_m)


def clip_edges_px(h: FloatArray, *, near_m: float = NEAR_PLANE_M) -> FloatArray:
    """Box edges from the 8 corners' homogeneous image coordinates ``h (N, 8, 3)``, clipped to
    ``w >= near_m`` before the perspective division: ``(N, 12, 2, 2)`` pixels, NaN if behind.

    Shared by :func:`project_boxes` (one camera) and the visualiser's batched projection (a
    camera per box): only ``h`` depends on the camera.
    """
    a, b = h[:, _EDGE_START], h[:, _EDGE_END]  # (N, 12, 3)
    w_a, w_b = a[..., 2], b[..., 2]
    front_a, front_b = w_a >= near_m, w_b >= near_m
    # The image map is linear in homogeneous coordinates, so the near-plane crossing of the 3D
    # edge is the same linear interpolation here. Only needed where exactly one end is in front
    # (then w_b != w_a); elsewhere t = 0 keeps the arithmetic finite.
    crosses = front_a != front_b
    t = np.where(crosses, (near_m - w_a) / np.where(crosses, w_b - w_a, 1.0), 0.0)
    crossing = a + t[..., None] * (b - a)
    a = np.where(front_a[..., None], a, crossing)
    b = np.where(front_b[..., None], b, crossing)
    ends = np.stack([a, b], axis=2)  # (N, 12, 2, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        ends_px = ends[..., :2] / ends[..., 2:3]
    behind = ~(front_a | front_b)
    ends_px[behind] = np.nan
    return ends_px


def project_boxes(
    boxes: Boxes | tuple[Any, Any, Any],
    camera: Camera,
    *,
    near_m: float = NEAR_PLANE_M,
    clip_to_image: bool = True,
) -> tuple[FloatArray, BoolArray]:
    """2D image boxes of 3D world boxes (the extent of the part in front of the near plane).

    Parameters
    ----------
    boxes : a :class:`Boxes` batch, or a tuple ``(xyz (N, 3), lwh (N, 3), yaw (N,))`` of world
        centres, sizes (metres) and headings (radians).
    camera : the camera to project into.
    near_m : near-plane distance; box edges are clipped to ``depth >= near_m`` before projecting.
    clip_to_image : clip the result to ``[0, width_px - 1] x [0, height_px - 1]`` (the KITTI
        pixel-index convention, as in the reference KITTI writer).

    Returns
    -------
    xyxy_image : (N, 4) x1, y1, x2, y2 in pixels; NaN for boxes that are not visible.
    visible : (N,) True when part of the box is in front of the near plane and its 2D box
        overlaps the image with a positive area.
    """
    corners = _corners_world(boxes)
    n = len(corners)
    if n == 0:
        return np.zeros((0, 4)), np.zeros(0, dtype=bool)
    h = _homogeneous_image(corners, camera)  # (N, 8, 3)
    if (h[..., 2] >= near_m).all():
        # Every corner in front of the near plane (the usual case): no edge is clipped, and the
        # clipped edges' end points below would be exactly these 8 corners.
        uv_px = h[..., :2] / h[..., 2:3]
        lo, hi = uv_px.min(axis=1), uv_px.max(axis=1)  # (N, 2)
        any_front = np.ones(n, dtype=bool)
    else:
        ends_px = _clipped_edges_px(corners, camera, near_m, h).reshape(n, -1, 2)  # (N, 24, 2)
        any_front = ~np.isnan(ends_px[..., 0]).all(axis=1)
        lo = np.where(np.isnan(ends_px), np.inf, ends_px).min(axis=1)  # (N, 2)
        hi = np.where(np.isnan(ends_px), -np.inf, ends_px).max(axis=1)
    xyxy_image = np.concatenate([lo, hi], axis=1)
    clipped, visible = clip_boxes_to_image(xyxy_image, any_front, camera)
    if clip_to_image:
        return clipped, visible
    xyxy_image[~visible] = np.nan
    return xyxy_image, visible


def in_image_fraction(
    xyz: FloatArray, lwh: FloatArray, yaw: FloatArray, camera: Camera
) -> FloatArray:
    """(N,) fraction of each projected box's width that lies inside the image, 0 where the
    box is not visible (:func:`project_boxes` unclipped). Numpy reference of the compiled
    ``kernels.camera.in_image_fraction_kernel``."""
    xyxy, visible = project_boxes((xyz, lwh, yaw), camera, clip_to_image=False)
    x1, x2 = xyxy[visible, 0], xyxy[visible, 2]
    inside = np.minimum(x2, camera.width_px - 1) - np.maximum(x1, 0.0)
    fraction = np.zeros(len(xyz))
    fraction[visible] = inside / np.maximum(x2 - x1, 1e-9)
    return fraction


def clip_boxes_to_image(
    xyxy: FloatArray, candidates: BoolArray, camera: Camera
) -> tuple[FloatArray, BoolArray]:
    """2D boxes clipped to ``[0, width_px - 1] x [0, height_px - 1]`` (the KITTI pixel-index
    convention) and ``visible``: a ``candidate`` whose clipped box has a positive area. Boxes
    that are not visible are NaN."""
    max_xy = np.array([camera.width_px - 1, camera.height_px - 1] * 2, dtype=np.float64)
    clipped = np.clip(xyxy, 0.0, max_xy)
    with np.errstate(invalid="ignore"):  # NaN rows: not visible
        visible = candidates & (clipped[:, 2:] > clipped[:, :2]).all(axis=1)
    clipped[~visible] = np.nan
    return clipped, visible


def box_wireframes_image(
    boxes: Boxes | tuple[Any, Any, Any],
    camera: Camera,
    *,
    near_m: float = NEAR_PLANE_M,
) -> FloatArray:
    """Projected box edges for drawing, clipped to the near plane (not to the image).

    Parameters
    ----------
    boxes : a :class:`Boxes` batch or an ``(xyz, lwh, yaw)`` tuple, as in :func:`project_boxes`.
    camera : the camera to project into.
    near_m : near-plane distance in metres.

    Returns
    -------
    segments_px : (N, 12, 2, 2) the two pixel end points of each edge of
        :data:`tracker.geometry.BOX_EDGES`; NaN for edges entirely behind the near plane.
        ``segments_px.reshape(-1, 2, 2)`` filtered on ``~isnan`` feeds a line-strip logger.
    """
    corners = _corners_world(boxes)
    if len(corners) == 0:
        return np.zeros((0, len(BOX_EDGES), 2, 2))
    return _clipped_edges_px(corners, camera, near_m)


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
    # batched matmul: einsum over these small axes is ~7x slower
    h = corners @ m[:, :, :3].transpose(0, 2, 1) + m[:, None, :, 3]  # (N, 8, 3)
    # Boxes wholly in front of the near plane (most): no edge is clipped, the edges' end points
    # are the corners (as in project_boxes); only the others go through the clipping.
    front = (h[..., 2] >= near_m).all(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):  # behind: replaced below
        uv = h[..., :2] / h[..., 2:3]
    seg = uv[:, _EDGE_ENDS]  # (N, 12, 2, 2)
    lo, hi = uv.min(axis=1), uv.max(axis=1)
    any_front = np.ones(n, dtype=bool)
    cut = np.flatnonzero(~front)
    if len(cut):
        seg[cut] = clip_edges_px(h[cut], near_m=near_m)  # the same clipping as project_boxes
        pts = seg[cut].reshape(len(cut), -1, 2)
        missing = np.isnan(pts)
        lo[cut] = np.where(missing, np.inf, pts).min(axis=1)
        hi[cut] = np.where(missing, -np.inf, pts).max(axis=1)
        any_front[cut] = ~missing[..., 0].all(axis=1)
    max_xy = np.asarray(size_px, dtype=np.float64) - 1.0
    lo_clip = np.clip(lo, 0.0, max_xy)
    hi_clip = np.clip(hi, 0.0, max_xy)
    visible = any_front & (hi_clip > lo_clip).all(axis=1)
    xyxy = np.concatenate([lo_clip, hi_clip], axis=1)
    xyxy[~visible] = np.nan
    return seg, xyxy, visible


def boxes_world_to_rect(
    xyz_world: FloatArray, lwh: FloatArray, yaw_world: FloatArray, rect_from_world: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Inverse of ``tracker.io.convert.kitti.boxes_rect_to_world``: world boxes back to KITTI
    rect-camera values.

    Use this (then an upright box about the camera's y axis, as KITTI and the reference writer
    do) to write KITTI results: projecting the z-up world box instead tilts it by the ego's
    pitch/roll relative to the world (up to ~4° with the ORB-SLAM3 poses), which inflates the
    2D box.

    Parameters
    ----------
    xyz_world : (N, 3) geometric centres. lwh : (N, 3). yaw_world : (N,) radians.
    rect_from_world : (4, 4) for all boxes, or (N, 4, 4) per box.

    Returns
    -------
    xyz_bottom_rect : (N, 3) KITTI ``location`` (bottom centre, rect frame).
    hwl : (N, 3) KITTI ``dimensions``.
    rotation_y : (N,) KITTI ``rotation_y`` in (−pi, pi]: the world heading rotated into rect and
        projected on the camera x-z plane.
    """
    xyz_world = np.asarray(xyz_world, dtype=np.float64).reshape(-1, 3)
    lwh = np.asarray(lwh, dtype=np.float64).reshape(-1, 3)
    yaw_world = np.asarray(yaw_world, dtype=np.float64).reshape(-1)
    transform = np.broadcast_to(np.asarray(rect_from_world, dtype=np.float64), (len(lwh), 4, 4))
    rotation = transform[:, :3, :3]
    centre_rect = np.einsum("nij,nj->ni", rotation, xyz_world) + transform[:, :3, 3]
    xyz_bottom_rect = centre_rect + np.stack(
        [np.zeros(len(lwh)), lwh[:, 2] / 2.0, np.zeros(len(lwh))], axis=1
    )
    heading_world = np.stack([np.cos(yaw_world), np.sin(yaw_world), np.zeros(len(lwh))], axis=1)
    heading_rect = np.einsum("nij,nj->ni", rotation, heading_world)
    rotation_y = wrap_angle(np.arctan2(-heading_rect[:, 2], heading_rect[:, 0]))
    return xyz_bottom_rect, lwh[:, ::-1].copy(), rotation_y


def upright_in_camera_axes(
    location: FloatArray, hwl: FloatArray, rotation_y: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Centres (N, 3) and z-up yaws (N,) of KITTI boxes (:func:`boxes_world_to_rect`'s values)
    stood upright in camera axes, in the z-up frame ``WORLD_FROM_CAMERA_AXES`` maps the camera's
    axes to: project them with ``inv(WORLD_FROM_CAMERA_AXES)`` as the camera's pose."""
    centre_cam = location - np.column_stack(
        [np.zeros(len(location)), hwl[:, 0] / 2.0, np.zeros(len(location))]
    )
    # the heading about camera -y, as a z-up yaw
    return centre_cam @ WORLD_FROM_CAMERA_AXES[:3, :3].T, -rotation_y - np.pi / 2.0


def project_boxes_upright(
    boxes: Boxes, camera: Camera
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, BoolArray]:
    """World boxes as KITTI writes them for a (rectified) camera, and their unclipped 2D boxes.

    Returns ``location`` (N, 3) (bottom centre in the camera, y down), ``hwl`` (N, 3),
    ``rotation_y`` (N,) (:func:`boxes_world_to_rect`), and the 2D boxes (N, 4) and ``visible``
    (N,) of :func:`project_boxes` (not clipped to the image) of each box stood *upright in
    camera axes*, as KITTI annotates it and detectors write it: projecting the z-up world box
    would tilt it by the ego's pitch/roll relative to the world.
    """
    location, hwl, rotation_y = boxes_world_to_rect(
        boxes.xyz, boxes.lwh, boxes.yaw, camera.camera_from_world
    )
    xyz, yaw = upright_in_camera_axes(location, hwl, rotation_y)
    upright = Boxes.create(xyz=xyz, lwh=boxes.lwh, yaw=yaw, category=boxes.category)
    camera_axes = Camera(
        camera.name,
        camera.image_from_camera,
        np.linalg.inv(WORLD_FROM_CAMERA_AXES),
        camera.width_px,
        camera.height_px,
    )
    xyxy, visible = project_boxes(upright, camera_axes, clip_to_image=False)
    return location, hwl, rotation_y, xyxy, visible
