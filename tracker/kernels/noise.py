"""Compiled noise estimate of the detections (numpy reference: tracker.noise.PositionNoise)."""

from __future__ import annotations

import math

import numba
import numpy as np

from tracker.boxes import FloatArray, IntArray
from tracker.kernels._common import _F1, _F1_OUT, _F2, _I1, _I1_OUT

_I2_OUT = numba.types.Array(numba.int64, 2, "A")


@numba.njit(
    (_F2, _F1, _I1, _F2, _I1, _I1, _F2, numba.boolean, _F1, _I2_OUT, _I1_OUT),
    cache=True, error_model="numpy", nogil=True,
)  # fmt: skip
def noise_update_kernel(
    xy: FloatArray,
    length: FloatArray,
    category: IntArray,
    prev_xy: FloatArray,
    prev_cat: IntArray,
    prev_link: IntArray,
    prev2_xy: FloatArray,
    triples: bool,
    edges: FloatArray,
    counts: np.ndarray,
    link: IntArray,
) -> None:  # pragma: no cover (compiled)
    """``PositionNoise.update``'s linking and counting, one loop over the boxes: ``link`` (out)
    each box's nearest box of its class in the previous frame within ``length[i]``, the
    caller's linking radius (-1: none);
    with ``triples``, every box chained over three frames adds its |Δ²z| in x and y to
    ``counts`` (C, bins) on ``edges``."""
    n_bins = counts.shape[1]
    for i in range(xy.shape[0]):
        best, nearest = math.inf, -1
        for j in range(prev_xy.shape[0]):
            if prev_cat[j] != category[i]:
                continue
            dx, dy = xy[i, 0] - prev_xy[j, 0], xy[i, 1] - prev_xy[j, 1]
            d2 = dx * dx + dy * dy
            if d2 < best:
                best, nearest = d2, j
        link[i] = -1
        if nearest < 0 or not best <= length[i] * length[i]:
            continue
        link[i] = nearest
        if triples and prev_link[nearest] >= 0:
            k = prev_link[nearest]
            for a in range(2):
                v = abs(xy[i, a] - 2.0 * prev_xy[nearest, a] + prev2_xy[k, a])
                b = min(max(np.searchsorted(edges, v, side="right") - 1, 0), n_bins - 1)
                counts[category[i], b] += 1


@numba.njit(
    (numba.types.Array(numba.int64, 2, "A", readonly=True), numba.int64, _F1, numba.float64,
     _F1_OUT),
    cache=True, error_model="numpy", nogil=True,
)  # fmt: skip
def noise_variance_kernel(
    counts: np.ndarray, min_samples: int, edges: FloatArray, mad_to_sigma: float, out: FloatArray
) -> None:  # pragma: no cover (compiled)
    """``PositionNoise.variance``: per category σ² = (mad_to_sigma · median|Δ²z|)² / 6 from the
    histogram, the median interpolated geometrically in its bin; NaN below ``min_samples``."""
    for c in range(counts.shape[0]):
        total = 0
        for b in range(counts.shape[1]):
            total += counts[c, b]
        if total < min_samples:
            out[c] = np.nan
            continue
        half = total / 2.0
        below = 0
        j = 0
        while below + counts[c, j] < half:  # first bin whose cumulative count reaches half
            below += counts[c, j]
            j += 1
        frac = (half - below) / counts[c, j]
        lo, hi = np.log(edges[j]), np.log(edges[j + 1])
        median = np.exp(lo + frac * (hi - lo))
        out[c] = (mad_to_sigma * median) ** 2 / 6.0 if median > edges[1] else np.nan
