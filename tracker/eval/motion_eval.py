"""Motion evaluation: match tracker output to ground truth and score four velocity estimators.

The maths lives in :mod:`tracker.eval.motion_metrics`; this module prepares its input from frames
and tracker output, like for like for every estimator, and formats the result.

Protocol (differences from the reference ``evaluation/eval_motion.py``, spec §4, are deliberate):

1. **Ground-truth velocity.** A dataset whose GT boxes carry a velocity (nuScenes) uses it. A
   dataset whose GT velocities are all unknown (NaN, null in BaseVersion; KITTI: none is
   annotated) gets it from the GT world positions, per (scene, GT track), over real time with
   :func:`~tracker.eval.motion_metrics.gt_velocity_central` (zero lag, 5-sample window; a
   track's first and last samples get the one-sided second-order difference, not 0). A GT track
   is split into segments where it skips a frame (Δt > 1.5 × the scene's median frame step); a
   one-sample segment has an unknown (NaN) velocity. A sample whose GT velocity is unknown (that,
   or NaN in the annotations: nuScenes' single-annotation instances, Waymo GT without ``velos``)
   is left out of every estimator's metrics and counted (``n_gt_velocity_unknown``, and
   ``counts[class]["gt_velocity_unknown"]``); it is never read as 0, which would score a
   standstill. Files written before unknown velocities were null hold 0 for every GT velocity
   (KITTI, Waymo without ``velos``): all exactly 0 is read as unknown too (logged, and noted in
   the protocol), as no real dataset annotates every object standing still.
   On KITTI the world frame comes from estimated (ORB-SLAM3) ego poses, so the "GT" velocity also
   carries the pose error.
2. **Association**, per scene, per frame, per class: the output boxes, in descending score order,
   each take the still-unmatched GT box of the same class with the smallest **BEV centre
   distance**, if that distance is at most the class's threshold (:data:`MAX_DISTANCE_M`: 2 m for
   vehicles, 1 m for pedestrians and cyclists; 2 m otherwise, as nuScenes' tracking benchmark).
   Centre distance, not BEV IoU (the reference's IoU > 0.2): a pedestrian box is ~0.6 m wide, so a
   0.3 m centre error already fails IoU 0.2 although the track is plainly on its object, and the
   motion metrics are about the velocity of a correctly associated track, not box overlap. GT boxes
   of other categories (van, person_sitting, DontCare...) are ignored: they neither match nor
   count.
3. **Samples**: the matched output boxes that were updated by a detection in that frame
   (``det_row >= 0``). Coasting and offline-interpolated boxes are counted (``matched_coasting``)
   but are not samples, because the detection and the two position-based baselines have no value
   there; every estimator is scored on exactly the same rows.
4. **Estimators** at each sample (all m/s, world frame):

   - ``kalman``: the tracker's velocity (the output box's ``velocity``): the Kalman filter's
     online, its RTS smoother's offline (``offline.rts``).
   - ``detection``: the matched detection's own velocity. When no detection of the evaluated
     classes has a non-zero velocity (KITTI's PointRCNN gives none) the estimator is *absent*:
     NaN metrics and the note ``n/a: detector has no velocity``, never zeros. A detection whose
     velocity is unknown (BaseVersion ``null``, NaN) is no estimate: that sample is left out of
     this estimator only and counted in its ``n_dropped_samples``.
   - ``difference``: backward difference of the track's matched-detection centres over real time
     (spec §2.10, but across a gap the real elapsed time is used; 0 at the track's first
     detection, as in the reference).
   - ``curve_fit``: least-squares line slope over the track's last 3 matched-detection centres
     against real time, m/s (the reference's was m/frame); 0 until 3 exist.

   Both baselines are causal, over a track's detection centres in time order. Online, the
   tracker computes them at every update (:mod:`tracker.velocity_baselines`, as the reference
   does), so they also see the detections a track took before it was confirmed and output; a
   track's first *output* row has a real estimate, not the 0 of a first detection. Where the
   output carries none (offline, whose rows hold every detection of each final track; a tracks
   file from before), they run over each output track's own detection rows, using the raw
   centre of the detection the tracker matched (``det_row`` indexes the input frame's boxes).
   Either way they are read at the GT-matched samples.
5. **Keys**: GT and output tracks are keyed by :func:`~tracker.eval.motion_metrics.composite_key`
   of (scene, id), so ids never collide across scenes; frames are ordered by time, so the input
   order of frames does not matter.
6. **Box errors** (ATE-style, not in the paper), over the same samples, for the tracker's output
   box and for the matched raw detection: BEV centre distance (m); heading error = the wrapped
   full angle ``|wrap(yaw - yaw_gt)|`` in [0°, 180°] (not modulo 180°: a box facing backwards
   counts 180°, because its heading is the motion direction the tracker reports) and the
   fraction of samples off by more than 90° (``heading_flip_ratio``); size errors ``|Δl|`` and
   ``|Δw|`` (m).
"""

from __future__ import annotations

import enum
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.categories import CATEGORIES, category_index
from tracker.eval.motion_metrics import (
    MotionMetricParams,
    MotionMetrics,
    combine_motion_metrics,
    composite_key,
    gt_velocity_central,
    motion_metrics,
    static_gt_mask,
    velocity_curve_fit,
    velocity_delays_at_peaks,
    velocity_differencing,
)
from tracker.events import TrackOutput
from tracker.frame import Frame
from tracker.geometry import wrap_angle

log = logging.getLogger(__name__)

__all__ = [
    "CURVE_FIT_WINDOW",
    "GT_SMOOTH_WINDOW",
    "MAX_DISTANCE_M",
    "METRIC_COLUMNS",
    "Estimator",
    "MotionSamples",
    "collect_motion_samples",
    "derive_gt_velocity",
    "evaluate_motion",
    "evaluate_samples",
    "greedy_match_bev_distance",
    "largest_delay_tracks",
    "metrics_from_dict",
    "motion_markdown",
    "plot_velocity_curves",
    "resolve_gt_velocity",
]


class Estimator(enum.Enum):
    """The four velocity sources compared by the paper (Table "motion metrics")."""

    KALMAN = "kalman"
    DETECTION = "detection"
    DIFFERENCE = "difference"
    CURVE_FIT = "curve_fit"


ESTIMATOR_DESCRIPTIONS: Final[dict[Estimator, str]] = {
    Estimator.KALMAN: (
        "the tracker's output velocity: its Kalman filter's (online) or RTS smoother's (offline)"
    ),
    Estimator.DETECTION: "matched detection's own velocity",
    Estimator.DIFFERENCE: "backward difference of the track's detection centres, real time",
    Estimator.CURVE_FIT: "LSQ line over the track's last 3 detection centres, m/s",
}

#: BEV centre-distance association threshold per class, metres (module docstring, point 2).
MAX_DISTANCE_M: Final[dict[str, float]] = {"car": 2.0, "pedestrian": 1.0, "cyclist": 1.0}
DEFAULT_MAX_DISTANCE_M: Final = 2.0
CURVE_FIT_WINDOW: Final = 3
GT_SMOOTH_WINDOW: Final = 5
GAP_FACTOR: Final = 1.5  # a GT track is split where Δt > GAP_FACTOR × the median frame step
NO_DETECTOR_VELOCITY: Final = "n/a: detector has no velocity"
NO_DETECTIONS: Final = "n/a: no detections given"

#: (metric key, markdown header) of the six paper metrics, in the paper's order.
METRIC_COLUMNS: Final[tuple[tuple[str, str], ...]] = (
    ("vae_deg", "VAE (°)"),
    ("vne_mps", "VNE (m/s)"),
    ("vaie_deg", "VAIE (°)"),
    ("vir_ratio", "VIR"),
    ("vse_mps", "VSE (m/s)"),
    ("vde_secs", "VDE (s)"),
)
BOX_ERROR_COLUMNS: Final[tuple[tuple[str, str], ...]] = (
    ("position_error_m", "position (m)"),
    ("heading_error_deg", "heading (°)"),
    ("heading_flip_ratio", "heading > 90°"),
    ("length_error_m", "length (m)"),
    ("width_error_m", "width (m)"),
)


# --------------------------------------------------------------------------------------------
# Samples
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class MotionSamples:
    """The matched samples of one class over all scenes: one row per (GT box, output box) pair
    whose output box was updated by a detection that frame.

    Attributes
    ----------
    category : class name.
    scene : (S,) scene name of each sample.
    frame_id, times_secs : (S,) frame and its time, seconds.
    gt_track_id, track_id : (S,) the raw ids (unique only within a scene).
    gt_key, est_key : (S,) int64 keys unique across scenes (``composite_key(scene, id)``).
    gt_xy, gt_velocity : (S, 2) GT centre (m) and velocity (m/s, NaN when unknown).
    gt_yaw_rad : (S,); gt_lw : (S, 2) length and width, m.
    track_xy, track_yaw_rad, track_lw : the output box, same layouts.
    det_xy, det_yaw_rad, det_lw : the matched detection (NaN without detections).
    distance_m : (S,) BEV centre distance output box -> GT box.
    velocity : estimator -> (S, 2) m/s (NaN everywhere for an absent estimator).
    absent : estimator -> why it has no value (absent estimators only).
    n_gt_boxes, n_output_boxes : boxes of the class in the evaluated frames.
    n_matched : matched pairs, including ``n_matched_coasting`` pairs without a detection.
    """

    category: str
    scene: NDArray[np.str_]
    frame_id: IntArray
    times_secs: FloatArray
    gt_track_id: IntArray
    track_id: IntArray
    gt_key: IntArray
    est_key: IntArray
    gt_xy: FloatArray
    gt_velocity: FloatArray
    gt_yaw_rad: FloatArray
    gt_lw: FloatArray
    track_xy: FloatArray
    track_yaw_rad: FloatArray
    track_lw: FloatArray
    det_xy: FloatArray
    det_yaw_rad: FloatArray
    det_lw: FloatArray
    distance_m: FloatArray
    velocity: dict[Estimator, FloatArray]
    absent: dict[Estimator, str]
    n_gt_boxes: int
    n_output_boxes: int
    n_matched: int
    n_matched_coasting: int

    def __len__(self) -> int:
        return int(self.times_secs.shape[0])


def greedy_match_bev_distance(
    track_xy: FloatArray,
    track_score: FloatArray,
    gt_xy: FloatArray,
    *,
    max_distance_m: float,
) -> IntArray:
    """Greedy association of one frame and class: by descending score, each output box takes
    the nearest still-unmatched GT box if its BEV centre distance is <= ``max_distance_m``.

    Parameters
    ----------
    track_xy : (M, 2) output box centres, metres.
    track_score : (M,) output scores; ties keep the input row order, NaN scores go last.
    gt_xy : (N, 2) GT centres, metres.
    max_distance_m : inclusive threshold.

    Returns
    -------
    (K, 2) int64 pairs ``[output row, GT row]``, in the order they were taken.
    """
    m, n = track_xy.shape[0], gt_xy.shape[0]
    if m == 0 or n == 0:
        return np.zeros((0, 2), dtype=np.int64)
    distance = np.linalg.norm(track_xy[:, None, :] - gt_xy[None, :, :], axis=2)  # (M, N)
    score = np.where(np.isnan(track_score), -np.inf, track_score)
    taken = np.zeros(n, dtype=bool)
    pairs: list[tuple[int, int]] = []
    for i in np.argsort(-score, kind="stable"):
        row = np.where(taken, np.inf, distance[i])
        j = int(np.argmin(row))
        if row[j] <= max_distance_m:
            taken[j] = True
            pairs.append((int(i), j))
    return np.asarray(pairs, dtype=np.int64).reshape(-1, 2)


def _time_order(times: Sequence[float], what: str) -> IntArray:
    """Indices sorting ``times``; two equal times are an error."""
    t = np.asarray(times, dtype=np.float64)
    if not np.isfinite(t).all():
        raise ValueError(f"{what}: every frame needs a finite time")
    order = np.argsort(t, kind="stable")
    if np.any(np.diff(t[order]) <= 0.0):
        raise ValueError(f"{what}: two frames share a time")
    return order


def derive_gt_velocity(
    gt_frames: Sequence[Frame], *, smooth_window: int = GT_SMOOTH_WINDOW
) -> list[FloatArray]:
    """GT velocity of one scene from its world positions (for datasets without GT velocity).

    Per GT track, in time order, split into segments where the track skips a frame (Δt greater
    than 1.5 × the scene's median frame step), each segment through
    :func:`~tracker.eval.motion_metrics.gt_velocity_central`. Boxes with ``track_id < 0`` and
    one-sample segments get NaN.

    Parameters
    ----------
    gt_frames : one scene's GT frames, in any order.
    smooth_window : passed to ``gt_velocity_central``.

    Returns
    -------
    Per frame, in the input order, (N_i, 2) velocity in m/s.
    """
    if not gt_frames:
        return []
    times = np.array([f.timestamp_secs for f in gt_frames])
    order = _time_order(times, f"scene {gt_frames[0].scene!r} GT")
    step = float(np.median(np.diff(times[order]))) if len(order) > 1 else math.inf
    frame_of_row = np.concatenate([np.full(len(f.boxes), i) for i, f in enumerate(gt_frames)])
    t = times[frame_of_row]
    tid = np.concatenate([f.boxes.track_id for f in gt_frames])
    xy = np.concatenate([f.boxes.xyz[:, :2] for f in gt_frames])
    velocity = np.full((t.shape[0], 2), np.nan)
    rows = np.lexsort((t, tid))
    rows = rows[tid[rows] >= 0]
    if rows.size:
        sorted_tid, sorted_t = tid[rows], t[rows]
        same = (sorted_tid[1:] == sorted_tid[:-1]) & (sorted_t[1:] == sorted_t[:-1])
        if same.any():
            k = int(np.flatnonzero(same)[0])
            raise ValueError(
                f"scene {gt_frames[0].scene!r}: GT track {sorted_tid[k]} appears twice at "
                f"{sorted_t[k]} s"
            )
        new_segment = np.r_[
            True,
            (sorted_tid[1:] != sorted_tid[:-1]) | (np.diff(sorted_t) > GAP_FACTOR * step),
        ]
        starts = np.flatnonzero(new_segment)
        for start, stop in zip(starts, np.r_[starts[1:], rows.size], strict=True):
            seg = rows[start:stop]
            velocity[seg] = gt_velocity_central(t[seg], xy[seg], smooth_window=smooth_window)
    return np.split(velocity, np.cumsum([len(f.boxes) for f in gt_frames])[:-1])


#: The note the protocol adds when every GT velocity is 0 (:func:`resolve_gt_velocity`).
LEGACY_ZERO_GT_VELOCITY_NOTE: Final = (
    "every GT velocity in the file is 0: read as unknown (written before unknown was null)"
)


def resolve_gt_velocity(
    gt_velocity: str, gt_scenes: Mapping[str, Sequence[Frame]]
) -> tuple[str, bool]:
    """``("annotated" | "positions", legacy)``: ``gt_velocity`` with ``"auto"`` resolved. Auto is
    ``"positions"`` when no GT velocity is known (every one NaN, null in BaseVersion: KITTI, Waymo
    without ``velos``), else ``"annotated"``; ``legacy``: resolved by the rule for older files
    (logged, and noted in the protocol)."""
    if gt_velocity != "auto":
        return gt_velocity, False
    known = False
    for frames in gt_scenes.values():
        for f in frames:
            v = f.boxes.velocity
            finite = np.isfinite(v)
            if np.any(finite & (v != 0.0)):
                return "annotated", False
            known = known or bool(finite.any())
    if not known:
        return "positions", False
    # Every known GT velocity exactly 0: a file written before unknown velocities were null
    # (KITTI's converter wrote 0 for all, as did Waymo's without velos), not a dataset of objects
    # all standing still; read as unknown, so those files give the figures they always gave.
    log.warning(
        "every ground-truth velocity is 0: read as unknown (a file written before unknown "
        "velocities were null), the GT velocity derived from the GT positions"
    )
    return "positions", True


def _detector_has_velocity(
    det_scenes: Mapping[str, Sequence[Frame]], categories: Sequence[int]
) -> bool:
    def given(v: FloatArray) -> bool:  # (NaN: no estimate, not a velocity)
        return bool(np.any(np.isfinite(v) & (v != 0.0)))

    return any(
        given(f.boxes.velocity[np.isin(f.boxes.category, categories)])
        for frames in det_scenes.values()
        for f in frames
    )


@dataclass(frozen=True, slots=True)
class _SceneRows:
    """One scene's output rows (time order) with their matched detection and GT pairs."""

    out_time: FloatArray
    out_frame: IntArray
    out_boxes: Boxes
    det_row: IntArray
    det_boxes: Boxes | None  # aligned with out rows (rows without a detection are NaN)
    baseline: dict[Estimator, FloatArray]
    gt_boxes: Boxes
    gt_velocity: FloatArray
    pairs: IntArray  # (K, 2) [out row, GT row], any class


def _scene_rows(
    scene: str,
    outputs: Sequence[TrackOutput],
    gt_frames: Sequence[Frame],
    det_frames: Sequence[Frame] | None,
    *,
    gt_from_positions: bool,
    categories: Sequence[int],
    max_distance_by_category: Mapping[int, float],
) -> _SceneRows:
    gt_by_id = {f.frame_id: f for f in gt_frames}
    gt_velocity_frames = (
        derive_gt_velocity(gt_frames)
        if gt_from_positions
        else [f.boxes.velocity.astype(np.float64) for f in gt_frames]
    )
    gt_velocity_by_id = {f.frame_id: v for f, v in zip(gt_frames, gt_velocity_frames, strict=True)}
    det_by_id = {f.frame_id: f for f in det_frames} if det_frames is not None else None

    outputs = [outputs[i] for i in _time_order([o.time_secs for o in outputs], scene)]
    out_parts, det_parts, gt_parts, gtv_parts, pair_parts = [], [], [], [], []
    out_time, out_frame, det_rows, tracker_baselines = [], [], [], []
    n_out = n_gt = 0
    for out in outputs:
        boxes = out.boxes
        keep = np.isin(boxes.category, categories)
        boxes, det_row = boxes[keep], out.det_row[keep]
        tracker_baselines.append(None if out.baselines is None else out.baselines[keep])
        out_parts.append(boxes)
        out_time.append(np.full(len(boxes), out.time_secs))
        out_frame.append(np.full(len(boxes), out.frame_id, dtype=np.int64))
        det_rows.append(det_row)
        if det_by_id is not None:
            if (det_row >= 0).any() and out.frame_id not in det_by_id:
                raise ValueError(f"scene {scene!r}: no detection frame {out.frame_id}")
            src = det_by_id.get(out.frame_id)
            if src is not None and det_row.max(initial=-1) >= len(src.boxes):
                raise ValueError(
                    f"scene {scene!r} frame {out.frame_id}: det_row {det_row.max()} beyond the "
                    f"frame's {len(src.boxes)} detections (wrong detections file?)"
                )
            det_parts.append(_rows_or_nan(src.boxes if src is not None else None, det_row))
        gt_frame = gt_by_id.get(out.frame_id)
        if gt_frame is not None:
            gkeep = np.isin(gt_frame.boxes.category, categories)
            gt = gt_frame.boxes[gkeep]
            gt_parts.append(gt)
            gtv_parts.append(gt_velocity_by_id[out.frame_id][gkeep])
            for c in categories:
                rows_o = np.flatnonzero(boxes.category == c)
                rows_g = np.flatnonzero(gt.category == c)
                pairs = greedy_match_bev_distance(
                    boxes.xyz[rows_o, :2],
                    boxes.score[rows_o],
                    gt.xyz[rows_g, :2],
                    max_distance_m=max_distance_by_category[c],
                )
                pair_parts.append(
                    np.column_stack([rows_o[pairs[:, 0]] + n_out, rows_g[pairs[:, 1]] + n_gt])
                )
            n_gt += len(gt)
        n_out += len(boxes)

    out_boxes = Boxes.concat(out_parts)
    det_row_all = np.concatenate(det_rows) if det_rows else np.zeros(0, dtype=np.int64)
    det_boxes = Boxes.concat(det_parts) if det_by_id is not None else None
    time_all = np.concatenate(out_time) if out_time else np.zeros(0)
    if tracker_baselines and all(b is not None for b in tracker_baselines):
        # the tracker's, over every detection its tracks took (tentative ones too)
        both = np.concatenate(tracker_baselines)
        baseline = {Estimator.DIFFERENCE: both[:, 0], Estimator.CURVE_FIT: both[:, 1]}
    else:  # over the output's own detection rows
        baseline = _baseline_velocities(out_boxes.track_id, time_all, det_row_all, det_boxes)
    return _SceneRows(
        out_time=time_all,
        out_frame=np.concatenate(out_frame) if out_frame else np.zeros(0, dtype=np.int64),
        out_boxes=out_boxes,
        det_row=det_row_all,
        det_boxes=det_boxes,
        baseline=baseline,
        gt_boxes=Boxes.concat(gt_parts),
        gt_velocity=np.concatenate(gtv_parts) if gtv_parts else np.zeros((0, 2)),
        pairs=np.concatenate(pair_parts).astype(np.int64)
        if pair_parts
        else np.zeros((0, 2), dtype=np.int64),
    )


def _rows_or_nan(boxes: Boxes | None, rows: IntArray) -> Boxes:
    """``boxes[rows]`` with NaN geometry where ``rows < 0`` (or there are no boxes)."""
    n = rows.shape[0]
    if boxes is None or not len(boxes):
        return Boxes.create(
            xyz=np.full((n, 3), np.nan),
            lwh=None,
            yaw=None,
            category=None,
            velocity=np.full((n, 2), np.nan),
        )
    picked = boxes[np.maximum(rows, 0)]
    missing = rows < 0
    if not missing.any():
        return picked
    nan2, nan3 = np.full((n, 2), np.nan), np.full((n, 3), np.nan)
    return picked.replace(
        xyz=np.where(missing[:, None], nan3, picked.xyz),
        lwh=np.where(missing[:, None], nan3, picked.lwh),
        yaw=np.where(missing, np.nan, picked.yaw),
        velocity=np.where(missing[:, None], nan2, picked.velocity),
    )


def _baseline_velocities(
    track_id: IntArray, times_secs: FloatArray, det_row: IntArray, det_boxes: Boxes | None
) -> dict[Estimator, FloatArray]:
    """Difference and curve-fit velocity at every output row backed by a detection (NaN at the
    others), over each track's detection centres in time order."""
    n = track_id.shape[0]
    diff, curve = np.full((n, 2), np.nan), np.full((n, 2), np.nan)
    if det_boxes is not None:
        rows = np.flatnonzero(det_row >= 0)
        rows = rows[np.lexsort((times_secs[rows], track_id[rows]))]
        if rows.size:  # no row (a scene without a detection-backed output): no track to fit
            ids = track_id[rows]
            starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
            stops = np.r_[starts[1:], rows.size]
            for start, stop in zip(starts, stops, strict=True):
                seg = rows[start:stop]
                t, xy = times_secs[seg], det_boxes.xyz[seg, :2]
                diff[seg] = velocity_differencing(t, xy)
                curve[seg] = velocity_curve_fit(t, xy, window=CURVE_FIT_WINDOW)
    return {Estimator.DIFFERENCE: diff, Estimator.CURVE_FIT: curve}


def collect_motion_samples(
    det_scenes: Mapping[str, Sequence[Frame]] | None,
    gt_scenes: Mapping[str, Sequence[Frame]],
    outputs_by_scene: Mapping[str, Sequence[TrackOutput]],
    *,
    classes: Sequence[str],
    max_distance_m: Mapping[str, float] | None = None,
    gt_velocity: str = "auto",
    detection_velocity: bool | None = None,
) -> dict[str, MotionSamples]:
    """Associate output boxes with GT boxes and gather every estimator's velocity per sample.

    Parameters
    ----------
    det_scenes : the tracker's input frames per scene (``det_row`` indexes their boxes), or None
        (then the detection estimator is absent, and the difference and curve-fit ones unless
        every output carries the tracker's ``baselines``).
    gt_scenes : GT frames per scene (``track_id`` set), any frame order.
    outputs_by_scene : tracker output per scene, any frame order. Scenes without GT are skipped
        (logged).
    classes : class names to evaluate, e.g. ``("car", "pedestrian")``.
    max_distance_m : per-class association threshold overrides (default :data:`MAX_DISTANCE_M`).
    gt_velocity : ``"auto"`` (:func:`resolve_gt_velocity`: from the positions when no GT
        velocity is known, else annotated), ``"annotated"`` or ``"positions"``.
    detection_velocity : does the detector give a velocity? None: yes iff any detection of the
        classes has a non-zero velocity.

    Returns
    -------
    class name -> :class:`MotionSamples` (in ``classes`` order).
    """
    unknown = [c for c in classes if category_index(c) < 0]
    if unknown:
        raise ValueError(f"unknown classes {unknown}; known: {list(CATEGORIES)}")
    if gt_velocity not in ("auto", "annotated", "positions"):
        raise ValueError(f"gt_velocity must be auto, annotated or positions, got {gt_velocity!r}")
    categories = [category_index(c) for c in classes]
    thresholds = {**MAX_DISTANCE_M, **(max_distance_m or {})}
    max_distance_by_category = {
        category_index(c): float(thresholds.get(c, DEFAULT_MAX_DISTANCE_M)) for c in classes
    }
    from_positions = resolve_gt_velocity(gt_velocity, gt_scenes)[0] == "positions"
    scenes = sorted(s for s in outputs_by_scene if s in gt_scenes)
    skipped = sorted(s for s in outputs_by_scene if s not in gt_scenes)
    if skipped:
        log.warning("motion evaluation: no ground truth for scenes %s (skipped)", skipped)
    absent: dict[Estimator, str] = {}
    if det_scenes is None:
        # (an online run's output carries the baselines: they need no detections)
        carried = all(o.baselines is not None for s in scenes for o in outputs_by_scene[s])
        baselines = (Estimator.DIFFERENCE, Estimator.CURVE_FIT) if carried else ()
        absent = {
            e: NO_DETECTIONS for e in Estimator if e is not Estimator.KALMAN and e not in baselines
        }
    else:
        if detection_velocity is None:
            detection_velocity = _detector_has_velocity(det_scenes, categories)
        if not detection_velocity:
            absent[Estimator.DETECTION] = NO_DETECTOR_VELOCITY

    if det_scenes is not None:
        missing = [s for s in scenes if s not in det_scenes]
        if missing:
            raise ValueError(f"no detections for scenes {missing}")
    per_scene = {
        s: _scene_rows(
            s,
            outputs_by_scene[s],
            gt_scenes[s],
            det_scenes[s] if det_scenes is not None else None,
            gt_from_positions=from_positions,
            categories=categories,
            max_distance_by_category=max_distance_by_category,
        )
        for s in scenes
    }
    return {
        name: _class_samples(name, category, per_scene, absent)
        for name, category in zip(classes, categories, strict=True)
    }


def _class_samples(
    name: str, category: int, per_scene: Mapping[str, _SceneRows], absent: dict[Estimator, str]
) -> MotionSamples:
    cols: dict[str, list[Any]] = {}

    def add(key: str, value: Any) -> None:
        cols.setdefault(key, []).append(value)

    n_gt = n_out = n_matched = n_coasting = 0
    for scene, r in per_scene.items():
        n_gt += int(np.sum(r.gt_boxes.category == category))
        n_out += int(np.sum(r.out_boxes.category == category))
        pairs = r.pairs[r.out_boxes.category[r.pairs[:, 0]] == category]
        detected = r.det_row[pairs[:, 0]] >= 0
        n_matched += len(pairs)
        n_coasting += int((~detected).sum())
        o, g = pairs[detected, 0], pairs[detected, 1]
        ob, gb = r.out_boxes[o], r.gt_boxes[g]
        db = r.det_boxes[o] if r.det_boxes is not None else _rows_or_nan(None, o)
        add("scene", np.full(len(o), scene, dtype=object))
        add("frame_id", r.out_frame[o])
        add("times_secs", r.out_time[o])
        add("gt_track_id", gb.track_id)
        add("track_id", ob.track_id)
        add("gt_xy", gb.xyz[:, :2])
        add("gt_velocity", r.gt_velocity[g])
        add("gt_yaw_rad", gb.yaw)
        add("gt_lw", gb.lwh[:, :2])
        add("track_xy", ob.xyz[:, :2])
        add("track_yaw_rad", ob.yaw)
        add("track_lw", ob.lwh[:, :2])
        add("det_xy", db.xyz[:, :2])
        add("det_yaw_rad", db.yaw)
        add("det_lw", db.lwh[:, :2])
        add("distance_m", np.linalg.norm(ob.xyz[:, :2] - gb.xyz[:, :2], axis=1))
        add(Estimator.KALMAN.value, ob.velocity)
        add(Estimator.DETECTION.value, db.velocity)
        for e in (Estimator.DIFFERENCE, Estimator.CURVE_FIT):
            add(e.value, r.baseline[e][o])

    def cat(key: str, shape: tuple[int, ...], dtype: Any = np.float64) -> NDArray[Any]:
        parts = cols.get(key)
        return np.concatenate(parts).astype(dtype) if parts else np.zeros(shape, dtype=dtype)

    scene_col = cat("scene", (0,), object).astype(str)
    gt_id, track_id = cat("gt_track_id", (0,), np.int64), cat("track_id", (0,), np.int64)
    n = scene_col.shape[0]
    velocity = {}
    for e in Estimator:
        v = cat(e.value, (0, 2))
        velocity[e] = np.full((n, 2), np.nan) if e in absent else v
    return MotionSamples(
        category=name,
        scene=scene_col,
        frame_id=cat("frame_id", (0,), np.int64),
        times_secs=cat("times_secs", (0,)),
        gt_track_id=gt_id,
        track_id=track_id,
        gt_key=composite_key(scene_col, gt_id) if n else np.zeros(0, dtype=np.int64),
        est_key=composite_key(scene_col, track_id) if n else np.zeros(0, dtype=np.int64),
        gt_xy=cat("gt_xy", (0, 2)),
        gt_velocity=cat("gt_velocity", (0, 2)),
        gt_yaw_rad=cat("gt_yaw_rad", (0,)),
        gt_lw=cat("gt_lw", (0, 2)),
        track_xy=cat("track_xy", (0, 2)),
        track_yaw_rad=cat("track_yaw_rad", (0,)),
        track_lw=cat("track_lw", (0, 2)),
        det_xy=cat("det_xy", (0, 2)),
        det_yaw_rad=cat("det_yaw_rad", (0,)),
        det_lw=cat("det_lw", (0, 2)),
        distance_m=cat("distance_m", (0,)),
        velocity=velocity,
        absent={e: why for e, why in absent.items()},
        n_gt_boxes=n_gt,
        n_output_boxes=n_out,
        n_matched=n_matched,
        n_matched_coasting=n_coasting,
    )


# --------------------------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------------------------


def _json_number(value: float | int) -> float | int | None:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _metrics_dict(m: MotionMetrics) -> dict[str, float | int | None]:
    return {k: _json_number(v) for k, v in m.as_dict().items()}


def metrics_from_dict(values: Mapping[str, Any]) -> MotionMetrics:
    """A :class:`MotionMetrics` back from its JSON form (None -> NaN; extra keys ignored)."""
    # (results written before n_gt_velocity_unknown counted those rows in n_dropped_samples)
    values = {"n_gt_velocity_unknown": 0, **values}
    return MotionMetrics(
        **{
            f.name: float("nan") if values[f.name] is None else values[f.name]
            for f in fields(MotionMetrics)
        }
    )


def _sample_metrics(
    s: MotionSamples, estimator: Estimator, params: MotionMetricParams | None
) -> MotionMetrics:
    return motion_metrics(
        gt_track_key=s.gt_key,
        times_secs=s.times_secs,
        gt_velocity=s.gt_velocity,
        est_velocity=s.velocity[estimator],
        est_track_key=s.est_key,
        gt_xy=s.gt_xy,
        params=params,
    )


def _box_errors(s: MotionSamples, source: str) -> dict[str, float]:
    """Sums (not means) of the box errors of one source, and their count."""
    xy, yaw, lw = (
        (s.track_xy, s.track_yaw_rad, s.track_lw)
        if source == "tracker"
        else (s.det_xy, s.det_yaw_rad, s.det_lw)
    )
    ok = np.isfinite(xy).all(axis=1) & np.isfinite(yaw) & np.isfinite(lw).all(axis=1)
    heading_error_deg = np.degrees(np.abs(wrap_angle(yaw[ok] - s.gt_yaw_rad[ok])))
    return {
        "position_error_m": float(np.linalg.norm(xy[ok] - s.gt_xy[ok], axis=1).sum()),
        "heading_error_deg": float(heading_error_deg.sum()),
        "heading_flip_ratio": float((heading_error_deg > 90.0).sum()),
        "length_error_m": float(np.abs(lw[ok, 0] - s.gt_lw[ok, 0]).sum()),
        "width_error_m": float(np.abs(lw[ok, 1] - s.gt_lw[ok, 1]).sum()),
        "n_samples": int(ok.sum()),
    }


def _box_error_means(sums: dict[str, float]) -> dict[str, float | int | None]:
    n = int(sums["n_samples"])
    out: dict[str, float | int | None] = {
        k: (v / n if n else None) for k, v in sums.items() if k != "n_samples"
    }
    out["n_samples"] = n
    return out


def evaluate_samples(
    samples_by_class: Mapping[str, MotionSamples],
    *,
    params: MotionMetricParams | None = None,
) -> dict[str, Any]:
    """The motion-evaluation result (JSON-serialisable, NaN written as None).

    Returns
    -------
    ``{"metrics": {estimator: {class | "all": {vae_deg, vne_mps, vaie_deg, vir_ratio, vse_mps,
    vde_secs, n_samples, ...}}}, "absent": {estimator: reason}, "counts": {class | "all":
    {...}}, "box_errors": {"tracker" | "detection": {class | "all": {...}}}}``. The "all" row
    pools the classes with :func:`~tracker.eval.motion_metrics.combine_motion_metrics`.
    """
    metrics: dict[str, dict[str, Any]] = {}
    absent: dict[str, str] = {}
    for e in Estimator:
        per_class = {c: _sample_metrics(s, e, params) for c, s in samples_by_class.items()}
        rows: dict[str, Any] = {c: _metrics_dict(m) for c, m in per_class.items()}
        rows["all"] = _metrics_dict(combine_motion_metrics(list(per_class.values())))
        reasons = {s.absent[e] for s in samples_by_class.values() if e in s.absent}
        if reasons:
            absent[e.value] = sorted(reasons)[0]
            for row in rows.values():
                row["note"] = absent[e.value]
        metrics[e.value] = rows

    counts: dict[str, dict[str, int]] = {
        c: {
            "gt_boxes": s.n_gt_boxes,
            "output_boxes": s.n_output_boxes,
            "matched": s.n_matched,
            "matched_coasting": s.n_matched_coasting,
            "samples": len(s),
            # (samples left out of every estimator's velocity metrics, not scored as 0)
            "gt_velocity_unknown": int((~np.isfinite(s.gt_velocity).all(axis=1)).sum()),
            "gt_tracks": int(np.unique(s.gt_key).size),
            "output_tracks": int(np.unique(s.est_key).size),
        }
        for c, s in samples_by_class.items()
    }
    counts["all"] = {k: sum(v[k] for v in counts.values()) for k in next(iter(counts.values()), {})}

    box_errors: dict[str, dict[str, Any]] = {}
    for source in ("tracker", "detection"):
        sums = {c: _box_errors(s, source) for c, s in samples_by_class.items()}
        total = {k: sum(v[k] for v in sums.values()) for k in next(iter(sums.values()), {})}
        box_errors[source] = {c: _box_error_means(v) for c, v in sums.items()}
        if total:
            box_errors[source]["all"] = _box_error_means(total)
    return {"metrics": metrics, "absent": absent, "counts": counts, "box_errors": box_errors}


def evaluate_motion(
    det_scenes: Mapping[str, Sequence[Frame]] | None,
    gt_scenes: Mapping[str, Sequence[Frame]],
    outputs_by_scene: Mapping[str, Sequence[TrackOutput]],
    *,
    classes: Sequence[str],
    max_distance_m: Mapping[str, float] | None = None,
    gt_velocity: str = "auto",
    detection_velocity: bool | None = None,
    params: MotionMetricParams | None = None,
    plot_path: str | Path | None = None,
) -> dict[str, Any]:
    """VAE, VNE, VAIE, VIR, VSE, VDE per estimator and class (see the module docstring).

    Parameters are those of :func:`collect_motion_samples`, plus ``params`` (thresholds of the
    metrics) and ``plot_path``: when given, :func:`plot_velocity_curves` writes the velocity
    curves of the tracks with the largest delay there.

    Returns
    -------
    :func:`evaluate_samples`' dict plus a ``"protocol"`` block (and ``"plot"`` with the plotted
    tracks when ``plot_path`` is given); JSON-serialisable, NaN written as None.
    """
    gt_velocity, legacy = resolve_gt_velocity(gt_velocity, gt_scenes)  # (collect checks it)
    samples = collect_motion_samples(
        det_scenes,
        gt_scenes,
        outputs_by_scene,
        classes=classes,
        max_distance_m=max_distance_m,
        gt_velocity=gt_velocity,
        detection_velocity=detection_velocity,
    )
    thresholds = {**MAX_DISTANCE_M, **(max_distance_m or {})}
    protocol = {
        "association": "greedy by descending output score on BEV centre distance, per class",
        "max_distance_m": {c: float(thresholds.get(c, DEFAULT_MAX_DISTANCE_M)) for c in classes},
        "samples": "matched output boxes updated by a detection that frame (det_row >= 0)",
        "gt_velocity": "annotated (GT box velocity)"
        if gt_velocity == "annotated"
        else f"GT world positions, central LSQ quadratic over {GT_SMOOTH_WINDOW} samples"
        + (f" ({LEGACY_ZERO_GT_VELOCITY_NOTE})" if legacy else ""),
        "estimators": {e.value: ESTIMATOR_DESCRIPTIONS[e] for e in Estimator},
        "scenes": sorted(s for s in outputs_by_scene if s in gt_scenes),
    }
    result = {"protocol": protocol, **evaluate_samples(samples, params=params)}
    if plot_path is not None:
        result["plot"] = {
            "path": str(plot_path),
            "tracks": plot_velocity_curves(samples, plot_path, params=params),
        }
    return result


# --------------------------------------------------------------------------------------------
# Report: markdown and velocity curves
# --------------------------------------------------------------------------------------------


def _fmt(value: Any, digits: int) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    return f"{value:.{digits}f}"


#: File name of the velocity-curve plot, written next to the report that embeds it.
MOTION_PLOT = "motion_velocity.png"


def motion_report_lines(result: Mapping[str, Any]) -> list[str]:
    """The motion section of a run's report: the metric tables, then the embedded plot
    (``plot_path=out / MOTION_PLOT`` given to :func:`evaluate_motion`)."""
    return [motion_markdown(result, heading_level=2), f"![velocity curves]({MOTION_PLOT})", ""]


def motion_markdown(result: Mapping[str, Any], *, heading_level: int = 3) -> str:
    """Markdown tables of an :func:`evaluate_motion` result: estimator × metric per class, then
    the box errors. An absent estimator's row says why instead of showing numbers."""
    h = "#" * heading_level
    metrics, absent = result["metrics"], result.get("absent", {})
    classes = list(next(iter(metrics.values())).keys())
    lines: list[str] = []
    header = "| estimator | " + " | ".join(t for _, t in METRIC_COLUMNS) + " | samples |"
    rule = "|---|" + "---:|" * (len(METRIC_COLUMNS) + 1)
    for cls in classes:
        counts = result.get("counts", {}).get(cls, {})
        lines += [f"{h} Motion metrics: {cls}", ""]
        if counts:
            unknown = counts.get("gt_velocity_unknown", 0)
            lines += [
                f"{counts['samples']} samples ({counts['gt_tracks']} GT tracks with samples, "
                f"{counts['output_tracks']} output tracks); {counts['matched']} matched boxes of "
                f"which {counts['matched_coasting']} coasting (not samples)."
                + (
                    " Samples whose GT velocity is unknown, left out of the velocity metrics: "
                    f"{unknown}."
                    if unknown
                    else ""
                ),
                "",
            ]
        lines += [header, rule]
        for est, rows in metrics.items():
            row = rows[cls]
            if est in absent:
                cells = [absent[est]] + [""] * (len(METRIC_COLUMNS) - 1) + ["0"]
            else:
                cells = [
                    _fmt(row[k], 3 if k in ("vir_ratio", "vne_mps", "vse_mps") else 2)
                    for k, _ in METRIC_COLUMNS
                ] + [str(row["n_samples"])]
            lines.append(f"| {est} | " + " | ".join(cells) + " |")
        lines.append("")
    errors = result.get("box_errors", {})
    if errors:
        lines += [
            f"{h} Box errors of the matched samples",
            "",
            "Mean BEV centre distance, wrapped heading error (0-180°), fraction of headings off by "
            "more than 90°, and absolute length and width errors against the matched GT box.",
            "",
            "| source | class | " + " | ".join(t for _, t in BOX_ERROR_COLUMNS) + " | samples |",
            "|---|---|" + "---:|" * (len(BOX_ERROR_COLUMNS) + 1),
        ]
        for source, rows in errors.items():
            for cls, row in rows.items():
                if not row["n_samples"]:
                    continue
                cells = [_fmt(row[k], 3) for k, _ in BOX_ERROR_COLUMNS]
                lines.append(
                    f"| {source} | {cls} | " + " | ".join(cells) + f" | {row['n_samples']} |"
                )
        lines.append("")
    return "\n".join(lines)


def largest_delay_tracks(
    samples_by_class: Mapping[str, MotionSamples],
    *,
    estimator: Estimator = Estimator.KALMAN,
    count: int = 4,
    moving_only: bool = True,
    params: MotionMetricParams | None = None,
) -> list[tuple[str, int, float]]:
    """The GT tracks whose ``estimator`` speed lags the GT speed most (VDE's per-track delay).

    With ``moving_only`` the static GT tracks (:func:`~tracker.eval.motion_metrics.static_gt_mask`)
    are left out: their "peaks" are label and pose noise, and so is their delay.

    Returns up to ``count`` ``(class, gt_key, delay_secs)``, largest max-delay first (ties: the
    longer track, then the smaller key). Tracks with no VDE candidate are left out.
    """
    ranked: list[tuple[float, int, str, int]] = []
    for cls, s in samples_by_class.items():
        keys = s.gt_key
        if moving_only:
            known = np.isfinite(s.gt_velocity).all(axis=1)
            static = static_gt_mask(
                s.gt_key[known], s.gt_velocity[known], s.gt_xy[known], params=params
            )
            keys = s.gt_key[known][~static]
        for key in np.unique(keys):
            ok, _, delays = _track_delays(s, int(key), estimator, params)
            if delays.size:
                ranked.append((float(delays.max()), int(ok.size), cls, int(key)))
    ranked.sort(key=lambda r: (-r[0], -r[1], r[2], r[3]))
    return [(cls, key, delay) for delay, _, cls, key in ranked[:count]]


def _track_delays(
    s: MotionSamples, key: int, estimator: Estimator, params: MotionMetricParams | None
) -> tuple[IntArray, IntArray, FloatArray]:
    """(the GT track's sample rows with both speeds known, in time order; the row of each
    delay's GT speed peak; the delays, s) of ``estimator`` behind the GT track ``key``."""
    v = s.velocity[estimator]
    rows = np.flatnonzero(s.gt_key == key)
    rows = rows[np.argsort(s.times_secs[rows], kind="stable")]
    ok = rows[np.isfinite(s.gt_velocity[rows]).all(axis=1) & np.isfinite(v[rows]).all(1)]
    if ok.size < 2:
        return ok, np.zeros(0, np.int64), np.zeros(0)
    at, delays = velocity_delays_at_peaks(
        s.times_secs[ok],
        np.linalg.norm(s.gt_velocity[ok], axis=1),
        np.linalg.norm(v[ok], axis=1),
        params=params,
    )
    return ok, ok[at], delays


def _break_gaps(times_secs: FloatArray, values: FloatArray) -> FloatArray:
    """``values`` with a NaN inserted after every gap (Δt > 1.5 × the median step), so a plotted
    line is not drawn across frames where the GT track was not matched."""
    if times_secs.size < 3:
        return values.astype(np.float64)
    steps = np.diff(times_secs)
    after = np.flatnonzero(steps > GAP_FACTOR * np.median(steps)) + 1
    return np.insert(values.astype(np.float64), after, np.nan)


def plot_velocity_curves(
    samples_by_class: Mapping[str, MotionSamples],
    path: str | Path,
    *,
    count: int = 4,
    params: MotionMetricParams | None = None,
) -> list[dict[str, Any]]:
    """PNG of GT speed vs every present estimator's speed over time, for the ``count`` moving GT
    tracks with the largest Kalman delay (:func:`largest_delay_tracks`; static ones only when no
    moving track has a delay); one panel per track.

    Returns the plotted tracks (class, scene, GT id, delay) for the report.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    chosen = largest_delay_tracks(samples_by_class, count=count, params=params)
    if not chosen:
        chosen = largest_delay_tracks(
            samples_by_class, count=count, moving_only=False, params=params
        )
    panels = max(len(chosen), 1)
    fig, axes = plt.subplots(panels, 1, figsize=(9, 2.6 * panels), squeeze=False)
    plotted: list[dict[str, Any]] = []
    styles = {
        Estimator.KALMAN: ("tab:blue", "-"),
        Estimator.DETECTION: ("tab:green", ":"),
        Estimator.DIFFERENCE: ("tab:orange", "--"),
        Estimator.CURVE_FIT: ("tab:red", "-."),
    }
    for ax, (cls, key, delay) in zip(axes[:, 0], chosen, strict=False):
        s = samples_by_class[cls]
        rows = np.flatnonzero(s.gt_key == key)
        rows = rows[np.argsort(s.times_secs[rows], kind="stable")]
        t = _break_gaps(s.times_secs[rows], s.times_secs[rows])
        scene, gt_id = str(s.scene[rows[0]]), int(s.gt_track_id[rows[0]])
        gt_speed = np.linalg.norm(s.gt_velocity[rows], axis=1)
        ax.plot(t, _break_gaps(s.times_secs[rows], gt_speed), "k-", lw=2.0, label="GT")
        for e, (colour, style) in styles.items():
            if e in s.absent:
                continue
            ax.plot(
                t,
                _break_gaps(s.times_secs[rows], np.linalg.norm(s.velocity[e][rows], axis=1)),
                color=colour,
                ls=style,
                lw=1.2,
                label=e.value,
            )
        # where the delay is: the GT speed peak it was measured at (the first of the largest),
        # and an arrow from there to where the Kalman curve reaches it that much later
        _, peaks, delays = _track_delays(s, key, Estimator.KALMAN, params)
        peak = int(peaks[int(np.argmax(delays))])
        t_peak, v_peak = float(s.times_secs[peak]), float(np.linalg.norm(s.gt_velocity[peak]))
        frame = int(s.frame_id[peak])
        ax.axvline(t_peak, color="tab:blue", ls=":", lw=1.0)
        ax.plot([t_peak], [v_peak], "o", ms=7, mfc="none", mec="tab:blue", mew=1.5)
        ax.annotate(
            "",
            xy=(t_peak + delay, v_peak),
            xytext=(t_peak, v_peak),
            arrowprops={"arrowstyle": "->", "color": "tab:blue", "lw": 1.2},
        )
        ax.set_title(
            f"{cls}, scene {scene}, GT track {gt_id}: Kalman delay {delay:.1f} s at frame "
            f"{frame} (t = {t_peak:.1f} s, marked)",
            fontsize=9,
        )
        ax.set_ylabel("speed (m/s)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=5, loc="upper right")
        plotted.append(
            {
                "class": cls,
                "scene": scene,
                "gt_track_id": gt_id,
                "kalman_delay_secs": delay,
                "kalman_delay_frame": frame,
            }
        )
    if not chosen:
        axes[0, 0].text(0.5, 0.5, "no GT track qualifies for VDE", ha="center", va="center")
        axes[0, 0].set_axis_off()
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return plotted
