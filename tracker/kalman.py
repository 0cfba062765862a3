"""Batched linear Kalman filters: pose (CV / CA), size (CV) and heading ([θ, ω]).

MCTrack (paper §3, motion module) gives every track three decoupled filters. The tracker keeps
all live tracks' states stacked, so every function takes a leading batch axis ``B`` and handles
the whole batch in a few numpy calls, never a Python loop over tracks.

Three layers, all pure functions:

1. Generic :func:`predict` / :func:`update` for any ``n``, ``m`` and any leading batch shape
   ``(...)``, with exact per-row measurement masks and angular innovations.
2. The reference's filters in their usual layout (``pose_*``, ``size_*``, ``heading_*``), built on
   (1): readable, and used for the parity traces of mctrack_reference.md §8.
3. The tracker's fast path (``motion_*``): the same three filters, stored per *axis*. With
   diagonal P0 / Q / R (always the case in the configs) and axis-separable F and H, the five
   axes x, y, l, w, θ never correlate, so the joint covariance is exactly block diagonal with one
   ``k × k`` block per axis (``k = 2`` for CV, ``3`` for CA). Storing ``x (B, 5, k)`` and
   ``P (B, 5, k, k)`` is therefore lossless. The tracker's problems are tiny (a few tracks), so
   the cost is the number of numpy calls, not arithmetic, and each case takes the fewest:
   a predict with one ``dt`` for every row (a frame) is two matrix products over the stacked
   blocks (``vec(F P Fᵀ)`` by ``F ⊗ F``); an update where only values are measured (positions,
   sizes, θ_det: KITTI) is the rank-one Joseph form for any k, and θ_vel joins it as one
   inverse-variance fused observation of θ (the same posterior); measured velocities use the
   2 × 2 closed form (CV) or layer (1) (CA). ``bench/bench_kalman.py`` times each against
   layer (2); ``tests/test_kalman.py`` checks every case against (2). Axis groups whose
   measurement is absent are left as predicted, so the tracker updates the heading after the
   pose when it needs the updated velocity.

Conventions
-----------
- ``x (B, n)`` state, ``P (B, n, n)`` covariance, ``z (B, m)`` measurement; ``F``, ``Q`` are
  ``(B, n, n)`` (or broadcastable), ``H (m, n)`` or ``(B, m, n)``, ``R (m, m)`` or ``(B, m, m)``.
- Transitions are built per row from a ``(B,)`` array of elapsed seconds, because coasting
  tracks advance by the real elapsed time.
- P0 / Q / R from the config are diagonal *variances* (reference §2.7). Per-category values are
  stacked per row by the caller (``q_diag (B, n)``); a single ``(n,)`` row broadcasts.
- Angles are radians wrapped to (-pi, pi] (:func:`tracker.geometry.wrap_angle`).

Differences from the reference code (mctrack_reference.md §2.7, §6)
-------------------------------------------------------------------
- Predict and update are separate (the reference predicts inside ``update``), and every filter
  can be predicted on a miss; the reference's pseudo-update is kept only as :func:`pseudo_update`.
- The covariance update is the Joseph form (symmetric, stays PSD). For the optimal gain it equals
  the reference's ``P = (I − K H) P``, so the §8 traces are reproduced to rounding.
- ``Q`` is the config's variance per nominal frame step (the reference never scales it) and is
  scaled by ``dt / dt_nominal``, so that at the nominal rate we reproduce the reference exactly.
- The heading filter uses the pre-2025 ``H = [[1, 0], [1, 0]]`` (θ_det and θ_vel both observe θ)
  and wraps every innovation and the state angle. The reference's 2025 ``H = I`` treats θ_vel as
  an observation of ω, and its ``norm_radian`` works modulo π: both are defects (§6 item 2).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum, IntEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tracker.boxes import FloatArray, IntArray
from tracker.geometry import wrap_angle

BoolArray = NDArray[np.bool_]
Gaussian = tuple[FloatArray, FloatArray]  # (x, P)

#: Heading measurement matrix: θ_det and θ_vel both observe θ (pre-2025 reference; correct).
HEADING_H: FloatArray = np.array([[1.0, 0.0], [1.0, 0.0]])

#: The reference's 2025 matrix (θ_vel "observes" ω). A defect, kept only for parity studies.
HEADING_H_REFERENCE_2025: FloatArray = np.eye(2)

#: Size measurement matrix: [l, w] from [l, w, vl, vw].
SIZE_H: FloatArray = np.eye(2, 4)


class MotionModel(Enum):
    """Pose motion model: constant velocity (reference code) or constant acceleration (paper)."""

    CV = "cv"
    CA = "ca"

    @property
    def order(self) -> int:
        """States per axis: 2 ([p, v]) for CV, 3 ([p, v, a]) for CA."""
        return 2 if self is MotionModel.CV else 3


class Axis(IntEnum):
    """Axes of the fast-path state ``x (B, 5, k)``; ``x[:, axis]`` is [value, rate(, acc)]."""

    X = 0
    Y = 1
    LENGTH = 2
    WIDTH = 3
    YAW = 4


N_AXES = len(Axis)


#: Wrap to (-pi, pi]; angles already in range (the usual case) are kept bit for bit, cheaply.
_wrap = wrap_angle


# ---------------------------------------------------------------------------------------------
# Noise container
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class DiagonalNoise:
    """Diagonal P0 / Q / R variances of one filter.

    Built for one category from the config lists, or stacked over categories with
    :meth:`stack` and then selected per track with :meth:`take`.

    Attributes
    ----------
    p0_diag : (..., n) initial covariance diagonal.
    q_diag : (..., n) process noise per *nominal* frame step (see :func:`process_noise`).
    r_diag : (..., m) measurement noise.
    per_category : True when axis 0 indexes categories (made by :meth:`stack`).
    """

    p0_diag: FloatArray
    q_diag: FloatArray
    r_diag: FloatArray
    per_category: bool = False

    def __post_init__(self) -> None:
        for name in ("p0_diag", "q_diag", "r_diag"):
            value = np.array(getattr(self, name), dtype=np.float64)
            if value.ndim == 0 or not np.all(np.isfinite(value)) or np.any(value < 0):
                raise ValueError(f"DiagonalNoise.{name} must be finite variances >= 0, got {value}")
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        if self.p0_diag.shape != self.q_diag.shape:
            raise ValueError(
                f"DiagonalNoise: p0_diag {self.p0_diag.shape} and q_diag {self.q_diag.shape} differ"
            )
        if self.r_diag.shape[:-1] != self.p0_diag.shape[:-1]:
            raise ValueError(
                f"DiagonalNoise: r_diag {self.r_diag.shape} does not stack like p0_diag "
                f"{self.p0_diag.shape}"
            )
        if np.any(self.r_diag <= 0):
            raise ValueError(f"DiagonalNoise.r_diag must be > 0, got {self.r_diag}")

    @classmethod
    def stack(cls, per_category: Sequence[DiagonalNoise]) -> DiagonalNoise:
        """Stack single-category noises into ``(C, ...)`` arrays indexed by category."""
        return cls(
            p0_diag=np.stack([n.p0_diag for n in per_category]),
            q_diag=np.stack([n.q_diag for n in per_category]),
            r_diag=np.stack([n.r_diag for n in per_category]),
            per_category=True,
        )

    def take(self, category: ArrayLike) -> DiagonalNoise:
        """Per-row ``(B, ...)`` noises for tracks of the given ``(B,)`` category indices."""
        if not self.per_category:
            raise ValueError("DiagonalNoise.take needs a per-category noise (DiagonalNoise.stack)")
        idx = np.asarray(category, dtype=np.int64)
        return DiagonalNoise(
            p0_diag=self.p0_diag[idx], q_diag=self.q_diag[idx], r_diag=self.r_diag[idx]
        )


# ---------------------------------------------------------------------------------------------
# Matrix builders
# ---------------------------------------------------------------------------------------------


def _kinematic_parts(order: int, n_axes: int) -> tuple[FloatArray, FloatArray]:
    """(D1, D2) with F = I + dt·D1 + dt²·D2 for ``n_axes`` interleaved chains p, v(, a)."""
    n = order * n_axes
    d1 = np.zeros((n, n))
    d2 = np.zeros((n, n))
    for axis in range(n_axes):
        for j in range(order - 1):
            d1[j * n_axes + axis, (j + 1) * n_axes + axis] = 1.0  # p += v·dt, v += a·dt
        if order == 3:
            d2[axis, 2 * n_axes + axis] = 0.5  # p += a·dt²/2
    return d1, d2


_CV_D1, _ = _kinematic_parts(2, 2)
_CA_D1, _CA_D2 = _kinematic_parts(3, 2)
_AXIS_D = {order: _kinematic_parts(order, 1) for order in (2, 3)}


def _dt_column(dt_secs: ArrayLike) -> FloatArray:
    """(B,) elapsed seconds as (B, 1, 1) for broadcasting against (n, n) matrices."""
    return np.asarray(dt_secs, dtype=np.float64).reshape(-1, 1, 1)


def cv_transition(dt_secs: ArrayLike) -> FloatArray:
    """Constant-velocity transition for [x, y, vx, vy].

    Parameters
    ----------
    dt_secs : (B,) elapsed time per track, seconds.

    Returns
    -------
    F : (B, 4, 4), ``F = I + dt·D`` (x += vx·dt, y += vy·dt).
    """
    return np.eye(4) + _dt_column(dt_secs) * _CV_D1


def ca_transition(dt_secs: ArrayLike) -> FloatArray:
    """Constant-acceleration transition for [x, y, vx, vy, ax, ay] (the paper's model).

    Parameters
    ----------
    dt_secs : (B,) elapsed time per track, seconds.

    Returns
    -------
    F : (B, 6, 6): p += v·dt + a·dt²/2, v += a·dt.
    """
    dt = _dt_column(dt_secs)
    return np.eye(6) + dt * _CA_D1 + (dt * dt) * _CA_D2


def heading_transition(dt_secs: ArrayLike) -> FloatArray:
    """Heading transition for [θ, ω] (θ += ω·dt). Returns (B, 2, 2)."""
    return np.eye(2) + _dt_column(dt_secs) * _AXIS_D[2][0]


def size_transition(dt_secs: ArrayLike) -> FloatArray:
    """Size transition for [l, w, vl, vw] (CV, as in the reference). Returns (B, 4, 4)."""
    return cv_transition(dt_secs)


def axis_transition(dt_secs: ArrayLike, *, model: MotionModel) -> FloatArray:
    """Per-axis transition of the fast path, shared by the 5 axes: (B, 1, k, k)."""
    d1, d2 = _AXIS_D[model.order]
    dt = _dt_column(dt_secs)
    return (np.eye(model.order) + dt * d1 + (dt * dt) * d2)[:, None]


def process_noise(q_diag: ArrayLike, dt_secs: ArrayLike, *, dt_nominal_secs: float) -> FloatArray:
    """Diagonal process noise for elapsed times ``dt``: ``Q = diag(q) · dt / dt_nominal``.

    The config's Q is a variance per frame (the reference adds it once per frame whatever the
    rate and never scales it by dt). Scaling it linearly with the elapsed time (a random-walk
    model) reproduces the reference exactly at the nominal rate, and makes one step of ``k·dt``
    add as much noise as ``k`` steps of ``dt`` (ignoring the transport of Q through F).

    Parameters
    ----------
    q_diag : (n,) or (B, n) variances per nominal step.
    dt_secs : (B,) elapsed time per track, seconds.
    dt_nominal_secs : the config's frame period (1 / FRAME_RATE), seconds.

    Returns
    -------
    Q : (B, n, n).
    """
    tau = np.asarray(dt_secs, dtype=np.float64).reshape(-1, 1) / dt_nominal_secs
    return diagonal_covariance(np.asarray(q_diag, dtype=np.float64) * tau)


def diagonal_covariance(diag: ArrayLike) -> FloatArray:
    """``(..., k)`` variances -> ``(..., k, k)`` diagonal covariances (P0 or R)."""
    d = np.asarray(diag, dtype=np.float64)
    return d[..., None] * np.eye(d.shape[-1])


def position_measurement_matrix(*, n_state: int, with_velocity: bool) -> FloatArray:
    """Pose H: the first 2 ([x, y]) or 4 ([x, y, vx, vy]) rows of I_n. Returns (m, n)."""
    return np.eye(4 if with_velocity else 2, n_state)


# ---------------------------------------------------------------------------------------------
# Generic batched predict / update
# ---------------------------------------------------------------------------------------------


def predict(x: FloatArray, P: FloatArray, F: FloatArray, Q: FloatArray) -> Gaussian:
    """Kalman prediction for a batch.

    Parameters
    ----------
    x : (..., n) states.
    P : (..., n, n) covariances.
    F : (..., n, n) transitions (broadcastable, e.g. (n, n)).
    Q : (..., n, n) process noise (broadcastable).

    Returns
    -------
    x : (..., n) ``F x``.
    P : (..., n, n) ``F P Fᵀ + Q``, symmetrised.
    """
    x_pred = (F @ x[..., None])[..., 0]  # x = F x
    P_pred = F @ P @ F.mT + Q  # P = F P Fᵀ + Q
    return x_pred, 0.5 * (P_pred + P_pred.mT)


def update(
    x: FloatArray,
    P: FloatArray,
    z: FloatArray,
    H: FloatArray,
    R: FloatArray,
    *,
    mask: ArrayLike | None = None,
    innovation_wrap: ArrayLike | None = None,
) -> Gaussian:
    """Kalman measurement update for a batch (Joseph form).

    Masking is exact, not a "large R" approximation: for a masked component ``i`` of a row, the
    row ``H[i]``, the innovation ``y[i]`` and the cross terms ``R[i, j≠i]`` are zeroed and
    ``R[i, i]`` is set to 1. Then ``S`` is block diagonal with an identity block on the masked
    components, the gain's masked columns are exactly zero, and the result equals an update of
    that row without those components. A fully masked row is left unchanged. Masked components
    of ``z`` may be NaN.

    Parameters
    ----------
    x : (..., n) predicted states.
    P : (..., n, n) predicted covariances.
    z : (..., m) measurements.
    H : (m, n) or (..., m, n) measurement matrices.
    R : (m, m) or (..., m, m) measurement noise (positive definite).
    mask : (..., m) bool, optional. True where the component is measured (default: all).
    innovation_wrap : angular components of ``z``, whose innovations are wrapped to (-pi, pi]:
        indices into the last axis, or a bool mask over the trailing axes of ``z``.

    Returns
    -------
    x : (..., n) ``x + K y``.
    P : (..., n, n) ``(I − K H) P (I − K H)ᵀ + K R Kᵀ``, symmetrised.
    """
    y = z - (H @ x[..., None])[..., 0]  # y = z − H x
    if innovation_wrap is not None:
        wrap = np.asarray(innovation_wrap)
        y[..., wrap] = _wrap(y[..., wrap])
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        y = np.where(mask, y, 0.0)
        H = H * mask[..., None]
        R = np.where(mask[..., :, None] & mask[..., None, :], R, np.eye(mask.shape[-1]))
    PHt = P @ H.mT
    S = H @ PHt + R  # S = H P Hᵀ + R
    K = np.linalg.solve(S, PHt.mT).mT  # K = P Hᵀ S⁻¹, as Kᵀ = S⁻¹ (H P) (S, P symmetric)
    x_new = x + (K @ y[..., None])[..., 0]  # x = x + K y
    A = np.eye(x.shape[-1]) - K @ H
    P_new = A @ P @ A.mT + K @ R @ K.mT  # P = (I − K H) P (I − K H)ᵀ + K R Kᵀ  (Joseph)
    return x_new, 0.5 * (P_new + P_new.mT)


def pseudo_update(x: FloatArray, P: FloatArray, H: FloatArray, R: FloatArray) -> Gaussian:
    """Reference parity only: the official tracker's update on a miss, ``z = H x`` (§2.6).

    Call it on the *predicted* state (the reference measures ``z = H F x`` and predicts inside
    its ``update``). The state is unchanged (zero innovation) but P shrinks as if a measurement
    had arrived, which makes coasting tracks over-confident. The tracker should only predict.

    Parameters
    ----------
    x : (..., n) predicted states.
    P : (..., n, n) predicted covariances.
    H : (m, n) or (..., m, n).
    R : (m, m) or (..., m, m).

    Returns
    -------
    x, P : (..., n), (..., n, n).
    """
    return update(x, P, (H @ x[..., None])[..., 0], H, R)


# ---------------------------------------------------------------------------------------------
# Reference layout: pose [x, y, vx, vy(, ax, ay)], size [l, w, vl, vw], heading [θ, ω]
# ---------------------------------------------------------------------------------------------


def pose_init(
    xy: ArrayLike, *, p0_diag: ArrayLike, velocity_xy: ArrayLike | None = None, n_state: int = 4
) -> Gaussian:
    """Initial pose states ``[x, y, vx, vy(, 0, 0)]`` with ``P0 = diag(p0)``.

    Parameters
    ----------
    xy : (B, 2) detection centres, metres.
    p0_diag : (n,) or (B, n) initial variances.
    velocity_xy : (B, 2) detector velocity, m/s; None or NaN entries start at 0.
    n_state : 4 (CV) or 6 (CA; the acceleration starts at 0).

    Returns
    -------
    x : (B, n), P : (B, n, n).
    """
    if n_state not in (4, 6):
        raise ValueError(f"pose n_state must be 4 (CV) or 6 (CA), got {n_state}")
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    x = np.zeros((len(xy), n_state))
    x[:, :2] = xy
    if velocity_xy is not None:
        x[:, 2:4] = np.nan_to_num(np.asarray(velocity_xy, dtype=np.float64).reshape(-1, 2))
    P = np.broadcast_to(diagonal_covariance(p0_diag), (len(xy), n_state, n_state)).copy()
    return x, P


def pose_predict(
    x: FloatArray, P: FloatArray, *, dt_secs: ArrayLike, q_diag: ArrayLike, dt_nominal_secs: float
) -> Gaussian:
    """Predict pose filters by ``dt`` (CV when ``n == 4``, CA when ``n == 6``).

    Parameters
    ----------
    x : (B, n), P : (B, n, n).
    dt_secs : (B,) elapsed seconds per track.
    q_diag : (n,) or (B, n) process variances per nominal step (see :func:`process_noise`).
    dt_nominal_secs : the config's frame period, seconds.

    Returns
    -------
    x : (B, n), P : (B, n, n).
    """
    F = cv_transition(dt_secs) if x.shape[-1] == 4 else ca_transition(dt_secs)
    return predict(x, P, F, process_noise(q_diag, dt_secs, dt_nominal_secs=dt_nominal_secs))


def pose_update(
    x: FloatArray,
    P: FloatArray,
    *,
    xy: ArrayLike,
    r_diag: ArrayLike,
    velocity_xy: ArrayLike | None = None,
    velocity_valid: ArrayLike | None = None,
) -> Gaussian:
    """Update pose filters with a position (KITTI / Waymo) or position + velocity (nuScenes).

    Parameters
    ----------
    x : (B, n), P : (B, n, n) predicted pose filters (n = 4 or 6).
    xy : (B, 2) measured centres, metres.
    r_diag : (m,) or (B, m) variances; m = 2 without velocity, 4 with.
    velocity_xy : (B, 2) detector velocity, m/s, or None for position-only measurements.
    velocity_valid : (B,) bool, rows whose velocity is used. Default: rows with finite velocity.
        An invalid row gets exactly the position-only update.

    Returns
    -------
    x : (B, n), P : (B, n, n).
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if velocity_xy is None:
        H = position_measurement_matrix(n_state=x.shape[-1], with_velocity=False)
        return update(x, P, xy, H, diagonal_covariance(r_diag))
    v = np.asarray(velocity_xy, dtype=np.float64).reshape(-1, 2)
    valid = np.isfinite(v).all(axis=-1) if velocity_valid is None else np.asarray(velocity_valid)
    mask = np.ones((len(xy), 4), dtype=bool)
    mask[:, 2:] = valid[:, None]
    H = position_measurement_matrix(n_state=x.shape[-1], with_velocity=True)
    z = np.concatenate([xy, v], axis=-1)
    return update(x, P, z, H, diagonal_covariance(r_diag), mask=mask)


def size_init(lw: ArrayLike, *, p0_diag: ArrayLike) -> Gaussian:
    """Initial size states ``[l, w, 0, 0]`` from ``lw (B, 2)`` metres; ``P0 = diag(p0)``."""
    lw = np.asarray(lw, dtype=np.float64).reshape(-1, 2)
    x = np.zeros((len(lw), 4))
    x[:, :2] = lw
    return x, np.broadcast_to(diagonal_covariance(p0_diag), (len(lw), 4, 4)).copy()


def size_predict(
    x: FloatArray, P: FloatArray, *, dt_secs: ArrayLike, q_diag: ArrayLike, dt_nominal_secs: float
) -> Gaussian:
    """Predict size filters by ``dt``; run on every frame, misses included. Shapes as pose."""
    F = size_transition(dt_secs)
    return predict(x, P, F, process_noise(q_diag, dt_secs, dt_nominal_secs=dt_nominal_secs))


def size_update(x: FloatArray, P: FloatArray, *, lw: ArrayLike, r_diag: ArrayLike) -> Gaussian:
    """Update size filters with measured ``lw (B, 2)`` metres; ``r_diag (2,)`` or ``(B, 2)``."""
    z = np.asarray(lw, dtype=np.float64).reshape(-1, 2)
    return update(x, P, z, SIZE_H, diagonal_covariance(r_diag))


def align_heading(measured_yaw_rad: ArrayLike, predicted_yaw_rad: ArrayLike) -> FloatArray:
    """Flip measured yaws by pi where they differ from the prediction by more than pi/2.

    Detectors report the box axis with a 180° ambiguity; a box is symmetric, so the flipped yaw
    is the same box. Apply it to θ_det (after the predict, before the update).

    Parameters
    ----------
    measured_yaw_rad : (B,) radians.
    predicted_yaw_rad : (B,) radians, the predicted θ.

    Returns
    -------
    (B,) radians in (-pi, pi], within pi/2 of the prediction.
    """
    measured = np.asarray(measured_yaw_rad, dtype=np.float64)
    gap = np.abs(_wrap(measured - np.asarray(predicted_yaw_rad, dtype=np.float64)))
    return _wrap(np.where(gap > 0.5 * np.pi, measured + np.pi, measured))


def velocity_heading(
    velocity_xy: ArrayLike, *, min_speed_mps: float
) -> tuple[FloatArray, BoolArray]:
    """θ_vel = atan2(vy, vx), and whether it is meaningful (speed > ``min_speed_mps``).

    Parameters
    ----------
    velocity_xy : (B, 2) m/s: the detector's velocity (what the reference uses) or the pose
        filter's predicted velocity.
    min_speed_mps : speed threshold, m/s.

    Returns
    -------
    yaw_rad : (B,) radians in [-pi, pi] (0 for a zero vector; NaN rows are invalid).
    valid : (B,) bool.
    """
    v = np.asarray(velocity_xy, dtype=np.float64).reshape(-1, 2)
    speed = np.hypot(v[:, 0], v[:, 1])
    return np.arctan2(v[:, 1], v[:, 0]), speed > min_speed_mps


def heading_init(yaw_rad: ArrayLike, *, p0_diag: ArrayLike) -> Gaussian:
    """Initial heading states ``[wrap(yaw), 0]`` from ``yaw_rad (B,)``; ``P0 = diag(p0)``."""
    yaw = np.asarray(yaw_rad, dtype=np.float64).reshape(-1)
    x = np.zeros((len(yaw), 2))
    x[:, 0] = _wrap(yaw)
    return x, np.broadcast_to(diagonal_covariance(p0_diag), (len(yaw), 2, 2)).copy()


def heading_predict(
    x: FloatArray, P: FloatArray, *, dt_secs: ArrayLike, q_diag: ArrayLike, dt_nominal_secs: float
) -> Gaussian:
    """Predict heading filters by ``dt`` (θ += ω·dt, then wrap θ). Shapes (B, 2), (B, 2, 2)."""
    F = heading_transition(dt_secs)
    x, P = predict(x, P, F, process_noise(q_diag, dt_secs, dt_nominal_secs=dt_nominal_secs))
    x[:, 0] = _wrap(x[:, 0])
    return x, P


def heading_update(
    x: FloatArray,
    P: FloatArray,
    *,
    yaw_det_rad: ArrayLike,
    r_diag: ArrayLike,
    yaw_vel_rad: ArrayLike | None = None,
    yaw_vel_valid: ArrayLike | None = None,
) -> Gaussian:
    """Update heading filters with θ_det and θ_vel, both observations of θ.

    ``H = [[1, 0], [1, 0]]``. Both innovations and the resulting θ are wrapped to (-pi, pi], so
    a heading of 3.1 measured as -3.1 moves by about +0.083, not by -6.2. Rows where θ_vel is
    invalid are updated exactly as with θ_det alone.

    Parameters
    ----------
    x : (B, 2), P : (B, 2, 2) predicted heading filters.
    yaw_det_rad : (B,) detector yaw (aligned first with :func:`align_heading`).
    r_diag : (2,) or (B, 2) variances of [θ_det, θ_vel].
    yaw_vel_rad : (B,) heading of the velocity (:func:`velocity_heading`); None: not measured.
    yaw_vel_valid : (B,) bool, rows where θ_vel is used. Default: rows with a finite θ_vel.

    Returns
    -------
    x : (B, 2), P : (B, 2, 2).
    """
    yaw_det = np.asarray(yaw_det_rad, dtype=np.float64).reshape(-1)
    if yaw_vel_rad is None:
        yaw_vel = np.full_like(yaw_det, np.nan)
    else:
        yaw_vel = np.asarray(yaw_vel_rad, dtype=np.float64).reshape(-1)
    valid = np.isfinite(yaw_vel) if yaw_vel_valid is None else np.asarray(yaw_vel_valid, bool)
    mask = np.stack([np.ones_like(valid), valid], axis=-1)
    z = np.stack([yaw_det, yaw_vel], axis=-1)
    R = diagonal_covariance(r_diag)
    x, P = update(x, P, z, HEADING_H, R, mask=mask, innovation_wrap=[0, 1])
    x[:, 0] = _wrap(x[:, 0])
    return x, P


# ---------------------------------------------------------------------------------------------
# Fast path: the three filters as 5 independent axes, x (B, 5, k), P (B, 5, k, k)
# ---------------------------------------------------------------------------------------------

_IS_YAW = np.arange(N_AXES) == Axis.YAW  # (5,) the yaw axis: z1 (θ_vel) observes the value
_YAW_C = _IS_YAW.astype(np.float64)  # h1 = [c, 1 − c, (0)] per axis
_RATE_C = 1.0 - _YAW_C
_YAW_WRAP = np.stack([_IS_YAW, _IS_YAW], axis=-1)  # (5, 2) angular measurement components


def _axis_measurement_matrix(order: int) -> FloatArray:
    """(5, 2, k): row 0 observes the value; row 1 the rate (x, y, l, w) or the value (yaw)."""
    H = np.zeros((N_AXES, 2, order))
    H[:, 0, 0] = 1.0
    H[:, 1, 0] = _YAW_C
    H[:, 1, 1] = _RATE_C
    return H


_AXIS_H = {order: _axis_measurement_matrix(order) for order in (2, 3)}


def _pose_axes(diag: FloatArray, order: int, what: str) -> FloatArray:
    """Config order [x, y, vx, vy(, ax, ay)] -> axes (2, order)."""
    if diag.shape != (2 * order,):
        raise ValueError(f"pose {what} needs {2 * order} entries for this model, got {diag}")
    return diag.reshape(order, 2).T


def _pad(axes: FloatArray, order: int) -> FloatArray:
    """Pad (a, 2) [value, rate] blocks to (a, order) with zeros (no acceleration state)."""
    return np.pad(axes, ((0, 0), (0, order - axes.shape[1])))


def motion_noise(
    *, pose: DiagonalNoise, size: DiagonalNoise, heading: DiagonalNoise, model: MotionModel
) -> DiagonalNoise:
    """Per-axis noise of the fast path from the config's three filters (one category).

    Parameters
    ----------
    pose : P0 / Q (4 entries for CV, 6 for CA, order [x, y, vx, vy(, ax, ay)]) and R (2 entries
        [x, y], or 4 [x, y, vx, vy] when the detector gives velocity).
    size : P0 / Q [l, w, vl, vw], R [l, w].
    heading : P0 / Q [θ, ω], R [θ_det, θ_vel].
    model : pose motion model. With CA, size and heading get a zero-variance acceleration state
        that stays exactly 0, so they remain CV filters.

    Returns
    -------
    DiagonalNoise with p0_diag, q_diag (5, k) and r_diag (5, 2). Measurement slots that are never
    used (size rates; velocity with a 2-entry pose R) get a placeholder variance 1.
    """
    k = model.order
    if size.p0_diag.shape != (4,) or size.r_diag.shape != (2,):
        raise ValueError("size noise needs P0/Q [l, w, vl, vw] and R [l, w]")
    if heading.p0_diag.shape != (2,) or heading.r_diag.shape != (2,):
        raise ValueError("heading noise needs P0/Q [θ, ω] and R [θ_det, θ_vel]")
    if pose.r_diag.shape not in ((2,), (4,)):
        raise ValueError(f"pose R needs 2 or 4 entries, got {pose.r_diag}")

    def state_axes(name: str) -> FloatArray:
        return np.concatenate(
            [
                _pose_axes(getattr(pose, name), k, name),
                _pad(getattr(size, name).reshape(2, 2).T, k),
                _pad(getattr(heading, name)[None], k),
            ]
        )

    r_pose = pose.r_diag if pose.r_diag.shape == (4,) else np.r_[pose.r_diag, 1.0, 1.0]
    r_diag = np.concatenate(
        [r_pose.reshape(2, 2).T, np.stack([size.r_diag, np.ones(2)], -1), heading.r_diag[None]]
    )
    return DiagonalNoise(p0_diag=state_axes("p0_diag"), q_diag=state_axes("q_diag"), r_diag=r_diag)


def motion_init(
    *,
    xy: ArrayLike,
    lw: ArrayLike,
    yaw_rad: ArrayLike,
    p0_diag: ArrayLike,
    velocity_xy: ArrayLike | None = None,
) -> Gaussian:
    """Initial fast-path states from detections.

    Parameters
    ----------
    xy : (B, 2) centres, metres.
    lw : (B, 2) length and width, metres.
    yaw_rad : (B,) headings, radians.
    p0_diag : (5, k) or (B, 5, k) initial variances (:func:`motion_noise`); k sets the model.
    velocity_xy : (B, 2) detector velocity, m/s; None or NaN start at 0.

    Returns
    -------
    x : (B, 5, k) with ``x[:, axis] = [value, rate(, acc)]``: [x, vx(, ax)], [y, vy(, ay)],
        [l, 0], [w, 0], [wrap(yaw), 0]. P : (B, 5, k, k) diagonal.
    """
    p0 = np.asarray(p0_diag, dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    n_rows, k = len(xy), p0.shape[-1]
    x = np.zeros((n_rows, N_AXES, k))
    x[:, Axis.X : Axis.Y + 1, 0] = xy
    x[:, Axis.LENGTH : Axis.WIDTH + 1, 0] = np.asarray(lw, dtype=np.float64).reshape(-1, 2)
    x[:, Axis.YAW, 0] = _wrap(np.asarray(yaw_rad, dtype=np.float64).reshape(-1))
    if velocity_xy is not None:
        v = np.asarray(velocity_xy, dtype=np.float64).reshape(-1, 2)
        x[:, Axis.X : Axis.Y + 1, 1] = np.nan_to_num(v)
    P = np.broadcast_to(diagonal_covariance(p0), (n_rows, N_AXES, k, k)).copy()
    return x, P


def motion_predict(
    x: FloatArray, P: FloatArray, *, dt_secs: ArrayLike, q_diag: ArrayLike, dt_nominal_secs: float
) -> Gaussian:
    """Predict the pose, size and heading filters of every track by its own ``dt``.

    Equals :func:`pose_predict`, :func:`size_predict` and :func:`heading_predict` together.

    Parameters
    ----------
    x : (B, 5, k), P : (B, 5, k, k) (k = 2: CV, k = 3: CA).
    dt_secs : (B,) elapsed seconds per track (may differ per row), or one value for all rows
        (a tracker frame: then ``F`` is shared and the whole batch is two matrix products).
    q_diag : (5, k) or (B, 5, k) variances per nominal step (:func:`process_noise`).
    dt_nominal_secs : the config's frame period, seconds.

    Returns
    -------
    x : (B, 5, k) with the yaw wrapped to (-pi, pi], P : (B, 5, k, k).
    """
    dt = np.asarray(dt_secs, dtype=np.float64)
    q = np.asarray(q_diag, dtype=np.float64)
    if dt.size == 1:
        return _predict_shared_dt(x, P, dt.item(), q, dt_nominal_secs)
    dt = dt.reshape(-1, 1)  # (B, 1) broadcasts over axes
    if x.shape[-1] != 2:
        Q = diagonal_covariance(q * (dt / dt_nominal_secs)[..., None])
        F = axis_transition(dt, model=MotionModel.CA)
        x_new, P_new = predict(x, P, F, Q)
        x_new[:, Axis.YAW, 0] = _wrap(x_new[:, Axis.YAW, 0])
        return x_new, P_new
    tau = dt / dt_nominal_secs
    value, rate = x[..., 0], x[..., 1]
    p00, p01, p11 = P[..., 0, 0], P[..., 0, 1], P[..., 1, 1]
    # P = F P Fᵀ + Q with F = [[1, dt], [0, 1]], Q = diag(q)·dt/dt_nominal
    n01 = p01 + dt * p11
    n00 = p00 + dt * (p01 + n01) + q[..., 0] * tau  # p00 + 2 dt p01 + dt² p11 + q0
    n11 = p11 + q[..., 1] * tau
    new_value = value + dt * rate  # x = F x
    new_value[:, Axis.YAW] = _wrap(new_value[:, Axis.YAW])
    return _pack_cv(new_value, rate, n00, n01, n11)


def _predict_shared_dt(
    x: FloatArray, P: FloatArray, dt: float, q: FloatArray, dt_nominal_secs: float
) -> Gaussian:
    """:func:`motion_predict` when every row advances by the same ``dt``.

    Every axis block uses one F, so x = F x is one product of the stacked states with Fᵀ, and
    P = F P Fᵀ one product of the stacked vec(P) with F ⊗ F (only the upper triangle's columns,
    mirrored, so P stays exactly symmetric).
    """
    k = x.shape[-1]
    f_t, kron_upper = _shared_transition(dt, k)
    n = x.shape[0] * N_AXES
    x_new = (x.reshape(n, k) @ f_t).reshape(x.shape)  # x = F x
    upper = P.reshape(n, k * k) @ kron_upper  # F P Fᵀ, upper triangle
    # + Q = diag(q)·dt/dt_nominal
    if q.shape != x.shape:
        q = np.broadcast_to(q, x.shape)
    upper[:, _UPPER_DIAGONAL[k]] += q.reshape(n, k) * (dt / dt_nominal_secs)
    x_new[:, Axis.YAW, 0] = _wrap(x_new[:, Axis.YAW, 0])
    return x_new, upper[:, _UPPER_OF[k]].reshape(P.shape)


def _upper_layout(k: int) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """Row/column of the k(k+1)/2 upper-triangle entries, the position of each of the k² entries
    in that list ((i, j) and (j, i) share one), and the positions of the diagonal."""
    rows, cols = np.triu_indices(k)
    position = np.empty((k, k), dtype=np.int64)
    position[rows, cols] = position[cols, rows] = np.arange(len(rows))
    return rows, cols, position.reshape(-1), position[np.arange(k), np.arange(k)]


_UPPER = {k: _upper_layout(k) for k in (2, 3)}
_UPPER_OF = {k: layout[2] for k, layout in _UPPER.items()}
_UPPER_DIAGONAL = {k: layout[3] for k, layout in _UPPER.items()}


@functools.lru_cache(maxsize=32)
def _shared_transition(dt: float, k: int) -> tuple[FloatArray, FloatArray]:
    """Fᵀ (k, k) and the (k², k(k+1)/2) matrix mapping vec(P) to the upper triangle of F P Fᵀ:
    entry (i, j) is Σ_ab F[i, a] P[a, b] F[j, b]."""
    d1, d2 = _AXIS_D[k]
    F = np.eye(k) + dt * d1 + (dt * dt) * d2
    rows, cols = _UPPER[k][:2]
    kron_upper = np.einsum("ia,jb->abij", F, F).reshape(k * k, k, k)[:, rows, cols]
    return np.ascontiguousarray(F.T), np.ascontiguousarray(kron_upper)


def motion_update(
    x: FloatArray,
    P: FloatArray,
    *,
    r_diag: ArrayLike,
    xy: ArrayLike | None = None,
    lw: ArrayLike | None = None,
    yaw_det_rad: ArrayLike | None = None,
    velocity_xy: ArrayLike | None = None,
    velocity_valid: ArrayLike | None = None,
    yaw_vel_rad: ArrayLike | None = None,
    yaw_vel_valid: ArrayLike | None = None,
    align_yaw_det: bool = False,
) -> Gaussian:
    """Update the pose, size and heading filters of every row with its matched detection.

    Equals :func:`pose_update`, :func:`size_update` and :func:`heading_update` together. Pass
    only the matched rows (``x[rows]``); unmatched tracks are just predicted. The axes are
    independent, so a group whose measurement is None (``xy``, ``lw`` or ``yaw_det_rad``) keeps
    its predicted state exactly: the tracker updates the pose and size first and the heading
    afterwards, with θ_vel from the *updated* velocity.

    Parameters
    ----------
    x : (B, 5, k), P : (B, 5, k, k) predicted states.
    r_diag : (5, 2) or (B, 5, 2) variances (:func:`motion_noise`).
    xy : (B, 2) measured centres, metres, or None (x and y not updated).
    lw : (B, 2) measured length and width, metres, or None (size not updated).
    yaw_det_rad : (B,) detector yaw, or None (heading not updated).
    velocity_xy : (B, 2) detector velocity, m/s, or None (not measured).
    velocity_valid : (B,) bool; default: rows with a finite velocity.
    yaw_vel_rad : (B,) θ_vel (:func:`velocity_heading`), or None (not measured).
    yaw_vel_valid : (B,) bool; default: rows with a finite θ_vel.
    align_yaw_det : resolve the detector's 180° ambiguity against the predicted θ, i.e. the same
        as passing ``align_heading(yaw_det_rad, θ_pred)``, but folded into the innovation
        (taken modulo pi, in (-pi/2, pi/2]) at no extra cost.

    Returns
    -------
    x : (B, 5, k) with the yaw wrapped to (-pi, pi], P : (B, 5, k, k).
    """
    measured = (xy is not None, lw is not None, yaw_det_rad is not None)
    if not any(measured):
        return x.copy(), P.copy()
    axes, yaw = _AXES_OF[measured]  # yaw: column of the yaw axis among the updated ones
    z0, z1, m1, with_velocity = _motion_measurement(
        measured, len(x), xy, lw, yaw_det_rad, velocity_xy, velocity_valid, yaw_vel_rad,
        yaw_vel_valid,
    )  # fmt: skip
    r = np.asarray(r_diag, dtype=np.float64)[..., axes, :]
    x_sub, P_sub = x[:, axes], P[:, axes]
    if m1 is None or not m1.any():
        y0 = _innovation_values(z0, x_sub[..., 0], yaw, align_yaw_det)
        x_sub, P_sub = _value_update(x_sub, P_sub, y0, r[..., 0], yaw)
    elif not with_velocity:
        # Only θ_vel is second: θ_det and θ_vel both observe θ with independent noise, which is
        # one observation with the inverse-variance fused innovation (the same posterior).
        assert yaw is not None
        y0 = _innovation_values(z0, x_sub[..., 0], yaw, align_yaw_det)
        y1 = _wrap(z1 - x_sub[..., 0])  # zero weight outside the masked-in yaw entries
        r0, r1 = r[..., 0], r[..., 1]
        y_fused = np.where(m1, (r1 * y0 + r0 * y1) / (r0 + r1), y0)
        r_fused = np.where(m1, (r0 * r1) / (r0 + r1), r0)
        x_sub, P_sub = _value_update(x_sub, P_sub, y_fused, r_fused, yaw)
    elif x.shape[-1] == 2:
        x_sub, P_sub = _cv_axes_update(
            x_sub, P_sub, z0, z1, m1, r[..., 0], r[..., 1],
            axes=axes, yaw=yaw, align_yaw_det=align_yaw_det,
        )  # fmt: skip
    else:
        x_sub, P_sub = _generic_axes_update(
            x, x_sub, P_sub, z0, z1, m1, r, axes=axes, yaw=yaw, align_yaw_det=align_yaw_det
        )
    if axes is _ALL_AXES:
        return x_sub, P_sub
    x_new, P_new = x.copy(), P.copy()
    x_new[:, axes], P_new[:, axes] = x_sub, P_sub
    return x_new, P_new


_ALL_AXES = slice(0, N_AXES)
#: For each (xy, lw, yaw) combination measured: the axes updated, and the yaw axis' column
#: among them (None when the heading is not updated).
_AXES_OF: dict[tuple[bool, bool, bool], tuple[slice | IntArray, int | None]] = {
    (True, True, True): (_ALL_AXES, Axis.YAW),
    (True, True, False): (slice(Axis.X, Axis.WIDTH + 1), None),
    (False, True, True): (slice(Axis.LENGTH, N_AXES), 2),
    (True, False, False): (slice(Axis.X, Axis.Y + 1), None),
    (False, True, False): (slice(Axis.LENGTH, Axis.WIDTH + 1), None),
    (False, False, True): (slice(Axis.YAW, N_AXES), 0),
    (True, False, True): (np.array([Axis.X, Axis.Y, Axis.YAW]), 2),
}


def _value_update(
    x: FloatArray, P: FloatArray, y0: FloatArray, r0: FloatArray, yaw: int | None
) -> Gaussian:
    """Update of axes whose value alone is measured, H = [1, 0(, 0)], any k; y0 = z0 − value.

    Joseph form from rank-one terms: with P₀ = H P (P's first row), (I − K H) P = P − K P₀, and
    right-multiplying by (I − K H)ᵀ subtracts its first column times Kᵀ. Symmetrised, as
    :func:`update`.
    """
    s = P[..., 0, 0] + r0  # S = H P Hᵀ + R
    gain = P[..., 0, :] / s[..., None]  # K = P Hᵀ S⁻¹
    x_new = x + gain * y0[..., None]  # x = x + K y
    if yaw is not None:
        x_new[:, yaw, 0] = _wrap(x_new[:, yaw, 0])
    # P = (I − K H) P (I − K H)ᵀ + K R Kᵀ
    a_p = P - gain[..., :, None] * P[..., None, 0, :]
    P_new = a_p - a_p[..., :, :1] * gain[..., None, :]
    P_new += (r0[..., None, None] * gain[..., :, None]) * gain[..., None, :]
    return x_new, 0.5 * (P_new + P_new.mT)


def _generic_axes_update(
    x: FloatArray,
    x_sub: FloatArray,
    P_sub: FloatArray,
    z0: FloatArray,
    z1: FloatArray,
    m1: BoolArray,
    r: FloatArray,
    *,
    axes: slice | IntArray,
    yaw: int | None,
    align_yaw_det: bool,
) -> Gaussian:
    """Two measurements per axis by the generic :func:`update` (masked, wrapped): CA velocity."""
    if align_yaw_det and yaw is not None:
        z0[:, yaw] = align_heading(z0[:, yaw], x[:, Axis.YAW, 0])
    z = np.stack([z0, z1], axis=-1)
    mask = np.stack([np.ones_like(m1), m1], axis=-1)
    H = _AXIS_H[x.shape[-1]][axes]
    x_new, P_new = update(
        x_sub, P_sub, z, H, diagonal_covariance(r), mask=mask, innovation_wrap=_YAW_WRAP[axes]
    )
    if yaw is not None:
        x_new[:, yaw, 0] = _wrap(x_new[:, yaw, 0])
    return x_new, P_new


def _innovation_values(
    z0: FloatArray, value: FloatArray, yaw: int | None, align_yaw_det: bool
) -> FloatArray:
    """y0 = z0 − value, the yaw column wrapped to (-pi, pi] (or taken mod pi when aligning)."""
    y0 = z0 - value
    if yaw is not None:
        if align_yaw_det:  # θ_det is an axis (mod pi): innovation in (-pi/2, pi/2]
            y0[:, yaw] = 0.5 * np.pi - np.mod(0.5 * np.pi - y0[:, yaw], np.pi)
        else:
            y0[:, yaw] = _wrap(y0[:, yaw])
    return y0


def _motion_measurement(
    measured: tuple[bool, bool, bool],
    n_rows: int,
    xy: ArrayLike | None,
    lw: ArrayLike | None,
    yaw_det_rad: ArrayLike | None,
    velocity_xy: ArrayLike | None,
    velocity_valid: ArrayLike | None,
    yaw_vel_rad: ArrayLike | None,
    yaw_vel_valid: ArrayLike | None,
) -> tuple[FloatArray, FloatArray | None, BoolArray | None, bool]:
    """Measurements of the updated axes (in axis order): z0 (B, A) of the values, z1 (B, A)
    second slots with their mask m1 (None, None when no second slot is measured at all), and
    whether the velocity is among them."""
    has_xy, has_lw, has_yaw = measured
    values = []
    if has_xy:
        values.append(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
    if has_lw:
        values.append(np.asarray(lw, dtype=np.float64).reshape(-1, 2))
    if has_yaw:
        values.append(np.asarray(yaw_det_rad, dtype=np.float64).reshape(-1, 1))
    z0 = np.concatenate(values, axis=1) if len(values) > 1 else values[0].copy()
    with_velocity = has_xy and velocity_xy is not None
    with_yaw_vel = has_yaw and yaw_vel_rad is not None
    if not (with_velocity or with_yaw_vel):
        return z0, None, None, False
    z1 = np.zeros((n_rows, z0.shape[1]))
    m1 = np.zeros((n_rows, z0.shape[1]), dtype=bool)
    if with_velocity:  # x and y are the first two columns
        v = np.asarray(velocity_xy, dtype=np.float64).reshape(-1, 2)
        z1[:, :2] = v
        valid = np.isfinite(v).all(-1) if velocity_valid is None else velocity_valid
        m1[:, :2] = np.asarray(valid)[:, None]
    if with_yaw_vel:  # yaw is the last column
        yaw_vel = np.asarray(yaw_vel_rad, dtype=np.float64).reshape(-1)
        z1[:, -1] = yaw_vel
        m1[:, -1] = np.isfinite(yaw_vel) if yaw_vel_valid is None else yaw_vel_valid
    return z0, z1, m1, with_velocity


def _pack_cv(
    value: FloatArray, rate: FloatArray, p00: FloatArray, p01: FloatArray, p11: FloatArray
) -> Gaussian:
    """(B, A) components -> x (B, A, 2), P (B, A, 2, 2)."""
    x = np.empty((*value.shape, 2))
    x[..., 0], x[..., 1] = value, rate
    P = np.empty((*p00.shape, 2, 2))
    P[..., 0, 0], P[..., 0, 1], P[..., 1, 0], P[..., 1, 1] = p00, p01, p01, p11
    return x, P


def _cv_axes_update(
    x: FloatArray,
    P: FloatArray,
    z0: FloatArray,
    z1: FloatArray,
    m1: BoolArray,
    r0: FloatArray,
    r1: FloatArray,
    *,
    axes: slice | IntArray,
    yaw: int | None,
    align_yaw_det: bool,
) -> Gaussian:
    """Closed-form CV update of the axes ``x[:, axes]`` with two measurements,
    H = [[1, 0], [c, 1 − c]] (c = 1 on yaw), diagonal R; ``yaw`` is the column of the yaw axis
    among them (None: not updated).

    The second measurement is masked exactly where ``m1`` is False (zero H row, zero innovation,
    unit S entry: see :func:`update`). ``S`` is 2 × 2 SPD (``S ⪰ R ≻ 0``) and is solved by
    Cramer's rule, which is forward stable for 2 × 2 systems (Higham 2002, §1.10.1).
    """
    value, rate = x[..., 0], x[..., 1]
    p00, p01, p11 = P[..., 0, 0], P[..., 0, 1], P[..., 1, 1]
    # y = z − H x; the yaw innovations are wrapped to (-pi, pi]
    y0 = _innovation_values(z0, value, yaw, align_yaw_det)
    is_yaw, yaw_c, rate_c = _IS_YAW[axes], _YAW_C[axes], _RATE_C[axes]
    y1 = np.where(m1, z1 - np.where(is_yaw, value, rate), 0.0)
    if yaw is not None:
        y1[:, yaw] = _wrap(y1[:, yaw])
    # P Hᵀ = [[p00, g0], [p01, g1]] with g = P h1ᵀ (zero where z1 is masked)
    g0 = np.where(m1, np.where(is_yaw, p00, p01), 0.0)
    g1 = np.where(m1, np.where(is_yaw, p01, p11), 0.0)
    # S = H P Hᵀ + R = [[p00 + r0, g0], [g0, h1·g + r1]] (1 in place of h1·g + r1 where masked)
    s00 = p00 + r0
    s11 = np.where(m1, np.where(is_yaw, g0, g1) + r1, 1.0)
    inv_det = 1.0 / (s00 * s11 - g0 * g0)
    # K = P Hᵀ S⁻¹ by Cramer's rule (s01 = g0):
    # K[:, 0] = (P h0ᵀ s11 − g s01) / det, K[:, 1] = (g s00 − P h0ᵀ s01) / det
    k00 = (p00 * s11 - g0 * g0) * inv_det
    k10 = (p01 * s11 - g1 * g0) * inv_det
    k01 = g0 * r0 * inv_det  # (g0 s00 − p00 g0) / det
    k11 = (g1 * s00 - p01 * g0) * inv_det
    # x = x + K y
    new_value = value + k00 * y0 + k01 * y1
    new_rate = rate + k10 * y0 + k11 * y1
    if yaw is not None:
        new_value[:, yaw] = _wrap(new_value[:, yaw])
    # P = A P Aᵀ + K R Kᵀ with A = I − K H (Joseph); A = [[a00, a01], [a10, a11]]
    a00 = 1.0 - k00 - k01 * yaw_c
    a01 = -k01 * rate_c
    a10 = -k10 - k11 * yaw_c
    a11 = 1.0 - k11 * rate_c
    t00 = a00 * p00 + a01 * p01  # T = A P
    t01 = a00 * p01 + a01 * p11
    t10 = a10 * p00 + a11 * p01
    t11 = a10 * p01 + a11 * p11
    n00 = t00 * a00 + t01 * a01 + k00 * k00 * r0 + k01 * k01 * r1
    n01 = t00 * a10 + t01 * a11 + k00 * k10 * r0 + k01 * k11 * r1
    n11 = t10 * a10 + t11 * a11 + k10 * k10 * r0 + k11 * k11 * r1
    return _pack_cv(new_value, new_rate, n00, n01, n11)


def motion_xy(x: FloatArray) -> FloatArray:
    """(B, 2) centre [x, y] of fast-path states ``x (B, 5, k)`` (a view)."""
    return x[:, Axis.X : Axis.Y + 1, 0]


def motion_velocity_xy(x: FloatArray) -> FloatArray:
    """(B, 2) velocity [vx, vy], m/s (a view)."""
    return x[:, Axis.X : Axis.Y + 1, 1]


def motion_acceleration_xy(x: FloatArray) -> FloatArray:
    """(B, 2) acceleration [ax, ay], m/s² (CA only; NaN for CV, which has none)."""
    if x.shape[-1] < 3:
        return np.full((len(x), 2), np.nan)
    return x[:, Axis.X : Axis.Y + 1, 2]


def motion_lw(x: FloatArray) -> FloatArray:
    """(B, 2) filtered length and width, metres (a view)."""
    return x[:, Axis.LENGTH : Axis.WIDTH + 1, 0]


def motion_yaw_rad(x: FloatArray) -> FloatArray:
    """(B,) filtered heading, radians in (-pi, pi] (a view)."""
    return x[:, Axis.YAW, 0]
