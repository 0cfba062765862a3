"""Offline: give back two neighbouring tracks the tails they exchanged.

Two people walking side by side 0.6 m apart, under centre noise of σ 0.3 m, are often followed
by two tracks that trade objects when one of the two boxes is missing or the noise brings each
box nearer the other's track; from then on each track follows the other person. Online nothing
tells the two apart (the boxes alone are ambiguous); offline the tracks' whole histories are
known, and two people who walk together keep their arrangement: the difference of their
detections d(t) = p_A(t) − p_B(t) changes slowly, while an exchange at t flips its sign.

So for two tracks A, B of one class whose detections come within :data:`NEAR_M` of each other, and
a frame t near where they do, the frames within ``window`` seconds either side of t where both
are detected are fitted twice with a straight line d(t) ≈ a + b·t (per axis, least squares):

    kept:       d(t) as the tracks hold it
    exchanged:  d(t) before t, −d(t) from t on (the tails after t swapped)

A line follows two tracks that drift apart or cross (their relative position moves steadily, as
when one overtakes the other), so a crossing is no exchange. Each detection's centre has
variance σ² per axis (the scene's estimated noise, ``tracker.noise``), so d has 2σ², and with
Gaussian noise the log-likelihood ratio of the exchanged tails against the kept ones is
(SSE_kept − SSE_exchanged) / (2 · 2σ²). The tails are exchanged at the best t where that log
ratio exceeds :data:`LOG_RATIO` (a likelihood ratio of e^5, about 150); each track takes part in
one exchange per pass, the most likely first, and passes repeat until none is left (at most
:data:`MAX_PASSES`).
"""

from __future__ import annotations

import numpy as np

from tracker.boxes import FloatArray, IntArray

#: two tracks are neighbours when their detections come this near in some frame (metres): an
#: exchange happens between boxes that could be confused, and 2 m is past any centre noise the
#: tracker follows (the robustness benchmark's double noise, σ 0.3 m per axis, is 4σ at 1.7 m)
NEAR_M = 2.0
#: an exchange can begin while one of the two is undetected: the frames tried as its start reach
#: this far from a frame where the two are near
REACH_FRAMES = 3
#: at least this many frames where both are detected on each side of t (two points fix a line)
MIN_SIDE = 3
#: the natural log of the likelihood ratio an exchange needs (e^5 ≈ 150)
LOG_RATIO = 5.0
MAX_PASSES = 5


def _line_sse(t: FloatArray, d: FloatArray) -> float:
    """Residual sum of squares of the least-squares line through (t, d), every column of d."""
    design = np.column_stack([np.ones_like(t), t - t.mean()])
    coef, *_ = np.linalg.lstsq(design, d, rcond=None)
    return float(((d - design @ coef) ** 2).sum())


def exchange_gain(times: FloatArray, d: FloatArray, after: np.ndarray) -> float:
    """SSE_kept − SSE_exchanged of the relative positions ``d`` (K, 2) at ``times`` (K,) when
    the rows where ``after`` are negated (module docstring)."""
    flipped = np.where(after[:, None], -d, d)
    return _line_sse(times, d) - _line_sse(times, flipped)


def window_gains(
    t: FloatArray,
    d: FloatArray,
    frame: IntArray,
    starts: IntArray,
    times: FloatArray,
    window_secs: float,
) -> FloatArray:
    """(S,) :func:`exchange_gain` at each of ``starts`` (frames), over the rows of (``t``, ``d``)
    (K,), (K, 2) at frames ``frame`` (K,, increasing) within ``window_secs`` of the start's time
    (``times``, per frame); -inf where either side has fewer than :data:`MIN_SIDE` rows.

    Vectorised over the starts: each window is a run of rows, so its sums come from prefix sums,
    and a line's residual is Σd² − (Σd)²/n − (Σ(t − t̄)d)² / Σ(t − t̄)² per axis; the exchanged
    tails negate the sums after the start."""
    # times from the pair's first row: epoch seconds (nuScenes, Waymo) squared would leave
    # nothing of a 6 s window's spread in float64
    ref = float(t[0]) if len(t) else 0.0
    t = t - ref
    zero = np.zeros((1, 2))
    c_t = np.concatenate([[0.0], np.cumsum(t)])
    c_tt = np.concatenate([[0.0], np.cumsum(t * t)])
    c_d = np.concatenate([zero, np.cumsum(d, axis=0)])
    c_td = np.concatenate([zero, np.cumsum(t[:, None] * d, axis=0)])
    t0 = times[starts] - ref
    slack = 1e-6  # (frame times are sums of floats)
    lo = np.searchsorted(t, t0 - window_secs - slack, side="left")
    hi = np.searchsorted(t, t0 + window_secs - slack, side="left")
    mid = np.clip(np.searchsorted(frame, starts, side="left"), lo, hi)
    n = (hi - lo).astype(np.float64)
    ok = (mid - lo >= MIN_SIDE) & (hi - mid >= MIN_SIDE)
    n_safe = np.where(ok, n, 1.0)
    s_t = c_t[hi] - c_t[lo]
    s_xx = np.where(ok, c_tt[hi] - c_tt[lo] - s_t**2 / n_safe, 1.0)

    def sse_terms(s_d: FloatArray, s_td: FloatArray) -> FloatArray:
        """The part of the residual that depends on the signs: (Σd)²/n + (Σ(t − t̄)d)²/Σ(t − t̄)²."""
        centred = s_td - s_t[:, None] * s_d / n_safe[:, None]
        return (s_d**2 / n_safe[:, None] + centred**2 / s_xx[:, None]).sum(axis=1)

    pre_d, post_d = c_d[mid] - c_d[lo], c_d[hi] - c_d[mid]
    pre_td, post_td = c_td[mid] - c_td[lo], c_td[hi] - c_td[mid]
    # SSE_kept − SSE_exchanged: Σd² is the same for both and cancels
    gain = sse_terms(pre_d - post_d, pre_td - post_td) - sse_terms(pre_d + post_d, pre_td + post_td)
    return np.where(ok & np.isfinite(gain), gain, -np.inf)


def exchange_tails(
    track_id: IntArray,
    frame_index: IntArray,
    times: FloatArray,
    xy: FloatArray,
    category: IntArray,
    rows: IntArray,
    variance: FloatArray,
    window_secs: float,
) -> IntArray:
    """(N,) track ids with exchanged tails given back (module docstring).

    ``track_id``, ``frame_index``, ``category`` (N,) and ``xy`` (N, 2) describe the scene's rows
    (at most one per track and frame; ``xy`` each detection's own centre); only ``rows`` (the
    detected rows) take part, and every row of a track after its exchange follows it.
    ``times`` (F,) the frames' times, ``variance`` (C,) each class's estimated centre variance
    σ² per axis (NaN or 0: that class is left alone), ``window_secs`` the span either side of
    an exchange that judges it (0: nothing is exchanged)."""
    track_id = track_id.copy()
    if window_secs <= 0 or len(rows) < 2:
        return track_id
    for c in np.unique(category[rows]):
        sigma2 = float(variance[c]) if c < len(variance) else float("nan")
        if not (np.isfinite(sigma2) and sigma2 > 0):
            continue
        mine = rows[category[rows] == c]
        threshold = 2 * (2 * sigma2) * LOG_RATIO
        for _ in range(MAX_PASSES):
            found = _exchanges(track_id, frame_index, times, xy, mine, window_secs, threshold)
            if not found:
                break
            busy: set[int] = set()
            for _gain, a, b, start in found:  # the most likely first, each track once a pass
                if a in busy or b in busy:
                    continue
                busy |= {a, b}
                tail_a = (track_id == a) & (frame_index >= start)
                tail_b = (track_id == b) & (frame_index >= start)
                track_id[tail_a], track_id[tail_b] = b, a
    return track_id


def _neighbour_frames(
    track: IntArray, frame: IntArray, xy: FloatArray
) -> list[tuple[tuple[int, int], IntArray]]:
    """``((a, b), frames)`` of every pair of tracks ``a < b`` (indices into the rows' ``track``)
    whose rows of one frame lie within :data:`NEAR_M` of each other, sorted by pair, each with
    the frames where they do (sorted). Every pair of rows of a frame is compared once: the
    rows in frame order, each paired with the rows after it in its frame."""
    order = np.argsort(frame, kind="stable")
    f = frame[order]
    end = np.searchsorted(f, f, side="right")  # past each row's frame's last row (in order)
    later = end - np.arange(len(f)) - 1  # rows after it in its frame
    i = np.repeat(np.arange(len(f)), later)
    j = i + 1 + np.arange(len(i)) - np.repeat(np.cumsum(later) - later, later)
    i, j = order[i], order[j]
    close = np.linalg.norm(xy[i] - xy[j], axis=-1) < NEAR_M
    a, b = np.minimum(track[i], track[j])[close], np.maximum(track[i], track[j])[close]
    pair_frames = np.unique(np.column_stack([a, b, frame[i][close]])[a != b], axis=0)
    if not len(pair_frames):
        return []
    pairs, starts = np.unique(pair_frames[:, :2], axis=0, return_index=True)
    groups = np.split(pair_frames[:, 2], starts[1:])
    return [((int(p[0]), int(p[1])), g) for p, g in zip(pairs, groups, strict=True)]


def _exchanges(
    track_id: IntArray,
    frame_index: IntArray,
    times: FloatArray,
    xy: FloatArray,
    rows: IntArray,
    window_secs: float,
    threshold: float,
) -> list[tuple[float, int, int, int]]:
    """``(gain, track A, track B, first frame of the tails)`` of every pair of neighbouring
    tracks whose best exchange gains more than ``threshold``, the most likely first (ties by
    the ids)."""
    n_frames = len(times)
    ids, k = np.unique(track_id[rows], return_inverse=True)
    # each track's rows in frame order: track i owns by_track[first[i]:first[i + 1]]
    by_track = rows[np.lexsort((frame_index[rows], k))]
    first = np.searchsorted(np.sort(k), np.arange(len(ids) + 1))
    near = _neighbour_frames(k, frame_index[rows], xy[rows])
    found = []
    for (a, b), frames in near:
        rows_a, rows_b = by_track[first[a] : first[a + 1]], by_track[first[b] : first[b + 1]]
        both, in_a, in_b = np.intersect1d(
            frame_index[rows_a], frame_index[rows_b], assume_unique=True, return_indices=True
        )
        tried = np.unique(np.add.outer(frames, np.arange(-REACH_FRAMES, REACH_FRAMES + 1)))
        tried = tried[(tried > 0) & (tried < n_frames)]
        if not len(tried):
            continue
        d = xy[rows_a[in_a]] - xy[rows_b[in_b]]
        gains = window_gains(times[both], d, both, tried, times, window_secs)
        best = int(np.argmax(gains))  # (the earliest of equal gains)
        if gains[best] > threshold:
            found.append((float(gains[best]), int(ids[a]), int(ids[b]), int(tried[best])))
    found.sort(key=lambda g: (-g[0], g[1], g[2]))
    return found
