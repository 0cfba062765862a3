"""Compiled stage-1 cost: the gated (T, D) 1 − Ro_GDIoU matrix of ``MCTracker._bev_cost``
(numpy reference: :func:`tracker.cost.ro_gdiou_bev_arrays`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from tracker.boxes import FloatArray, IntArray
from tracker.kernels._common import _F1, _F2, _I1
from tracker.kernels.geometry import _corners, _intersection, _min_area_rect


@numba.njit(
    (_F2, _I1, _F2, _I1, _F1, _F1, _F1),
    cache=True,
    error_model="numpy",
    nogil=True,
)
def bev_cost_kernel(
    track_bev: FloatArray,
    track_category: IntArray,
    det_bev: FloatArray,
    det_category: IntArray,
    gate_sq: FloatArray,
    w1: FloatArray,
    w2: FloatArray,
) -> tuple:  # pragma: no cover (compiled)
    """Stage 1's (T, D) cost 1 − Ro_GDIoU and the (T, D) mask of the pairs scored.

    A pair is scored when track and detection share a category and their centres are closer
    than the track category's gate (``gate_sq``, squared metres, per category); every other
    pair, and a pair with a non-finite similarity, costs +inf. Weights ``w1``, ``w2`` are per
    category. The numpy path is ``MCTracker._bev_cost`` (forward cost state) with
    :func:`tracker.cost.ro_gdiou_bev_arrays`.
    """
    n_tracks, n_dets = track_bev.shape[0], det_bev.shape[0]
    cost = np.full((n_tracks, n_dets), np.inf)
    mask = np.zeros((n_tracks, n_dets), dtype=np.bool_)
    corners_a, corners_b = _corners(track_bev), _corners(det_bev)
    a = np.empty((4, 2))
    b = np.empty((4, 2))
    work = np.empty((10, 24))
    for t in range(n_tracks):
        c = track_category[t]
        box_a = track_bev[t]
        for d in range(n_dets):
            if det_category[d] != c:
                continue
            box_b = det_bev[d]
            dx, dy = box_a[0] - box_b[0], box_a[1] - box_b[1]
            if not dx * dx + dy * dy < gate_sq[c]:  # (NaN: not scored)
                continue
            mask[t, d] = True
            finite = True
            for j in range(5):
                finite = finite and math.isfinite(box_a[j]) and math.isfinite(box_b[j])
            if not finite:
                continue  # a missing box: NaN similarity, +inf cost
            centre_dist_sq = dx * dx + dy * dy
            ca, cb = corners_a[t], corners_b[d]
            ox, oy = 0.5 * (ca[0, 0] + ca[2, 0]), 0.5 * (ca[0, 1] + ca[2, 1])
            for k in range(4):
                a[k, 0], a[k, 1] = ca[k, 0] - ox, ca[k, 1] - oy
                b[k, 0], b[k, 1] = cb[k, 0] - ox, cb[k, 1] - oy
            inter = 0.0
            reach = 0.5 * math.hypot(box_a[2], box_a[3]) + 0.5 * math.hypot(box_b[2], box_b[3])
            if centre_dist_sq < reach**2:
                inter = _intersection(a, b, work)
            enclosing, diag_sq = _min_area_rect(a, b)
            # U = l_a·w_a + l_b·w_b − I; degenerate terms are 0 (tracker.cost._bev_pair_terms)
            union = box_a[2] * box_a[3] + box_b[2] * box_b[3] - inter
            iou = inter / union if union > 0 else 0.0
            similarity = iou
            if w1[c] != 0:
                enclosure = (enclosing - union) / enclosing if enclosing > 0 else 0.0
                similarity -= w1[c] * enclosure
            if w2[c] != 0:
                distance = centre_dist_sq / diag_sq if diag_sq > 0 else 0.0
                similarity -= w2[c] * distance
            if math.isfinite(similarity):
                cost[t, d] = 1.0 - similarity
    return cost, mask
