"""Geometry shared by conversion, costs, writers and visualisation (all vectorised)."""

from __future__ import annotations

import functools
import os
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from tracker.boxes import FloatArray, IntArray

TWO_PI = 2.0 * np.pi


def wrap_angle(angle_rad: ArrayLike) -> FloatArray:
    """Wrap angles to (-pi, pi]. Angles already in range are returned bit-for-bit unchanged."""
    a = np.asarray(angle_rad, dtype=np.float64)
    if a.size == 0 or np.abs(a).max() < np.pi:  # inside the range, the usual case (NaN: not)
        return a.copy()
    wrapped = np.mod(a + np.pi, TWO_PI) - np.pi  # in [-pi, pi)
    wrapped = np.where(wrapped <= -np.pi, wrapped + TWO_PI, wrapped)
    return np.where((a > np.pi) | (a <= -np.pi), wrapped, a)


def corners_bev(xy: ArrayLike, lw: ArrayLike, yaw_rad: ArrayLike) -> FloatArray:
    """(N, 4, 2) BEV corners, counter-clockwise: front-left, rear-left, rear-right, front-right."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    lw = np.asarray(lw, dtype=np.float64).reshape(-1, 2)
    yaw = np.asarray(yaw_rad, dtype=np.float64).reshape(-1, 1)
    # local corners (±l/2, ±w/2) in the box frame (a sign flip is exact), then rotated
    local_x = (lw[:, 0:1] / 2.0) * _CORNER_SIGN_L  # (N, 4)
    local_y = (lw[:, 1:2] / 2.0) * _CORNER_SIGN_W
    c, s = np.cos(yaw), np.sin(yaw)
    corners = np.empty((len(xy), 4, 2))
    corners[..., 0] = local_x * c - local_y * s + xy[:, 0:1]
    corners[..., 1] = local_x * s + local_y * c + xy[:, 1:2]
    return corners


_CORNER_SIGN_L = np.array([1.0, -1.0, -1.0, 1.0])
_CORNER_SIGN_W = np.array([1.0, 1.0, -1.0, -1.0])


def corners_3d(xyz: ArrayLike, lwh: ArrayLike, yaw_rad: ArrayLike) -> FloatArray:
    """(N, 8, 3) corners in the world frame: the 4 BEV corners at the bottom, then at the top."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    lwh = np.asarray(lwh, dtype=np.float64).reshape(-1, 3)
    bev = corners_bev(xyz[:, :2], lwh[:, :2], yaw_rad)  # (N, 4, 2)
    half_h = lwh[:, 2:3] / 2.0
    corners = np.empty((len(xyz), 8, 3))
    corners[:, :4, :2] = bev
    corners[:, 4:, :2] = bev
    corners[:, :4, 2] = xyz[:, 2:3] - half_h
    corners[:, 4:, 2] = xyz[:, 2:3] + half_h
    return corners


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
    finite = np.isfinite(a).all(axis=(0, 1)) & np.isfinite(b).all(axis=(0, 1))
    if not finite.all():  # computed as points (no warnings), reported as NaN
        a, b = np.where(finite, a, 0.0), np.where(finite, b, 0.0)
    if n_pairs <= _CHUNK_PAIRS:
        outs = fn(a, b)
    else:
        parts = [
            fn(a[..., s : s + _CHUNK_PAIRS], b[..., s : s + _CHUNK_PAIRS])
            for s in range(0, n_pairs, _CHUNK_PAIRS)
        ]
        outs = tuple(np.concatenate(chunks) for chunks in zip(*parts, strict=True))
    if not finite.all():
        outs = tuple(np.where(finite, out, np.nan) for out in outs)
    return outs


def _shoelace(x: FloatArray, y: FloatArray) -> FloatArray:
    """Signed area of polygons given as (K, p) vertex coordinates (positive when CCW)."""
    x_next = np.concatenate([x[1:], x[:1]])
    y_next = np.concatenate([y[1:], y[:1]])
    return 0.5 * np.sum(x * y_next - x_next * y, axis=0)


def _to_frame(
    x: FloatArray, y: FloatArray, ux: FloatArray, uy: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Coordinates of points (x, y) in the frame whose x axis is the unit vector (ux, uy)."""
    return ux * x + uy * y, ux * y - uy * x


def _rect_frame(r: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Unit length axis (ux, uy) and half length/width of rectangles (4, 2, p)."""
    hx, hy = 0.5 * (r[0, 0] - r[1, 0]), 0.5 * (r[0, 1] - r[1, 1])
    half_l = np.hypot(hx, hy)
    half_w = 0.5 * np.hypot(r[0, 0] - r[3, 0], r[0, 1] - r[3, 1])
    safe = np.where(half_l > 0, half_l, 1.0)
    return np.where(half_l > 0, hx / safe, 1.0), hy / safe, half_l, half_w


# Corners of a rectangle [-l, l] × [-w, w] in its own frame, counter-clockwise.
_SIGN_L = np.array([1.0, -1.0, -1.0, 1.0])[:, None]
_SIGN_W = np.array([1.0, 1.0, -1.0, -1.0])[:, None]


def _intersection_area(a: FloatArray, b: FloatArray) -> tuple[FloatArray]:
    """Intersection areas of rectangles (4, 2, p); see :func:`intersection_area_bev`."""
    n_pairs = a.shape[-1]
    area = np.zeros(n_pairs)
    # In A's frame A is the box [-la, la] × [-wa, wa]; in B's frame B is [-lb, lb] × [-wb, wb].
    ux, uy, la, wa = _rect_frame(a)
    bx, by = _to_frame(b[:, 0], b[:, 1], ux, uy)  # (4, p) B's corners in A's frame
    vx, vy = _to_frame(b[0, 0] - b[1, 0], b[0, 1] - b[1, 1], ux, uy)  # B's axis, length 2 lb
    lb = 0.5 * np.hypot(vx, vy)
    wb = 0.5 * np.hypot(b[0, 0] - b[3, 0], b[0, 1] - b[3, 1])
    safe = np.where(lb > 0, 2.0 * lb, 1.0)
    vx, vy = np.where(lb > 0, vx / safe, 1.0), vy / safe
    centre_x, centre_y = 0.5 * (bx[0] + bx[2]), 0.5 * (by[0] + by[2])
    # A's corners in B's frame (relative to B's centre).
    ax, ay = _to_frame(_SIGN_L * la - centre_x, _SIGN_W * wa - centre_y, vx, vy)

    # Separating axes (A's and B's): strictly apart means no overlap, the area is exactly 0.
    apart = (
        (bx.max(axis=0) < -la) | (bx.min(axis=0) > la) | (by.max(axis=0) < -wa)
        | (by.min(axis=0) > wa) | (ax.max(axis=0) < -lb) | (ax.min(axis=0) > lb)
        | (ay.max(axis=0) < -wb) | (ay.min(axis=0) > wb) | (la * wa * lb * wb == 0)
    )  # fmt: skip
    keep = np.flatnonzero(~apart)
    if len(keep) == 0:
        return (area,)
    la, wa, lb, wb = la[keep], wa[keep], lb[keep], wb[keep]
    bx, by, ax, ay = bx[:, keep], by[:, keep], ax[:, keep], ay[:, keep]
    k = len(keep)
    tol = _BOUNDARY_RTOL * (la + wa + lb + wb + np.abs(centre_x[keep]) + np.abs(centre_y[keep]))

    b_in_a = (np.abs(bx) <= la + tol) & (np.abs(by) <= wa + tol)  # (4, k)
    a_in_b = (np.abs(ax) <= lb + tol) & (np.abs(ay) <= wb + tol)

    # B's edge j, b_j + t e_j (t in [0, 1]), crosses A's side x = ±la at t = (±la - bx_j) / ex_j
    # (and y = ±wa likewise). The crossing is placed exactly on A's side: for a nearly parallel
    # edge t is noise, but the edge then lies on the side line, so any t in [0, 1] gives a point
    # of the intersection's boundary. It counts if it is within the side's extent.
    ex, ey = bx[_NEXT] - bx, by[_NEXT] - by
    side_l = np.concatenate([la[None], -la[None]])[:, None]  # (2, 1, k): x = ±la
    side_w = np.concatenate([wa[None], -wa[None]])[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_l = (side_l - bx) / ex  # (2, 4, k)
        t_w = (side_w - by) / ey
    ok_l = (t_l >= -_BOUNDARY_RTOL) & (t_l <= 1.0 + _BOUNDARY_RTOL)  # False for NaN/inf
    ok_w = (t_w >= -_BOUNDARY_RTOL) & (t_w <= 1.0 + _BOUNDARY_RTOL)
    y_l = by + np.clip(np.where(ok_l, t_l, 0.0), 0.0, 1.0) * ey
    x_w = bx + np.clip(np.where(ok_w, t_w, 0.0), 0.0, 1.0) * ex
    ok_l &= np.abs(y_l) <= wa + tol
    ok_w &= np.abs(x_w) <= la + tol

    px = np.concatenate([bx, _SIGN_L * la, np.broadcast_to(side_l, (2, 4, k)).reshape(8, k)])
    py = np.concatenate([by, _SIGN_W * wa, y_l.reshape(8, k)])
    px = np.concatenate([px, x_w.reshape(8, k)])  # (24, k)
    py = np.concatenate([py, np.broadcast_to(side_w, (2, 4, k)).reshape(8, k)])
    valid = np.concatenate([b_in_a, a_in_b, ok_l.reshape(8, k), ok_w.reshape(8, k)])

    # All candidates lie on the boundary of the convex intersection: sort them by angle about
    # their centroid and take the shoelace area.
    count = valid.sum(axis=0)
    weight = valid / np.maximum(count, 1)
    px -= np.sum(px * weight, axis=0)
    py -= np.sum(py * weight, axis=0)
    order = np.argsort(np.where(valid, np.arctan2(py, px), np.inf), axis=0)
    flat = (order * k + np.arange(k)).ravel()
    px, py, valid = (v.ravel()[flat].reshape(24, k) for v in (px, py, valid))
    # Invalid slots (sorted last) repeat the first vertex: they add zero-length edges only.
    px = np.where(valid, px, px[0])
    py = np.where(valid, py, py[0])
    inter = np.where(count >= 3, np.maximum(_shoelace(px, py), 0.0), 0.0)
    area[keep] = np.minimum(inter, 4.0 * np.minimum(la * wa, lb * wb))
    return (area,)


def intersection_area_bev(corners_a: ArrayLike, corners_b: ArrayLike) -> FloatArray:
    """Intersection area of P pairs of rectangles (pair p is ``a[p]`` with ``b[p]``).

    The intersection of two convex polygons is the convex hull of: the corners of A inside B,
    the corners of B inside A, and the crossings of A's edges with B's edges. Those points all lie
    on its boundary, so sorting them by angle about their centroid gives the polygon, and the
    shoelace formula its area. Each test is done in the frame of the rectangle it concerns, where
    that rectangle is axis-aligned; pairs apart along one of the 4 axes (separating axis theorem)
    are 0 without further work.

    Parameters
    ----------
    corners_a, corners_b : (P, 4, 2)
        Rectangle corners in consecutive order (as from :func:`corners_bev`), metres.

    Returns
    -------
    (P,) intersection areas in m², exact to float64 rounding, including touching, identical,
    nested and disjoint pairs (those give 0 or the smaller area exactly, not cv2's float32).
    NaN where a corner is not finite.
    """
    (area,) = _chunked(_intersection_area, corners_a, corners_b, n_outputs=1)
    return area


def pairwise_intersection_area_bev(corners_a: ArrayLike, corners_b: ArrayLike) -> FloatArray:
    """(M, N) intersection areas of every rectangle in ``corners_a`` (M, 4, 2) with (N, 4, 2)."""
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
        Rectangle corners, counter-clockwise (as from :func:`corners_bev`), metres.

    Returns
    -------
    area : (P,) C, the rectangle's area, m² (NaN where a corner is not finite).
    diag_sq : (P,) d², its squared diagonal, m².
    """
    area, diag_sq = _chunked(_min_area_rect, corners_a, corners_b, n_outputs=2)
    return area, diag_sq


# --- Pairs given by index: the BEV costs' entry point ------------------------------------------


def bev_pair_geometry(
    boxes_a: FloatArray,
    boxes_b: FloatArray,
    rows: IntArray,
    cols: IntArray,
    *,
    with_enclosing: bool = True,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The BEV geometry of the pairs ``(boxes_a[rows[p]], boxes_b[cols[p]])``.

    What every BEV cost needs, in one call over the flat list of pairs it scores: the
    intersection area (computed only where the circumscribed circles overlap, else 0 exactly),
    the minimum-area rectangle enclosing both boxes and its squared diagonal
    (:func:`min_area_rect_bev`), and the squared centre distance. Runs the compiled kernel of
    :mod:`tracker.kernels.geometry` when numba is installed (and the environment variable
    ``MCTRACK_NUMBA`` is not ``0``), else :func:`bev_pair_geometry_numpy`; both agree to float64
    rounding.

    Parameters
    ----------
    boxes_a : (M, 5) and boxes_b : (N, 5)
        BEV boxes ``[x, y, l, w, yaw]`` (metres, radians).
    rows, cols : (P,) int64
        The pairs.
    with_enclosing : compute the enclosing rectangle (else its two outputs are NaN).

    Returns
    -------
    intersection : (P,) m².
    enclosing_area : (P,) m².
    diag_sq : (P,) m², the enclosing rectangle's squared diagonal.
    centre_dist_sq : (P,) m².
    A pair with a non-finite x, y, l, w or yaw (a missing box) is NaN in every output.
    """
    kernel = _geometry_kernel()
    if kernel is not None:
        return kernel(  # type: ignore[no-any-return]
            np.ascontiguousarray(boxes_a, dtype=np.float64),
            np.ascontiguousarray(boxes_b, dtype=np.float64),
            np.ascontiguousarray(rows, dtype=np.int64),
            np.ascontiguousarray(cols, dtype=np.int64),
            with_enclosing,
        )
    return bev_pair_geometry_numpy(boxes_a, boxes_b, rows, cols, with_enclosing=with_enclosing)


def bev_pair_geometry_numpy(
    boxes_a: FloatArray,
    boxes_b: FloatArray,
    rows: IntArray,
    cols: IntArray,
    *,
    with_enclosing: bool = True,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """:func:`bev_pair_geometry` in numpy: the fallback and the compiled kernel's reference."""
    a = np.asarray(boxes_a, dtype=np.float64).reshape(-1, 5)
    b = np.asarray(boxes_b, dtype=np.float64).reshape(-1, 5)
    # c² = (x1 - x2)² + (y1 - y2)²
    dx = b[cols, 0] - a[rows, 0]
    dy = b[cols, 1] - a[rows, 1]
    centre_dist_sq = dx * dx + dy * dy
    # beyond the sum of half-diagonals the boxes cannot overlap: I = 0 exactly
    half_diag_a = 0.5 * np.hypot(a[:, 2], a[:, 3])
    half_diag_b = 0.5 * np.hypot(b[:, 2], b[:, 3])
    close = centre_dist_sq < (half_diag_a[rows] + half_diag_b[cols]) ** 2
    with np.errstate(invalid="ignore"):  # a missing box's corners are NaN: reported below
        corners_a = corners_bev(a[:, :2], a[:, 2:4], a[:, 4])
        corners_b = corners_bev(b[:, :2], b[:, 2:4], b[:, 4])
    inter = np.zeros(len(rows))
    if close.any():
        inter[close] = intersection_area_bev(corners_a[rows[close]], corners_b[cols[close]])
    if with_enclosing:
        enclosing_area, diag_sq = min_area_rect_bev(corners_a[rows], corners_b[cols])
    else:
        enclosing_area, diag_sq = np.full(len(rows), np.nan), np.full(len(rows), np.nan)
    missing = ~(np.isfinite(a).all(axis=1)[rows] & np.isfinite(b).all(axis=1)[cols])
    for out in (inter, enclosing_area, diag_sq, centre_dist_sq):
        out[missing] = np.nan
    return inter, enclosing_area, diag_sq, centre_dist_sq


@functools.cache
def _geometry_kernel() -> Callable[..., tuple[FloatArray, ...]] | None:
    """The compiled kernel, loaded (or compiled and cached on disk) once; None without numba."""
    if os.environ.get("MCTRACK_NUMBA", "1") == "0":
        return None
    try:
        from tracker.kernels.geometry import bev_pair_geometry_kernel
    except ImportError:
        return None
    # compile (first run of a checkout) or load from numba's cache now, not on first use
    none = np.zeros(0, dtype=np.int64)
    bev_pair_geometry_kernel(np.zeros((0, 5)), np.zeros((0, 5)), none, none, True)
    return bev_pair_geometry_kernel  # type: ignore[no-any-return]


def prepare_kernels() -> None:
    """Load the compiled geometry kernel now (the tracker calls this at construction, so the
    one-time JIT load never lands inside a timed frame)."""
    _geometry_kernel()
