"""Geometry shared by conversion, costs, writers and visualisation (all vectorised)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from tracker.boxes import FloatArray

TWO_PI = 2.0 * np.pi


def wrap_angle(angle_rad: ArrayLike) -> FloatArray:
    """Wrap angles to (-pi, pi]. Angles already in range are returned bit-for-bit unchanged."""
    a = np.asarray(angle_rad, dtype=np.float64)
    wrapped = np.mod(a + np.pi, TWO_PI) - np.pi  # in [-pi, pi)
    wrapped = np.where(wrapped <= -np.pi, wrapped + TWO_PI, wrapped)
    return np.where((a > np.pi) | (a <= -np.pi), wrapped, a)


def corners_bev(xy: ArrayLike, lw: ArrayLike, yaw_rad: ArrayLike) -> FloatArray:
    """(N, 4, 2) BEV corners, counter-clockwise: front-left, rear-left, rear-right, front-right."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    lw = np.asarray(lw, dtype=np.float64).reshape(-1, 2)
    yaw = np.asarray(yaw_rad, dtype=np.float64).reshape(-1)
    half_l, half_w = lw[:, 0:1] / 2.0, lw[:, 1:2] / 2.0
    local = np.stack(
        [
            np.hstack([half_l, half_w]),
            np.hstack([-half_l, half_w]),
            np.hstack([-half_l, -half_w]),
            np.hstack([half_l, -half_w]),
        ],
        axis=1,
    )  # (N, 4, 2)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    x = local[..., 0] * c - local[..., 1] * s
    y = local[..., 0] * s + local[..., 1] * c
    return np.stack([x, y], axis=-1) + xy[:, None, :]


def corners_3d(xyz: ArrayLike, lwh: ArrayLike, yaw_rad: ArrayLike) -> FloatArray:
    """(N, 8, 3) corners in the world frame: the 4 BEV corners at the bottom, then at the top."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    lwh = np.asarray(lwh, dtype=np.float64).reshape(-1, 3)
    bev = corners_bev(xyz[:, :2], lwh[:, :2], yaw_rad)  # (N, 4, 2)
    z_bottom = (xyz[:, 2] - lwh[:, 2] / 2.0)[:, None, None]
    z_top = (xyz[:, 2] + lwh[:, 2] / 2.0)[:, None, None]
    bottom = np.concatenate([bev, np.broadcast_to(z_bottom, (len(xyz), 4, 1))], axis=-1)
    top = np.concatenate([bev, np.broadcast_to(z_top, (len(xyz), 4, 1))], axis=-1)
    return np.concatenate([bottom, top], axis=1)


#: The 12 edges of a box from :func:`corners_3d`, as index pairs (for wireframes).
BOX_EDGES: tuple[tuple[int, int], ...] = (
    (0, 1), (1, 2), (2, 3), (3, 0),
    (4, 5), (5, 6), (6, 7), (7, 4),
    (0, 4), (1, 5), (2, 6), (3, 7),
)  # fmt: skip


def transform_points(matrix_4x4: ArrayLike, points: ArrayLike) -> FloatArray:
    """Apply a 4x4 rigid transform to (..., 3) points."""
    m = np.asarray(matrix_4x4, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    return p @ m[:3, :3].T + m[:3, 3]


def yaw_of_rotation(rotation_3x3: ArrayLike) -> float:
    """Heading of a rotation's x axis projected on the xy plane (radians)."""
    r = np.asarray(rotation_3x3, dtype=np.float64)
    return float(np.arctan2(r[1, 0], r[0, 0]))
