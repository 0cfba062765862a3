"""Compiled in-image fraction of coasting boxes (numpy reference:
:func:`tracker.camera.in_image_fraction`)."""

from __future__ import annotations

import math

import numba
import numpy as np

from tracker.boxes import FloatArray
from tracker.kernels._common import _F1, _F2
from tracker.kernels.geometry import _corners


@numba.njit(
    (_F2, _F2, _F1, _F2, numba.float64, numba.float64, numba.float64),
    cache=True,
    error_model="numpy",
    nogil=True,
)
def in_image_fraction_kernel(
    xyz: FloatArray,
    lwh: FloatArray,
    yaw: FloatArray,
    image_from_world: FloatArray,
    max_x: float,
    max_y: float,
    near_m: float,
) -> FloatArray:  # pragma: no cover (compiled)
    """Per box, the fraction of its projected 2D box's width inside ``[0, max_x]``, 0 when
    the clipped box has no area; NaN when a corner lies behind the near plane (the caller
    then uses the numpy reference, which clips the edges)."""
    n = xyz.shape[0]
    m = image_from_world
    bev = np.empty((n, 5))  # x, y, l, w, yaw
    bev[:, :2], bev[:, 2:4], bev[:, 4] = xyz[:, :2], lwh[:, :2], yaw
    corners = _corners(bev)  # (N, 4, 2), bottom and top share them
    out = np.empty(n)
    for i in range(n):
        hh = lwh[i, 2] / 2.0
        x1 = y1 = math.inf
        x2 = y2 = -math.inf
        behind = False
        for k in range(8):
            px, py = corners[i, k % 4, 0], corners[i, k % 4, 1]
            pz = xyz[i, 2] - hh if k < 4 else xyz[i, 2] + hh
            w = px * m[2, 0] + py * m[2, 1] + pz * m[2, 2] + m[2, 3]
            if not w >= near_m:
                behind = True
                break
            u = (px * m[0, 0] + py * m[0, 1] + pz * m[0, 2] + m[0, 3]) / w
            v = (px * m[1, 0] + py * m[1, 1] + pz * m[1, 2] + m[1, 3]) / w
            x1, x2, y1, y2 = min(x1, u), max(x2, u), min(y1, v), max(y2, v)
        if behind:
            out[i] = math.nan
            continue
        cx1, cx2 = min(max(x1, 0.0), max_x), min(max(x2, 0.0), max_x)
        cy1, cy2 = min(max(y1, 0.0), max_y), min(max(y2, 0.0), max_y)
        if cx2 > cx1 and cy2 > cy1:
            out[i] = (min(x2, max_x) - max(x1, 0.0)) / max(x2 - x1, 1e-9)
        else:
            out[i] = 0.0
    return out
