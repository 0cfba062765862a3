"""Geometry shared by conversion, costs, writers and visualisation (all vectorised)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

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


# --- Rotated rectangles in BEV: the geometry behind the BEV costs -------------------------------
# Pair functions take P pairs as (P, 4, 2) corners and work internally in a (component, P) layout,
# so every numpy call runs one long contiguous loop over the pairs. Large P is processed in chunks
# to keep the temporaries small (in cache, and not mmap-allocated afresh by every numpy call).

_CHUNK_PAIRS = 512

#: "On the boundary" tolerance, relative to a pair's coordinate scale. float64 rounding noise is
#: ~1e-16 of the scale, so corners of touching, identical or nested boxes are kept; a point admitted
#: wrongly lies at most this far outside, which moves the area by ~1e-12 of the boxes' areas.
_BOUNDARY_RTOL = 1e-12

_NEXT = np.array([1, 2, 3, 0])  # corner k + 1 (mod 4)

# Corners b_j and a_i that a hull "bridge" can join (see min_area_rect_bev): for each corner j of B,
# the two corners of A at offsets 0 and 1 from j + quadrant(yaw_b - yaw_a).
_BRIDGE_J = np.repeat(np.arange(4), 2)
_BRIDGE_OFFSET = np.tile(np.arange(2), 4)[:, None]  # (8, 1)


def _paired_corners(corners_a: ArrayLike, corners_b: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Both (P, 4, 2) corner sets as (4, 2, P), translated so A's centre is the origin.

    Working relative to A keeps full float64 precision for world coordinates far from 0.
    """
    a = np.asarray(corners_a, dtype=np.float64).reshape(-1, 4, 2)
    b = np.asarray(corners_b, dtype=np.float64).reshape(-1, 4, 2)
    if a.shape != b.shape:
        raise ValueError(f"corner pairs: shapes {a.shape} and {b.shape} differ")
    origin = 0.5 * (a[:, 0] + a[:, 2])  # (P, 2)
    a_t = (a - origin[:, None]).transpose(1, 2, 0)
    b_t = (b - origin[:, None]).transpose(1, 2, 0)
    return np.ascontiguousarray(a_t), np.ascontiguousarray(b_t)


def _chunked(
    fn: Callable[[FloatArray, FloatArray], tuple[FloatArray, ...]],
    corners_a: ArrayLike,
    corners_b: ArrayLike,
    *,
    n_outputs: int,
) -> tuple[FloatArray, ...]:
    """Apply ``fn`` to (4, 2, p) chunks of the pairs; concatenate its ``n_outputs`` (p,) arrays."""
    a, b = _paired_corners(corners_a, corners_b)
    n_pairs = a.shape[-1]
    if n_pairs == 0:
        return tuple(np.zeros(0) for _ in range(n_outputs))
    if n_pairs <= _CHUNK_PAIRS:
        return fn(a, b)
    parts = [
        fn(a[..., s : s + _CHUNK_PAIRS], b[..., s : s + _CHUNK_PAIRS])
        for s in range(0, n_pairs, _CHUNK_PAIRS)
    ]
    return tuple(np.concatenate(outs) for outs in zip(*parts, strict=True))


def _inside_convex(
    px: FloatArray, py: FloatArray, poly: FloatArray, edges: FloatArray, slack: FloatArray
) -> NDArray[np.bool_]:
    """(K, p) whether points (K, p) lie in the CCW quads ``poly`` (4, 2, p), boundary included.

    ``slack`` (4, p) is the tolerance times each edge's length.
    """
    # Left of (or on) every edge: cross(edge_k, point - corner_k) >= -tol · |edge_k|.
    ex, ey = edges[:, 0, None], edges[:, 1, None]  # (4, 1, p)
    cross = ex * (py - poly[:, 1, None]) - ey * (px - poly[:, 0, None])  # (4, K, p)
    return np.all(cross >= -slack[:, None], axis=0)


def _shoelace(x: FloatArray, y: FloatArray) -> FloatArray:
    """Signed area of polygons given as (K, p) vertex coordinates (positive when CCW)."""
    x_next = np.concatenate([x[1:], x[:1]])
    y_next = np.concatenate([y[1:], y[:1]])
    return 0.5 * np.sum(x * y_next - x_next * y, axis=0)


def _intersection_area(a: FloatArray, b: FloatArray) -> tuple[FloatArray]:
    """Intersection areas of quads (4, 2, p) ``a`` and ``b``; see :func:`intersection_area_bev`."""
    n_pairs = a.shape[-1]
    tol = _BOUNDARY_RTOL * np.maximum(np.abs(a).max(axis=(0, 1)), np.abs(b).max(axis=(0, 1)))
    edges_a = a[_NEXT] - a  # edge k runs from corner k to corner k + 1
    edges_b = b[_NEXT] - b
    len_sq_b = edges_b[:, 0] ** 2 + edges_b[:, 1] ** 2  # (4, p)
    slack_b = tol * np.sqrt(len_sq_b)
    a_in_b = _inside_convex(a[:, 0], a[:, 1], b, edges_b, slack_b)  # (4, p)
    slack_a = tol * np.hypot(edges_a[:, 0], edges_a[:, 1])
    b_in_a = _inside_convex(b[:, 0], b[:, 1], a, edges_a, slack_a)

    # Edge i of A, a_i + t r with t in [0, 1], meets the line of edge j of B, b_j + u s, at
    # t = (q × s) / (r × s), q = b_j - a_i. Parallel edges give no crossing (the ends of their
    # overlap are corners, found above). For nearly parallel edges t is noise, so a crossing is
    # accepted by where it lands: on B's edge (0 <= u <= 1, and on its line within tolerance).
    # Any such point of A's edge is on the intersection's boundary, whatever t was.
    rx, ry = edges_a[:, None, 0], edges_a[:, None, 1]  # (4, 1, p)
    sx, sy = edges_b[None, :, 0], edges_b[None, :, 1]  # (1, 4, p)
    qx = b[None, :, 0] - a[:, None, 0]  # (4, 4, p)
    qy = b[None, :, 1] - a[:, None, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qx * sy - qy * sx) / (rx * sy - ry * sx)
    on_a = (t >= -_BOUNDARY_RTOL) & (t <= 1.0 + _BOUNDARY_RTOL)  # False for NaN/inf
    t = np.clip(np.where(on_a, t, 0.0), 0.0, 1.0)
    ox, oy = t * rx - qx, t * ry - qy  # crossing - b_j
    u_len_sq = ox * sx + oy * sy  # u · |s|²
    on_b = (
        (u_len_sq >= -_BOUNDARY_RTOL * len_sq_b)
        & (u_len_sq <= (1.0 + _BOUNDARY_RTOL) * len_sq_b)
        & (np.abs(sx * oy - sy * ox) <= slack_b)
    )

    px = np.concatenate([a[:, 0], b[:, 0], (ox + b[None, :, 0]).reshape(16, n_pairs)])  # (24, p)
    py = np.concatenate([a[:, 1], b[:, 1], (oy + b[None, :, 1]).reshape(16, n_pairs)])
    valid = np.concatenate([a_in_b, b_in_a, (on_a & on_b).reshape(16, n_pairs)])
    count = valid.sum(axis=0)
    weight = valid / np.maximum(count, 1)
    px -= np.sum(px * weight, axis=0)  # centred on the centroid of the valid points
    py -= np.sum(py * weight, axis=0)
    order = np.argsort(np.where(valid, np.arctan2(py, px), np.inf), axis=0)
    flat = (order * n_pairs + np.arange(n_pairs)).ravel()
    px, py, valid = (v.ravel()[flat].reshape(24, n_pairs) for v in (px, py, valid))
    # Invalid slots (sorted last) repeat the first vertex: they add zero-length edges only.
    px = np.where(valid, px, px[0])
    py = np.where(valid, py, py[0])
    area = np.where(count >= 3, np.maximum(_shoelace(px, py), 0.0), 0.0)
    smaller = np.minimum(_shoelace(a[:, 0], a[:, 1]), _shoelace(b[:, 0], b[:, 1]))
    return (np.minimum(area, np.maximum(smaller, 0.0)),)


def intersection_area_bev(corners_a: ArrayLike, corners_b: ArrayLike) -> FloatArray:
    """Intersection area of P pairs of convex quadrilaterals (pair p is ``a[p]`` with ``b[p]``).

    The intersection of two convex polygons is the convex hull of: the corners of A inside B,
    the corners of B inside A, and the crossings of A's edges with B's edges. Those points all lie
    on its boundary, so sorting them by angle about their centroid gives the polygon, and the
    shoelace formula its area.

    Parameters
    ----------
    corners_a, corners_b : (P, 4, 2)
        Counter-clockwise corners, metres (as from :func:`corners_bev`).

    Returns
    -------
    (P,) intersection areas in m², exact to float64 rounding, including touching, identical,
    nested and disjoint pairs (those give 0 or the smaller area exactly, not cv2's float32).
    """
    (area,) = _chunked(_intersection_area, corners_a, corners_b, n_outputs=1)
    return area


def pairwise_intersection_area_bev(corners_a: ArrayLike, corners_b: ArrayLike) -> FloatArray:
    """(M, N) intersection areas of each quad of ``corners_a`` (M, 4, 2) with each of (N, 4, 2)."""
    a = np.asarray(corners_a, dtype=np.float64).reshape(-1, 4, 2)
    b = np.asarray(corners_b, dtype=np.float64).reshape(-1, 4, 2)
    rows, cols = np.divmod(np.arange(len(a) * len(b)), max(len(b), 1))
    return intersection_area_bev(a[rows], b[cols]).reshape(len(a), len(b))


def _half_axes(h: FloatArray, g: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Longer half-axis vector (2, p), its length and the shorter/longer length ratio (p,)."""
    len_h, len_g = np.hypot(h[0], h[1]), np.hypot(g[0], g[1])
    h_is_long = len_h >= len_g
    half_long, half_short = np.maximum(len_h, len_g), np.minimum(len_h, len_g)
    ratio = half_short / np.where(half_long > 0, half_long, 1.0)  # 0 for a point
    return np.where(h_is_long, h, g), half_long, ratio


def _min_area_rect(a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Enclosing-rectangle area and squared diagonal; see :func:`min_area_rect_bev`."""
    ha, hb = 0.5 * (a[0] - a[1]), 0.5 * (b[0] - b[1])  # half-axes along corner 1 -> 0
    # Quadrant of B's heading relative to A's: B's corner j has the normal cone of A's corner
    # j + quadrant, turned by the remainder, so it overlaps the cones of A's corners j + quadrant
    # and j + quadrant + 1 only.
    dot = ha[0] * hb[0] + ha[1] * hb[1]
    crs = ha[0] * hb[1] - ha[1] * hb[0]
    upper = (crs > 0) | ((crs == 0) & (dot >= 0))
    quadrant = np.where(upper, np.where(dot > 0, 0, 1), np.where(dot < 0, 2, 3))
    i = (_BRIDGE_J[:, None] + quadrant + _BRIDGE_OFFSET) & 3  # (8, p), mod 4
    n_pairs = a.shape[-1]
    flat_i = (i * (2 * n_pairs) + np.arange(n_pairs)).ravel()  # into a.reshape(-1)
    bridge_x = b[_BRIDGE_J, 0] - a.reshape(-1)[flat_i].reshape(8, n_pairs)
    bridge_y = b[_BRIDGE_J, 1] - a.reshape(-1)[flat_i + n_pairs].reshape(8, n_pairs)

    # Work in A's frame (x along A's longer axis), where A is [-la, la] × [-wa, wa]. A rectangle
    # with longer half-axis h and width ratio k has support |h·u| + k |h × u| along u (and
    # |h × u| + k |h·u| along the normal): no unit vectors needed, degenerate boxes are fine.
    long_a, la, ka = _half_axes(ha, 0.5 * (a[0] - a[3]))
    safe_la = np.where(la > 0, la, 1.0)
    ux = np.where(la > 0, long_a[0] / safe_la, 1.0)  # A's axis, unit ((1, 0) for a point)
    uy = long_a[1] / safe_la
    wa = ka * la
    long_b, _, kb = _half_axes(hb, 0.5 * (b[0] - b[3]))
    hbx, hby = ux * long_b[0] + uy * long_b[1], ux * long_b[1] - uy * long_b[0]
    centre_b = 0.5 * (b[0] + b[2])
    dx, dy = ux * centre_b[0] + uy * centre_b[1], ux * centre_b[1] - uy * centre_b[0]
    # Candidate sides u: A's axis (1, 0), B's axis, and the 8 bridges, all in A's frame.
    ex, ey = np.empty((10, n_pairs)), np.empty((10, n_pairs))
    ex[0], ey[0], ex[1], ey[1] = 1.0, 0.0, hbx, hby
    ex[2:] = ux * bridge_x + uy * bridge_y
    ey[2:] = ux * bridge_y - uy * bridge_x

    # Everything below is scaled by |u| (u is not normalised): areas by |u|², fixed at the end.
    abs_ex, abs_ey = np.abs(ex), np.abs(ey)
    a_u, a_n = la * abs_ex + wa * abs_ey, la * abs_ey + wa * abs_ex  # A's half-extents
    along = np.abs(hbx * ex + hby * ey)
    across = np.abs(hbx * ey - hby * ex)
    b_u, b_n = along + kb * across, across + kb * along  # B's half-extents

    def extent(offset: FloatArray, half_a: FloatArray, half_b: FloatArray) -> FloatArray:
        # A spans ±half_a, B spans offset ± half_b: max - min of the union.
        return np.maximum(half_a, offset + half_b) + np.maximum(half_a, half_b - offset)

    ext_u = extent(dx * ex + dy * ey, a_u, b_u)
    ext_n = extent(dx * ey - dy * ex, a_n, b_n)
    norm_sq = ex * ex + ey * ey
    area = np.divide(ext_u * ext_n, norm_sq, out=np.full_like(norm_sq, np.inf), where=norm_sq > 0)
    flat = np.argmin(area, axis=0) * n_pairs + np.arange(n_pairs)
    ext_u, ext_n, norm_sq = ext_u.ravel()[flat], ext_n.ravel()[flat], norm_sq.ravel()[flat]
    # The first candidate (A's axis) has |u| = 1, so norm_sq > 0 here.
    return ext_u * ext_n / norm_sq, (ext_u**2 + ext_n**2) / norm_sq


def min_area_rect_bev(corners_a: ArrayLike, corners_b: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Minimum-area rectangle enclosing both rectangles of a pair (what ``cv2.minAreaRect`` gives).

    The optimal rectangle has a side on an edge of the convex hull of the 8 corners (rotating
    calipers). Hull edges are edges of A or B (two rectangle orientations) or "bridges" from a
    corner a_i to a corner b_j whose line supports both boxes: a_i and b_j are then extreme along
    the same normal, so their normal cones (90° each) overlap. Which cones overlap depends only on
    the quadrant of yaw_b - yaw_a: 8 of the 16 corner pairs. We evaluate those 10 directions
    exactly; C = min over directions of extent_u · extent_v.

    Parameters
    ----------
    corners_a, corners_b : (P, 4, 2)
        Rectangle corners in consecutive order (as from :func:`corners_bev`), metres.

    Returns
    -------
    area : (P,) C, the rectangle's area, m².
    diag_sq : (P,) d², its squared diagonal, m².
    """
    area, diag_sq = _chunked(_min_area_rect, corners_a, corners_b, n_outputs=2)
    return area, diag_sq
