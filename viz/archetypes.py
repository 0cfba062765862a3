"""Tracker types -> Rerun archetypes: boxes, projected wireframes, cost heat maps, stable colours.

Everything is vectorised over a batch: one archetype per stage per frame (Rerun logs batches far
faster than single objects). Arrays are handed over as float32, which Rerun stores anyway.
"""

from __future__ import annotations

import colorsys
from typing import Any

import numpy as np
import rerun as rr
from numpy.typing import NDArray

from tracker.boxes import Boxes, FloatArray
from tracker.camera import box_wireframes_image
from tracker.categories import CATEGORIES
from tracker.frame import Camera

Rgb = NDArray[np.uint8]

_PALETTE_SIZE = 1024
# golden-ratio hues: consecutive ids (born together) get far-apart colours, and an id keeps its
# colour in every entity and every recording
_PALETTE = np.array(
    [
        colorsys.hsv_to_rgb((i * 0.618033988749895) % 1.0, 0.70 + 0.25 * (i % 2), 0.95)
        for i in range(_PALETTE_SIZE)
    ]
)
#: The viewer's dark background, and the WCAG contrast every track colour keeps against it
#: (4.5 = body text): a saturated blue on black is otherwise unreadable as a label.
BACKGROUND_RGB = (18, 18, 18)
MIN_CONTRAST = 4.5


def _luminance(rgb01: FloatArray) -> FloatArray:
    """WCAG relative luminance of (..., 3) sRGB colours in [0, 1]."""
    lin = np.where(rgb01 <= 0.04045, rgb01 / 12.92, ((rgb01 + 0.055) / 1.055) ** 2.4)
    return lin @ np.array([0.2126, 0.7152, 0.0722])


def contrast_ratio(rgb01: FloatArray, background01: FloatArray) -> FloatArray:
    """WCAG contrast ratio of (..., 3) colours against one background colour (both in [0, 1])."""
    return (_luminance(rgb01) + 0.05) / (_luminance(np.asarray(background01)) + 0.05)


def _legible(rgb01: FloatArray) -> FloatArray:
    """Blend each colour towards white just enough to reach :data:`MIN_CONTRAST`."""
    bg = np.asarray(BACKGROUND_RGB) / 255.0
    steps = np.linspace(0.0, 1.0, 41)  # blend fractions, smallest first
    mixed = rgb01[:, None, :] + steps[None, :, None] * (1.0 - rgb01[:, None, :])
    ok = contrast_ratio(mixed, bg) >= MIN_CONTRAST + 0.05  # margin for rounding to uint8
    first = np.argmax(ok, axis=1)
    return mixed[np.arange(len(rgb01)), first]


PALETTE_U8: Rgb = (_legible(_PALETTE) * 255).round().astype(np.uint8)

DETECTION_KEPT_RGB = (235, 235, 235)
DETECTION_DROPPED_RGB = (110, 110, 110)
GT_RGB = (60, 220, 120)
UNMATCHED_TRACK_RGB = (255, 60, 60)
UNMATCHED_DETECTION_RGB = (255, 170, 0)
ID_SWITCH_RGB = (255, 0, 255)
REJECTED_RGB = (255, 60, 60)


def track_colors(track_ids: NDArray[np.integer]) -> Rgb:
    """(N, 3) uint8: one stable colour per track id."""
    return PALETTE_U8[np.asarray(track_ids, dtype=np.int64) % _PALETTE_SIZE]


def cost_colors(cost: FloatArray, max_cost: FloatArray) -> Rgb:
    """(..., 3) uint8 for costs: green (cheap) -> yellow (at the threshold) when accepted,
    dark red above the threshold, near black when not comparable (inf / NaN)."""
    cost = np.asarray(cost, dtype=np.float64)
    max_cost = np.broadcast_to(np.asarray(max_cost, dtype=np.float64), cost.shape)
    finite = np.isfinite(cost)
    # costs are 1 - similarity with similarity in [-1, 1] (Ro_GDIoU: wider), so cheap is <= 0
    lo = np.minimum(max_cost - 1.0, -1.0)
    with np.errstate(invalid="ignore"):
        t = np.clip((cost - lo) / np.maximum(max_cost - lo, 1e-9), 0.0, 1.0)
    rgb = np.empty((*cost.shape, 3), dtype=np.float64)
    rgb[..., 0] = 40 + 215 * t
    rgb[..., 1] = 200 + 30 * t
    rgb[..., 2] = 60 * (1 - t)
    with np.errstate(invalid="ignore"):
        above = finite & (cost > max_cost)
    rgb[above] = (120, 20, 30)
    rgb[~finite] = (25, 25, 30)
    return rgb.astype(np.uint8)


def quaternions_xyzw(yaw_rad: FloatArray) -> NDArray[np.float32]:
    """(N, 4) rotation about +z by yaw, as Rerun's xyzw quaternions."""
    half = np.asarray(yaw_rad, dtype=np.float64) / 2.0
    q = np.zeros((len(half), 4), dtype=np.float32)
    q[:, 2], q[:, 3] = np.sin(half), np.cos(half)
    return q


def pack_rgb(rgb: Any) -> NDArray[np.uint32]:
    """(..., 3) uint8 -> (...) packed 0xRRGGBBAA, the form Rerun stores (no per-call conversion)."""
    c = np.asarray(rgb, dtype=np.uint32)
    return (c[..., 0] << 24) | (c[..., 1] << 16) | (c[..., 2] << 8) | np.uint32(0xFF)


PALETTE_U32: NDArray[np.uint32] = pack_rgb(PALETTE_U8)


def track_colors_u32(track_ids: NDArray[np.integer]) -> NDArray[np.uint32]:
    return PALETTE_U32[np.asarray(track_ids, dtype=np.int64) % _PALETTE_SIZE]


def solid(rgb: tuple[int, int, int], n: int) -> NDArray[np.uint32]:
    return np.full(n, pack_rgb(rgb), dtype=np.uint32)


def boxes3d_fields(
    boxes: Boxes,
    *,
    colors: NDArray[np.uint32],
    labels: list[str],
    radius: float | FloatArray,
) -> dict[str, Any]:
    """Per-instance Boxes3D fields of a batch (class ids from the root AnnotationContext)."""
    n = len(boxes)
    finite = np.isfinite(boxes.lwh).all(axis=1)
    half = np.where(finite[:, None], boxes.lwh, 0.5) / 2.0
    return {
        "centers": boxes.xyz.astype(np.float32),
        "half_sizes": half.astype(np.float32),
        "quaternions": quaternions_xyzw(np.nan_to_num(boxes.yaw)),
        "colors": colors,
        "radii": np.broadcast_to(np.asarray(radius, dtype=np.float32), (n,)).copy(),
        "labels": labels,
        "class_ids": boxes.category.astype(np.uint16),
    }


def boxes2d_fields(
    xyxy: FloatArray, *, colors: NDArray[np.uint32], labels: list[str], ui_points: float
) -> dict[str, Any]:
    xyxy = np.asarray(xyxy, dtype=np.float32).reshape(-1, 4)
    return {
        "centers": (xyxy[:, :2] + xyxy[:, 2:]) / 2,
        "half_sizes": (xyxy[:, 2:] - xyxy[:, :2]) / 2,
        "colors": colors,
        "labels": labels,
        "radii": np.full(len(xyxy), -ui_points, dtype=np.float32),  # negative = UI points
    }


def project_wireframes(
    boxes: Boxes, camera: Camera, *, margin_px: float = 2000.0
) -> tuple[NDArray[np.float32], NDArray[np.int64], FloatArray, NDArray[np.bool_]]:
    """Projected box edges and 2D boxes from one projection of the corners.

    Returns ``segments (S, 2, 2)`` pixel end points of the drawable edges, ``rows (S,)`` the box
    of each segment, and ``xyxy (N, 4)`` / ``visible (N,)`` exactly as
    :func:`tracker.camera.project_boxes` computes them (the image extent of the part of each box
    in front of the near plane). Edges behind the camera are dropped, and so are whole boxes
    that land far outside the image (projected from beside the camera).
    """
    n = len(boxes)
    if not n:
        return (
            np.zeros((0, 2, 2), np.float32),
            np.zeros(0, np.int64),
            np.zeros((0, 4)),
            np.zeros(0, bool),
        )
    seg = box_wireframes_image(boxes, camera)  # (N, 12, 2, 2), NaN behind the near plane
    ends = seg.reshape(n, -1, 2)
    missing = np.isnan(ends)
    lo = np.where(missing, np.inf, ends).min(axis=1)
    hi = np.where(missing, -np.inf, ends).max(axis=1)
    max_xy = np.array([camera.width_px - 1, camera.height_px - 1], dtype=np.float64)
    lo_clip, hi_clip = np.clip(lo, 0.0, max_xy), np.clip(hi, 0.0, max_xy)
    visible = ~missing[..., 0].all(axis=1) & (hi_clip > lo_clip).all(axis=1)
    xyxy = np.concatenate([lo_clip, hi_clip], axis=1)
    xyxy[~visible] = np.nan

    ok = ~np.isnan(seg).any(axis=(2, 3))  # (N, 12)
    lim_lo = np.array([-margin_px, -margin_px])
    lim_hi = np.array([camera.width_px + margin_px, camera.height_px + margin_px])
    with np.errstate(invalid="ignore"):
        inside = ((seg >= lim_lo) & (seg <= lim_hi)).all(axis=(2, 3))
    keep = ok & (ok & inside).any(axis=1)[:, None]
    rows = np.broadcast_to(np.arange(n)[:, None], keep.shape)[keep]
    return seg[keep].astype(np.float32), rows, xyxy, visible


def annotation_context() -> rr.AnnotationContext:
    """Class ids = :data:`tracker.categories.CATEGORIES` indices (hover shows the class)."""
    return rr.AnnotationContext(
        [rr.AnnotationInfo(id=i, label=n) for i, n in enumerate(CATEGORIES)]
    )


def cost_image_rgb(cost: FloatArray, max_cost_per_row: FloatArray) -> NDArray[np.uint8]:
    """The (tracks x detections) cost matrix as an (M, N, 3) heat map, one pixel per cell."""
    return cost_colors(cost, np.asarray(max_cost_per_row, dtype=np.float64)[:, None])
