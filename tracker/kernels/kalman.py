"""Compiled Kalman stages: every track's per-axis predict, and the update with the heading
logic (numpy reference: ``MCTracker._predict`` / ``MCTracker._update`` with :mod:`tracker.kalman`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from tracker.boxes import FloatArray, IntArray
from tracker.kernels._common import (
    _F1,
    _F2,
    _F3,
    _F3_OUT,
    _F4,
    _F4_OUT,
    _HALF_PI,
    _I1,
    _I1_OUT,
    _PI,
    _align,
    _f8,
    _i8,
    _wrap,
)

# state layout of tracker.kalman's fast path: axes x, y, l, w, θ of [value, rate(, acc)]
_X, _Y, _YAW = 0, 1, 4
_N_AXES = 5


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
