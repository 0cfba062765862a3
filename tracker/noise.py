"""The detector's position noise, estimated from its own detections (no labels), causally.

A detected centre is z_t = s(t) + e_t: the object's smooth path plus the detector's error, white
with variance σ² per axis. The second difference over three frames a step dt apart,

    Δ²z_t = z_t − 2 z_{t−1} + z_{t−2} = s''·dt² + e_t − 2 e_{t−1} + e_{t−2},

drops the path up to its acceleration (2 cm at 2 m/s² and 10 Hz) and leaves
var(Δ²z) = (1 + 4 + 1) σ² = 6 σ²: a difference-based variance estimator (Gasser, Sroka and
Jennen-Steinmetz, Biometrika 1986). The three centres are chained as the self-calibration
chains boxes (:func:`tracker.eval.calibrate.chain_ids`): each box to the nearest box of its
class in the previous frame, within the box's own length or ``LINK_SIGMAS`` σ of the estimate so
far, whichever is larger. The frame-to-frame step of the noise is σ√2 per axis, so a radius of
5σ holds all but e^(−6.25) ≈ 0.2 % of it; within the length alone, noise comparable to the box
(a pedestrian's 0.8 m under σ 0.3 m) loses its largest steps and reads about a fifth low. A
wrong link or a false positive is an outlier, so the scale is robust:
σ = 1.4826 · median|Δ²z| / √6 (the normal's MAD; Δ²z has median 0). The median comes from a
histogram of |Δ²z| on log-spaced bins, so each frame costs its own boxes and the bins, never the
history, and the estimate at frame t uses frames up to t only (online).

Why the tracker wants it: the measurement variance r that tracks best follows the detections'
noise. On PointRCNN (KITTI, car), r near 0.1-0.3 m² is best on its own boxes, 1.7 with σ 0.15 m
of added jitter, 4 with σ 0.3 m; one fixed r must trade them. ``pose.r_scale`` makes r a
multiple of this estimate instead (:class:`tracker.mctracker.MCTracker`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tracker.boxes import FloatArray, IntArray

# |Δ²z| bins: 0.1 mm to 100 m, 5 % wide (the median, interpolated within its bin, to ~1 %)
EDGES = np.geomspace(1e-4, 1e2, 284)
# fewer second differences (two per chained triple, x and y) than this: no estimate yet; nor
# while their median lies in the first bin (boxes without noise: r would vanish)
MIN_SAMPLES = 60
# Δ²z of a triple whose two frame steps differ by more than this fraction holds a velocity term
STEP_TOLERANCE = 0.1
# a box links to a box of the previous frame within max(its length, LINK_SIGMAS σ): the noise's
# frame-to-frame step (σ√2 per axis, Rayleigh in 2D) lies beyond 5σ with probability e^(−6.25)
LINK_SIGMAS = 5.0
_MAD_TO_SIGMA = 1.482602218505602  # 1 / Φ⁻¹(3/4)


class PositionNoise:
    """Running estimate of the detections' centre variance σ² (m², per axis) per category.

    Feed every frame's detections, in time order, with :meth:`update`; :meth:`variance` is the
    estimate from the frames fed so far.
    """

    def __init__(self, n_categories: int, kernels: Any = None) -> None:
        self.counts = np.zeros((n_categories, len(EDGES) - 1), dtype=np.int64)
        self._frames: list[tuple[float, FloatArray, IntArray, IntArray]] = []  # last two
        # the compiled twins (tracker.kernels.load()); None: numpy, the reference
        self._kernels = kernels
        self._variance: FloatArray | None = None  # variance() of the counts as they are

    def update(
        self, time_secs: float, xy: FloatArray, length: FloatArray, category: IntArray
    ) -> None:
        """Add one frame's boxes: ``xy`` (n, 2) world-frame centres (m), ``length`` (n,) their
        lengths (the linking radius, widened to ``LINK_SIGMAS`` σ of the estimate so far),
        ``category`` (n,) their categories."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        category = np.asarray(category, dtype=np.int64)
        link = np.full(len(xy), -1, dtype=np.int64)  # each box's box in the previous frame
        if self._frames and len(xy) and len(self._frames[-1][1]):
            _, prev_xy, prev_cat, prev_link = self._frames[-1]
            triples = len(self._frames) == 2 and even_steps(
                self._frames[0][0], self._frames[1][0], time_secs
            )
            prev2_xy = self._frames[0][1] if triples else prev_xy
            # (fmax: no estimate yet, NaN, leaves the length)
            length = np.fmax(
                np.asarray(length, dtype=np.float64),
                LINK_SIGMAS * np.sqrt(self.variance())[category],
            )
            self._variance = None
            if self._kernels is not None:
                self._kernels.noise_update_kernel(
                    xy, length, category, prev_xy, prev_cat, prev_link, prev2_xy, triples, EDGES,
                    self.counts, link,
                )  # fmt: skip
            else:
                delta = xy[:, None, :] - prev_xy[None, :, :]
                d2 = np.einsum("ijk,ijk->ij", delta, delta)
                d2[category[:, None] != prev_cat[None, :]] = np.inf  # chains stay in their class
                d2[np.isnan(d2)] = np.inf  # (a NaN centre links to nothing, as in the kernel)
                nearest = d2.argmin(axis=1)
                ok = d2[np.arange(len(xy)), nearest] <= length * length
                link[ok] = nearest[ok]
                if triples:
                    cur = np.flatnonzero(ok)
                    cur = cur[prev_link[link[cur]] >= 0]  # chained over three frames
                    if len(cur):
                        p = link[cur]
                        second = xy[cur] - 2.0 * prev_xy[p] + prev2_xy[prev_link[p]]
                        count_magnitudes(self.counts, category[cur], np.abs(second))
        self._frames = [*self._frames[-1:], (time_secs, xy, category, link)]

    def variance(self) -> FloatArray:
        """(C,) σ² per axis (m²) per category; NaN where fewer than ``MIN_SAMPLES`` counted."""
        if self._variance is None:  # (computed once per frame: the tracker and update ask)
            if self._kernels is not None:
                out = np.empty(len(self.counts))
                self._kernels.noise_variance_kernel(
                    self.counts, MIN_SAMPLES, EDGES, _MAD_TO_SIGMA, out
                )
                self._variance = out
            else:
                self._variance = robust_square_scale(self.counts) / 6.0
        return self._variance.copy()


def count_magnitudes(counts: IntArray, category: IntArray, magnitude: FloatArray) -> None:
    """Count ``magnitude`` (n,) or (n, k) of boxes of ``category`` (n,) into ``counts``
    (C, bins) on :data:`EDGES`, in place."""
    n_bins = counts.shape[1]
    b = np.clip(np.searchsorted(EDGES, magnitude, side="right") - 1, 0, n_bins - 1)
    rows = category[:, None] if b.ndim == 2 else category
    flat = (rows * n_bins + b).ravel()
    counts += np.bincount(flat, minlength=counts.size).reshape(counts.shape)


def robust_square_scale(counts: IntArray) -> FloatArray:
    """(C,) (1.4826 · median)² of the magnitudes counted in each row of ``counts``: the variance
    of a zero-mean normal whose |values| they are. NaN below ``MIN_SAMPLES`` counts, and where
    the median lies in the first bin (below the histogram's resolution)."""
    total = counts.sum(axis=1)
    out = np.full(len(total), np.nan)
    ready = np.flatnonzero(total >= MIN_SAMPLES)
    if len(ready):
        median = histogram_median(counts[ready])
        out[ready] = np.where(median > EDGES[1], (_MAD_TO_SIGMA * median) ** 2, np.nan)
    return out


def even_steps(t2: float, t1: float, t0: float) -> bool:
    """Whether the frame steps t2 -> t1 -> t0 are equal within ``STEP_TOLERANCE``."""
    step, before = t0 - t1, t1 - t2
    return abs(step - before) <= STEP_TOLERANCE * max(abs(before), 1e-9)


def histogram_median(counts: IntArray) -> FloatArray:
    """(R,) medians of the values counted on :data:`EDGES`, one row of (R, bins) ``counts``
    each (none empty), interpolated geometrically within the median's bin."""
    cum = np.cumsum(counts, axis=1)
    half = cum[:, -1] / 2.0
    rows = np.arange(len(counts))
    j = (cum < half[:, None]).sum(axis=1)  # first bin whose cumulative count reaches half
    below = np.where(j > 0, cum[rows, np.maximum(j - 1, 0)], 0)
    frac = (half - below) / counts[rows, j]
    lo, hi = np.log(EDGES[j]), np.log(EDGES[j + 1])
    return np.exp(lo + frac * (hi - lo))


def second_difference_variance(xy: FloatArray) -> float:
    """σ² per axis of one evenly sampled track (T, 2) by the same estimator, with the exact
    median: the reference :class:`PositionNoise` is tested against."""
    second = np.abs(xy[2:] - 2.0 * xy[1:-1] + xy[:-2]).ravel()
    return float((_MAD_TO_SIGMA * np.median(second)) ** 2 / 6.0)
