"""Compiled (numba) twins of the tracker's per-frame stages, one module beside each stage.

=====================  ==========================================  ===========================
kernel module          speeds up                                   numpy reference
=====================  ==========================================  ===========================
``kernels.geometry``   rotated-box BEV intersection / enclosure    :mod:`tracker.geometry`
``kernels.cost``       stage-1 gated Ro_GDIoU cost matrix          :mod:`tracker.cost`
``kernels.kalman``     predict; update with the heading logic      :mod:`tracker.kalman`
``kernels.matching``   uncontested stage-1 assignment              :mod:`tracker.matching`
``kernels.lifecycle``  per-category lifecycle rules; hit records  ``MCTracker._lifecycle``,
                       and the velocity baselines' windows         ``._record_hits``,
                                                                   ``TrackTable.record_detections``
``kernels.camera``     in-image fraction of coasting boxes        :mod:`tracker.camera`
``kernels.noise``      the detections' noise estimate (r_scale)   :mod:`tracker.noise`
=====================  ==========================================  ===========================

Why: a KITTI frame holds ~10 tracks and ~10 detections, so numpy stages spend their time in
hundreds of ~1 µs numpy calls rather than in arithmetic; each kernel is one loop doing the same
operations in the same order. The numpy code stays the reference, the fallback (no numba, or
``MCTRACK_NUMBA=0``) and the test oracle (``tests/test_kernels*.py`` compare them on random inputs
and whole scenes; KITTI result files are byte-identical either way).

Kernels carry explicit signatures, so they compile (or load from numba's cache) on import,
never inside a frame. Import them only through :func:`load`, which returns None without numba.
"""

from __future__ import annotations

import functools
import os
from types import SimpleNamespace


@functools.cache
def load() -> SimpleNamespace | None:
    """The per-frame kernels as one namespace, loaded once; None without numba or with
    ``MCTRACK_NUMBA=0`` (then every stage runs its numpy code)."""
    if os.environ.get("MCTRACK_NUMBA", "1") == "0":
        return None
    try:
        from tracker.kernels import camera, cost, kalman, lifecycle, matching, noise
    except ImportError:
        return None
    return SimpleNamespace(
        bev_cost_kernel=cost.bev_cost_kernel,
        motion_predict_kernel=kalman.motion_predict_kernel,
        motion_update_kernel=kalman.motion_update_kernel,
        isolated_pairs_kernel=matching.isolated_pairs_kernel,
        lifecycle_kernel=lifecycle.lifecycle_kernel,
        record_hits_kernel=lifecycle.record_hits_kernel,
        record_detections_kernel=lifecycle.record_detections_kernel,
        in_image_fraction_kernel=camera.in_image_fraction_kernel,
        noise_update_kernel=noise.noise_update_kernel,
        noise_variance_kernel=noise.noise_variance_kernel,
        CONFIRMED_NOW=lifecycle.CONFIRMED_NOW,
        REACQUIRED_FROM_LOST=lifecycle.REACQUIRED_FROM_LOST,
        LOST_NOW=lifecycle.LOST_NOW,
        DEAD=lifecycle.DEAD,
    )
