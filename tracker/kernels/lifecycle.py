"""Compiled lifecycle rules (numpy reference: ``MCTracker._lifecycle``)."""

from __future__ import annotations

import numba
import numpy as np

from tracker.boxes import FloatArray, IntArray
from tracker.events import TrackStatus
from tracker.kernels._common import _B1, _F1, _F2, _I1, _S1

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

    ``thresholds`` (C, 6) per category: min_hits, confirm_score, max_misses_output,
    max_misses, max_misses_tentative, confirm_evidence (``-log(1 - confirm_prob)``). Returns the
    new status (int8), the new consecutive misses, and per track the flags CONFIRMED_NOW,
    REACQUIRED_FROM_LOST, LOST_NOW, DEAD.
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
            state = _LOST if miss > th[2] else _COASTING
            dead = miss > th[3]
        if dead:
            flags[t] |= DEAD
        elif state == _LOST and old != _LOST:
            flags[t] |= LOST_NOW
        new_status[t] = state
    return new_status, new_misses, flags
