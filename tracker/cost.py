"""Pairwise similarities between track boxes (M rows) and detections (N columns).

Every function returns an (M, N) float64 *similarity* (higher is better); the matcher uses
cost = 1 - similarity. Pairs that are not compared (outside ``mask``, or with a missing box) get
-inf, i.e. cost +inf, so they can never be matched.

BEV scores follow the reference ``cal_rotation_gdiou_inbev`` (mctrack_reference.md §2.3) in
float64 instead of cv2's float32: expect ~1e-6 agreement with the official code, not bit equality.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.geometry import bev_pair_geometry


@dataclass(frozen=True, slots=True)
class RoGdiouTerms:
    """The three terms of Ro_GDIoU per pair, each (M, N); NaN where not computed.

    Ro_GDIoU = iou - w1 · enclosure - w2 · distance (MCTrack Alg. 1).

    Attributes
    ----------
    iou : (M, N) I / U: intersection over union, U = l_a·w_a + l_b·w_b - I.
    enclosure : (M, N) (C - U) / C, C the minimum-area rotated rectangle around both boxes.
    distance : (M, N) c² / d², c the BEV centre distance, d the diagonal of that rectangle.
    """

    iou: FloatArray
    enclosure: FloatArray
    distance: FloatArray

    def combine(self, *, w1: ArrayLike, w2: ArrayLike) -> FloatArray:
        """(M, N) Ro_GDIoU for weights that are scalars or (M,) per-track-row arrays."""
        m = self.iou.shape[0]
        w1_rows = np.broadcast_to(np.asarray(w1, dtype=np.float64), (m,))[:, None]
        w2_rows = np.broadcast_to(np.asarray(w2, dtype=np.float64), (m,))[:, None]
        return _finite_or_neg_inf(
            _combine(self.iou, self.enclosure, self.distance, w1_rows, w2_rows)
        )


def _combine(
    iou: FloatArray, enclosure: FloatArray, distance: FloatArray, w1: FloatArray, w2: FloatArray
) -> FloatArray:
    """Ro_GDIoU = IoU - w1·(C - U)/C - w2·c²/d² (a zero weight's term is skipped)."""
    similarity = iou.copy()
    if w1.any():
        similarity -= w1 * enclosure
    if w2.any():
        similarity -= w2 * distance
    return similarity


def _per_row(weight: ArrayLike, m: int) -> FloatArray:
    """A scalar or (M,) weight as an (M,) array."""
    w = np.asarray(weight, dtype=np.float64)
    return w if w.shape == (m,) else np.broadcast_to(w, (m,))


def _finite_or_neg_inf(similarity: FloatArray) -> FloatArray:
    return np.where(np.isfinite(similarity), similarity, -np.inf)


def _pairs(m: int, n: int, mask: ArrayLike | None) -> tuple[IntArray, IntArray]:
    """Row and column of every pair to compute, in row-major order."""
    if mask is None:
        rows, cols = np.divmod(np.arange(m * n, dtype=np.int64), max(n, 1))
        return rows, cols
    mask_arr = np.asarray(mask, dtype=bool)
    if mask_arr.shape != (m, n):
        raise ValueError(f"mask: expected shape {(m, n)}, got {mask_arr.shape}")
    rows, cols = np.nonzero(mask_arr)
    return rows.astype(np.int64, copy=False), cols.astype(np.int64, copy=False)


def _scatter(
    values: FloatArray, rows: IntArray, cols: IntArray, shape: tuple[int, int], fill: float
) -> FloatArray:
    """(M, N) array holding ``values`` at the computed pairs and ``fill`` elsewhere."""
    if len(values) == shape[0] * shape[1]:  # every pair, in row-major order (see _pairs)
        return values.reshape(shape)
    out = np.full(shape, fill)
    out[rows, cols] = values
    return out


def _bev_terms(
    a: Boxes, b: Boxes, mask: ArrayLike | None, *, with_enclosure: bool
) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """IoU, and optionally (C - U)/C and c²/d², as (M, N) arrays (NaN outside ``mask``)."""
    shape = (len(a), len(b))
    rows, cols = _pairs(*shape, mask)
    if len(rows) == 0:  # nothing requested: every term is NaN
        return (
            np.full(shape, np.nan),
            np.full(shape, np.nan) if with_enclosure else None,
            np.full(shape, np.nan) if with_enclosure else None,
        )
    iou, enclosure, distance = _bev_pair_terms(
        bev_array(a), bev_array(b), rows, cols, with_enclosure=with_enclosure
    )
    if enclosure is None or distance is None:
        return _scatter(iou, rows, cols, shape, np.nan), None, None
    return (
        _scatter(iou, rows, cols, shape, np.nan),
        _scatter(enclosure, rows, cols, shape, np.nan),
        _scatter(distance, rows, cols, shape, np.nan),
    )


def _bev_pair_terms(
    bev_a: FloatArray, bev_b: FloatArray, rows: IntArray, cols: IntArray, *, with_enclosure: bool
) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """IoU, and optionally (C - U)/C and c²/d², of the pairs (rows[p], cols[p]) of (M, 5) and
    (N, 5) BEV boxes [x, y, l, w, yaw], each (P,).

    The single code path behind every BEV similarity: all terms are computed on the flat list
    of requested pairs, and the intersection only on pairs whose circumscribed circles overlap.
    A pair with a non-finite position, size or heading gets NaN in every term.
    """
    inter, enclosing_area, diag_sq, centre_dist_sq = bev_pair_geometry(
        bev_a, bev_b, rows, cols, with_enclosing=with_enclosure
    )
    # U = l_a·w_a + l_b·w_b - I (areas from the dimensions, as the reference)
    area_a, area_b = bev_a[:, 2] * bev_a[:, 3], bev_b[:, 2] * bev_b[:, 3]
    union = area_a[rows] + area_b[cols] - inter
    # Degenerate boxes: no union, an empty enclosure or a zero diagonal give 0, not a division.
    iou = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
    # A box with a non-finite position, size or heading is missing: every term is NaN.
    missing = np.isnan(inter)
    any_missing = missing.any()
    if any_missing:
        iou[missing] = np.nan
    if not with_enclosure:
        return iou, None, None
    # IoU − w1 (C − U)/C − w2 c²/d²
    enclosure = np.divide(
        enclosing_area - union,
        enclosing_area,
        out=np.zeros_like(inter),
        where=enclosing_area > 0,
    )
    distance = np.divide(centre_dist_sq, diag_sq, out=np.zeros_like(inter), where=diag_sq > 0)
    if any_missing:
        enclosure[missing] = np.nan
        distance[missing] = np.nan
    return iou, enclosure, distance


def bev_array(boxes: Boxes) -> FloatArray:
    """(N, 5) BEV boxes [x, y, l, w, yaw] (the layout of :func:`ro_gdiou_bev_arrays`)."""
    return np.concatenate((boxes.xyz[:, :2], boxes.lwh[:, :2], boxes.yaw[:, None]), axis=1)


def ro_gdiou_terms_bev(a: Boxes, b: Boxes, *, mask: ArrayLike | None = None) -> RoGdiouTerms:
    """The Ro_GDIoU terms of every pair, for debugging views and for :func:`ro_gdiou_bev`.

    Parameters
    ----------
    a : Boxes
        M boxes (rows), usually predicted tracks.
    b : Boxes
        N boxes (columns), usually detections.
    mask : (M, N) bool, optional
        Pairs to compute; the others are NaN in every term.

    Returns
    -------
    RoGdiouTerms with (M, N) ``iou``, ``enclosure`` (C - U)/C and ``distance`` c²/d².
    """
    iou, enclosure, distance = _bev_terms(a, b, mask, with_enclosure=True)
    assert enclosure is not None and distance is not None
    return RoGdiouTerms(iou=iou, enclosure=enclosure, distance=distance)


def ro_gdiou_bev(
    a: Boxes, b: Boxes, *, w1: ArrayLike, w2: ArrayLike, mask: ArrayLike | None = None
) -> FloatArray:
    """Ro_GDIoU = IoU - w1 · (C - U)/C - w2 · c²/d² in bird's-eye view (MCTrack Alg. 1).

    C is the minimum-area rotated rectangle enclosing both boxes' BEV corners, d its diagonal,
    c the distance between the BEV centres, U the union area. Heading only enters through the
    geometry: a box flipped by 180° scores 1.

    Parameters
    ----------
    a : Boxes
        M boxes (rows), usually predicted tracks.
    b : Boxes
        N boxes (columns), usually detections.
    w1, w2 : float or (M,) array
        Weights of the enclosure and distance terms; arrays give one weight per row (the
        reference takes them from the track's category).
    mask : (M, N) bool, optional
        Pairs to compute; the others get -inf.

    Returns
    -------
    (M, N) similarity in (-(w1 + w2), 1]; -inf outside ``mask`` or for boxes with NaN fields.
    """
    return ro_gdiou_bev_arrays(bev_array(a), bev_array(b), w1=w1, w2=w2, mask=mask)


def ro_gdiou_bev_arrays(
    bev_a: FloatArray,
    bev_b: FloatArray,
    *,
    w1: ArrayLike,
    w2: ArrayLike,
    mask: ArrayLike | None = None,
) -> FloatArray:
    """:func:`ro_gdiou_bev` of BEV boxes given as arrays (the tracker's predictions are rows of
    its filter state, so it skips building a :class:`~tracker.boxes.Boxes` for them).

    Parameters
    ----------
    bev_a : (M, 5), bev_b : (N, 5)
        BEV boxes [x, y, l, w, yaw], metres and radians.
    w1, w2, mask : as :func:`ro_gdiou_bev`.

    Returns
    -------
    (M, N) similarity, as :func:`ro_gdiou_bev`.
    """
    shape = (len(bev_a), len(bev_b))
    rows, cols = _pairs(*shape, mask)
    if len(rows) == 0:
        return np.full(shape, -np.inf)
    iou, enclosure, distance = _bev_pair_terms(bev_a, bev_b, rows, cols, with_enclosure=True)
    assert enclosure is not None and distance is not None
    w1_rows, w2_rows = _per_row(w1, shape[0]), _per_row(w2, shape[0])
    # per pair, then scattered once: the values of ro_gdiou_terms_bev(...).combine(...) (a
    # weight that is 0 on every paired row subtracts 0 · finite term there, so skipping is exact)
    similarity = _combine(iou, enclosure, distance, w1_rows[rows], w2_rows[rows])
    return _scatter(_finite_or_neg_inf(similarity), rows, cols, shape, -np.inf)


def giou_bev(a: Boxes, b: Boxes, *, mask: ArrayLike | None = None) -> FloatArray:
    """(M, N) rotated GIoU = IoU - (C - U)/C: :func:`ro_gdiou_bev` with w1 = 1, w2 = 0."""
    return ro_gdiou_bev(a, b, w1=1.0, w2=0.0, mask=mask)


def diou_bev(a: Boxes, b: Boxes, *, mask: ArrayLike | None = None) -> FloatArray:
    """(M, N) rotated DIoU = IoU - c²/d²: :func:`ro_gdiou_bev` with w1 = 0, w2 = 1."""
    return ro_gdiou_bev(a, b, w1=0.0, w2=1.0, mask=mask)


def iou_bev(a: Boxes, b: Boxes, *, mask: ArrayLike | None = None) -> FloatArray:
    """(M, N) rotated BEV IoU, I / (l_a·w_a + l_b·w_b - I); -inf outside ``mask`` or NaN boxes.

    Used by NMS as well as matching; skips the enclosing rectangle entirely.
    """
    iou, _, _ = _bev_terms(a, b, mask, with_enclosure=False)
    return _finite_or_neg_inf(iou)


def iou_xyxy(xyxy_a: ArrayLike, xyxy_b: ArrayLike) -> FloatArray:
    """Plain IoU of 2D boxes ``(..., 4)`` (x1, y1, x2, y2; positive areas) broadcast against
    each other: ``a[:, None], b[None]`` gives the matrix, equal shapes the pairs."""
    a, b = np.asarray(xyxy_a, dtype=np.float64), np.asarray(xyxy_b, dtype=np.float64)
    w = np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0])
    h = np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1])
    inter = np.clip(w, 0.0, None) * np.clip(h, 0.0, None)
    area_a = (a[..., 2] - a[..., 0]) * (a[..., 3] - a[..., 1])
    area_b = (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])
    return inter / (area_a + area_b - inter)


def sdiou_image(xyxy_a: ArrayLike, xyxy_b: ArrayLike) -> FloatArray:
    """(M, N) SDIoU between 2D image boxes, exactly as the reference ``cal_sdiou_inrv``.

    SDIoU = IoU + area_ratio · (1 - |centre_a - centre_b| / enclosing_diagonal) · aspect_ratio,
    in [0, 2]. IoU and the area ratio use KITTI-style inclusive pixel areas (+1); the distance
    and aspect terms do not. It is 0 where the union, the enclosing diagonal or the area ratio is
    0 (as the reference). A zero-height (or zero-width) box gets an aspect term of 0, where the
    reference divides by zero.

    Parameters
    ----------
    xyxy_a : (M, 4) track boxes (x1, y1, x2, y2), pixels.
    xyxy_b : (N, 4) detection boxes, pixels.

    Returns
    -------
    (M, N) similarity; -inf where either box has a NaN coordinate (no box in this camera).
    """
    a = np.asarray(xyxy_a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(xyxy_b, dtype=np.float64).reshape(-1, 4)
    return _sdiou(a[:, None, :], b[None, :, :])


def sdiou_pairs(xyxy_a: ArrayLike, xyxy_b: ArrayLike) -> FloatArray:
    """(P,) SDIoU of the pairs ``(xyxy_a[k], xyxy_b[k])``: the cells of :func:`sdiou_image`
    (the same arithmetic, element by element) without the rest of the matrix."""
    a = np.asarray(xyxy_a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(xyxy_b, dtype=np.float64).reshape(-1, 4)
    return _sdiou(a, b)


def _sdiou(a: FloatArray, b: FloatArray) -> FloatArray:
    """SDIoU of boxes ``a[..., :4]`` and ``b[..., :4]`` broadcast against each other."""
    ax1, ay1, ax2, ay2 = (a[..., k] for k in range(4))
    bx1, by1, bx2, by2 = (b[..., k] for k in range(4))

    inter_w = np.maximum(0.0, np.minimum(ax2, bx2) - np.maximum(ax1, bx1) + 1.0)
    inter_h = np.maximum(0.0, np.minimum(ay2, by2) - np.maximum(ay1, by1) + 1.0)
    inter = inter_w * inter_h
    area_a = (ax2 - ax1 + 1.0) * (ay2 - ay1 + 1.0)
    area_b = (bx2 - bx1 + 1.0) * (by2 - by1 + 1.0)
    union = area_a + area_b - inter
    enclosing_w = np.maximum(ax2, bx2) - np.minimum(ax1, bx1)
    enclosing_h = np.maximum(ay2, by2) - np.minimum(ay1, by1)
    enclosing_diag = np.hypot(enclosing_w, enclosing_h)
    centre_dist = 0.5 * np.hypot((bx1 + bx2) - (ax1 + ax2), (by1 + by2) - (ay1 + ay2))
    with np.errstate(divide="ignore", invalid="ignore"):
        # The reference's "x / y if y > x else y / x" (min / max for positive values).
        area_ratio = np.where(area_b > area_a, area_a / area_b, area_b / area_a)
        aspect_a = (ax2 - ax1) / (ay2 - ay1)
        aspect_b = (bx2 - bx1) / (by2 - by1)
        aspect = np.where(aspect_b > aspect_a, aspect_a / aspect_b, aspect_b / aspect_a)
        degenerate = (union == 0) | (enclosing_diag == 0) | ~(area_ratio != 0)  # NaN ratio too
        aspect = np.where(np.isfinite(aspect), aspect, 0.0)
        sdiou = inter / union + area_ratio * (1.0 - centre_dist / enclosing_diag) * aspect
    sdiou = np.where(degenerate, 0.0, sdiou)
    missing = np.isnan(a).any(axis=-1) | np.isnan(b).any(axis=-1)
    return np.where(missing, -np.inf, sdiou)


def back_predict(dets: Boxes, dt_secs: float) -> Boxes:
    """Detections moved back in time by their velocity: xy - v·dt (the BackPredict cost state).

    The reference hard-codes dt_secs = 0.5 (nuScenes' sample interval) for every dataset. An
    unknown velocity (NaN) moves nothing, as when it was read as 0.
    """
    xyz = dets.xyz.copy()
    xyz[:, :2] -= np.nan_to_num(dets.velocity) * dt_secs
    return dets.replace(xyz=xyz)


__all__ = [
    "RoGdiouTerms",
    "back_predict",
    "bev_array",
    "diou_bev",
    "giou_bev",
    "iou_bev",
    "ro_gdiou_bev",
    "ro_gdiou_bev_arrays",
    "ro_gdiou_terms_bev",
    "sdiou_image",
    "sdiou_pairs",
]
