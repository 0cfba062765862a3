"""The paper's two velocity baselines, kept by the tracker at every update (spec §2.10).

MCTrack compares its Kalman velocity with the velocity a track's own detection centres give:

- **difference**: (p_k - p_{k-1}) / (t_k - t_{k-1}) over its last two detections;
- **curve fit**: the least-squares slope of a line through its last :data:`WINDOW` detections,
  Σ(t - t̄)(p - p̄) / Σ(t - t̄)², in m/s (the reference fitted against the frame index: m/frame).

Both are 0 until enough detections exist, as in the reference. The tracker computes them over
every detection a track took, tentative ones included, so a track's first output row has the
detections before its confirmation behind it. The same maths over a whole track is
:func:`tracker.eval.motion_metrics.velocity_differencing` and ``velocity_curve_fit``; the tests
keep the two equal.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from tracker.boxes import FloatArray

#: Detections per curve fit (the reference's 3), and so the detections a track keeps.
WINDOW: Final = 3


def latest_velocities(times_secs: FloatArray, xy: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Difference and curve-fit velocity at each track's latest detection.

    Parameters
    ----------
    times_secs : (R, W) each track's last W detection times, oldest first, NaN where the track
        has fewer (on the left).
    xy : (R, W, 2) their world centres, m (NaN likewise).

    Returns
    -------
    (difference, curve_fit), each (R, 2) m/s; 0 where the track has fewer than 2 (W) detections.
    """
    dt = times_secs[:, -1] - times_secs[:, -2]
    difference = (xy[:, -1] - xy[:, -2]) / dt[:, None]
    difference[np.isnan(dt)] = 0.0
    u = times_secs - times_secs.mean(axis=1, keepdims=True)
    p = xy - xy.mean(axis=1, keepdims=True)
    curve = np.einsum("rk,rkd->rd", u, p) / (u**2).sum(axis=1)[:, None]
    curve[np.isnan(times_secs[:, 0])] = 0.0
    return difference, curve
