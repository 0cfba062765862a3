"""One call from frames to a complete debug recording: :func:`record_scene`.

During the run the :class:`~viz.observer.RerunObserver` streams every stage to the sinks (a
file sink keeps memory flat). Whatever is only known after the run is logged at the end: the
velocity curves (``send_columns``, one call per series), the ID switches and fragmentations
against the ground truth (at their frames), the summary and the index of frames worth a
screenshot (``summary/index``, read back by ``mctrack shots``), and the final blueprint, which
focuses the velocity views on the tracks of the largest lag and of the first ID switch.
"""

from __future__ import annotations

import functools
import gc
import itertools
import json
import logging
import math
import shlex
import time
import uuid
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import rerun as rr

from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.config import TrackerConfig, config_to_dict
from tracker.eval.fates import FateCounter, Tee
from tracker.eval.id_causes import (
    CAUSE_HELP,
    Cause,
    EventCause,
    StageLog,
    cause_counts,
    cause_table_markdown,
    classify_events,
)
from tracker.eval.id_switches import (
    IdEvaluation,
    IdEvent,
    IdEventKind,
    bev_id_events,
    kitti_evaluation_and_id_events,
)
from tracker.eval.kitti import SequenceEvaluation
from tracker.eval.motion_metrics import gt_velocity_central
from tracker.events import Observer, TrackOutput
from tracker.frame import Frame
from tracker.io.fileio import (
    finish_temp,
    path_in,
    remove_stale_temps,
    temp_name,
    work_folder,
)
from tracker.pipeline import run_scene
from viz import paths
from viz.archetypes import (
    ID_SWITCH_RGB,
    annotation_context,
    pack_rgb,
    quaternions_xyzw,
    track_colors_u32,
)
from viz.columns import ColumnBuffer, SeriesColumns, StaticEntities, pair_key, unit_lists
from viz.layout import debug_blueprint
from viz.observer import RerunObserver

log = logging.getLogger(__name__)

KITTI_EVAL_CLASSES = ("car", "pedestrian", "cyclist")
#: Output samples at the start of each track left out of the lag search: the filter starts from
#: zero velocity (KITTI detections carry none) and its birth transient (spikes to 13 m/s seen)
#: is not lag. 10 samples = 1 s at KITTI's 10 Hz.
LAG_WARMUP_SAMPLES = 10
#: Velocity-lag search (:func:`find_velocity_lag`): a (track, GT object) pair qualifies with at
#: least LAG_MIN_SAMPLES samples whose smoothed GT speed (moving average of LAG_SMOOTH_SAMPLES)
#: changes by at least LAG_MIN_SPEED_CHANGE_MPS and by LAG_NOISE_FACTOR times the GT speed's own
#: noise (std of GT speed minus its smoothed curve); its lag is the shift of the track's speed
#: (0..LAG_MAX_SHIFT_SAMPLES) that best matches the GT's, counted only when it reduces the mean
#: speed gap by at least LAG_MIN_IMPROVEMENT (fraction) over no shift.
LAG_MIN_SAMPLES = 20
LAG_SMOOTH_SAMPLES = 5
LAG_MIN_SPEED_CHANGE_MPS = 1.0
LAG_NOISE_FACTOR = 3.0
LAG_MAX_SHIFT_SAMPLES = 15
LAG_MIN_IMPROVEMENT = 0.2
LAG_CRITERION = (
    f"GT speed change >= {LAG_MIN_SPEED_CHANGE_MPS:g} m/s and >= {LAG_NOISE_FACTOR:g}x its "
    f"noise over >= {LAG_MIN_SAMPLES} samples, first {LAG_WARMUP_SAMPLES} outputs of a track "
    f"skipped, shift cuts the mean speed gap by >= {LAG_MIN_IMPROVEMENT:.0%}"
)
#: How long an ID-switch marker stays in the 3D view after its frame (scrubbing finds it).
MARKER_HOLD_FRAMES = 5
#: A picture of an event prefers a frame with a camera image at most this many frames away.
IMAGE_SEARCH_FRAMES = 3
#: Frames of track trails and GT path drawn before / after an event in its focused view.
FOCUS_BEFORE_FRAMES = 20
FOCUS_AFTER_FRAMES = 10
GT_SERIES_RGB = (60, 220, 120)
GT_SERIES_U32 = int(pack_rgb(GT_SERIES_RGB))
#: Tracks output in fewer frames get no velocity curves: a one- or two-point "curve" shows
#: nothing, and on KITTI most such tracks are false positives (hundreds of entities otherwise).
MIN_SERIES_SAMPLES = 3


@dataclass(frozen=True, slots=True)
class LagSample:
    """Where the velocity lags most (see :func:`find_velocity_lag`)."""

    frame_id: int
    track_id: int
    gt_id: int
    track_speed_mps: float
    gt_speed_mps: float
    delay_secs: float  # how far the track's speed curve trails the GT's
    speed_change_mps: float = float("nan")  # range of the smoothed GT speed
    mean_gap_before_mps: float = float("nan")  # mean |track - GT| speed, unshifted
    mean_gap_after_mps: float = float("nan")  # the same with the track shifted by the delay
    speed_max_mps: float = float("nan")  # largest speed of the pair after the warm-up (plot range)

    @property
    def error_mps(self) -> float:
        return abs(self.track_speed_mps - self.gt_speed_mps)


@dataclass(frozen=True, slots=True)
class EventFocus:
    """Where ID event ``index`` happened: the focused view's target and its best frame."""

    index: int
    frame_id: int
    shot_frame: int  # the event frame, or the nearest one with a camera image nearby
    xyz: tuple[float, float, float]  # world position of the GT object (NaN when unknown)
    track_ids: tuple[int, int]  # old, new


@dataclass
class RecordResult:
    """What :func:`record_scene` did: the tracker's outputs, timings and the GT analysis."""

    scene: str
    path: Path | None
    outputs: list[TrackOutput]
    tracker_seconds: float  # tracker + observer (the observer runs inside each step)
    total_seconds: float  # everything, post-run analysis and flushing included
    id_evaluation: IdEvaluation | None = None
    lag: LagSample | None = None
    kitti_metrics: dict[str, dict[str, float]] | None = None
    motion_markdown: str = "motion metrics: not available"
    counts: dict[str, int] = field(default_factory=dict)
    #: the cause of every ID event (same order as ``id_evaluation.events``)
    causes: list[EventCause] = field(default_factory=list)
    #: per ID event: where the focused view looks (world xyz) and the frame worth a picture
    focus: list[EventFocus] = field(default_factory=list)
    #: frames with a camera image
    image_frames: list[int] = field(default_factory=list)
    #: camera images left out of the recording, each a line naming the file and why (a file
    #: that cannot be read or decoded: RerunObserver.skipped_images)
    skipped_images: list[str] = field(default_factory=list)
    #: wall seconds per phase: "track" (tracker + observer), "flush", "evaluate" (ID switches,
    #: TrackEval, motion metrics: analysis, not recording), "post" (curves, events, summary)
    seconds: dict[str, float] = field(default_factory=dict)
    #: process CPU seconds per phase (all threads: Rerun compresses and writes in the background)
    cpu_seconds: dict[str, float] = field(default_factory=dict)
    #: detections per fate and class (tracker.eval.fates.FateCounter.summary)
    fates: dict[str, Any] = field(default_factory=dict)
    #: TrackEval's per-sequence results (KITTI labels), for combining a run's sequences
    evaluation: SequenceEvaluation | None = None
    #: offline post-processing's removed tracks (tracker.pipeline.SceneResult.removed_offline)
    removed_offline: list[Any] = field(default_factory=list)

    @property
    def recording_seconds(self) -> float:
        """Wall time of everything except the evaluation."""
        return self.total_seconds - self.seconds.get("evaluate", 0.0)

    @property
    def track_ids(self) -> list[int]:
        return sorted({int(i) for o in self.outputs for i in o.boxes.track_id})


def partial_path(path: Path) -> Path:
    """Where to stream a recording meant for ``path``: a hidden temporary name in the same
    folder, renamed by :func:`tracker.io.fileio.finish_temp` when complete (a killed run leaves
    no footer-less file under the real name; the next run removes the temporary one)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(path.parent)
    return path.parent / f"{temp_name(path)}{uuid.uuid4().hex[:8]}.tmp"


def new_recording(
    scene: str,
    *,
    path: str | Path | None = None,
    recording_id: str | None = None,
) -> rr.RecordingStream:
    """A recording stream of its own (never the global one); with ``path`` it streams to a file.

    The blueprint is sent at the end of :func:`record_scene` (it depends on the results); a live
    viewer gets a preliminary one right away from the caller.
    """
    rec = rr.RecordingStream(
        paths.APPLICATION_ID, recording_id=recording_id or f"{scene}-{uuid.uuid4().hex[:8]}"
    )
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        rec.save(path)
    rec.send_recording_name(f"MCTrack {scene}")
    return rec


def _heap_frozen(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Run ``fn`` with the objects alive at its start frozen for the garbage collector.

    A recording keeps its per-frame rows alive until they are sent, which makes Python's
    cyclic GC run a full collection during the run now and then; a full collection walks every
    object of the process (rerun, pyarrow, TrackEval, the scene's frames): 0.2-0.25 s on KITTI
    0001, ~0.5 ms per frame whenever it lands in a recording, the largest part of the
    run-to-run spread of ``bench/bench_record.py``. Frozen objects are skipped by collections
    (``gc.freeze``) and put back afterwards. If the caller froze objects already, their state is
    left alone."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        if gc.get_freeze_count():
            return fn(*args, **kwargs)
        gc.freeze()
        try:
            return fn(*args, **kwargs)
        finally:
            gc.unfreeze()

    return wrapper


@_heap_frozen
def record_scene(
    frames: Sequence[Frame],
    config: TrackerConfig,
    gt_frames: Sequence[Frame] | None = None,
    path: str | Path | None = None,
    *,
    rec: rr.RecordingStream | None = None,
    labels_dir: str | Path | None = None,
    images: Mapping[str, str | Path] | None = None,
    input_description: str = "",
    motion_metrics: bool = True,
    live: bool = False,
    kitti_metrics: dict[str, dict[str, float]] | None = None,
    result_file: str | Path | None = None,
    progress: Observer | None = None,
    on_tracked: Callable[[list[TrackOutput]], None] | None = None,
) -> RecordResult:
    """Track one scene with the Rerun observer and write the full debug recording.

    Parameters
    ----------
    frames : the scene's detection frames, in time order.
    config : the resolved tracker configuration.
    gt_frames : ground truth of the same scene (GT boxes, velocity curves, and the ID switches
        by BEV IoU when there are no KITTI labels).
    path : the ``.rrd`` to write (streamed). Ignored when ``rec`` is given.
    rec : an existing stream (live viewer, web viewer); the caller owns and closes it.
    labels_dir : a KITTI ``label_02`` folder: when it has ``<scene>.txt``, the ID switches and
        the static metrics come from TrackEval's KITTI protocol (also without ``gt_frames``).
    images : camera name -> folder of ``<frame_id:06d>.png`` images.
    input_description : free text for the summary (input files, frame range).
    motion_metrics : call ``tracker.eval.motion_eval.evaluate_motion`` when it is importable.
    live : a viewer watches while it runs: send rows every few frames instead of every few
        hundred (slightly more overhead, no visible lag).
    kitti_metrics : this sequence's TrackEval metrics when the caller has them already
        (``mctrack kitti`` evaluates all sequences in one run); else computed here.
    result_file : the KITTI result file of this very run, written by then (see ``on_tracked``).
    progress : also gets every stage event (a progress bar counts ``FrameStarted``).
    on_tracked : called with the outputs as soon as tracking ends, before the evaluation (a
        caller writes its result files there: ``mctrack kitti`` tracks once, with the recording).

    Returns
    -------
    The outputs (identical to a run without observer), timings and the GT analysis.
    """
    start, cpu_start = time.perf_counter(), time.process_time()
    scene = frames[0].scene if frames else ""
    cameras = [(c.name, c.width_px, c.height_px) for c in frames[0].cameras] if frames else []
    camera_names = [name for name, _, _ in cameras]
    own = rec is None
    partial: Path | None = None
    if rec is None:
        # stream to a hidden temporary name, renamed when complete: a killed run leaves no
        # footer-less file under the real name (and the next write to the folder removes it)
        partial = None if path is None else partial_path(Path(path))
        rec = new_recording(scene, path=partial)
    rec.log(paths.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log("/", annotation_context(), static=True)

    gt_by_frame = {f.frame_id: f for f in gt_frames} if gt_frames else None
    # named as the label checks (tracker.eval.kitti) and mctrack kitti find it: escaped, inside
    label_file = path_in(labels_dir, scene, ".txt") if labels_dir else None
    if label_file is not None and not (label_file.is_file() and camera_names):
        label_file = None
    observer = RerunObserver(
        rec,
        gt=gt_by_frame,
        images=images,
        flush_rows=8 if live else 512,
        flush_secs=0.25 if live else 4.0,
    )
    fates = FateCounter(rv_gate_consumes=config.rv_reference)
    # the stage log explains the ID events afterwards (only worth keeping with a GT)
    stages = StageLog() if (gt_frames or label_file is not None) else None
    scene_result = run_scene(frames, config, observer=Tee(observer, fates, stages, progress))
    t_track, c_track = time.perf_counter(), time.process_time()
    observer.flush()
    t_flush, c_flush = time.perf_counter(), time.process_time()
    outputs = scene_result.outputs
    result = RecordResult(
        scene=scene,
        path=Path(path) if (own and path is not None) else None,
        outputs=outputs,
        tracker_seconds=scene_result.tracker_seconds,
        total_seconds=0.0,
        removed_offline=list(scene_result.removed_offline),
    )

    if on_tracked is not None:
        on_tracked(outputs)
    gt_index = _GtIndex(gt_frames) if gt_frames else None
    with work_folder("record") as tmp:
        if label_file is not None:
            restricted = _labels_for_frames(label_file, frames, tmp)
            classes = [c for c in config.categories if c in KITTI_EVAL_CLASSES]
            # one TrackEval loading and preprocessing gives the metrics and the ID events
            evaluation, result.id_evaluation = kitti_evaluation_and_id_events(
                outputs,
                frames,
                restricted,
                classes=classes,
                camera_name=camera_names[0],
                result_file=result_file if restricted == label_file else None,
                **config.kitti_writer_options(),
            )
            result.evaluation = evaluation.without_id_inputs()
            result.kitti_metrics = kitti_metrics or evaluation.metrics
        elif gt_frames:
            result.id_evaluation = bev_id_events(
                outputs, gt_frames, categories=list(config.categories)
            )
    if result.id_evaluation is not None and stages is not None:
        result.causes = classify_events(result.id_evaluation, stages, gt_by_frame or {})
    result.image_frames = observer.image_frames
    result.skipped_images = observer.skipped_images
    if gt_frames and motion_metrics:
        result.motion_markdown = _motion_metrics(frames, gt_frames, outputs, config)
    t_eval, c_eval = time.perf_counter(), time.process_time()

    times = _frame_times(outputs, gt_frames)
    result.lag, n_series = _log_velocity_series(rec, outputs, times, result.id_evaluation, gt_index)
    if result.id_evaluation is not None:
        result.focus = _log_id_events(rec, result, times, gt_index, stages)
    if observer.ego_xyz:
        rec.log(
            paths.EGO_PATH,
            rr.LineStrips3D([np.array(observer.ego_xyz)], colors=(200, 200, 200), radii=0.05),
            static=True,
        )
    result.counts = {
        "frames": len(frames),
        "tracks": len(result.track_ids),
        f"tracks with velocity curves (>= {MIN_SERIES_SAMPLES} outputs)": n_series,
        "detections_raw": observer.detection_counts["raw"],
        "detections_kept": observer.detection_counts["kept"],
        **{f"tracks_{k}": v for k, v in observer.lifecycle_counts.items()},
    }
    result.fates = fates.summary()
    _log_index(rec, result)
    rec.log(
        paths.SUMMARY,
        rr.TextDocument(
            summary_markdown(result, config, input_description),
            media_type=rr.MediaType.MARKDOWN,
        ),
        static=True,
    )
    first_switch = result.id_evaluation.id_switches[:1] if result.id_evaluation else []
    rec.send_blueprint(
        debug_blueprint(
            cameras,
            lag_track_ids=[result.lag.track_id] if result.lag else [],
            # the y axis fits the pair after the warm-up: a birth spike would squash the curves
            lag_speed_max_mps=1.15 * result.lag.speed_max_mps if result.lag else None,
            switch_track_ids=[e for s in first_switch for e in (s.old_track_id, s.new_track_id)],
            switch_gt_id=first_switch[0].gt_id if first_switch and gt_index is not None else None,
            noise_view=any(c.pose.r_scale > 0 for c in config.per_category.values()),
            gate_view=any(
                math.isfinite(config.per_category[name].bev.gate_motion_m)
                for name in config.categories
                if name in config.per_category
            ),
        ),
        make_active=True,
        make_default=True,
    )
    if own:
        rec.flush()
        rec.disconnect()
        if partial is not None and path is not None:
            finish_temp(partial, Path(path))
    end, cpu_end = time.perf_counter(), time.process_time()
    result.total_seconds = end - start
    result.cpu_seconds = {
        "track": c_track - cpu_start,
        "flush": c_flush - c_track,
        "evaluate": c_eval - c_flush,
        "post": cpu_end - c_eval,
    }
    result.seconds = {
        "track": t_track - start,
        "flush": t_flush - t_track,
        "evaluate": t_eval - t_flush,
        "post": end - t_eval,
    }
    return result


# ---------------------------------------------------------------------------------------------
# ground truth helpers


class _GtIndex:
    """GT boxes of a scene as one table, with the GT velocity from positions per GT id."""

    def __init__(self, gt_frames: Sequence[Frame]) -> None:
        self.boxes = Boxes.concat([f.boxes for f in gt_frames])
        self.frame_id = np.concatenate(
            [np.full(len(f.boxes), f.frame_id, dtype=np.int64) for f in gt_frames]
        )
        times = np.concatenate([np.full(len(f.boxes), f.timestamp_secs) for f in gt_frames])
        if not np.isfinite(times).all():
            times = self.frame_id * 0.1  # BaseVersion without timestamps: KITTI's 10 Hz
        self.velocity = np.full((len(self.boxes), 2), np.nan)
        ids = self.boxes.track_id
        order = np.lexsort((times, ids))
        bounds = np.flatnonzero(np.r_[True, ids[order][1:] != ids[order][:-1], True])
        for a, b in itertools.pairwise(bounds if len(ids) else ()):  # (no box: no id)
            rows = order[a:b]
            t = times[rows]
            keep = np.r_[True, np.diff(t) > 0]  # a GT id twice in one frame: first one wins
            rows, t = rows[keep], t[keep]
            self.velocity[rows] = gt_velocity_central(t, self.boxes.xyz[rows, :2])
        self._keys = pair_key(self.frame_id, ids)

    def rows(self, frame_ids: IntArray, gt_ids: IntArray) -> IntArray:
        """Row of each (frame, GT id); -1 when absent."""
        return _lookup(self._keys, np.arange(len(self._keys)), pair_key(frame_ids, gt_ids))


def _labels_for_frames(label_file: Path, frames: Sequence[Frame], tmp: Path) -> Path:
    """The label file restricted to the tracked frames (a --frames range is not all FNs)."""
    wanted = {f.frame_id for f in frames}
    lines = label_file.read_text().splitlines(keepends=True)
    kept = [ln for ln in lines if ln.strip() and int(ln.split(maxsplit=1)[0]) in wanted]
    if len(kept) == sum(1 for ln in lines if ln.strip()):
        return label_file
    target = tmp / "labels" / label_file.name
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text("".join(kept))
    return target


def _motion_metrics(
    frames: Sequence[Frame],
    gt_frames: Sequence[Frame],
    outputs: Sequence[TrackOutput],
    config: TrackerConfig,
) -> str:
    """Motion metrics from ``tracker.eval.motion_eval`` (written separately) when it is there."""
    try:
        from tracker.eval.motion_eval import evaluate_motion, motion_markdown
    except ImportError:
        return "motion metrics: not available"
    scene = frames[0].scene
    try:
        result = evaluate_motion(
            {scene: frames}, {scene: gt_frames}, {scene: outputs}, classes=list(config.categories)
        )
        return motion_markdown(result, heading_level=3)
    except Exception as exc:  # a module under construction must not break recording
        log.warning("motion metrics failed: %s", exc)
        return f"motion metrics: not available ({type(exc).__name__}: {exc})"


# ---------------------------------------------------------------------------------------------
# post-run logging


def _frame_times(
    outputs: Sequence[TrackOutput], gt_frames: Sequence[Frame] | None
) -> dict[int, float]:
    """frame id -> time: the tracker outputs one row per frame, with its time."""
    times = {f.frame_id: f.timestamp_secs for f in gt_frames or ()}
    times.update({o.frame_id: o.time_secs for o in outputs})
    return times


def _log_velocity_series(
    rec: rr.RecordingStream,
    outputs: Sequence[TrackOutput],
    times: Mapping[int, float],
    evaluation: IdEvaluation | None,
    gt: _GtIndex | None,
) -> tuple[LagSample | None, int]:
    """tracks/<id>/{speed, velocity_x, velocity_y, heading, acceleration_x, acceleration_y}
    and the matched GT's curves (no GT acceleration).

    One ``send_columns`` per curve, sliced from arrow arrays built once for all tracks
    (:class:`viz.columns.SeriesColumns`). The style (colour, legend name) rides along as per-row
    components instead of a static ``SeriesLines`` log: a static log per entity costs ~0.3 ms
    each for hundreds of entities (and mixes static and temporal data on one entity).

    Returns the largest lag and the number of tracks given curves.
    """
    if not outputs:
        return None, 0
    boxes = Boxes.concat([o.boxes for o in outputs])
    lengths = np.array([len(o) for o in outputs], dtype=np.int64)
    out_frames = np.array([o.frame_id for o in outputs], dtype=np.int64)
    frame_ids = np.repeat(out_frames, lengths)
    time_of = np.repeat(np.array([times[int(f)] for f in out_frames.tolist()]), lengths)
    ids = boxes.track_id
    # GT matched to each output row (CLEAR matches of its frame)
    gt_row = np.full(len(boxes), -1, dtype=np.int64)
    gt_id = np.full(len(boxes), -1, dtype=np.int64)
    if evaluation is not None and gt is not None:
        matched = [m for m in evaluation.matches if len(m.track_ids)]
        if matched:
            m_frame = np.concatenate([np.full(len(m.track_ids), m.frame_id) for m in matched])
            m_track = np.concatenate([m.track_ids for m in matched])
            m_gt = np.concatenate([m.gt_ids for m in matched])
            gt_id = _lookup(pair_key(m_frame, m_track), m_gt, pair_key(frame_ids, ids))
        has = gt_id >= 0
        gt_row[has] = gt.rows(frame_ids[has], gt_id[has])

    speed = np.hypot(boxes.velocity[:, 0], boxes.velocity[:, 1])
    acceleration = np.concatenate([o.acceleration for o in outputs])
    order = np.lexsort((frame_ids, ids))
    bounds = np.flatnonzero(np.r_[True, ids[order][1:] != ids[order][:-1], True])
    group_len = np.diff(bounds)
    keep = group_len >= MIN_SERIES_SAMPLES
    rows = order[np.repeat(keep, group_len)]  # the kept tracks' rows, by track then frame
    counts = group_len[keep]
    n_tracks = len(counts)
    if not n_tracks:
        return None, 0
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    track_ids = ids[rows[starts]]
    group = np.repeat(np.arange(n_tracks), counts)  # track (series) index of every row
    f, t = frame_ids[rows], time_of[rows]
    own = SeriesColumns(f, t, starts, counts)
    colors = unit_lists(np.repeat(track_colors_u32(track_ids), counts), pa.uint32())
    scalars, names, gt_names = {}, {}, {}
    values = {
        paths.SPEED: speed[rows],
        paths.VELOCITY_X: boxes.velocity[rows, 0],
        paths.VELOCITY_Y: boxes.velocity[rows, 1],
        paths.HEADING: boxes.yaw[rows],
        paths.ACCELERATION_X: acceleration[rows, 0],
        paths.ACCELERATION_Y: acceleration[rows, 1],
    }
    index = pa.array(group)
    for series, v in values.items():
        scalars[series] = unit_lists(np.asarray(v, dtype=np.float64), pa.float64())
        labels = pa.array([f"T{i} {series}" for i in track_ids.tolist()], pa.utf8())
        names[series] = unit_lists(labels.take(index))
    # (a constant-velocity track has no acceleration: NaN)
    with_acc = np.logical_and.reduceat(np.isfinite(acceleration[rows]).all(axis=1), starts)
    desc_scalars = rr.Scalars.descriptor_scalars()
    desc_colors = rr.SeriesLines.descriptor_colors()
    desc_names = rr.SeriesLines.descriptor_names()
    for k, tid in enumerate(track_ids.tolist()):
        own.add_group(
            k,
            [
                (
                    paths.track_series(tid, series),
                    [
                        (desc_scalars, scalars[series]),
                        (desc_colors, colors),
                        (desc_names, names[series]),
                    ],
                )
                for series in (values if with_acc[k] else paths.SERIES)
            ],
        )
    own.send(rec)
    if gt is None:
        return None, n_tracks

    g = gt_row[rows]
    on = g >= 0
    if not on.any():
        return find_velocity_lag([]), n_tracks
    gt_counts = np.add.reduceat(on.astype(np.int64), starts)
    gt_starts = np.r_[0, np.cumsum(gt_counts)[:-1]]
    gv = gt.velocity[g[on]]
    gt_series = SeriesColumns(f[on], t[on], gt_starts, gt_counts)
    gt_colors = unit_lists(np.full(int(on.sum()), GT_SERIES_U32, np.uint32), pa.uint32())
    gt_values = {
        paths.SPEED: np.hypot(gv[:, 0], gv[:, 1]),
        paths.VELOCITY_X: gv[:, 0],
        paths.VELOCITY_Y: gv[:, 1],
        paths.HEADING: gt.boxes.yaw[g[on]],
    }
    gt_index = pa.array(group[on])
    gt_scalars = {}
    for series, v in gt_values.items():
        gt_scalars[series] = unit_lists(np.asarray(v, dtype=np.float64), pa.float64())
        labels = pa.array([f"GT of T{i} {series}" for i in track_ids.tolist()], pa.utf8())
        gt_names[series] = unit_lists(labels.take(gt_index))
    for k, tid in enumerate(track_ids.tolist()):
        if gt_counts[k]:
            gt_series.add_group(
                k,
                [
                    (
                        paths.track_series(tid, paths.GT_PREFIX + series),
                        [
                            (desc_scalars, gt_scalars[series]),
                            (desc_colors, gt_colors),
                            (desc_names, gt_names[series]),
                        ],
                    )
                    for series in gt_values
                ],
            )
    gt_series.send(rec)
    # the lag search skips each track's first outputs (its position among all its rows)
    position = np.arange(len(rows)) - np.repeat(starts, counts)
    warm = position[on] >= LAG_WARMUP_SAMPLES
    sample = (
        f[on][warm],
        t[on][warm],
        track_ids[group[on][warm]],
        gt_id[rows][on][warm],
        speed[rows][on][warm],
        gv[warm],
        gt.boxes.xyz[g[on][warm], :2],
    )
    return find_velocity_lag([sample]), n_tracks


def _lookup(keys: IntArray, values: IntArray, wanted: IntArray) -> IntArray:
    """``values`` at each ``wanted`` key (the last one of equal keys, as a dict built in order
    would keep), -1 where absent."""
    if not len(keys):
        return np.full(len(wanted), -1, dtype=np.int64)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    at = np.searchsorted(sorted_keys, wanted, side="right") - 1
    ok = at >= 0
    ok[ok] = sorted_keys[at[ok]] == wanted[ok]
    out = np.full(len(wanted), -1, dtype=np.int64)
    out[ok] = np.asarray(values, dtype=np.int64)[order[at[ok]]]
    return out


def find_velocity_lag(samples: Sequence[tuple[np.ndarray, ...]]) -> LagSample | None:
    """The (track, GT object) pair whose speed curve trails the GT's the longest, or None.

    ``samples``: per track, arrays (frame, time, track id, GT id, track speed, GT velocity (K, 2),
    GT xy (K, 2)) of its GT-matched outputs after the warm-up. Static GT objects are left out
    (their GT "velocity" is label and ego-pose noise). The criterion is :data:`LAG_CRITERION`
    (see the constants above): only a pair whose GT speed really changes can lag, and a shift
    must explain the gap better than noise does. The reported frame is where the smoothed GT
    speed changes fastest (the lag is plainest there).
    """
    from tracker.eval.motion_metrics import static_gt_mask

    if not samples:
        return None
    columns = [np.concatenate(x) for x in zip(*samples, strict=True)]
    frame, times, track, gt_id, speed, gt_vel, gt_xy = columns
    ok = np.isfinite(gt_vel).all(axis=1) & np.isfinite(speed)
    frame, times, track, gt_id, speed = frame[ok], times[ok], track[ok], gt_id[ok], speed[ok]
    gt_vel, gt_xy = gt_vel[ok], gt_xy[ok]
    if not len(frame):
        return None
    moving = ~static_gt_mask(gt_id, gt_vel, gt_xy)
    gt_speed = np.hypot(gt_vel[:, 0], gt_vel[:, 1])
    best: tuple[float, float] | None = None
    found: LagSample | None = None
    pairs = np.unique(np.column_stack([gt_id[moving], track[moving]]), axis=0)
    for g, t in pairs.tolist():
        rows = np.flatnonzero((gt_id == g) & (track == t) & moving)
        rows = rows[np.argsort(times[rows], kind="stable")]
        _, first = np.unique(times[rows], return_index=True)  # one sample per time
        rows = rows[np.sort(first)]
        if len(rows) < LAG_MIN_SAMPLES:
            continue
        gs = _moving_average(gt_speed[rows], LAG_SMOOTH_SAMPLES)
        noise = float(np.std(gt_speed[rows] - gs))
        change = float(np.ptp(gs))
        if change < max(LAG_MIN_SPEED_CHANGE_MPS, LAG_NOISE_FACTOR * noise):
            continue
        gaps = _shift_gaps(gs, speed[rows], LAG_MAX_SHIFT_SAMPLES)
        shift = int(np.argmin(gaps))
        if shift == 0 or gaps[shift] > (1.0 - LAG_MIN_IMPROVEMENT) * gaps[0]:
            continue
        delay = shift * float(np.median(np.diff(times[rows])))
        if best is not None and (delay, change) <= best:
            continue
        best = (delay, change)
        k = rows[int(np.argmax(np.abs(np.gradient(gs))))]
        found = LagSample(
            frame_id=int(frame[k]),
            track_id=int(t),
            gt_id=int(g),
            track_speed_mps=float(speed[k]),
            gt_speed_mps=float(gt_speed[k]),
            delay_secs=delay,
            speed_change_mps=change,
            mean_gap_before_mps=float(gaps[0]),
            mean_gap_after_mps=float(gaps[shift]),
            speed_max_mps=float(max(np.max(gt_speed[rows]), np.max(speed[rows]))),
        )
    return found


def _moving_average(x: FloatArray, window: int) -> FloatArray:
    """Centred moving average; the ends average over the samples that exist (no zero padding,
    which would fake a speed change at both ends)."""
    if len(x) == 0:
        return np.zeros(0)
    kernel = np.ones(window)
    total = np.convolve(x, kernel, mode="same")
    count = np.convolve(np.ones(len(x)), kernel, mode="same")
    return total / count


def _shift_gaps(reference: FloatArray, delayed: FloatArray, max_shift: int) -> FloatArray:
    """Mean |delayed[i + s] - reference[i]| for each shift s = 0..max_shift (fewer when short)."""
    n = len(reference)
    return np.array(
        [
            float(np.mean(np.abs(delayed[s:] - reference[: n - s])))
            for s in range(min(max_shift, n // 2) + 1)
        ]
    )


def _log_id_events(
    rec: rr.RecordingStream,
    result: RecordResult,
    times: Mapping[int, float],
    gt: _GtIndex | None,
    stages: StageLog | None,
) -> list[EventFocus]:
    """Per ID event: a short WARN TextLog at its frame (``#K`` = its number in the summary), a
    3D marker for ID switches (held a few frames), and its focus entities (trails of both
    tracks, the GT path, the three boxes, the cost row/column text) under ``focus/e<K>``.

    Per-frame rows go out as columns (one ``ColumnBuffer``, one call per entity)."""
    evaluation = result.id_evaluation
    assert evaluation is not None
    outputs = result.outputs
    by_frame = {o.frame_id: o for o in outputs}
    causes = result.causes or [None] * len(evaluation.events)
    buffer = ColumnBuffer(rec, max_rows=1 << 30, max_secs=float("inf"))
    markers: dict[int, list[tuple[np.ndarray, str]]] = {}
    track_path = _TrackPaths(outputs)
    focus: list[EventFocus] = []
    images = np.array(result.image_frames, dtype=np.int64)
    static = StaticEntities()
    for k, (e, cause) in enumerate(zip(evaluation.events, causes, strict=True)):
        time_secs = times.get(e.frame_id, np.nan)
        text = f"#{k} " + (cause.short_text() if cause is not None else _plain_text(e))
        buffer.add(paths.EVENTS, rr.TextLog, e.frame_id, time_secs, 1, text=[text], level=["WARN"])
        xyz = _event_position(e, by_frame.get(e.frame_id), gt)
        centre = xyz if xyz is not None else np.full(3, np.nan)
        focus.append(
            EventFocus(
                k,
                e.frame_id,
                _shot_frame(e.frame_id, images),
                (float(centre[0]), float(centre[1]), float(centre[2])),
                (e.old_track_id, e.new_track_id),
            )
        )
        _log_focus(static, k, e, cause, track_path, gt, stages)
        if e.kind is not IdEventKind.ID_SWITCH or xyz is None:
            continue
        label = f"#{k} GT{e.gt_id}: T{e.old_track_id}->T{e.new_track_id}"
        for f in range(e.frame_id, e.frame_id + MARKER_HOLD_FRAMES):
            markers.setdefault(f, []).append((xyz + np.array([0.0, 0.0, 2.0]), label))
    shown = False
    for f in sorted(times):
        items = markers.get(f)
        if items is None and not shown:
            continue
        items = items or []  # an empty row ends the marker's hold
        n = len(items)
        buffer.add(
            paths.ID_SWITCH_MARKERS,
            rr.Points3D,
            f,
            times[f],
            n,
            mono={"show_labels": [True]},
            positions=np.array([p for p, _ in items], dtype=np.float32).reshape(-1, 3),
            radii=np.full(n, 0.25, np.float32),
            colors=np.full(n, pack_rgb(ID_SWITCH_RGB), np.uint32),
            labels=[lbl for _, lbl in items],
        )
        shown = bool(items)
    buffer.flush()
    static.send(rec)
    if gt is not None:
        _log_event_gt_speed(rec, sorted({e.gt_id for e in evaluation.events}), gt, times)
    return focus


def _log_event_gt_speed(
    rec: rr.RecordingStream, gt_ids: Sequence[int], gt: _GtIndex, times: Mapping[int, float]
) -> None:
    """``event_gt/<id>/speed``: each event GT object's speed at its recorded frames, one
    curve for the event's speed views (the tracks' ``gt_speed`` curves are pieces of it, one
    per track, and showed it twice)."""
    rows = np.flatnonzero(np.isin(gt.boxes.track_id, np.asarray(gt_ids, dtype=np.int64)))
    frames = gt.frame_id[rows]
    known = np.isin(frames, np.fromiter(times, np.int64, len(times)))
    speed = np.hypot(gt.velocity[rows, 0], gt.velocity[rows, 1])
    rows = rows[known & np.isfinite(speed)]
    ids = gt.boxes.track_id[rows]
    order = np.lexsort((gt.frame_id[rows], ids))
    rows, ids = rows[order], ids[order]
    if not len(rows):
        return
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    counts = np.diff(np.r_[starts, len(rows)])
    f = gt.frame_id[rows]
    series = SeriesColumns(f, np.array([times[int(x)] for x in f.tolist()]), starts, counts)
    scalars = unit_lists(np.hypot(gt.velocity[rows, 0], gt.velocity[rows, 1]), pa.float64())
    colors = unit_lists(np.full(len(rows), GT_SERIES_U32, np.uint32), pa.uint32())
    names = unit_lists(pa.array([f"GT {i} speed" for i in ids.tolist()], pa.utf8()))
    for k, gid in enumerate(ids[starts].tolist()):
        series.add_group(
            k,
            [
                (
                    paths.event_gt_series(gid),
                    [
                        (rr.Scalars.descriptor_scalars(), scalars),
                        (rr.SeriesLines.descriptor_colors(), colors),
                        (rr.SeriesLines.descriptor_names(), names),
                    ],
                )
            ],
        )
    series.send(rec)


def _shot_frame(frame_id: int, image_frames: IntArray) -> int:
    """The nearest frame with a camera image within :data:`IMAGE_SEARCH_FRAMES`, else the
    event's frame (ties: the earlier one)."""
    if not len(image_frames):
        return frame_id
    d = np.abs(image_frames - frame_id)
    k = int(np.argmin(d))
    return int(image_frames[k]) if d[k] <= IMAGE_SEARCH_FRAMES else frame_id


class _TrackPaths:
    """Output positions and boxes per track id, in frame order (one sorted table)."""

    def __init__(self, outputs: Sequence[TrackOutput]) -> None:
        boxes = Boxes.concat([o.boxes for o in outputs]) if outputs else Boxes.empty()
        frames = np.repeat(
            np.array([o.frame_id for o in outputs], dtype=np.int64),
            np.array([len(o) for o in outputs], dtype=np.int64),
        )
        order = np.lexsort((frames, boxes.track_id))
        self._boxes = boxes[order]
        self._keys = pair_key(self._boxes.track_id, frames[order])

    def _range(self, track_id: int, first: int, last: int) -> tuple[int, int]:
        lo, hi = pair_key(np.array([track_id, track_id]), np.array([first, last]))
        return (
            int(np.searchsorted(self._keys, lo, side="left")),
            int(np.searchsorted(self._keys, hi, side="right")),
        )

    def path(self, track_id: int, first: int, last: int) -> np.ndarray:
        a, b = self._range(track_id, first, last)
        return np.asarray(self._boxes.xyz[a:b]).reshape(-1, 3)

    def box_at_or_before(self, track_id: int, frame_id: int) -> Boxes | None:
        a, b = self._range(track_id, -(2**31), frame_id)
        return self._boxes[np.array([b - 1])] if b > a else None


#: Colours of the focused view: old track, new track, GT (bright on the dark background).
FOCUS_OLD_RGB = (255, 150, 40)
FOCUS_NEW_RGB = (60, 200, 255)
FOCUS_GT_RGB = (80, 255, 120)


def focus_path(k: int) -> str:
    return f"{paths.FOCUS}/e{k}"


def _log_focus(
    static: StaticEntities,
    k: int,
    e: IdEvent,
    cause: EventCause | None,
    tracks: _TrackPaths,
    gt: _GtIndex | None,
    stages: StageLog | None,
) -> None:
    """Static entities of one event's focused view (hidden in the default layout)."""
    first = (e.last_frame_id if e.last_frame_id >= 0 else e.frame_id) - FOCUS_BEFORE_FRAMES
    last = e.frame_id + FOCUS_AFTER_FRAMES
    strips, colors, labels = [], [], []
    roles = event_track_roles(e)  # old = new (a fragmentation) is drawn once
    role_rgb = {"old": FOCUS_OLD_RGB, "new": FOCUS_NEW_RGB, "old = new": FOCUS_OLD_RGB}
    for tid, role in roles:
        p = tracks.path(tid, first, last)
        if len(p) >= 2:
            strips.append(p)
            colors.append(role_rgb[role])
            labels.append(f"{role} T{tid}")
    boxes, box_colors, box_labels = [], [], []
    if gt is not None:
        sel = (gt.boxes.track_id == e.gt_id) & (gt.frame_id >= first) & (gt.frame_id <= last)
        rows = np.flatnonzero(sel)
        rows = rows[np.argsort(gt.frame_id[rows], kind="stable")]
        if len(rows) >= 2:
            strips.append(gt.boxes.xyz[rows])
            colors.append(FOCUS_GT_RGB)
            labels.append(f"GT {e.gt_id}")
        at = rows[gt.frame_id[rows] == e.frame_id]
        if len(at):
            boxes.append(gt.boxes[at[:1]])
            box_colors.append(FOCUS_GT_RGB)
            box_labels.append(f"GT {e.gt_id}")
    for tid, role in roles:
        b = tracks.box_at_or_before(tid, e.frame_id)
        if b is not None:
            boxes.append(b)
            box_colors.append(role_rgb[role])
            box_labels.append(f"T{tid}")
    base = focus_path(k)
    if strips:
        static.add(
            f"{base}/paths",
            # labels on hover only: the boxes carry the same names at the event
            rr.LineStrips3D(
                [s.astype(np.float32) for s in strips],
                colors=colors,
                radii=0.08,
                labels=labels,
                show_labels=False,
            ),
        )
    if boxes:
        b = Boxes.concat(boxes)
        static.add(
            f"{base}/boxes",
            rr.Boxes3D(
                centers=b.xyz,
                half_sizes=b.lwh / 2,
                quaternions=quaternions_xyzw(b.yaw),
                colors=box_colors,
                labels=box_labels,
                radii=0.1,
                fill_mode="MajorWireframe",
                show_labels=True,
            ),
        )
    static.add(
        f"{base}/explain",
        rr.TextDocument(explain_markdown(k, e, cause, stages), media_type=rr.MediaType.MARKDOWN),
    )


def explain_markdown(k: int, e: IdEvent, cause: EventCause | None, stages: StageLog | None) -> str:
    """The event, its cause with the evidence, and the deciding frame's BEV cost row of both
    tracks (their costs to every comparable detection, gate per row)."""
    what = "ID switch" if e.kind is IdEventKind.ID_SWITCH else "fragmentation"
    lines = [
        f"# #{k} {what} at frame {e.frame_id}",
        "",
        f"GT {e.gt_id} ({e.category}): T{e.old_track_id} -> T{e.new_track_id}; last matched at "
        f"frame {e.last_frame_id}; evaluator similarity {e.similarity:.2f}.",
        "",
    ]
    if cause is not None:
        lines += [f"**Cause: {cause.cause.value}**: {CAUSE_HELP[cause.cause]}.", ""]
        lines += ["| evidence | value |", "|---|---|"]
        lines += [f"| {key} | {_cell(v)} |" for key, v in cause.evidence.items()]
        lines.append("")
    st = stages.frames.get(e.frame_id) if stages is not None else None
    c = st.bev if st is not None else None
    if c is not None:
        roles = event_track_roles(e)
        rows = [t for t, _ in roles if np.any(c.track_ids == t)]
        cols = (
            np.flatnonzero(np.isfinite(c.cost[np.isin(c.track_ids, rows)]).any(axis=0))
            if rows
            else np.zeros(0, np.int64)
        )
        lines += [f"BEV cost at frame {e.frame_id} (gate per row; - = not comparable):", ""]
        if rows and len(cols):
            head = "| track | role | gate | " + " | ".join(f"d{c.det_rows[j]}" for j in cols)
            lines += [head + " |", "|---|---|---:|" + "---:|" * len(cols)]
            for t, role in roles:
                if t not in rows:
                    continue
                r = int(np.flatnonzero(c.track_ids == t)[0])
                cells = [_cell(float(c.cost[r, j])) for j in cols]
                gate = float(np.asarray(c.max_cost_per_row)[r])
                lines.append(f"| T{t} | {role} | {gate:.2f} | " + " | ".join(cells) + " |")
        else:
            what = "the track" if len(roles) == 1 else "neither track"
            lines.append(f"{what} had no comparable detection")
    return "\n".join(lines)


def event_track_roles(e: IdEvent) -> list[tuple[int, str]]:
    """The event's tracks with their role: old and new, or one row "old = new" when the GT
    comes back to the same track (a fragmentation without an ID switch)."""
    if e.old_track_id == e.new_track_id:
        return [(e.old_track_id, "old = new")]
    return [(t, role) for t, role in ((e.old_track_id, "old"), (e.new_track_id, "new")) if t >= 0]


def _cell(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.2f}" if np.isfinite(v) else "-"
    return str(v)


def _event_position(
    e: IdEvent, output: TrackOutput | None, gt: _GtIndex | None
) -> np.ndarray | None:
    """World position of the event: the GT object's centre, else the new track's."""
    if gt is not None:
        row = gt.rows(np.array([e.frame_id]), np.array([e.gt_id]))[0]
        if row >= 0:
            return np.asarray(gt.boxes.xyz[row], dtype=np.float64)
    if output is not None:
        hit = np.flatnonzero(output.boxes.track_id == e.new_track_id)
        if len(hit):
            return np.asarray(output.boxes.xyz[hit[0]], dtype=np.float64)
    return None


def _plain_text(e: IdEvent) -> str:
    what = "IDSW" if e.kind is IdEventKind.ID_SWITCH else "Frag"
    return f"{what} f{e.frame_id} {e.category} GT{e.gt_id} T{e.old_track_id}->T{e.new_track_id}"


def _log_index(rec: rr.RecordingStream, result: RecordResult) -> None:
    """Static ``summary/index``: where ``mctrack shots`` / ``inspect`` (or a test) should look.

    Per ID event (both kinds, in the summary's ``#K`` order): frame, kind (0 ID switch,
    1 fragmentation), GT id, old and new track, cause (index into :class:`Cause`), the world
    position the focused view looks at (x, y, z, flattened) and the frame to picture.
    Empty lists are left out (Rerun drops empty AnyValues columns with a warning); a reader
    treats a missing field as empty."""
    ev = result.id_evaluation
    events = list(ev.events) if ev else []
    switches = ev.id_switches if ev else []
    frags = ev.fragmentations if ev else []
    lag = result.lag
    causes = list(Cause)
    fields: dict[str, list] = {
        "id_switch_frames": [e.frame_id for e in switches],
        "id_switch_gt_ids": [e.gt_id for e in switches],
        "id_switch_old_track_ids": [e.old_track_id for e in switches],
        "id_switch_new_track_ids": [e.new_track_id for e in switches],
        "fragmentation_frames": [e.frame_id for e in frags],
        "event_frames": [e.frame_id for e in events],
        "event_kinds": [int(e.kind is IdEventKind.FRAGMENTATION) for e in events],
        "event_gt_ids": [e.gt_id for e in events],
        "event_old_track_ids": [e.old_track_id for e in events],
        "event_new_track_ids": [e.new_track_id for e in events],
        "event_causes": [causes.index(c.cause) for c in result.causes],
        "event_xyz_m": [v for f in result.focus for v in f.xyz],
        "event_shot_frames": [f.shot_frame for f in result.focus],
        "image_frames": list(result.image_frames),
        "lag_frame": [lag.frame_id] if lag else [],
        "lag_track_id": [lag.track_id] if lag else [],
        "lag_gt_id": [lag.gt_id] if lag else [],
        "lag_error_mps": [lag.error_mps] if lag else [],
        "lag_delay_secs": [lag.delay_secs] if lag and lag.delay_secs is not None else [],
        "frames": [result.counts.get("frames", 0)],
    }
    values = {
        k: np.array(v, dtype=np.float64 if k.endswith(("_mps", "_secs", "_m")) else np.int64)
        for k, v in fields.items()
        if v
    }
    rec.log(paths.SHOT_INDEX, rr.AnyValues(**values), static=True)


def summary_markdown(
    result: RecordResult,
    config: TrackerConfig,
    input_description: str,
) -> str:
    """The static ``summary`` document."""
    lines = [f"# MCTrack debug recording: scene {result.scene}", "", "## Input", ""]
    lines += [input_description or "(not given)", ""]
    lines += ["## Counts", "", "| what | count |", "|---|---:|"]
    lines += [f"| {k.replace('_', ' ')} | {v} |" for k, v in result.counts.items()]
    if result.fates:
        lines += ["", "## Detection fates", "", "Every input detection has exactly one fate.", ""]
        classes = sorted({c for d in result.fates["per_fate_and_class"].values() for c in d})
        lines += ["| fate | total | " + " | ".join(classes) + " |"]
        lines += ["|---|---:|" + "---:|" * len(classes)]
        for fate, total in result.fates["per_fate"].items():
            per = result.fates["per_fate_and_class"].get(fate, {})
            lines.append(
                f"| {fate} | {total} | " + " | ".join(str(per.get(c, 0)) for c in classes) + " |"
            )
        lines += [
            f"| **all** | {result.fates['detections']} |" + " |" * len(classes),
            "",
            f"{result.fates['in_unconfirmed_tracks']} matched or born detections went into "
            f"tracks never confirmed; {result.fates.get('fed_not_output', 0)} fed a track that "
            "was not output in that frame (tentative, or below the track score gate).",
        ]
    ev = result.id_evaluation
    lines += ["", "## Static metrics", ""]
    if result.kitti_metrics:
        cols = ["HOTA", "DetA", "AssA", "MOTA", "IDF1", "IDSW", "Frag", "FP", "FN"]
        lines += ["TrackEval 1.3.0, KITTI 2D-box protocol.", ""]
        lines += ["| class | " + " | ".join(cols) + " |", "|---|" + "---:|" * len(cols)]
        from tracker.eval.kitti import absent_classes

        absent = absent_classes(result.kitti_metrics)
        for cls, m in result.kitti_metrics.items():
            if cls in absent:  # scores of false positives only: meaningless
                lines.append(f"| {cls} | absent: no ground truth in this scene" + " |" * len(cols))
            else:
                lines.append(f"| {cls} | " + " | ".join(str(m[c]) for c in cols) + " |")
    elif ev is not None:
        lines += [
            f"{ev.method}: "
            + ", ".join(f"{c} IDSW {n['IDSW']} Frag {n['Frag']}" for c, n in ev.counts.items())
        ]
    else:
        lines.append("no ground truth given")
    lines += ["", "## Motion metrics", "", result.motion_markdown, ""]
    if result.lag is not None:
        lag = result.lag
        lines += [
            f"Largest velocity lag ({LAG_CRITERION}): T{lag.track_id} trails GT {lag.gt_id} by "
            f"{lag.delay_secs:.1f} s; at frame {lag.frame_id} {lag.track_speed_mps:.2f} m/s "
            f"vs GT {lag.gt_speed_mps:.2f} m/s (mean gap {lag.mean_gap_before_mps:.2f} m/s "
            f"unshifted, {lag.mean_gap_after_mps:.2f} m/s shifted).",
            "",
        ]
    else:
        lines += [f"No velocity lag found ({LAG_CRITERION}).", ""]
    lines += ["## ID switches and fragmentations", ""]
    if ev is None:
        lines.append("no ground truth given")
    else:
        lines += [f"Counted as TrackEval's CLEAR does ({ev.method}).", ""]
        if result.causes:
            lines += ["### Causes", ""]
            lines += cause_table_markdown({result.scene: cause_counts(result.causes)})
            lines.append("")
        # (absolute: the summary is read in the viewer, whatever folder it was started from)
        rec_arg = shlex.quote(str(result.path.resolve())) if result.path is not None else "REC.rrd"
        lines += [
            "### Events",
            "",
            f"Open one focused: `mctrack inspect {rec_arg} --event K`; picture it: "
            f"`mctrack shots {rec_arg} --event K --out DIR`.",
            "",
            "| # | frame | kind | class | GT | old -> new | cause | evidence |",
            "|---:|---:|---|---|---:|---|---|---|",
        ]
        causes = result.causes or [None] * len(ev.events)
        for k, (e, c) in enumerate(zip(ev.events, causes, strict=True)):
            kind = "IDSW" if e.kind is IdEventKind.ID_SWITCH else "Frag"
            cause = c.cause.value if c is not None else "-"
            evidence = ", ".join(f"{key} {_cell(v)}" for key, v in c.evidence.items()) if c else ""
            lines.append(
                f"| {k} | {e.frame_id} | {kind} | {e.category} | {e.gt_id} | "
                f"T{e.old_track_id} -> T{e.new_track_id} | {cause} | {evidence} |"
            )
        if not ev.events:
            lines.append("| | | none | | | | | |")
    lines += [
        "",
        "## Config (resolved)",
        "",
        "```json",
        json.dumps(config_to_dict(config), indent=1, default=str),
        "```",
    ]
    return "\n".join(lines)
