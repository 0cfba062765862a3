"""Compiled (numba) kernels for MCTracker's per-frame stages: predict, BEV cost, update.

Why: a KITTI frame holds ~10 tracks and ~10 detections, so the numpy stages of
:mod:`tracker.mctracker` spend their time in ~300 numpy calls per frame (a microsecond each)
rather than in arithmetic. Each kernel below replaces one stage's numpy calls with one loop over
the rows, performing the same operations in the same order; the numpy code stays the reference,
the fallback (no numba, or ``MCTRACK_NUMBA=0``) and the test oracle
(``tests/test_mctracker_numba.py`` compares them on random inputs, and on whole KITTI scenes).

The public kernels carry explicit signatures (any memory layout), so they are compiled, or
loaded from numba's on-disk cache, when this module is imported, never inside a frame. Import it
only through :func:`tracker.mctracker.frame_kernels`, which falls back to numpy when numba is
missing.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from tracker.boxes import FloatArray, IntArray
from tracker.events import TrackStatus
from tracker.geometry_numba import _corners, _intersection, _min_area_rect

# state layout of tracker.kalman's fast path: axes x, y, l, w, θ of [value, rate(, acc)]
_X, _Y, _YAW = 0, 1, 4
_N_AXES = 5
_PI = math.pi
_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi

# Kernel signatures: inputs are read-only arrays of any layout (numba accepts writable and
# strided arrays for them too), outputs updated in place are writable.
_f8, _i8 = numba.float64, numba.int64
_F1, _F2, _F3, _F4 = (numba.types.Array(_f8, n, "A", readonly=True) for n in (1, 2, 3, 4))
_I1 = numba.types.Array(_i8, 1, "A", readonly=True)
_F3_OUT, _F4_OUT = numba.types.Array(_f8, 3, "A"), numba.types.Array(_f8, 4, "A")
_I1_OUT = numba.types.Array(_i8, 1, "A")
_S1 = numba.types.Array(numba.int8, 1, "A", readonly=True)
_B1 = numba.types.Array(numba.boolean, 1, "A", readonly=True)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _wrap(a: float) -> float:  # pragma: no cover (compiled)
    """tracker.geometry.wrap_angle of one value: (-pi, pi], in-range values bit-for-bit."""
    if abs(a) < _PI or not (a > _PI or a <= -_PI):  # in range (or NaN): unchanged
        return a
    wrapped = (a + _PI) % _TWO_PI - _PI  # Python's float % takes the divisor's sign, as np.mod
    return wrapped + _TWO_PI if wrapped <= -_PI else wrapped


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _align(measured: float, predicted: float) -> float:  # pragma: no cover (compiled)
    """tracker.kalman.align_heading of one value."""
    if abs(_wrap(measured - predicted)) > _HALF_PI:
        return _wrap(measured + _PI)
    return _wrap(measured)


# ---------------------------------------------------------------------------------------------
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


# ---------------------------------------------------------------------------------------------
@numba.njit(
    (_F3, _F4, _I1, _F3, _f8, _f8),
    cache=True,
    error_model="numpy",
    nogil=True,
)
def motion_predict_kernel(
    x: FloatArray, P: FloatArray, category: IntArray, q: FloatArray, dt: float, tau: float
) -> tuple:  # pragma: no cover (compiled)
    """Every track's per-axis filters advanced by ``dt``: x = F x, P = F P Fᵀ + diag(q)·tau.

    x (T, 5, k), P (T, 5, k, k), q (C, 5, k) per category; F = [[1, dt(, dt²/2)], [0, 1(, dt)]
    (, [0, 0, 1])]. The yaw value is wrapped. Returns new arrays (numpy path:
    :func:`tracker.kalman.motion_predict`).
    """
    n, k = x.shape[0], x.shape[2]
    F = np.eye(k)
    for i in range(k - 1):
        F[i, i + 1] = dt
    if k == 3:
        F[0, 2] = 0.5 * dt * dt
    x_new = np.empty_like(x)
    P_new = np.empty_like(P)
    fp = np.empty((k, k))
    for t in range(n):
        c = category[t]
        for ax in range(_N_AXES):
            xa, pa = x[t, ax], P[t, ax]
            for i in range(k):
                s = 0.0
                for j in range(i, k):  # F is upper triangular
                    s += F[i, j] * xa[j]
                x_new[t, ax, i] = s
                for j in range(k):
                    s = 0.0
                    for m in range(i, k):
                        s += F[i, m] * pa[m, j]
                    fp[i, j] = s
            for i in range(k):  # (F P) Fᵀ, upper triangle mirrored: exactly symmetric
                for j in range(i, k):
                    s = 0.0
                    for m in range(j, k):
                        s += fp[i, m] * F[j, m]
                    if i == j:
                        s += q[c, ax, i] * tau
                    P_new[t, ax, i, j] = s
                    P_new[t, ax, j, i] = s
        x_new[t, _YAW, 0] = _wrap(x_new[t, _YAW, 0])
    return x_new, P_new


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _value_update(
    x: FloatArray, P: FloatArray, y: float, r: float, gain: FloatArray, new_p: FloatArray
) -> None:  # pragma: no cover (compiled)
    """In place: one axis [value, rate(, acc)] updated with its measured value, H = [1, 0(, 0)],
    innovation ``y``, variance ``r``; Joseph form, symmetrised (tracker.kalman._value_update)."""
    k = x.shape[0]
    s = P[0, 0] + r  # S = H P Hᵀ + R
    for j in range(k):
        gain[j] = P[0, j] / s  # K = P Hᵀ S⁻¹
    for j in range(k):
        x[j] = x[j] + gain[j] * y  # x = x + K y
    # P = (I − K H) P (I − K H)ᵀ + K R Kᵀ, from rank-one terms: A P = P − K P₀ (P₀ = H P), then
    # − (A P)[:, 0] Kᵀ, + r K Kᵀ
    for j in range(k):
        for m in range(k):
            new_p[j, m] = P[j, m] - gain[j] * P[0, m]
    for j in range(k):
        first = new_p[j, 0]
        for m in range(k):
            new_p[j, m] = new_p[j, m] - first * gain[m] + (r * gain[j]) * gain[m]
    for j in range(k):
        for m in range(k):
            P[j, m] = 0.5 * (new_p[j, m] + new_p[m, j])


@numba.njit(
    (_F3_OUT, _F4_OUT, _I1_OUT, _I1, _I1, _F2, _F2, _F1, _F3, _F1, _i8),
    cache=True,
    error_model="numpy",
    nogil=True,
)
def motion_update_kernel(
    x: FloatArray,
    P: FloatArray,
    votes: IntArray,
    rows: IntArray,
    category: IntArray,
    xy: FloatArray,
    lw: FloatArray,
    det_yaw: FloatArray,
    r: FloatArray,
    head_min_speed: FloatArray,
    flip_votes: int,
) -> None:  # pragma: no cover (compiled)
    """In place: tracks ``rows`` of x (T, 5, k), P (T, 5, k, k) updated with their detections'
    centre ``xy``, size ``lw`` and yaw, and the heading sign logic of ``MCTracker._update``.

    Per row: the detection's yaw is aligned to the predicted θ (mod pi) and every axis is
    updated with its value. If the object then clearly moves (speed above its category's
    threshold and 3 sigma) θ follows the direction of travel; if it does not move and
    ``flip_votes`` consecutive detections disagreed with θ by more than 90°, θ flips. In both
    cases the heading axis is redone from its prediction with θ_det aligned to the new θ, fused
    with θ_vel = atan2(vy, vx) when moving. ``votes`` (T,) counts the consecutive
    disagreements. ``r`` (C, 5, 2) variances of [value, second measurement] per category.
    No velocity measurement (the numpy path handles that).
    """
    k = x.shape[2]
    gain = np.empty(k)
    new_p = np.empty((k, k))
    yaw_x = np.empty(k)
    yaw_p = np.empty((k, k))
    for j in range(rows.shape[0]):
        t, c = rows[j], category[j]
        heading = x[t, _YAW, 0]  # predicted θ
        for i in range(k):
            yaw_x[i] = x[t, _YAW, i]
            for m in range(k):
                yaw_p[i, m] = P[t, _YAW, i, m]
        disagree = abs(_wrap(det_yaw[j] - heading)) > _HALF_PI
        yaw_det = _wrap(det_yaw[j] + _PI if disagree else det_yaw[j])
        z0 = xy[j, 0]
        for ax in range(_N_AXES):
            if ax == 0:
                z0 = xy[j, 0]
            elif ax == 1:
                z0 = xy[j, 1]
            elif ax == 2:
                z0 = lw[j, 0]
            elif ax == 3:
                z0 = lw[j, 1]
            else:
                z0 = yaw_det
            y = z0 - x[t, ax, 0]
            if ax == _YAW:
                y = _wrap(y)
            _value_update(x[t, ax], P[t, ax], y, r[c, ax, 0], gain, new_p)
        x[t, _YAW, 0] = _wrap(x[t, _YAW, 0])
        vx, vy = x[t, _X, 1], x[t, _Y, 1]
        speed = math.hypot(vx, vy)
        speed_sigma = math.sqrt(P[t, _X, 1, 1] + P[t, _Y, 1, 1])
        moving = speed > max(head_min_speed[c], 3.0 * speed_sigma)
        count = votes[t] + 1 if disagree else 0
        flip = not moving and count >= flip_votes
        if moving or flip:
            yaw_vel = math.atan2(vy, vx)
            if moving:
                heading = _align(heading, yaw_vel)
            if flip:
                heading = _wrap(heading + _PI)
            count = 0
            for i in range(k):  # the heading axis again, from its prediction
                x[t, _YAW, i] = yaw_x[i]
                for m in range(k):
                    P[t, _YAW, i, m] = yaw_p[i, m]
            x[t, _YAW, 0] = heading
            y0 = _wrap(_align(det_yaw[j], heading) - heading)
            r0 = r[c, _YAW, 0]
            if moving:
                # θ_det and θ_vel observe θ with independent noise: one observation with the
                # inverse-variance fused innovation (tracker.kalman.motion_update)
                r1 = r[c, _YAW, 1]
                y1 = _wrap(yaw_vel - heading)
                y0, r0 = (r1 * y0 + r0 * y1) / (r0 + r1), (r0 * r1) / (r0 + r1)
            _value_update(x[t, _YAW], P[t, _YAW], y0, r0, gain, new_p)
            x[t, _YAW, 0] = _wrap(x[t, _YAW, 0])
        votes[t] = count


# ---------------------------------------------------------------------------------------------
@numba.njit((_F2, _F1), cache=True, error_model="numpy", nogil=True)
def isolated_pairs_kernel(cost: FloatArray, threshold: FloatArray) -> tuple:  # pragma: no cover
    """Stage 1's assignment when no feasible pair is contested, the usual case in tracking.

    A pair is feasible when its cost is finite and <= its row's ``threshold``. When no row and
    no column has two feasible pairs, every feasible pair is matched (the optimum of
    :func:`tracker.matching.hungarian`, which this returns without a solver): the pairs (K, 2)
    sorted by row, their costs, the unmatched rows and columns, and True. Otherwise the arrays
    are empty and the flag is False: the caller runs the solver.
    """
    m, n = cost.shape
    row_count = np.zeros(m, dtype=np.int64)
    col_count = np.zeros(n, dtype=np.int64)
    row_col = np.full(m, -1, dtype=np.int64)
    total = 0
    for i in range(m):
        for j in range(n):
            c = cost[i, j]
            if math.isfinite(c) and c <= threshold[i]:
                row_count[i] += 1
                col_count[j] += 1
                row_col[i] = j
                total += 1
    contested = False
    for i in range(m):
        contested = contested or row_count[i] > 1
    for j in range(n):
        contested = contested or col_count[j] > 1
    if contested:
        none = np.zeros(0, dtype=np.int64)
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0), none, none.copy(), False
    pairs = np.empty((total, 2), dtype=np.int64)
    costs = np.empty(total)
    free_rows = np.empty(m - total, dtype=np.int64)
    free_cols = np.empty(n - total, dtype=np.int64)
    p = f = 0
    for i in range(m):
        if row_col[i] >= 0:
            pairs[p, 0], pairs[p, 1] = i, row_col[i]
            costs[p] = cost[i, row_col[i]]
            p += 1
        else:
            free_rows[f] = i
            f += 1
    f = 0
    for j in range(n):
        if col_count[j] == 0:
            free_cols[f] = j
            f += 1
    return pairs, costs, free_rows, free_cols, True


# lifecycle outcome flags per track (lifecycle_kernel)
CONFIRMED_NOW, REACQUIRED_FROM_LOST, LOST_NOW, DEAD = 1, 2, 4, 8
_TENTATIVE, _CONFIRMED = int(TrackStatus.TENTATIVE), int(TrackStatus.CONFIRMED)
_COASTING, _LOST = int(TrackStatus.COASTING), int(TrackStatus.LOST)


@numba.njit((_S1, _I1, _I1, _F1, _I1, _B1, _F2), cache=True, error_model="numpy", nogil=True)
def lifecycle_kernel(
    status: np.ndarray,
    hits: IntArray,
    misses: IntArray,
    score: FloatArray,
    category: IntArray,
    hit: np.ndarray,
    thresholds: FloatArray,
) -> tuple:  # pragma: no cover (compiled)
    """The per-category lifecycle rules of ``MCTracker._lifecycle``, one pass over the tracks.

    ``thresholds`` (C, 5) per category: min_hits, confirm_score, max_misses_output,
    max_misses, max_misses_tentative. Returns the new status (int8), the new consecutive
    misses, and per track the flags CONFIRMED_NOW, REACQUIRED_FROM_LOST, LOST_NOW, DEAD.
    """
    n = status.shape[0]
    new_status = np.empty(n, dtype=np.int8)
    new_misses = np.empty(n, dtype=np.int64)
    flags = np.zeros(n, dtype=np.int8)
    for t in range(n):
        th = thresholds[category[t]]
        old = status[t]
        miss = 0 if hit[t] else misses[t] + 1
        new_misses[t] = miss
        state = old
        dead = False
        if hit[t]:
            if old == _TENTATIVE:
                if hits[t] >= th[0] or score[t] >= th[1]:
                    state = _CONFIRMED
                    flags[t] |= CONFIRMED_NOW
            elif old == _COASTING or old == _LOST:
                state = _CONFIRMED
                if old == _LOST:
                    flags[t] |= REACQUIRED_FROM_LOST
        elif old == _TENTATIVE:
            dead = miss > th[4]
        else:  # missed a live track: coast, then lost, then deleted
            state = _LOST if miss > th[2] else _COASTING
            dead = miss > th[3]
        if dead:
            flags[t] |= DEAD
        elif state == _LOST and old != _LOST:
            flags[t] |= LOST_NOW
        new_status[t] = state
    return new_status, new_misses, flags
