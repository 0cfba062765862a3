"""The plausibility bounds of boxes and poses, one for every reader of them.

A finite number can still be absurd: a centre at 1e300 m passes every finiteness check, then
its squared distances, areas and covariances overflow downstream (inf, NaN, numpy warnings, a
silently surprising metric). Every reader of boxes, detections and ground truth alike
(BaseVersion, the KITTI, nuScenes and Waymo converters), refuses a centre coordinate or a size
beyond :data:`MAX_BOX_METRES` with :func:`beyond_bound`, in an error naming the file, the record
and the field that ends in :data:`BOUND_NOTE`. Every reader of poses (KITTI pose and calib
files, nuScenes ego_pose and calibrated_sensor, BaseVersion ``transform_matrix``, Waymo
``ego_info``) refuses a translation beyond the same bound (a pose at 1e300 m puts every box of
its frame there), and every reader of velocities (detections and ground truth) one beyond
:data:`MAX_SPEED_MPS`, ending in :data:`SPEED_NOTE`. The BaseVersion reader refuses a heading
(``global_yaw``) beyond :data:`MAX_ANGLE_RAD`, ending in :data:`ANGLE_NOTE`, and so do the
converters' readers of headings that may be unwrapped (KITTI ``rotation_y``, Waymo ``heading``;
nuScenes headings are quaternions); the converters write headings wrapped into (−π, π].
"""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: 100 000 km: every georeferenced frame on Earth stays below it (UTM northings < 1e7 m, ECEF and
#: Web Mercator < 2.1e7 m), and squares of it (1e16) are far from float64's overflow.
MAX_BOX_METRES: Final = 1e8
#: The end of a bound error: what the bound is and why a value beyond it is refused.
BOUND_NOTE: Final = f"beyond ±{MAX_BOX_METRES:g} m (farther or larger than anything on Earth)"

#: 10 km/s per axis: faster than any vehicle (cars < 150 m/s), aircraft or satellite in low orbit
#: (7.8 km/s), so no annotation or estimate of a real object reaches it; its square (1e8) and its
#: products with any time step stay far from float64's overflow.
MAX_SPEED_MPS: Final = 1e4
#: The end of a velocity bound error.
SPEED_NOTE: Final = f"beyond ±{MAX_SPEED_MPS:g} m/s (faster than anything on or near Earth)"

#: 10 000 rad (~1600 turns) for a heading: converters write one within a few turns of zero (the
#: official KITTI one in [π/2, 9π/2)), so no real heading reaches it; below it the float spacing
#: stays under 2e-12 rad and wrapping to (−π, π] keeps the heading. At 1e300 the spacing (1e284)
#: is more than a turn: the wrapped heading would be an arbitrary angle, read without a word.
MAX_ANGLE_RAD: Final = 1e4
#: The end of an angle bound error.
ANGLE_NOTE: Final = f"beyond ±{MAX_ANGLE_RAD:g} rad (a heading is within a few turns of zero)"


def beyond_bound(values: ArrayLike, bound: float = MAX_BOX_METRES) -> NDArray[np.bool_]:
    """(N,) whether each row of (N, k) or (N,) values has an entry beyond ±``bound``
    (:data:`MAX_BOX_METRES`, :data:`MAX_SPEED_MPS` for velocities or :data:`MAX_ANGLE_RAD` for
    headings; inf included; NaN is not: the readers refuse it as not finite, or read it as
    unknown)."""
    magnitude = np.abs(np.asarray(values, dtype=np.float64))
    if magnitude.ndim == 1:
        magnitude = magnitude[:, None]
    return (magnitude > bound).any(axis=1)
