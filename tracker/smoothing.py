"""Offline smoothing of whole tracks: the online Kalman filter's forward pass, then the
Rauch-Tung-Striebel backward pass.

Online, a track's position at frame t can only use the detections up to t, so a filter that
trusts one box little (a large R, what noisy detections ask for) lags behind a moving object.
Offline, the whole track is known: the RTS smoother (Rauch, Tung and Striebel 1965) gives each
frame the estimate conditioned on *all* the track's detections, with the online filter's own
motion model and noise, so it averages the boxes' noise without the lag:

    forward (the online filter):  x̂ₜ⁻ = F x̂ₜ₋₁,  Pₜ⁻ = F Pₜ₋₁ Fᵀ + Q;  update with zₜ when detected
    backward:                      Cₜ = Pₜ Fᵀ (Pₜ₊₁⁻)⁻¹,  x̃ₜ = x̂ₜ + Cₜ (x̃ₜ₊₁ − x̂ₜ₊₁⁻)

x and y are independent chains [p, v(, a)] (the tracker's decoupled pose filter), so every track
and both axes run as one batch, frame by frame. Only the detected centres are measurements: where
the online filter also measures a detector's velocity (nuScenes), the smoother does not.

The heading is smoothed the same way with the heading filter [θ, ω] (:func:`rts_smooth_heading`),
over the detections' box axes: a box's yaw is known modulo π, so each track's detected yaws are
first chained into one continuous angle (each step taken modulo π, the smallest turn), and the
smoothed axis then takes the direction the online filter gave the row (from the direction of
travel, or the detector's majority). Only the detected yaws are measurements (not the direction
of travel).
"""

from __future__ import annotations

import numpy as np

from tracker.boxes import FloatArray, IntArray
from tracker.config import TrackerConfig
from tracker.kalman import Axis, align_heading
from tracker.mctracker import motion_noise_tables

_RIDGE = 1e-12  # keeps P⁻ invertible where a CV chain has a zero-variance acceleration


_POSE = (Axis.X, Axis.Y)


def _axis_noise(
    config: TrackerConfig,
    category: IntArray,
    axes: tuple[Axis, ...],
    motion_r: FloatArray | None = None,
) -> tuple[FloatArray, ...]:
    """Per track: P0 and Q (n, len(axes), 3) and R (n, len(axes)) of its category's filter on
    ``axes``, as [p, v, a] chains: the tracker's own tables (a CV pose, and the heading, have
    zero acceleration variances, so the chain is then exactly CV); ``motion_r`` (C, 5, 2), when
    given, replaces the config's R (the tracker's ``motion_r``, which follows the detections'
    noise with ``pose.r_scale``)."""
    p0, q, r = motion_noise_tables(config)
    if motion_r is not None:
        r = motion_r
    pad = ((0, 0), (0, 0), (0, 3 - p0.shape[-1]))  # (k = 2 when every tracked class is CV)
    rows = list(axes)
    return (
        np.pad(p0[:, rows], pad)[category],
        np.pad(q[:, rows], pad)[category],
        r[:, rows, 0][category],
    )


def rts_smooth(
    times: FloatArray,
    frame_index: IntArray,
    track: IntArray,
    measured: FloatArray,
    category: IntArray,
    config: TrackerConfig,
    axes: tuple[Axis, ...] = _POSE,
    *,
    motion_r: FloatArray | None = None,
) -> FloatArray:
    """(N, len(axes), 3) RTS-smoothed states [p, v, a] at N measurements (at most one per track
    and frame); by default of x and y: position (m), velocity (m/s), acceleration (m/s², 0 for a
    CV pose).

    ``times`` (F,) seconds of the scene's frames; ``frame_index`` (N,) each measurement's frame;
    ``track`` (N,) its track (any integer ids); ``measured`` (N, len(axes)) the measured values
    of ``axes`` (:class:`tracker.kalman.Axis`; by default the centres' x and y);
    ``category`` (N,) the track's category (a tracked one); ``motion_r`` (C, 5, 2) the R table
    to use instead of the config's (see :func:`_axis_noise`). Every frame from a track's first
    measurement to its last is a filter step, predicted only where it has no measurement."""
    k = len(axes)
    measured = np.asarray(measured, dtype=np.float64).reshape(len(measured), k)
    if not len(measured):
        return np.zeros((0, k, 3))
    ids, tk = np.unique(track, return_inverse=True)
    n = len(ids)
    first = np.full(n, np.iinfo(np.int64).max)
    last = np.full(n, -1)
    np.minimum.at(first, tk, frame_index)
    np.maximum.at(last, tk, frame_index)
    cat = np.zeros(n, dtype=np.int64)
    cat[tk] = category
    p0, q, r = _axis_noise(config, cat, axes, motion_r)
    z = np.full((len(times), n, k), np.nan)  # z[t, track]: its measurement (NaN: none)
    z[frame_index, tk] = measured
    eye = np.eye(3)
    x, P = np.zeros((n, k, 3)), np.zeros((n, k, 3, 3))
    # forward pass (the online filter), keeping per frame what the backward pass needs
    steps = []
    for t in range(int(first.min()), int(last.max()) + 1):
        live = np.flatnonzero((first <= t) & (last >= t))
        if not len(live):
            continue
        born = live[first[live] == t]
        x[born] = 0.0
        x[born, :, 0] = z[t, born]
        P[born] = p0[born][..., None] * eye
        going = live[first[live] < t]  # alive in the previous frame too: predicted
        F = eye
        if len(going):
            dt = float(times[t] - times[t - 1])
            F = np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
            x[going] = x[going] @ F.T  # x̂⁻ = F x̂
            P_pred = F @ P[going] @ F.T  # P⁻ = F P Fᵀ + Q (Q per nominal frame, as online)
            P_pred += (q[going] * (dt / config.nominal_dt_secs))[..., None] * eye
            P[going] = P_pred
        x_pred, P_pred = x[going].copy(), P[going].copy()
        # update of the value with the measurement, variance r (rows without one keep x̂⁻)
        zt = z[t, live]
        seen = np.isfinite(zt)
        Pl = P[live]
        gain = Pl[..., :, 0] / (Pl[..., 0, 0] + r[live])[..., None]
        gain *= seen[..., None]
        x[live] += gain * np.where(seen, zt - x[live, :, 0], 0.0)[..., None]
        Pl = Pl - gain[..., :, None] * Pl[..., 0, None, :]
        P[live] = 0.5 * (Pl + np.swapaxes(Pl, -1, -2))
        steps.append((t, live, going, x_pred, P_pred, F, x[live].copy(), P[live].copy()))
    # backward pass: x̃ₜ = x̂ₜ + Cₜ (x̃ₜ₊₁ − x̂ₜ₊₁⁻), Cₜ = Pₜ Fᵀ (Pₜ₊₁⁻)⁻¹
    smoothed = np.zeros((n, k, 3))
    out = np.full((len(times), n, k, 3), np.nan)
    after = None  # the next frame's (going, x̂⁻, P⁻, F)
    for t, live, going, x_pred, P_pred, F, x_f, P_f in reversed(steps):
        xs = x_f
        if after is not None and len(after[0]):
            rows, x_next, P_next, F_next = after
            pos = np.searchsorted(live, rows)  # (the next frame's predicted rows live here)
            # Cₜᵀ = (Pₜ₊₁⁻)⁻¹ F Pₜ (both covariances symmetric)
            gain_t = np.linalg.solve(P_next + _RIDGE * eye, F_next @ P_f[pos])
            diff = smoothed[rows] - x_next
            xs = x_f.copy()
            xs[pos] += (np.swapaxes(gain_t, -1, -2) @ diff[..., None])[..., 0]
        smoothed[live] = xs
        out[t, live] = xs
        after = (going, x_pred, P_pred, F)
    return out[frame_index, tk]


def rts_smooth_heading(
    times: FloatArray,
    frame_index: IntArray,
    track: IntArray,
    yaw: FloatArray,
    heading: FloatArray,
    category: IntArray,
    config: TrackerConfig,
) -> FloatArray:
    """(N,) headings (radians, wrapped) from the RTS smoother of the heading filter over N
    detected yaws (at most one per track and frame; arguments as :func:`rts_smooth`).

    ``yaw`` (N,) the detections' yaws (box axes: known modulo π); ``heading`` (N,) the online
    filter's heading of each row, which decides the direction of the smoothed axis."""
    yaw = np.asarray(yaw, dtype=np.float64)
    frame_index, track = np.asarray(frame_index), np.asarray(track)
    if not len(yaw):
        return np.zeros(0)
    if not np.isfinite(yaw).all():
        raise ValueError("rts_smooth_heading: every yaw must be finite")
    order = np.lexsort((frame_index, track))
    step = np.diff(yaw[order], prepend=0.0)
    step = np.mod(step + np.pi / 2, np.pi) - np.pi / 2  # the axis turns by less than π/2
    first = np.r_[True, track[order][1:] != track[order][:-1]]
    step[first] = 0.0  # each track starts from its first yaw (added below)
    run = np.cumsum(step)
    start = np.maximum.accumulate(np.where(first, np.arange(len(run)), 0))
    chained = np.empty(len(yaw))
    chained[order] = run - run[start] + yaw[order][start]  # continuous along each track
    axis = rts_smooth(
        times, frame_index, track, chained[:, None], category, config, axes=(Axis.YAW,)
    )[:, 0, 0]
    return align_heading(axis, heading)  # the smoothed axis, in the online heading's direction
