"""Compiled (numba) kernel for the pairwise BEV rectangle geometry behind the BEV costs.

Why numba: the tracker's matching problems are tiny (KITTI: ~8 tracks × ~8 detections, ~20
pairs inside the gate), so the vectorised numpy geometry in :mod:`tracker.geometry` spends its
time in ~200 numpy calls per frame rather than in arithmetic. One compiled loop over the pair
list does the same work in microseconds. Compiled rotated-box kernels are the field's standard
for this (OpenPCDet / second.pytorch's KITTI evaluation use numba for rotated IoU; the reference
MCTrack lists it as a dependency).

The kernel ports :func:`tracker.geometry.intersection_area_bev` and
:func:`tracker.geometry.min_area_rect_bev` operation by operation (same candidates, tolerances,
degenerate-box rules and 10 enclosing directions), so they agree to float64 rounding; the numpy
functions stay the reference and the fallback (``tests/test_kernels_geometry.py`` compares them).
Import this module only through :func:`tracker.geometry.bev_pair_geometry`, which falls back to
numpy when numba is missing.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from tracker.boxes import FloatArray, IntArray

#: Must equal tracker.geometry._BOUNDARY_RTOL (checked by the tests).
BOUNDARY_RTOL = 1e-12

_SIGN_L = (1.0, -1.0, -1.0, 1.0)
_SIGN_W = (1.0, 1.0, -1.0, -1.0)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _intersection(a: FloatArray, b: FloatArray, work: FloatArray) -> float:  # pragma: no cover
    """Intersection area of rectangles a, b (4, 2), both relative to A's centre.

    ``work`` (10, 24) is scratch space (no allocation per pair).
    """
    # A's frame: unit axis (ux, uy), half length la, half width wa
    hx, hy = 0.5 * (a[0, 0] - a[1, 0]), 0.5 * (a[0, 1] - a[1, 1])
    la = math.hypot(hx, hy)
    wa = 0.5 * math.hypot(a[0, 0] - a[3, 0], a[0, 1] - a[3, 1])
    if la > 0:
        ux, uy = hx / la, hy / la
    else:
        ux, uy = 1.0, hy / 1.0
    bx, by, ax, ay = work[0, :4], work[1, :4], work[2, :4], work[3, :4]
    px, py, valid = work[4], work[5], work[6]  # valid: 1.0 / 0.0
    xs, ys, angle = work[7], work[8], work[9]
    for k in range(4):  # B's corners in A's frame
        bx[k] = ux * b[k, 0] + uy * b[k, 1]
        by[k] = ux * b[k, 1] - uy * b[k, 0]
    ex0, ey0 = b[0, 0] - b[1, 0], b[0, 1] - b[1, 1]
    vx, vy = ux * ex0 + uy * ey0, ux * ey0 - uy * ex0  # B's axis in A's frame, length 2 lb
    lb = 0.5 * math.hypot(vx, vy)
    wb = 0.5 * math.hypot(b[0, 0] - b[3, 0], b[0, 1] - b[3, 1])
    if lb > 0:
        vx, vy = vx / (2.0 * lb), vy / (2.0 * lb)
    else:
        vx, vy = 1.0, vy / 1.0
    centre_x, centre_y = 0.5 * (bx[0] + bx[2]), 0.5 * (by[0] + by[2])
    for k in range(4):  # A's corners in B's frame (relative to B's centre)
        rel_x, rel_y = _SIGN_L[k] * la - centre_x, _SIGN_W[k] * wa - centre_y
        ax[k] = vx * rel_x + vy * rel_y
        ay[k] = vx * rel_y - vy * rel_x
    # separating axes: strictly apart means no overlap
    if (
        max(bx[0], bx[1], bx[2], bx[3]) < -la or min(bx[0], bx[1], bx[2], bx[3]) > la
        or max(by[0], by[1], by[2], by[3]) < -wa or min(by[0], by[1], by[2], by[3]) > wa
        or max(ax[0], ax[1], ax[2], ax[3]) < -lb or min(ax[0], ax[1], ax[2], ax[3]) > lb
        or max(ay[0], ay[1], ay[2], ay[3]) < -wb or min(ay[0], ay[1], ay[2], ay[3]) > wb
        or la * wa * lb * wb == 0
    ):  # fmt: skip
        return 0.0
    tol = BOUNDARY_RTOL * (la + wa + lb + wb + abs(centre_x) + abs(centre_y))
    # candidates, in the numpy order: B's corners in A, A's corners in B, B's edges crossing
    # A's sides x = ±la, then y = ±wa
    for k in range(4):
        px[k], py[k] = bx[k], by[k]
        valid[k] = abs(bx[k]) <= la + tol and abs(by[k]) <= wa + tol
        px[4 + k], py[4 + k] = _SIGN_L[k] * la, _SIGN_W[k] * wa
        valid[4 + k] = abs(ax[k]) <= lb + tol and abs(ay[k]) <= wb + tol
    for s in range(2):
        side_l = la if s == 0 else -la
        side_w = wa if s == 0 else -wa
        for k in range(4):
            nxt = (k + 1) & 3
            ex, ey = bx[nxt] - bx[k], by[nxt] - by[k]
            t = (side_l - bx[k]) / ex
            ok = t >= -BOUNDARY_RTOL and t <= 1.0 + BOUNDARY_RTOL  # False for NaN
            y = by[k] + min(max(t if ok else 0.0, 0.0), 1.0) * ey
            px[8 + 4 * s + k], py[8 + 4 * s + k] = side_l, y
            valid[8 + 4 * s + k] = ok and abs(y) <= wa + tol
            t = (side_w - by[k]) / ey
            ok = t >= -BOUNDARY_RTOL and t <= 1.0 + BOUNDARY_RTOL
            x = bx[k] + min(max(t if ok else 0.0, 0.0), 1.0) * ex
            px[16 + 4 * s + k], py[16 + 4 * s + k] = x, side_w
            valid[16 + 4 * s + k] = ok and abs(x) <= la + tol
    count = 0
    for i in range(24):
        count += valid[i] != 0
    if count < 3:
        return 0.0
    # all candidates lie on the convex intersection's boundary: sort by angle about their
    # centroid, then the shoelace formula
    weight = 1.0 / count
    cx, cy = 0.0, 0.0
    for i in range(24):
        if valid[i]:
            cx += px[i] * weight
            cy += py[i] * weight
    n = 0
    for i in range(24):
        if valid[i]:
            xs[n], ys[n] = px[i] - cx, py[i] - cy
            angle[n] = _pseudo_angle(xs[n], ys[n])
            n += 1
    for i in range(1, count):  # insertion sort by angle (count <= 24)
        key_a, key_x, key_y = angle[i], xs[i], ys[i]
        j = i - 1
        while j >= 0 and angle[j] > key_a:
            angle[j + 1], xs[j + 1], ys[j + 1] = angle[j], xs[j], ys[j]
            j -= 1
        angle[j + 1], xs[j + 1], ys[j + 1] = key_a, key_x, key_y
    twice_area = 0.0
    for i in range(count):
        j = i + 1 if i + 1 < count else 0
        twice_area += xs[i] * ys[j] - xs[j] * ys[i]
    inter = max(0.5 * twice_area, 0.0)
    return min(inter, 4.0 * min(la * wa, lb * wb))


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _pseudo_angle(dx: float, dy: float) -> float:  # pragma: no cover (compiled)
    """A strictly increasing function of atan2(dy, dx) on (-pi, pi], in (-2, 2]: sorting by
    it orders points as the numpy code's atan2 does, without the transcendental call."""
    d = abs(dx) + abs(dy)
    if d == 0:
        return 0.0
    return 1.0 - dx / d if dy >= 0 else dx / d - 1.0


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _half_axes(hx: float, hy: float, gx: float, gy: float) -> tuple:  # pragma: no cover
    """Longer half-axis vector, its length and the shorter/longer ratio."""
    len_h, len_g = math.hypot(hx, hy), math.hypot(gx, gy)
    half_long, half_short = max(len_h, len_g), min(len_h, len_g)
    ratio = half_short / (half_long if half_long > 0 else 1.0)
    if len_h >= len_g:
        return hx, hy, half_long, ratio
    return gx, gy, half_long, ratio


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _min_area_rect(a: FloatArray, b: FloatArray) -> tuple:  # pragma: no cover (compiled)
    """Enclosing-rectangle area and squared diagonal of a, b (4, 2) relative to A's centre."""
    hax, hay = 0.5 * (a[0, 0] - a[1, 0]), 0.5 * (a[0, 1] - a[1, 1])
    hbx0, hby0 = 0.5 * (b[0, 0] - b[1, 0]), 0.5 * (b[0, 1] - b[1, 1])
    dot = hax * hbx0 + hay * hby0
    crs = hax * hby0 - hay * hbx0
    if crs > 0 or (crs == 0 and dot >= 0):
        quadrant = 0 if dot > 0 else 1
    else:
        quadrant = 2 if dot < 0 else 3
    long_ax, long_ay, la, ka = _half_axes(
        hax, hay, 0.5 * (a[0, 0] - a[3, 0]), 0.5 * (a[0, 1] - a[3, 1])
    )
    if la > 0:
        ux, uy = long_ax / la, long_ay / la
    else:
        ux, uy = 1.0, long_ay / 1.0
    wa = ka * la
    long_bx, long_by, _, kb = _half_axes(
        hbx0, hby0, 0.5 * (b[0, 0] - b[3, 0]), 0.5 * (b[0, 1] - b[3, 1])
    )
    hbx, hby = ux * long_bx + uy * long_by, ux * long_by - uy * long_bx
    cbx, cby = 0.5 * (b[0, 0] + b[2, 0]), 0.5 * (b[0, 1] + b[2, 1])
    dx, dy = ux * cbx + uy * cby, ux * cby - uy * cbx
    best_area, best_u, best_n, best_norm = np.inf, 0.0, 0.0, 1.0
    for cand in range(10):  # A's axis, B's axis, then the 8 bridges b_j - a_i
        if cand == 0:
            ex, ey = 1.0, 0.0
        elif cand == 1:
            ex, ey = hbx, hby
        else:
            j = (cand - 2) >> 1
            i = (j + quadrant + ((cand - 2) & 1)) & 3
            bridge_x, bridge_y = b[j, 0] - a[i, 0], b[j, 1] - a[i, 1]
            ex, ey = ux * bridge_x + uy * bridge_y, ux * bridge_y - uy * bridge_x
        abs_ex, abs_ey = abs(ex), abs(ey)
        a_u, a_n = la * abs_ex + wa * abs_ey, la * abs_ey + wa * abs_ex
        along = abs(hbx * ex + hby * ey)
        across = abs(hbx * ey - hby * ex)
        b_u, b_n = along + kb * across, across + kb * along
        off_u, off_n = dx * ex + dy * ey, dx * ey - dy * ex
        ext_u = max(a_u, off_u + b_u) + max(a_u, b_u - off_u)
        ext_n = max(a_n, off_n + b_n) + max(a_n, b_n - off_n)
        norm_sq = ex * ex + ey * ey
        area = ext_u * ext_n / norm_sq if norm_sq > 0 else np.inf
        if area < best_area:
            best_area, best_u, best_n, best_norm = area, ext_u, ext_n, norm_sq
    return best_u * best_n / best_norm, (best_u**2 + best_n**2) / best_norm


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _corners(boxes: FloatArray) -> FloatArray:  # pragma: no cover (compiled)
    """(N, 4, 2) corners of (N, 5) [x, y, l, w, yaw] boxes (as tracker.geometry.corners_bev)."""
    n = boxes.shape[0]
    out = np.empty((n, 4, 2))
    for i in range(n):
        half_l, half_w = boxes[i, 2] / 2.0, boxes[i, 3] / 2.0
        c, s = math.cos(boxes[i, 4]), math.sin(boxes[i, 4])
        for k in range(4):
            local_x, local_y = half_l * _SIGN_L[k], half_w * _SIGN_W[k]
            out[i, k, 0] = local_x * c - local_y * s + boxes[i, 0]
            out[i, k, 1] = local_x * s + local_y * c + boxes[i, 1]
    return out


@numba.njit(cache=True, error_model="numpy", nogil=True)
def bev_pair_geometry_kernel(
    boxes_a: FloatArray,
    boxes_b: FloatArray,
    rows: IntArray,
    cols: IntArray,
    with_enclosing: bool,
) -> tuple:  # pragma: no cover (compiled)
    """See :func:`tracker.geometry.bev_pair_geometry` (same contract, compiled)."""
    n_pairs = len(rows)
    inter = np.zeros(n_pairs)
    enclosing = np.full(n_pairs, np.nan)
    diag_sq = np.full(n_pairs, np.nan)
    centre_dist_sq = np.empty(n_pairs)
    corners_a, corners_b = _corners(boxes_a), _corners(boxes_b)
    a = np.empty((4, 2))
    b = np.empty((4, 2))
    work = np.empty((10, 24))
    for p in range(n_pairs):
        box_a, box_b = boxes_a[rows[p]], boxes_b[cols[p]]
        finite = True
        for j in range(5):
            finite = finite and math.isfinite(box_a[j]) and math.isfinite(box_b[j])
        if not finite:  # a missing box: every output is NaN
            inter[p] = centre_dist_sq[p] = np.nan
            continue
        dx, dy = box_b[0] - box_a[0], box_b[1] - box_a[1]
        centre_dist_sq[p] = dx * dx + dy * dy
        ca, cb = corners_a[rows[p]], corners_b[cols[p]]
        # relative to A's centre: full float64 precision far from the origin
        ox, oy = 0.5 * (ca[0, 0] + ca[2, 0]), 0.5 * (ca[0, 1] + ca[2, 1])
        for k in range(4):
            a[k, 0], a[k, 1] = ca[k, 0] - ox, ca[k, 1] - oy
            b[k, 0], b[k, 1] = cb[k, 0] - ox, cb[k, 1] - oy
        # beyond the sum of half-diagonals the boxes cannot overlap: I = 0 exactly
        reach = 0.5 * math.hypot(box_a[2], box_a[3]) + 0.5 * math.hypot(box_b[2], box_b[3])
        if centre_dist_sq[p] < reach**2:
            inter[p] = _intersection(a, b, work)
        if with_enclosing:
            enclosing[p], diag_sq[p] = _min_area_rect(a, b)
    return inter, enclosing, diag_sq, centre_dist_sq
