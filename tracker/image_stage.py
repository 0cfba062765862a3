"""Stage 2 (image plane) of many frames at once, for the frames the tracker skipped.

When stage 2 can match nothing on a frame (no leftover pair within its gate) the tracker skips
it, and tells an observer that asked (``rv_costs_deferred``) with an
:class:`~tracker.events.ImageStageDeferred`. :func:`deferred_image_stage` computes the events
the full stage would have emitted, ``CostComputed`` and ``Matched`` of ``Stage.RV``, with the
arithmetic of ``MCTracker._rv_stage`` (projection of the predicted boxes, SDIoU, greedy, gate)
vectorised over all frames given: the recording does this once per buffer of frames instead of
once per frame (a few hundred small numpy calls).

Equal to the tracker's own events up to the rounding of the projection (a batched matrix
product), with one difference no picture uses: a track with no leftover detection of its
category gets no 2D box (``track_xyxy`` NaN, ``camera`` -1), its cost row being +inf anyway.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from tracker.boxes import Boxes, IntArray
from tracker.camera import project_boxes_batched
from tracker.cost import sdiou_pairs
from tracker.events import CostComputed, ImageStageDeferred, Matched, Stage
from tracker.frame import Frame
from tracker.geometry import wrap_angle
from tracker.matching import greedy


def deferred_image_stage(
    items: Sequence[tuple[Frame, IntArray, Boxes, ImageStageDeferred]],
) -> list[tuple[CostComputed, Matched]]:
    """The stage-2 events of skipped frames.

    Parameters
    ----------
    items : per frame: the frame, its ``Predicted`` event's track ids and boxes, and the
        deferred event.

    Returns
    -------
    Per item, the ``CostComputed`` and ``Matched`` (all pairs rejected by the gate) of stage 2.

    Raises
    ------
    RuntimeError : a pair passes the gate (the tracker skipped a stage that could match).
    """
    if not items:
        return []
    k = len(items)
    events = [e for _, _, _, e in items]
    m = np.array([len(e.track_rows) for e in events], dtype=np.int64)
    n = np.array([len(e.det_rows) for e in events], dtype=np.int64)
    # the leftover tracks and detections of all frames, concatenated
    pred_n = np.array([len(b) for _, _, b, _ in items], dtype=np.int64)
    t_at = np.concatenate([e.track_rows for e in events]) + np.repeat(np.cumsum(pred_n) - pred_n, m)
    t_xyz = np.concatenate([b.xyz for _, _, b, _ in items]).reshape(-1, 3)[t_at]
    t_lwh = np.concatenate([b.lwh for _, _, b, _ in items]).reshape(-1, 3)[t_at]
    t_yaw = np.concatenate([b.yaw for _, _, b, _ in items])[t_at]
    t_cat = np.concatenate([b.category for _, _, b, _ in items])[t_at]
    t_ids = np.concatenate([ids for _, ids, _, _ in items])[t_at]
    frame_n = np.array([len(f.boxes) for f, _, _, _ in items], dtype=np.int64)
    d_at = np.concatenate([e.det_rows for e in events]) + np.repeat(np.cumsum(frame_n) - frame_n, n)
    boxes = [f.boxes for f, _, _, _ in items]
    d_cam = np.concatenate([b.camera for b in boxes])[d_at].astype(np.int64)
    d_xyxy = np.concatenate([b.xyxy_image for b in boxes]).reshape(-1, 4)[d_at]
    d_cat = np.concatenate([b.category for b in boxes])[d_at]
    d_yaw = np.concatenate([b.yaw for b in boxes])[d_at]
    d_xyz = np.concatenate([b.xyz for b in boxes]).reshape(-1, 3)[d_at]
    t_item, d_item = np.repeat(np.arange(k), m), np.repeat(np.arange(k), n)
    t_start, d_start = np.cumsum(m) - m, np.cumsum(n) - n

    # all (track, detection) cells, row-major per frame
    sizes = m * n
    cell_item = np.repeat(np.arange(k), sizes)
    local = np.arange(int(sizes.sum())) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    c_t = t_start[cell_item] + local // np.maximum(n, 1)[cell_item]
    c_d = d_start[cell_item] + local % np.maximum(n, 1)[cell_item]
    same = t_cat[c_t] == d_cat[c_d]

    # the cameras of each frame's detections (as _cameras_of: sorted, >= 0), one projection of
    # every track that has a detection of its category there into each of them
    seen = d_cam >= 0
    n_cams = int(d_cam.max()) + 1 if seen.any() else 1
    combos, combo_of_det = np.unique(d_item[seen] * n_cams + d_cam[seen], return_inverse=True)
    combo_item, combo_cam = combos // n_cams, combos % n_cams
    per_item = np.bincount(combo_item, minlength=k)
    combo_start = np.cumsum(per_item) - per_item
    det_combo = np.full(len(d_cam), -1, dtype=np.int64)
    det_combo[seen] = combo_of_det
    wanted = np.zeros(len(t_ids), dtype=bool)
    wanted[c_t[same & seen[c_d]]] = True
    proj_n = np.where(wanted, per_item[t_item], 0)
    proj_start = np.cumsum(proj_n) - proj_n
    p_track = np.repeat(np.arange(len(t_ids)), proj_n)
    p_combo = combo_start[t_item[p_track]] + (
        np.arange(int(proj_n.sum())) - np.repeat(proj_start, proj_n)
    )
    cameras = [items[int(i)][0].cameras[int(c)] for i, c in zip(combo_item, combo_cam, strict=True)]
    image_from_world = np.array([c.image_from_world for c in cameras]).reshape(-1, 3, 4)
    size_px = np.array([[c.width_px, c.height_px] for c in cameras]).reshape(-1, 2)
    _, p_xyxy, p_visible = project_boxes_batched(
        t_xyz[p_track],
        t_lwh[p_track],
        t_yaw[p_track],
        image_from_world[p_combo],
        size_px[p_combo],
    )

    # each cell: the track's box in the detection's camera, SDIoU where visible and same class
    cost = np.full(len(c_t), np.inf)
    live = same & seen[c_d]
    at = proj_start[c_t[live]] + (det_combo[c_d[live]] - combo_start[d_item[c_d[live]]])
    ok = p_visible[at]
    cells = np.flatnonzero(live)[ok]
    cost[cells] = 1.0 - sdiou_pairs(p_xyxy[at[ok]], d_xyxy[c_d[cells]])

    # the box and camera of a track: its first camera (in index order) where it is visible
    track_xyxy = np.full((len(t_ids), 4), np.nan)
    track_cam = np.full(len(t_ids), -1, dtype=np.int64)
    vis = np.flatnonzero(p_visible)
    first_track, first = np.unique(p_track[vis], return_index=True)
    track_xyxy[first_track] = p_xyxy[vis[first]]
    track_cam[first_track] = combo_cam[p_combo[vis[first]]]

    # greedy only pairs cells within their row's threshold: most frames have none
    limit = np.concatenate([e.max_cost_per_row for e in events])
    feasible = np.isfinite(cost) & (cost <= limit[c_t])  # as matching._feasible
    any_feasible = np.bincount(cell_item[feasible], minlength=k) > 0
    out: list[tuple[CostComputed, Matched]] = []
    cell_start = np.cumsum(sizes) - sizes
    no_pairs = np.zeros((0, 2), dtype=np.int64)
    for i, (frame, _, _, e) in enumerate(items):
        ts = slice(t_start[i], t_start[i] + m[i])
        matrix = cost[cell_start[i] : cell_start[i] + sizes[i]].reshape(m[i], n[i])
        pairs = (
            greedy(matrix, max_cost_per_row=e.max_cost_per_row, order=e.greedy_order).pairs
            if any_feasible[i]
            else no_pairs
        )
        rows, cols = pairs[:, 0] + t_start[i], pairs[:, 1] + d_start[i]
        yaw_gap = np.abs(wrap_angle(t_yaw[rows] - d_yaw[cols]))
        dist = np.linalg.norm(t_xyz[rows] - d_xyz[cols], axis=1)
        passes = (yaw_gap <= e.yaw_gate_rad[pairs[:, 0]]) & (dist <= e.distance_gate_m[pairs[:, 0]])
        if passes.any():
            raise RuntimeError(
                f"frame {frame.frame_id}: stage 2 was skipped but a pair passes its gate"
            )
        ids = t_ids[ts]
        out.append(
            (
                CostComputed(
                    Stage.RV,
                    matrix,
                    ids,
                    e.det_rows,
                    e.max_cost_per_row,
                    track_xyxy=track_xyxy[ts],
                    camera=track_cam[ts],
                ),
                Matched(
                    Stage.RV,
                    ids[:0],
                    e.det_rows[:0],
                    np.zeros(0),
                    t_ids[rows],
                    e.det_rows[pairs[:, 1]],
                ),
            )
        )
    return out
