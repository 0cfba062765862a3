"""Compiled lifecycle rules and hit bookkeeping (numpy reference: ``MCTracker._lifecycle``,
``MCTracker._record_hits``, ``TrackTable.record_detections``)."""

from __future__ import annotations

import math

import numba
import numpy as np

from tracker.boxes import FloatArray, IntArray
from tracker.events import TrackStatus
from tracker.kernels._common import (
    _B1,
    _F1,
    _F1_OUT,
    _F2,
    _F2_OUT,
    _F3_OUT,
    _I1,
    _I1_OUT,
    _S1,
)

# lifecycle outcome flags per track (lifecycle_kernel)
CONFIRMED_NOW, REACQUIRED_FROM_LOST, LOST_NOW, DEAD = 1, 2, 4, 8
_TENTATIVE, _CONFIRMED = int(TrackStatus.TENTATIVE), int(TrackStatus.CONFIRMED)
_COASTING, _LOST = int(TrackStatus.COASTING), int(TrackStatus.LOST)


@numba.njit((_S1, _I1, _I1, _F1, _F1, _I1, _B1, _F2), cache=True, error_model="numpy", nogil=True)
def lifecycle_kernel(
    status: np.ndarray,
    hits: IntArray,
    misses: IntArray,
    score: FloatArray,
    evidence: FloatArray,
    category: IntArray,
    hit: np.ndarray,
    thresholds: FloatArray,
) -> tuple:  # pragma: no cover (compiled)
    """The per-category lifecycle rules of ``MCTracker._lifecycle``, one pass over the tracks.

    ``thresholds`` (C, 7) per category: min_hits, confirm_score, max_misses_output,
    max_misses, max_misses_tentative, confirm_evidence (``-log(1 - confirm_prob)``),
    coast_min_hits. Returns the new status (int8), the new consecutive misses, and per track the
    flags CONFIRMED_NOW, REACQUIRED_FROM_LOST, LOST_NOW, DEAD.
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
                if hits[t] >= th[0] or score[t] >= th[1] or evidence[t] >= th[5]:
                    state = _CONFIRMED
                    flags[t] |= CONFIRMED_NOW
            elif old == _COASTING or old == _LOST:
                state = _CONFIRMED
                if old == _LOST:
                    flags[t] |= REACQUIRED_FROM_LOST
        elif old == _TENTATIVE:
            dead = miss > th[4]
        else:  # missed a live track: coast, then lost, then deleted
            state = _LOST if miss > th[2] or hits[t] < th[6] else _COASTING
            dead = miss > th[3]
        if dead:
            flags[t] |= DEAD
        elif state == _LOST and old != _LOST:
            flags[t] |= LOST_NOW
        new_status[t] = state
    return new_status, new_misses, flags


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _logit(x: float) -> float:  # pragma: no cover (compiled)
    """scipy.special.logit of one value (its formula: the log1p form near 0.5)."""
    if x < 0.3 or x > 0.65:
        return math.log(x / (1.0 - x))
    s = 2.0 * (x - 0.5)
    return math.log1p(s) - math.log1p(-s)


@numba.njit(
    (
        *(_I1, _I1, _F1, _F2, _I1, _F2, _F2, _F1, _I1, _F1, numba.boolean),  # inputs
        *(_F1_OUT, _F2_OUT, _I1_OUT, _F2_OUT, _F2_OUT, _F2_OUT, _F1_OUT, _I1_OUT, _F1_OUT, _F1_OUT),
    ),
    cache=True,
    error_model="numpy",
    nogil=True,
)
def record_hits_kernel(
    idx: IntArray,
    det_rows: IntArray,
    det_score: FloatArray,
    det_xyxy: FloatArray,
    det_camera: IntArray,
    det_xyz: FloatArray,
    det_lwh: FloatArray,
    det_yaw: FloatArray,
    category: IntArray,
    vertical_gain: FloatArray,
    smooth_vertical: bool,
    score: FloatArray,
    last_xyxy: FloatArray,
    last_camera: IntArray,
    last_det_xyz: FloatArray,
    last_det_lwh: FloatArray,
    zh: FloatArray,
    last_det_yaw: FloatArray,
    hits: IntArray,
    evidence: FloatArray,
    log_odds: FloatArray,
) -> None:  # pragma: no cover (compiled)
    """``MCTracker._record_hits`` in place: track ``idx[k]`` keeps detection ``det_rows[k]``'s
    fields, its z and height move by the category's ``vertical_gain`` towards the detection's
    (when ``smooth_vertical``; else they are the detection's), and it counts the hit: +1, its
    evidence -log(1 - p) and its log-odds (NaN scores: p 0 and log-odds 0)."""
    for k in range(idx.shape[0]):
        t, d = idx[k], det_rows[k]
        s = det_score[d]
        score[t] = s
        for j in range(4):
            last_xyxy[t, j] = det_xyxy[d, j]
        last_camera[t] = det_camera[d]
        for j in range(3):
            last_det_xyz[t, j] = det_xyz[d, j]
            last_det_lwh[t, j] = det_lwh[d, j]
        z, h = det_xyz[d, 2], det_lwh[d, 2]
        if smooth_vertical:
            g = vertical_gain[category[t]]
            z, h = zh[t, 0] + g * (z - zh[t, 0]), zh[t, 1] + g * (h - zh[t, 1])
        zh[t, 0], zh[t, 1] = z, h
        last_det_yaw[t] = det_yaw[d]
        hits[t] += 1
        p = min(s if s > 0.0 else 0.0, 1.0 - 1e-9)  # (NaN: 0)
        evidence[t] += -math.log1p(-p)
        if s == s:  # not NaN
            log_odds[t] += _logit(min(max(s, 1e-6), 1.0 - 1e-6))


@numba.njit(
    (_I1, numba.float64, _F2, _F2_OUT, _F3_OUT, _F3_OUT),
    cache=True,
    error_model="numpy",
    nogil=True,
)
def record_detections_kernel(
    idx: IntArray,
    time_secs: float,
    xy: FloatArray,
    det_t: FloatArray,
    det_xy: FloatArray,
    baseline: FloatArray,
) -> None:  # pragma: no cover (compiled)
    """``TrackTable.record_detections`` in place: track ``idx[k]``'s window of its last W
    detections moves on to ``xy[k]`` at ``time_secs``, and its difference (``baseline[t, 0]``)
    and curve-fit (``[t, 1]``) velocities are recomputed (0 while too few detections)."""
    w = det_t.shape[1]
    for k in range(idx.shape[0]):
        t = idx[k]
        for j in range(w - 1):
            det_t[t, j] = det_t[t, j + 1]
            det_xy[t, j, 0], det_xy[t, j, 1] = det_xy[t, j + 1, 0], det_xy[t, j + 1, 1]
        det_t[t, w - 1] = time_secs
        det_xy[t, w - 1, 0], det_xy[t, w - 1, 1] = xy[k, 0], xy[k, 1]
        dt = det_t[t, w - 1] - det_t[t, w - 2]
        for a in range(2):
            baseline[t, 0, a] = (
                0.0 if dt != dt else (det_xy[t, w - 1, a] - det_xy[t, w - 2, a]) / dt
            )
        if det_t[t, 0] != det_t[t, 0]:  # (NaN: fewer than W detections yet)
            baseline[t, 1, 0] = baseline[t, 1, 1] = 0.0
            continue
        mean_t = 0.0
        for j in range(w):
            mean_t += det_t[t, j]
        mean_t /= w
        for a in range(2):
            mean_p = 0.0
            for j in range(w):
                mean_p += det_xy[t, j, a]
            mean_p /= w
            num = den = 0.0
            for j in range(w):
                u = det_t[t, j] - mean_t
                num += u * (det_xy[t, j, a] - mean_p)
                den += u * u
            baseline[t, 1, a] = num / den
