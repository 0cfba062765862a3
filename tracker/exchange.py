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
(SSE_kept − SSE_exchanged) / (2 · 2σ²). The tails are exchanged at the best t where that ratio
exceeds e^:data:`LOG_RATIO` (about 150); each track takes part in one exchange per pass, the most
likely first, and passes repeat until none is left (at most :data:`MAX_PASSES`).
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
    ids = np.unique(track_id[rows])
    position = np.full((len(ids), n_frames, 2), np.nan)  # [track, frame] detected centre
    k = np.searchsorted(ids, track_id[rows])
    position[k, frame_index[rows]] = xy[rows]
    # neighbours: pairs of rows of one frame whose centres are within NEAR_M
    near: dict[tuple[int, int], set[int]] = {}
    order = rows[np.argsort(frame_index[rows], kind="stable")]
    starts = np.flatnonzero(np.diff(frame_index[order], prepend=-1))
    for group in np.split(order, starts[1:]):
        if len(group) < 2:
            continue
        gap = np.linalg.norm(xy[group, None] - xy[None, group], axis=-1)
        for i, j in zip(*np.nonzero(np.triu(gap < NEAR_M, 1)), strict=True):
            a, b = sorted((int(np.searchsorted(ids, track_id[group[i]])),
                           int(np.searchsorted(ids, track_id[group[j]]))))  # fmt: skip
            if a != b:
                near.setdefault((a, b), set()).add(int(frame_index[group[i]]))
    found = []
    for (a, b), frames in sorted(near.items()):
        both = np.flatnonzero(np.isfinite(position[a, :, 0]) & np.isfinite(position[b, :, 0]))
        d = position[a, both] - position[b, both]
        tried = sorted({f + r for f in frames for r in range(-REACH_FRAMES, REACH_FRAMES + 1)})
        best, best_start = threshold, -1
        for start in tried:
            if not 0 < start < n_frames:
                continue
            lag = times[both] - times[start]  # (a µs of slack: frame times are sums of floats)
            inside = (lag >= -window_secs - 1e-6) & (lag < window_secs - 1e-6)
            after = both >= start
            if (inside & ~after).sum() < MIN_SIDE or (inside & after).sum() < MIN_SIDE:
                continue
            gain = exchange_gain(times[both[inside]], d[inside], after[inside])
            if gain > best:
                best, best_start = gain, start
        if best_start >= 0:
            found.append((best, int(ids[a]), int(ids[b]), best_start))
    found.sort(key=lambda g: (-g[0], g[1], g[2]))
    return found
