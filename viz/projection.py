"""Which projected box edges are worth drawing.

The observer buffers a few hundred frames and projects them in one call with
:func:`tracker.camera.project_boxes_batched` (each box with its own camera matrix), which removes
the per-frame numpy overhead (the dominant cost of drawing wireframes every frame);
tests/test_viz_projection.py checks equality with :func:`tracker.camera.project_boxes` and
:func:`tracker.camera.box_wireframes_image`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from tracker.boxes import FloatArray


def drawable_segments(
    segments_px: FloatArray, size_px: NDArray[np.integer], *, margin_px: float = 2000.0
) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
    """The segments worth drawing, ``(S, 2, 2)`` float32, and the box row of each.

    Edges behind the camera are dropped, and so are whole boxes far outside the image
    (projected from beside the camera): their huge coordinates only confuse a 2D view.
    """
    n = len(segments_px)
    if n == 0:
        return np.zeros((0, 2, 2), np.float32), np.zeros(0, np.int64)
    ok = ~np.isnan(segments_px).any(axis=(2, 3))  # (N, 12)
    size = np.asarray(size_px, dtype=np.float64)[:, None, None, :]
    with np.errstate(invalid="ignore"):
        inside = ((segments_px >= -margin_px) & (segments_px <= size + margin_px)).all(axis=(2, 3))
    keep = ok & (ok & inside).any(axis=1)[:, None]
    rows = np.broadcast_to(np.arange(n)[:, None], keep.shape)[keep]
    return segments_px[keep].astype(np.float32), rows
