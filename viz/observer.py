"""RerunObserver: turns the tracker's stage events into one row per stage per frame.

It takes an explicit :class:`rerun.RecordingStream` (never the global one) and logs under the
paths of :mod:`viz.paths`. Per frame, a handler only keeps references to arrays the tracker
computed anyway; every few hundred frames the rows of each entity are turned into Rerun fields in
one vectorised pass and sent with ``send_columns`` (:mod:`viz.columns`), an order of magnitude
cheaper than ``rec.log`` per entity per frame. Stages that produce nothing this frame still write
an empty row (or a Clear), so scrubbing never shows a stale box from an earlier frame.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
from numpy.typing import NDArray

from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.camera import project_boxes_batched
from tracker.categories import CATEGORIES
from tracker.events import (
    CostComputed,
    DetectionsFiltered,
    DropReason,
    Event,
    FrameFinished,
    FrameStarted,
    ImageStageDeferred,
    LifecycleChanged,
    Matched,
    NoiseEstimated,
    Predicted,
    Stage,
    TrackOutput,
    TrackStatus,
)
from tracker.frame import Camera, Frame
from tracker.image_stage import deferred_image_stage
from viz import paths
from viz.archetypes import (
    BACKGROUND_RGB,
    DETECTION_DROPPED_RGB,
    DETECTION_KEPT_RGB,
    GT_RGB,
    REJECTED_RGB,
    UNMATCHED_DETECTION_RGB,
    UNMATCHED_TRACK_RGB,
    boxes2d_fields,
    boxes3d_fields,
    cost_colors,
    pack_rgb,
    quaternions_xyzw,
    solid,
    track_colors_u32,
)
from viz.columns import Built, ColumnBuffer, pair_key, set_frame_time
from viz.projection import drawable_segments

_DROP_LABEL = {
    DropReason.CATEGORY: "dropped: category",
    DropReason.SCORE: "dropped: score",
    DropReason.NMS: "dropped: nms",
}
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
#: Cost cells get a text label only up to this many comparable cells (labels are slow to draw).
MAX_CELL_LABELS = 400
_KEPT = pack_rgb(DETECTION_KEPT_RGB)
_DROPPED = pack_rgb(DETECTION_DROPPED_RGB)
_EMPTY_INT = np.zeros(0, dtype=np.int64)
_NO_BOXES = Boxes.empty()  # read-only arrays: one shared (Boxes.empty() costs ~0.1 ms)


@dataclass(slots=True)
class _FrameState:
    frame: Frame
    time_secs: float
    kept_rows: IntArray = field(default_factory=lambda: _EMPTY_INT)
    pred_ids: IntArray = field(default_factory=lambda: _EMPTY_INT)
    pred_boxes: Boxes = field(default_factory=lambda: _NO_BOXES)
    bev_cost: CostComputed | None = None
    rv_cost: CostComputed | None = None
    bev_matched: Matched | None = None
    rv_matched: Matched | None = None
    rv_deferred: ImageStageDeferred | None = None


class RerunObserver:
    """Logs every tracker stage of every frame to ``rec``.

    Parameters
    ----------
    rec : the recording to log to (its sinks decide file / viewer / web).
    gt : ground-truth frames by ``frame_id`` (logged as ``world/gt`` and in the cameras).
    images : camera name -> folder of ``<frame_id:06d>.png|jpg`` images (KITTI layout).
    trail_frames : positions kept per track for ``world/trails``.
    flush_rows, flush_secs : rows are sent after this many frames or seconds (smaller = lower
        latency in a live viewer, a little more overhead; larger = fewer, bigger chunks, whose
        per-chunk bookkeeping in the file sink is what grows with a long recording).
    """

    #: stage 2 of the frames where it cannot match is computed at flush, for the whole buffer
    rv_costs_deferred = True

    def __init__(
        self,
        rec: rr.RecordingStream,
        *,
        gt: Mapping[int, Frame] | None = None,
        images: Mapping[str, str | Path] | None = None,
        trail_frames: int = 20,
        flush_rows: int = 512,
        flush_secs: float = 4.0,
    ) -> None:
        self.rec = rec
        self.gt = gt or {}
        self.trail_frames = trail_frames
        self.columns = ColumnBuffer(
            rec, max_rows=flush_rows, max_secs=flush_secs, before_flush=self._log_image_stage
        )
        # frames whose stage 2 is not logged yet (see _log_image_stage)
        self._rv_queue: list[_FrameState] = []
        self._images = {cam: list_images(Path(d)) for cam, d in (images or {}).items()}
        #: frame ids that have a camera image (``mctrack shots`` prefers them)
        self.image_frames = sorted({f for imgs in self._images.values() for f in imgs})
        #: the images left out, each a line naming the file and why (see _checked_image)
        self.skipped_images: list[str] = []
        self._pinholes: set[str] = set()
        self._image_shown: set[str] = set()
        self._rv_shown = False
        self._cost_shown = {paths.COST_BEV: False, paths.COST_RV: False}
        # (frame id, track ids, positions) of the last ``trail_frames`` frames already sent
        self._trail_history: list[tuple[int, IntArray, np.ndarray]] = []
        self._state: _FrameState | None = None
        # kept for the post-run part of the recording (small per frame)
        self.ego_xyz: list[np.ndarray] = []
        self.lifecycle_counts = {"born": 0, "lost": 0, "reacquired": 0, "deleted": 0}
        self.detection_counts = {"raw": 0, "kept": 0}
        self._dispatch: dict[type, Any] = {
            FrameStarted: self._on_frame_started,
            DetectionsFiltered: self._on_detections_filtered,
            Predicted: self._on_predicted,
            CostComputed: self._on_cost,
            ImageStageDeferred: self._on_image_stage_deferred,
            Matched: self._on_matched,
            LifecycleChanged: self._on_lifecycle,
            NoiseEstimated: self._on_noise,
            FrameFinished: self._on_frame_finished,
        }

    def __call__(self, event: Event) -> None:
        self._dispatch[type(event)](event)

    def flush(self) -> None:
        """Send every buffered row (call after the last frame)."""
        self.columns.flush()

    # -----------------------------------------------------------------------------------------
    def _add(
        self, path: str, archetype: Any, n: int, mono: dict[str, Any] | None = None, **fields: Any
    ) -> None:
        s = self._require_state()
        self.columns.add(path, archetype, s.frame.frame_id, s.time_secs, n, mono, **fields)

    def _defer(self, path: str, archetype: Any, payload: Any, build: Any) -> None:
        s = self._require_state()
        self.columns.add_deferred(path, archetype, s.frame.frame_id, s.time_secs, payload, build)

    def _on_frame_started(self, event: FrameStarted) -> None:
        frame = event.frame
        self._state = _FrameState(frame, event.time_secs)
        pose = frame.world_from_ego
        if np.isfinite(pose).all():
            self.ego_xyz.append(pose[:3, 3].astype(np.float32))
            self._defer(paths.EGO, rr.Transform3D, pose, self._build_ego)
            self._defer(paths.EGO, rr.TransformAxes3D, None, _build_ego_axes)
        gt = self.gt.get(frame.frame_id)
        if gt is not None:
            self._defer(paths.GT, rr.Boxes3D, gt.boxes, _build_gt)
        for cam in frame.cameras:
            self._log_camera_static(cam, frame.frame_id)
            if gt is not None:
                self._defer(
                    f"{paths.camera(cam.name)}/gt",
                    rr.LineStrips2D,
                    (gt.boxes, None, cam, GT_RGB),
                    _build_wireframes,
                )

    def _build_ego(self, poses: list[FloatArray]) -> Built:
        """The ego as a z-up frame heading where the pose says the vehicle faces.

        See :func:`ego_yaw`: the heading comes from the pose's rotation alone, so a parked ego
        (KITTI 0012/0016/0017) faces the right way from the first frame."""
        pose = np.stack(poses)  # (R, 4, 4)
        mono = {
            "translation": pose[:, :3, 3].astype(np.float32),
            "quaternion": quaternions_xyzw(ego_yaw(pose)),
        }
        return {}, np.zeros(len(poses), np.int64), mono

    def _log_camera_static(self, cam: Camera, frame_id: int) -> None:
        rec = self.rec
        if cam.name not in self._pinholes:
            self._pinholes.add(cam.name)
            # the 2D space of the camera view exists even without any image
            rec.log(
                paths.camera(cam.name),
                rr.Pinhole(
                    image_from_camera=cam.image_from_camera[:, :3],
                    resolution=[cam.width_px, cam.height_px],
                    camera_xyz=rr.ViewCoordinates.RDF,
                ),
                static=True,
            )
        image = self._images.get(cam.name, {}).get(frame_id)
        if image is not None:
            image = self._checked_image(image, cam.name, frame_id)
        if image is not None or cam.name in self._image_shown:  # rare: a direct log is fine
            state = self._require_state()
            set_frame_time(rec, frame_id, state.time_secs)
        if image is not None:
            rec.log(paths.camera_image(cam.name), rr.EncodedImage(path=image, opacity=1.0))
            self._image_shown.add(cam.name)
        elif cam.name in self._image_shown:
            # the viewer plays encoded images as a video stream and ignores a Clear (0.41): hide
            # the last one instead, or it would stand behind the boxes of later frames
            rec.log(paths.camera_image(cam.name), rr.EncodedImage.from_fields(opacity=0.0))
            self._image_shown.discard(cam.name)

    def _checked_image(self, image: Path, camera: str, frame_id: int) -> Path | None:
        """``image``, or None when it cannot be shown: then it is left out, named in
        :attr:`skipped_images` (Rerun logged its bytes as they were, and the viewer showed
        nothing for that frame, without a word; ``view`` refuses such a file before recording).
        The check reads a PNG to its end, not every pixel (:func:`image_problem`)."""
        problem = image_problem(image, decode=False)
        if problem is None:
            return image
        self.skipped_images.append(
            f"{image}: image of frame {frame_id} (camera {camera}) {problem}"
        )
        del self._images[camera][frame_id]
        self.image_frames = sorted({f for imgs in self._images.values() for f in imgs})
        return None

    def _on_detections_filtered(self, event: DetectionsFiltered) -> None:
        frame = event.frame
        self._require_state().kept_rows = event.kept_rows
        self.detection_counts["raw"] += len(frame.boxes)
        self.detection_counts["kept"] += len(event.kept_rows)
        payload = (frame.boxes, event.reason)
        self._defer(paths.DETECTIONS_RAW, rr.Boxes3D, payload, _build_detections_raw)
        self._defer(paths.DETECTIONS_KEPT, rr.Boxes3D, payload, _build_detections_kept)
        kept = event.reason == DropReason.KEPT
        for c, cam in enumerate(frame.cameras):
            path = paths.camera_detections(cam.name)
            self._defer(
                path,
                rr.LineStrips2D,
                (frame.boxes, kept, cam, DETECTION_KEPT_RGB),
                _build_wireframes,
            )
            self._defer(path, rr.Boxes2D, (frame.boxes, kept, c), _build_detection_boxes2d)

    def _on_predicted(self, event: Predicted) -> None:
        state = self._require_state()
        state.pred_ids, state.pred_boxes = event.track_ids, event.boxes
        self._defer(
            paths.TRACKS_PREDICTED, rr.Boxes3D, (event.track_ids, event.boxes), _build_predicted
        )

    def _on_cost(self, event: CostComputed) -> None:
        state = self._require_state()
        if event.stage is Stage.BEV:
            state.bev_cost = event
        else:
            state.rv_cost = event

    def _on_image_stage_deferred(self, event: ImageStageDeferred) -> None:
        self._require_state().rv_deferred = event

    def _log_image_stage(self) -> None:
        """Stage 2 of the frames since the last flush, in frame order (the rows of its matrix
        and match lines depend on the frame before). On the frames where it could match
        nothing the tracker skipped it (as a plain run does) and left its inputs: its matrix
        and gated pairs are computed here for all those frames at once."""
        queue, self._rv_queue = self._rv_queue, []
        skipped = [s for s in queue if s.rv_deferred is not None]
        computed = deferred_image_stage(
            [(s.frame, s.pred_ids, s.pred_boxes, s.rv_deferred) for s in skipped if s.rv_deferred]
        )
        for s, (cost, matched) in zip(skipped, computed, strict=True):
            s.rv_cost, s.rv_matched = cost, matched
        for s in queue:
            self._state = s
            self._log_cost(paths.COST_RV, s.rv_cost, s.rv_matched)
            self._log_matches_rv(s)
        self._state = None

    def _on_matched(self, event: Matched) -> None:
        state = self._require_state()
        if event.stage is Stage.BEV:
            state.bev_matched = event
            self._defer(paths.MATCHES_BEV, rr.LineStrips3D, state, _build_matches_bev)
        else:
            state.rv_matched = event

    def _on_noise(self, event: NoiseEstimated) -> None:
        """The position filter's r per class (``noise/<class>``) and the BEV distance gate's
        radius (``gate/<class>``), time series."""
        for c in np.flatnonzero(np.isfinite(event.r)):
            self._add(f"{paths.NOISE}/{CATEGORIES[c]}", rr.Scalars, 1, scalars=event.r[c : c + 1])
        for c in np.flatnonzero(np.isfinite(event.gate_m)):
            self._add(
                f"{paths.GATE}/{CATEGORIES[c]}", rr.Scalars, 1, scalars=event.gate_m[c : c + 1]
            )

    def _on_lifecycle(self, event: LifecycleChanged) -> None:
        for kind, key, ids in (
            ("born", "born", event.born),
            ("lost", "lost", event.lost),
            ("re-acquired", "reacquired", event.reacquired),
            ("deleted", "deleted", event.deleted),
        ):
            if len(ids):
                self.lifecycle_counts[key] += len(ids)
                # one message per row: a TextLog's level is one per row, not per message
                text = f"{kind}: " + ", ".join(f"T{i}" for i in ids.tolist())
                level = "DEBUG" if kind == "born" else "INFO"
                self._add(paths.EVENTS_LIFECYCLE, rr.TextLog, 1, text=[text], level=[level])

    def _on_frame_finished(self, event: FrameFinished) -> None:
        state, out = self._require_state(), event.output
        self._defer(paths.TRACKS_UPDATED, rr.Boxes3D, out, _build_updated)
        self._defer(paths.TRACKS_VELOCITY, rr.Arrows3D, out, _build_velocity)
        self._defer(paths.TRAILS, rr.LineStrips3D, out, self._build_trails)
        self._log_unmatched(state)
        for cam in state.frame.cameras:
            path = paths.camera_tracks(cam.name)
            self._defer(path, rr.LineStrips2D, (out.boxes, None, cam, None), _build_wireframes)
            self._defer(path, rr.Boxes2D, (out.boxes, None, cam, None), _build_track_boxes2d)
        self._log_cost(paths.COST_BEV, state.bev_cost, state.bev_matched)
        self._rv_queue.append(state)
        self._state = None
        self.columns.end_frame()

    def _log_cost(self, path: str, cost: CostComputed | None, matched: Matched | None) -> None:
        """Only non-empty matrices are sent; an empty one clears the previous picture once."""
        if cost is None or not np.isfinite(cost.cost).any():
            if self._cost_shown[path]:
                self._add(path, rr.Clear, 0, mono={"is_recursive": [True]})
                self._cost_shown[path] = False
            return
        self._cost_shown[path] = True
        part = _CostPart(cost, matched)
        self._defer(path, rr.Image, part, _build_cost_image)
        self._defer(f"{path}/{paths.COST_LABELS}", rr.Points2D, part, _build_cost_labels)
        self._defer(f"{path}/{paths.COST_MATCHED}", rr.Boxes2D, part, _build_cost_matched)
        self._defer(f"{path}/{paths.COST_EXTENT}", rr.Boxes2D, part, _build_cost_extent)

    def _log_matches_rv(self, state: _FrameState) -> None:
        """The image-plane stage: track box used -> detection box, labelled with the SDIoU."""
        cost, event, frame = state.rv_cost, state.rv_matched, state.frame
        active = cost is not None and event is not None and cost.track_xyxy is not None
        if not active:
            if self._rv_shown:
                for cam in frame.cameras:
                    self._add(
                        paths.camera_matches_rv(cam.name),
                        rr.Clear,
                        0,
                        mono={"is_recursive": [False]},
                    )
            self._rv_shown = False
            return
        assert cost is not None and event is not None and cost.track_xyxy is not None
        self._rv_shown = True
        for c, cam in enumerate(frame.cameras):
            path = paths.camera_matches_rv(cam.name)
            part = _RvPart(cost, event, frame, c)
            self._defer(path, rr.LineStrips2D, part, _build_rv_lines)
            self._defer(path, rr.Boxes2D, part, _build_rv_boxes)

    def _build_trails(self, outputs: list[TrackOutput]) -> Built:
        """Each output track's positions over the last ``trail_frames`` frames (this one
        included), for all buffered frames at once: one table of the recent outputs sorted by
        (track, frame), and a window of it per (frame, track)."""
        recent = self._trail_history + [
            (o.frame_id, o.boxes.track_id, o.boxes.xyz.astype(np.float32)) for o in outputs
        ]
        lengths = np.array([len(ids) for _, ids, _ in recent], dtype=np.int64)
        frames = np.repeat(np.array([f for f, _, _ in recent], dtype=np.int64), lengths)
        ids = np.concatenate([i for _, i, _ in recent])
        xyz = np.concatenate([x for _, _, x in recent]).reshape(-1, 3)
        order = np.lexsort((frames, ids))
        keys = pair_key(ids[order], frames[order])
        start = int(lengths[: len(self._trail_history)].sum())
        q_ids, q_frames = ids[start:], frames[start:]
        hi = np.searchsorted(keys, pair_key(q_ids, q_frames), side="right")
        lo = np.searchsorted(keys, pair_key(q_ids, q_frames - self.trail_frames), side="right")
        counts = hi - lo
        firsts = lo - (np.cumsum(counts) - counts)
        points = xyz[order][np.repeat(firsts, counts) + np.arange(int(counts.sum()))]
        # the next flush's trails reach back into these frames
        self._trail_history = recent[-self.trail_frames :]
        fields = {
            "strips": (points, counts),
            "colors": track_colors_u32(q_ids),
            "radii": np.full(len(q_ids), 0.04, np.float32),
        }
        return fields, lengths[len(recent) - len(outputs) :], {}

    def _log_unmatched(self, state: _FrameState) -> None:
        # built at flush, when the stage-2 pairs of the skipped frames are known too
        self._defer(paths.UNMATCHED_TRACKS, rr.Points3D, state, _build_unmatched_tracks)
        self._defer(paths.UNMATCHED_DETECTIONS, rr.Points3D, state, _build_unmatched_detections)

    def _require_state(self) -> _FrameState:
        if self._state is None:
            raise RuntimeError("RerunObserver: stage event before FrameStarted")
        return self._state


# ---------------------------------------------------------------------------------------------
# Builders: a list of per-frame payloads -> (fields over all rows, lengths, one-per-row fields)


def ego_yaw(world_from_ego: FloatArray) -> FloatArray:
    """Heading (rad, about world z) of the vehicle for (..., 4, 4) ego poses.

    Datasets disagree on the ego axes: vehicle axes (nuScenes, Waymo: x forward, z up) or camera
    axes (KITTI's ego is the rectified camera: x right, y down, z forward). The pose tells which:
    a vehicle frame's z axis is (near) vertical in the z-up world, a camera frame's is not. The
    forward axis is then x or z, and its direction in the world is the heading."""
    r = np.asarray(world_from_ego)[..., :3, :3]
    camera_axes = np.abs(r[..., 2, 2]) < 0.7
    forward = np.where(camera_axes[..., None], r[..., :, 2], r[..., :, 0])
    return np.arctan2(forward[..., 1], forward[..., 0])


#: Recent :func:`_concat_boxes` results: (identities of the parts, result, parts kept alive).
_CONCAT_CACHE: list[tuple[tuple[int, ...], Boxes, Sequence[Boxes]]] = []


def _concat_boxes(parts: Sequence[Boxes]) -> Boxes:
    """``Boxes.concat`` of buffered boxes: several builders of one flush concatenate the same
    frames' boxes (a frame's detections: raw, kept, 2D and wireframe rows; its outputs: boxes,
    velocities, wireframes), ~3 ms each for a buffer of KITTI frames."""
    key = tuple(map(id, parts))
    for k, boxes, _ in _CONCAT_CACHE:
        if k == key:
            return boxes
    boxes = Boxes.concat(list(parts))
    # keeping ``parts`` alive keeps the ids in the key from being reused by new objects
    _CONCAT_CACHE[:] = [(key, boxes, parts), *_CONCAT_CACHE[:3]]
    return boxes


def _hidden(rows: int) -> dict[str, list[Any]]:
    """Labels only on hover: shown, the 3D view drowns in text."""
    return {"show_labels": [False] * rows}


def _wire(rows: int, *, labels: bool) -> dict[str, list[Any]]:
    """Boxes as wireframes (a filled box hides the ones inside it: track in detection in GT)."""
    return {"show_labels": [labels] * rows, "fill_mode": ["MajorWireframe"] * rows}


def _lengths(parts: Sequence[Any]) -> IntArray:
    return np.array([len(p) for p in parts], dtype=np.int64)


def _build_ego_axes(parts: list[None]) -> Built:
    return {}, np.zeros(len(parts), np.int64), {"axis_length": [3.0] * len(parts)}


def _build_gt(parts: list[Boxes]) -> Built:
    boxes = _concat_boxes(parts)
    labels = [f"gt {i}" for i in boxes.track_id.tolist()]
    fields = boxes3d_fields(boxes, colors=solid(GT_RGB, len(boxes)), labels=labels, radius=0.02)
    return fields, _lengths(parts), _wire(len(parts), labels=False)


def _frame_rows(lengths: IntArray) -> IntArray:
    """Row index within its frame for every instance of concatenated frames."""
    starts = np.repeat(np.cumsum(lengths) - lengths, lengths)
    return np.arange(int(lengths.sum())) - starts


def _build_detections_raw(parts: list[tuple[Boxes, np.ndarray]]) -> Built:
    boxes = _concat_boxes([b for b, _ in parts])
    reason = np.concatenate([r for _, r in parts])
    lengths = _lengths([r for _, r in parts])
    rows = _frame_rows(lengths)
    labels = [
        f"d{i} {s:.2f}" if r == DropReason.KEPT else f"d{i} {_DROP_LABEL[DropReason(r)]}"
        for i, s, r in zip(rows.tolist(), boxes.score.tolist(), reason.tolist(), strict=True)
    ]
    colors = np.where(reason == DropReason.KEPT, _KEPT, _DROPPED).astype(np.uint32)
    return (
        boxes3d_fields(boxes, colors=colors, labels=labels, radius=0.015),
        lengths,
        _wire(len(parts), labels=False),
    )


def _build_detections_kept(parts: list[tuple[Boxes, np.ndarray]]) -> Built:
    boxes = _concat_boxes([b for b, _ in parts])
    reason = np.concatenate([r for _, r in parts])
    rows = _frame_rows(_lengths([r for _, r in parts]))
    kept = reason == DropReason.KEPT
    lengths = np.array([int(np.count_nonzero(r == DropReason.KEPT)) for _, r in parts])
    boxes = boxes[kept]
    labels = [
        f"d{i} {s:.2f}" for i, s in zip(rows[kept].tolist(), boxes.score.tolist(), strict=True)
    ]
    fields = boxes3d_fields(
        boxes, colors=solid(DETECTION_KEPT_RGB, len(boxes)), labels=labels, radius=0.03
    )
    return fields, lengths, _wire(len(parts), labels=False)


def _build_predicted(parts: list[tuple[IntArray, Boxes]]) -> Built:
    ids = np.concatenate([i for i, _ in parts])
    boxes = _concat_boxes([b for _, b in parts])
    fields = boxes3d_fields(
        boxes, colors=track_colors_u32(ids), labels=[str(i) for i in ids.tolist()], radius=0.015
    )
    return fields, _lengths([i for i, _ in parts]), _wire(len(parts), labels=False)


def _build_updated(outputs: list[TrackOutput]) -> Built:
    boxes = _concat_boxes([o.boxes for o in outputs])
    status = np.concatenate([o.status for o in outputs])
    ids = boxes.track_id
    radius = np.where(status == TrackStatus.COASTING, 0.03, 0.07)  # thin while coasting
    fields = boxes3d_fields(
        boxes, colors=track_colors_u32(ids), labels=[str(i) for i in ids.tolist()], radius=radius
    )
    return fields, _lengths(outputs), _wire(len(outputs), labels=True)


def _build_velocity(outputs: list[TrackOutput]) -> Built:
    boxes = _concat_boxes([o.boxes for o in outputs])
    n = len(boxes)
    fields = {
        "origins": boxes.xyz.astype(np.float32),
        "vectors": np.column_stack([boxes.velocity, np.zeros(n)]).astype(np.float32),
        "colors": track_colors_u32(boxes.track_id),
        "radii": np.full(n, 0.08, np.float32),
    }
    return fields, _lengths(outputs), {}


#: One-slot cache of :func:`_project` (key: identities of the rows' objects, alive while the
#: buffer holds them).
_LAST_PROJECTION: list[Any] = []


def _project(
    parts: Sequence[tuple[Boxes, np.ndarray | None, Camera]],
) -> tuple[Boxes, FloatArray, FloatArray, np.ndarray, IntArray, np.ndarray]:
    """Concatenate (boxes, row mask or None, camera) rows and project every selected box into
    its row's camera. Returns the boxes, segments, 2D boxes, visibility, the row of each box and
    its image size."""
    key = tuple((id(b), id(mask), id(c)) for b, mask, c in parts)
    if _LAST_PROJECTION and _LAST_PROJECTION[0] == key:
        return tuple(_LAST_PROJECTION[1])
    boxes = _concat_boxes([b for b, _, _ in parts])
    frame_of_box = np.repeat(np.arange(len(parts)), _lengths([b for b, _, _ in parts]))
    if any(mask is not None for _, mask, _ in parts):
        sel = np.concatenate(
            [np.ones(len(b), bool) if mask is None else mask for b, mask, _ in parts]
        )
        boxes, frame_of_box = boxes[sel], frame_of_box[sel]
    m = np.stack([c.image_from_world for _, _, c in parts])[frame_of_box]
    size = np.array([[c.width_px, c.height_px] for _, _, c in parts]).reshape(-1, 2)[frame_of_box]
    seg, xyxy, visible = project_boxes_batched(boxes.xyz, boxes.lwh, boxes.yaw, m, size)
    result = (boxes, seg, xyxy, visible, frame_of_box, size)
    # the tracks' wireframes and 2D boxes are built one after the other from the same rows
    # (keeping ``parts`` alive keeps the ids in the key from being reused by new objects)
    _LAST_PROJECTION[:] = [key, result, parts]
    return result


def _build_wireframes(parts: list[tuple[Boxes, Any, Camera, Any]]) -> Built:
    """Projected 3D boxes. Payload: (boxes, row mask or None, camera, one RGB colour, or None
    to colour each box by its track id)."""
    boxes, seg, _, _, frame_of_box, size = _project([(b, m, c) for b, m, c, _ in parts])
    strips, box_rows = drawable_segments(seg, size)
    rgb = parts[0][3]
    if rgb is None:
        colors, radius = track_colors_u32(boxes.track_id)[box_rows], -1.5
    else:
        colors, radius = solid(rgb, len(strips)), -1.0
    fields = {
        "strips": strips,
        "colors": colors,
        "radii": np.full(len(strips), radius, np.float32),
    }
    return fields, np.bincount(frame_of_box[box_rows], minlength=len(parts)), {}


def _build_track_boxes2d(parts: list[tuple[Boxes, Any, Camera, Any]]) -> Built:
    """The tracks' projected 2D boxes (same payload, and projection, as their wireframes)."""
    boxes, _, xyxy, visible, frame_of_box, _ = _project([(b, m, c) for b, m, c, _ in parts])
    ids = boxes.track_id[visible]
    fields = boxes2d_fields(
        xyxy[visible],
        colors=track_colors_u32(ids),
        labels=[f"T{i}" for i in ids.tolist()],
        ui_points=0.75,
    )
    return fields, np.bincount(frame_of_box[visible], minlength=len(parts)), {}


def _build_detection_boxes2d(parts: list[tuple[Boxes, np.ndarray, int]]) -> Built:
    """The detector's own 2D boxes of the kept detections in this camera."""
    boxes = _concat_boxes([b for b, _, _ in parts])
    lengths = _lengths([b for b, _, _ in parts])
    cam = np.repeat([c for _, _, c in parts], lengths)
    sel = np.concatenate([k for _, k, _ in parts]) & (boxes.camera == cam)
    rows = _frame_rows(lengths)[sel]
    frame_of_box = np.repeat(np.arange(len(parts)), lengths)[sel]
    fields = boxes2d_fields(
        boxes.xyxy_image[sel],
        colors=solid(DETECTION_KEPT_RGB, len(rows)),
        labels=[f"d{i}" for i in rows.tolist()],
        ui_points=1.0,
    )
    # labels on hover only: a detection and its track share a corner, "d5" over "T5" is unreadable
    return fields, np.bincount(frame_of_box, minlength=len(parts)), _hidden(len(parts))


def _frame_keys(parts: Sequence[Any]) -> IntArray:
    """The buffered frame (its position) of every element of concatenated per-frame arrays."""
    return np.repeat(np.arange(len(parts)), _lengths(parts))


def _build_matches_bev(states: list[_FrameState]) -> Built:
    """Stage 1's accepted pairs: predicted track position -> detection, coloured by cost."""
    matched = [s.bev_matched for s in states if s.bev_matched is not None]
    assert len(matched) == len(states)  # only frames with a stage-1 Matched event
    pred_ids = [s.pred_ids for s in states]
    pred_xyz = np.concatenate([s.pred_boxes.xyz for s in states]).reshape(-1, 3)
    # each row's threshold (without a cost matrix there are no pairs: any value will do)
    limit = np.concatenate(
        [
            s.bev_cost.max_cost_per_row
            if s.bev_cost is not None
            else np.full(len(s.pred_ids), np.inf)
            for s in states
        ]
    )
    track_ids = [m.track_ids for m in matched]
    part = _frame_keys(track_ids)
    at = _find(
        pair_key(_frame_keys(pred_ids), np.concatenate(pred_ids)),
        pair_key(part, np.concatenate(track_ids)),
    )
    dets = _concat_boxes([s.frame.boxes for s in states])
    det_n = _lengths([s.frame.boxes for s in states])
    det_at = np.concatenate([m.det_rows for m in matched]) + (np.cumsum(det_n) - det_n)[part]
    costs = np.concatenate([m.costs for m in matched])
    n = len(costs)
    fields = {
        "strips": np.stack([pred_xyz[at], dets.xyz[det_at]], axis=1).astype(np.float32),
        "colors": pack_rgb(cost_colors(costs, limit[at])).reshape(n),
        "radii": np.full(n, 0.06, np.float32),
        "labels": [f"{c:.2f}" for c in costs.tolist()],
    }
    return fields, np.bincount(part, minlength=len(states)), _hidden(len(states))


def _matched_keys(states: list[_FrameState], detections: bool) -> IntArray:
    """(frame position, track id or detection row) keys of the accepted pairs of both stages."""
    frame, values = [], []
    for i, s in enumerate(states):
        for m in (s.bev_matched, s.rv_matched):
            if m is not None and len(m.track_ids):
                v = m.det_rows if detections else m.track_ids
                frame.append(np.full(len(v), i))
                values.append(v)
    if not values:
        return _EMPTY_INT
    return pair_key(np.concatenate(frame), np.concatenate(values))


def _build_unmatched(
    states: list[_FrameState],
    *,
    detections: bool,
    radius: float,
    rgb: tuple[int, int, int],
) -> Built:
    """Points for the predicted tracks that took no detection, or the kept detections that
    went to no track, of each frame."""
    if detections:
        rows = [s.kept_rows for s in states]
        boxes = _concat_boxes([s.frame.boxes for s in states])
        n_boxes = _lengths([s.frame.boxes for s in states])
        at = np.concatenate(rows) + np.repeat(np.cumsum(n_boxes) - n_boxes, _lengths(rows))
        values, xyz, prefix = np.concatenate(rows), boxes.xyz[at], "d"
    else:
        rows = [s.pred_ids for s in states]
        values = np.concatenate(rows)
        xyz = np.concatenate([s.pred_boxes.xyz for s in states]).reshape(-1, 3)
        prefix = "T"
    part = _frame_keys(rows)
    lonely = ~np.isin(pair_key(part, values), _matched_keys(states, detections))
    ids = values[lonely]
    n = len(ids)
    fields = {
        "positions": xyz[lonely].astype(np.float32).reshape(-1, 3),
        "radii": np.full(n, radius, np.float32),
        "colors": solid(rgb, n),
        "labels": [f"{prefix}{i} unmatched" for i in ids.tolist()],
    }
    return fields, np.bincount(part[lonely], minlength=len(states)), _hidden(len(states))


_build_unmatched_tracks = functools.partial(
    _build_unmatched, detections=False, radius=0.35, rgb=UNMATCHED_TRACK_RGB
)
_build_unmatched_detections = functools.partial(
    _build_unmatched, detections=True, radius=0.3, rgb=UNMATCHED_DETECTION_RGB
)


@dataclass(frozen=True, slots=True)
class _RvPart:
    """One frame's image-plane stage (its costs and pairs) as seen by camera ``camera``."""

    cost: CostComputed
    matched: Matched
    frame: Frame
    camera: int


#: One-slot cache of :func:`_rv_pairs` (the lines and the boxes are built from the same rows).
_LAST_RV_PAIRS: list[Any] = []


def _rv_pairs(parts: Sequence[_RvPart]) -> tuple[Any, ...]:
    """The stage-2 pairs (accepted, then gated) of every buffered frame whose detection is in
    the part's camera: track ids, detection rows, accepted, SDIoU, the track's box used and the
    detection's box (image xyxy), and the pairs per frame."""
    key = tuple(id(p) for p in parts)
    if _LAST_RV_PAIRS and _LAST_RV_PAIRS[0] == key:
        return _LAST_RV_PAIRS[1]
    ids = np.concatenate(
        [np.concatenate([p.matched.track_ids, p.matched.rejected_track_ids]) for p in parts]
    )
    det_rows = np.concatenate(
        [np.concatenate([p.matched.det_rows, p.matched.rejected_det_rows]) for p in parts]
    )
    n_ok = np.array([len(p.matched.track_ids) for p in parts], dtype=np.int64)
    n_all = n_ok + np.array([len(p.matched.rejected_track_ids) for p in parts], dtype=np.int64)
    part = np.repeat(np.arange(len(parts)), n_all)
    accepted = np.arange(len(ids)) - np.repeat(np.cumsum(n_all) - n_all, n_all) < n_ok[part]
    sdiou = np.concatenate(
        [
            np.concatenate(
                [1.0 - p.matched.costs, np.full(len(p.matched.rejected_track_ids), np.nan)]
            )
            for p in parts
        ]
    )
    # detection rows index the frame's boxes: offset them into the concatenated boxes
    det_n = np.array([len(p.frame.boxes) for p in parts], dtype=np.int64)
    det_at = det_rows + (np.cumsum(det_n) - det_n)[part]
    det_camera = np.concatenate([p.frame.boxes.camera for p in parts])[det_at]
    det_xyxy = np.concatenate([p.frame.boxes.xyxy_image for p in parts]).reshape(-1, 4)[det_at]
    on_cam = det_camera == np.array([p.camera for p in parts], dtype=np.int64)[part]
    cost_part = np.repeat(np.arange(len(parts)), [len(p.cost.track_ids) for p in parts])
    cost_ids = np.concatenate([p.cost.track_ids for p in parts])
    track_xyxy = np.concatenate([p.cost.track_xyxy for p in parts]).reshape(-1, 4)
    at = _find(pair_key(cost_part, cost_ids), pair_key(part[on_cam], ids[on_cam]))
    result = (
        ids[on_cam],
        det_rows[on_cam],
        accepted[on_cam],
        sdiou[on_cam],
        track_xyxy[at],
        det_xyxy[on_cam],
        np.bincount(part[on_cam], minlength=len(parts)),
    )
    # keeping ``parts`` alive keeps the ids in the key from being reused by new objects
    _LAST_RV_PAIRS[:] = [key, result, parts]
    return result


def _rv_style(ids: IntArray, ok: np.ndarray) -> NDArray[np.uint32]:
    return np.where(ok, track_colors_u32(ids), pack_rgb(REJECTED_RGB)).astype(np.uint32)


def _build_rv_lines(parts: list[_RvPart]) -> Built:
    """The image-plane stage: track box used -> detection box, labelled with the SDIoU."""
    ids, det_rows, ok, sdiou, t_xyxy, d_xyxy, lengths = _rv_pairs(parts)
    centres = np.stack(
        [(t_xyxy[:, :2] + t_xyxy[:, 2:]) / 2, (d_xyxy[:, :2] + d_xyxy[:, 2:]) / 2], axis=1
    )
    labels = [
        f"T{t}-d{d} SDIoU {v:.2f}" if a else f"T{t}-d{d} gated"
        for t, d, v, a in zip(
            ids.tolist(), det_rows.tolist(), sdiou.tolist(), ok.tolist(), strict=True
        )
    ]
    k = len(labels)
    fields = {
        "strips": centres.astype(np.float32).reshape(-1, 2, 2),
        "colors": _rv_style(ids, ok),
        "labels": labels,
        "radii": np.full(k, -2.0, np.float32),
    }
    return fields, lengths, {"show_labels": [True] * len(parts)}


def _build_rv_boxes(parts: list[_RvPart]) -> Built:
    """The track boxes the image-plane stage compared (same rows as :func:`_build_rv_lines`)."""
    ids, _, ok, _, t_xyxy, _, lengths = _rv_pairs(parts)
    fields = boxes2d_fields(
        t_xyxy, colors=_rv_style(ids, ok), labels=[""] * len(ids), ui_points=2.0
    )
    return fields, lengths, {}


#: Up to this many detections every column is shown; beyond, only the columns with a feasible
#: (or at least comparable) cost in the shown rows, so 30 x 30 stays legible.
MAX_ALL_COLUMNS = 12


@dataclass(frozen=True, slots=True)
class _CostPart:
    """One frame's matrix of a stage and its accepted pairs (None: no Matched event)."""

    event: CostComputed
    matched: Matched | None


@dataclass(frozen=True, slots=True)
class _CostTables:
    """The shown part of every buffered matrix of one stage, as flat tables.

    Rows shown: the tracks with a feasible detection (cost within the row's threshold). The
    others cannot match anything this frame, and there are many: KITTI keeps lost tracks for 30
    frames, so ~50-90 rows against ~15 detections would bury the few that compete. Without any
    feasible pair, the rows with any comparable (finite) cost. Columns: all up to
    :data:`MAX_ALL_COLUMNS` detections; beyond, those with a feasible (else a comparable) cost
    in the shown rows."""

    m: IntArray  # shown rows per matrix
    n: IntArray  # shown columns per matrix
    hidden_rows: IntArray  # per matrix
    hidden_cols: IntArray
    row_track: IntArray  # per shown row (all matrices, in order): its track id
    row_part: IntArray  # ... and its matrix
    row_pos: IntArray  # ... and its position among the matrix's shown rows
    col_det: IntArray  # per shown column: its detection row
    col_part: IntArray
    col_pos: IntArray
    cost: FloatArray  # per shown cell, row-major per matrix
    limit: FloatArray  # ... the cell's row threshold
    cell_part: IntArray
    cell_row: IntArray  # ... index into the shown rows
    cell_pos: tuple[IntArray, IntArray]  # ... (row, column) position in its matrix


#: One-slot cache of :func:`_cost_tables` (the image, labels and outlines of a stage are built
#: one after the other from the same rows).
_LAST_COST_TABLES: list[Any] = []


def _cost_tables(parts: Sequence[_CostPart]) -> _CostTables:
    """All matrices of the buffered frames at once: the per-matrix numpy calls of a few hundred
    small matrices cost more than the cells."""
    key = tuple(id(p) for p in parts)
    if _LAST_COST_TABLES and _LAST_COST_TABLES[0] == key:
        return _LAST_COST_TABLES[1]
    n_parts = len(parts)
    events = [p.event for p in parts]
    t_n = np.array([e.cost.shape[0] for e in events], dtype=np.int64)
    d_n = np.array([e.cost.shape[1] for e in events], dtype=np.int64)
    cost = np.concatenate([e.cost.ravel() for e in events]).astype(np.float64, copy=False)
    max_cost = np.concatenate([np.asarray(e.max_cost_per_row, np.float64) for e in events])
    track_ids = np.concatenate([e.track_ids for e in events])
    det_rows = np.concatenate([e.det_rows for e in events])
    sizes = t_n * d_n
    cell_part = np.repeat(np.arange(n_parts), sizes)
    local = np.arange(len(cost)) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    cell_grow = np.repeat(np.cumsum(t_n) - t_n, sizes) + local // d_n[cell_part]
    cell_gcol = np.repeat(np.cumsum(d_n) - d_n, sizes) + local % d_n[cell_part]
    with np.errstate(invalid="ignore"):
        feasible = cost <= max_cost[cell_grow]
    finite = np.isfinite(cost)
    rows_total, cols_total = int(t_n.sum()), int(d_n.sum())
    row_part = np.repeat(np.arange(n_parts), t_n)
    col_part = np.repeat(np.arange(n_parts), d_n)
    row_feasible = np.bincount(cell_grow[feasible], minlength=rows_total) > 0
    row_finite = np.bincount(cell_grow[finite], minlength=rows_total) > 0
    any_feasible = np.bincount(row_part[row_feasible], minlength=n_parts) > 0
    row_shown = np.where(any_feasible[row_part], row_feasible, row_finite)
    in_rows = row_shown[cell_grow]
    col_feasible = np.bincount(cell_gcol[feasible & in_rows], minlength=cols_total) > 0
    col_finite = np.bincount(cell_gcol[finite & in_rows], minlength=cols_total) > 0
    any_col = np.bincount(col_part[col_feasible], minlength=n_parts) > 0
    m = np.bincount(row_part[row_shown], minlength=n_parts)
    select = (d_n > MAX_ALL_COLUMNS) & (m > 0)
    col_shown = np.where(
        select[col_part], np.where(any_col[col_part], col_feasible, col_finite), True
    )
    n = np.bincount(col_part[col_shown], minlength=n_parts)
    cell_shown = in_rows & col_shown[cell_gcol]
    row_rank = np.cumsum(row_shown) - 1
    col_rank = np.cumsum(col_shown) - 1
    row_pos = row_rank - (np.cumsum(m) - m)[row_part]
    col_pos = col_rank - (np.cumsum(n) - n)[col_part]
    cells = np.flatnonzero(cell_shown)
    tables = _CostTables(
        m=m,
        n=n,
        hidden_rows=t_n - m,
        hidden_cols=d_n - n,
        row_track=track_ids[row_shown],
        row_part=row_part[row_shown],
        row_pos=row_pos[row_shown],
        col_det=det_rows[col_shown],
        col_part=col_part[col_shown],
        col_pos=col_pos[col_shown],
        cost=cost[cells],
        limit=max_cost[cell_grow[cells]],
        cell_part=cell_part[cells],
        cell_row=row_rank[cell_grow[cells]],
        cell_pos=(row_pos[cell_grow[cells]], col_pos[cell_gcol[cells]]),
    )
    # keeping ``parts`` alive keeps the ids in the key from being reused by new objects
    _LAST_COST_TABLES[:] = [key, tables, parts]
    return tables


def _build_cost_image(parts: list[_CostPart]) -> Built:
    """One RGB pixel per cell (rows tracks, columns detections); see :func:`cost_colors`."""
    t = _cost_tables(parts)
    flat = cost_colors(t.cost, t.limit)  # (cells, 3)
    sizes = t.m * t.n
    ends = np.cumsum(sizes)
    data = np.ascontiguousarray(flat, dtype=np.uint8).ravel()
    buffers = (data, ends * 3)
    formats = [(int(w), int(h)) for h, w in zip(t.m.tolist(), t.n.tolist(), strict=True)]
    return {}, np.zeros(len(parts), np.int64), {"buffer": [buffers], "format": formats}


#: The cost views' labels are laid out for the smallest of those views, the focused layout's
#: in a 1920x1080 viewer (px, plot area; a larger view only gives them more room). Rerun draws
#: a label's text at a fixed size, its box from a little below its point, and frames a 2D view
#: on the points and boxes: so the matrix's scale (px per cell) follows from the extent the
#: labels need, and how many labels fit from that scale.
COST_VIEW_PX = (700.0, 240.0)
#: Labels are lifted to centre their text on their row at the scale of a view this tall (px):
#: between the focused layout's cost view and the default layout's (~330 px), so that in
#: either the text sits within a third of a row of its row (it hung 1-2 rows below it).
COST_VIEW_LIFT_HEIGHT_PX = 290.0
LABEL_LINE_PX = 16.0  # a label's box: its text, with a margin (backgrounds may just touch)
LABEL_BELOW_PX = 6.0  # from a label's point down to the top of its box
LABEL_CHAR_PX = 6.0
LABEL_PAD_PX = 13.0  # a label box's width beyond its characters
LABEL_GAP_PX = 2.0
VALUE_LABEL_CHARS = 5  # "12.34", "-0.50": the widest cell value drawn


def label_width_px(chars: Any) -> Any:
    """Width of a label of ``chars`` characters (px)."""
    return LABEL_CHAR_PX * np.asarray(chars, dtype=np.float64) + LABEL_PAD_PX


@dataclass(frozen=True, slots=True)
class CostLabelLayout:
    """Where the labels of cost matrices go, one entry per matrix (positions in cells, the
    matrix from (0, 0) to (columns, rows)); at :data:`COST_VIEW_PX` none overlaps another.

    Every ``row_step``-th row is labelled (from the first) and every ``col_step``-th column,
    in one line or two staggered ones; cell values are thinned to ``value_rows`` x
    ``value_cols`` apart (:func:`_thinned_values`). A label's point sits ``lift`` above where
    its text is to be centred, since Rerun draws the text below the point."""

    px: FloatArray  # pixels per cell
    row_step: IntArray
    row_x: FloatArray  # x of the row labels' points
    col_step: IntArray
    col_lines: IntArray  # 1, or 2 staggered
    line_y: FloatArray  # (matrices, 3): y of the points of column line 0, line 1, the note
    lift: FloatArray
    value_rows: IntArray
    value_cols: IntArray
    top: FloatArray  # the extent: from the note's point
    bottom: FloatArray  # to below the last row

    @property
    def left(self) -> FloatArray:
        return self.row_x


def cost_label_layout(
    rows: IntArray, cols: IntArray, row_chars: IntArray, col_chars: IntArray
) -> CostLabelLayout:
    """The label layout of matrices of ``rows`` x ``cols`` cells whose row and column labels
    have up to ``row_chars`` and ``col_chars`` characters."""
    m = np.asarray(rows, dtype=np.float64)
    n = np.maximum(np.asarray(cols, dtype=np.float64), 1.0)
    width, height = COST_VIEW_PX
    line, gap = LABEL_LINE_PX, LABEL_GAP_PX
    w_row, w_col = label_width_px(row_chars), label_width_px(col_chars)
    w_val = float(label_width_px(VALUE_LABEL_CHARS))
    to_centre = LABEL_BELOW_PX + line / 2  # a label's point -> the centre of its box (px)
    # above the matrix: column line 0, line 1, the note (box centres, px; a value of the first
    # row may reach half a line above the matrix when the cells are small)
    centres = -(line + gap + line / 2 + line * np.arange(3.0))
    bottom = m * (1.0 + COST_EXTENT_BELOW_SHARE) + COST_EXTENT_BELOW_ROWS
    across = (width - w_row - w_val / 2 - 2 * gap) / n
    # the view spans from the note's point (lifted by to_centre at px_lift) to ``bottom``
    above = -centres[2]
    lift_fit = (COST_VIEW_LIFT_HEIGHT_PX - above - to_centre) / bottom
    px_lift = np.maximum(np.minimum(lift_fit, across), 1.0)
    px = np.maximum(np.minimum((height - above) / (bottom + to_centre / px_lift), across), 1.0)
    # row labels right-aligned left of the first column's values (a value is wider than a cell)
    row_right = np.minimum(0.0, px / 2 - w_val / 2) - gap
    one_line = w_col + gap <= px
    col_step = np.where(one_line, 1, np.ceil((w_col + gap) / (2 * px)))
    lift = to_centre / px_lift
    return CostLabelLayout(
        px=px,
        row_step=np.ceil(line / px - 1e-9).astype(np.int64).clip(1),
        row_x=(row_right - w_row / 2) / px,
        col_step=col_step.astype(np.int64).clip(1),
        col_lines=np.where(one_line, 1, 2).astype(np.int64),
        line_y=centres[None, :] / px[:, None] - lift[:, None],
        lift=lift,
        value_rows=np.ceil(line / px - 1e-9).astype(np.int64).clip(1),
        value_cols=np.ceil((w_val + gap) / px - 1e-9).astype(np.int64).clip(1),
        top=centres[2] / px - lift,
        bottom=bottom,
    )


def _cost_layout(t: _CostTables) -> CostLabelLayout:
    """:func:`cost_label_layout` of the shown matrices (their labels' lengths)."""
    n_parts = len(t.m)
    row_chars = np.zeros(n_parts, np.int64)
    col_chars = np.zeros(n_parts, np.int64)
    if len(t.row_track):
        np.maximum.at(row_chars, t.row_part, _digits(t.row_track) + 1)  # "T<id>"
    if len(t.col_det):
        np.maximum.at(col_chars, t.col_part, _digits(t.col_det) + 1)  # "d<row>"
    return cost_label_layout(t.m, t.n, row_chars, col_chars)


def _digits(values: IntArray) -> IntArray:
    v = np.abs(np.asarray(values, dtype=np.int64))
    return np.floor(np.log10(np.maximum(v, 1))).astype(np.int64) + 1 + (values < 0)


def _build_cost_labels(parts: list[_CostPart]) -> Built:
    """Row ids "T<track>" left of the matrix, column ids "d<detection row>" above it, cell
    values, and a note on the rows and columns not shown (above the column ids), laid out by
    :func:`cost_label_layout`: with many rows or columns, every second (third, ...) one is
    labelled and the values are thinned (matched pairs first), so that no two overlap."""
    t = _cost_tables(parts)
    lay = _cost_layout(t)
    n_parts = len(parts)
    # values only where a match was allowed: dark red cells (over the threshold) say enough,
    # and their numbers would crowd out the ones that decide; with many columns only each
    # row's cheapest (a cell is ~4 characters wide at most)
    with np.errstate(invalid="ignore"):
        ok = t.cost <= t.limit
    many = t.n[t.cell_part] > MAX_ALL_COLUMNS
    if many.any():
        best = np.full(len(t.row_track), np.inf)
        np.minimum.at(best, t.cell_row[ok], t.cost[ok])
        ok &= ~many | (t.cost == best[t.cell_row])
    per_part = np.bincount(t.cell_part[ok], minlength=n_parts)
    ok &= per_part[t.cell_part] <= MAX_CELL_LABELS
    cells = _thinned_values(parts, t, lay, np.flatnonzero(ok))
    values = t.cost[cells]
    r, k = t.cell_pos[0][cells], t.cell_pos[1][cells]
    value_part = t.cell_part[cells]
    row_kept = t.row_pos % lay.row_step[t.row_part] == 0
    row_part, row_pos, row_track = t.row_part[row_kept], t.row_pos[row_kept], t.row_track[row_kept]
    col_kept = t.col_pos % lay.col_step[t.col_part] == 0
    col_part, col_pos, col_det = t.col_part[col_kept], t.col_pos[col_kept], t.col_det[col_kept]
    col_line = np.where(lay.col_lines[col_part] > 1, (col_pos // lay.col_step[col_part]) % 2, 0)
    has_note = (t.hidden_rows > 0) | (t.hidden_cols > 0)
    note_part = np.flatnonzero(has_note)
    notes = []
    hidden = zip(t.hidden_rows[note_part].tolist(), t.hidden_cols[note_part].tolist(), strict=True)
    for hr, hc in hidden:
        note = ([f"+{hr} tracks"] if hr else []) + ([f"+{hc} detections"] if hc else [])
        notes.append(" and ".join(note) + " without a feasible pair")
    # order per matrix: row ids, column ids, cell values, then the note on what is not shown
    kind_part = np.concatenate([row_part, col_part, value_part, note_part])
    kind = np.repeat(np.arange(4), [len(row_part), len(col_part), len(values), len(notes)])
    order = np.lexsort((np.arange(len(kind)), kind, kind_part))
    positions = np.concatenate(
        [
            np.column_stack([lay.row_x[row_part], row_pos + 0.5 - lay.lift[row_part]]),
            np.column_stack([col_pos + 0.5, lay.line_y[col_part, col_line]]),
            np.column_stack([k + 0.5, r + 0.5 - lay.lift[value_part]]),
            np.column_stack([t.n[note_part] / 2.0, lay.line_y[note_part, 2]]),
        ]
    )
    colors = np.concatenate(
        [
            track_colors_u32(row_track),
            solid(DETECTION_KEPT_RGB, len(col_part)),
            solid((255, 255, 255), len(values)),
            solid((190, 190, 190), len(notes)),
        ]
    )
    labels = (
        [f"T{i}" for i in row_track.tolist()]
        + [f"d{i}" for i in col_det.tolist()]
        + [f"{v:.2f}" for v in values.tolist()]
        + notes
    )
    total = len(labels)
    fields = {
        "positions": positions[order].astype(np.float32),
        "radii": np.full(total, 0.03, np.float32),
        "colors": colors[order],
        "labels": [labels[i] for i in order.tolist()],
    }
    return fields, np.bincount(kind_part, minlength=n_parts), {"show_labels": [True] * n_parts}


def _thinned_values(
    parts: list[_CostPart], t: _CostTables, lay: CostLabelLayout, cells: IntArray
) -> IntArray:
    """The ``cells`` whose values are drawn: in a matrix whose cells are smaller than a value's
    label, none closer than ``value_rows`` rows and ``value_cols`` columns to another (closer,
    their labels overlap), chosen greedily, the accepted pairs first, then the cheapest."""
    part = t.cell_part[cells]
    crowded = ((lay.value_rows > 1) | (lay.value_cols > 1))[part]
    if not crowded.any():
        return cells
    crowd = cells[crowded]
    part = part[crowded]
    col_start = np.cumsum(t.n) - t.n
    rows, cols = t.cell_pos[0][crowd], t.cell_pos[1][crowd]
    # (part, detection row) as one int32: a buffer holds at most a few hundred frames
    where = part * (1 << 20) + t.col_det[col_start[part] + cols]
    pairs = [
        (np.full(len(p.matched.track_ids), i) * (1 << 20) + p.matched.det_rows, p.matched.track_ids)
        for i, p in enumerate(parts)
        if p.matched is not None and len(p.matched.track_ids)
    ]
    accepted = np.zeros(len(crowd), bool)
    if pairs:
        at, ids = zip(*pairs, strict=True)
        keys = pair_key(np.concatenate(at), np.concatenate(ids))
        accepted = np.isin(pair_key(where, t.row_track[t.cell_row[crowd]]), keys)
    priority = np.where(accepted, -np.inf, t.cost[crowd])
    order = np.lexsort((np.arange(len(crowd)), priority, part))
    min_rows, min_cols = lay.value_rows[part].tolist(), lay.value_cols[part].tolist()
    r_list, c_list, p_list = rows.tolist(), cols.tolist(), part.tolist()
    keep: list[int] = []
    taken: list[tuple[int, int]] = []
    current = -1
    for i in order.tolist():
        if p_list[i] != current:
            current, taken = p_list[i], []
        r, c, dr, dc = r_list[i], c_list[i], min_rows[i], min_cols[i]
        if all(abs(r - r2) >= dr or abs(c - c2) >= dc for r2, c2 in taken):
            taken.append((r, c))
            keep.append(i)
    return np.sort(np.concatenate([cells[~crowded], crowd[np.array(keep, dtype=np.int64)]]))


def _build_cost_matched(parts: list[_CostPart]) -> Built:
    """White outlines of the accepted cells."""
    t = _cost_tables(parts)
    n_parts = len(parts)
    pairs = [
        (i, p.matched)
        for i, p in enumerate(parts)
        if p.matched is not None and len(p.matched.track_ids)
    ]
    if pairs:
        part = np.concatenate([np.full(len(mt.track_ids), i) for i, mt in pairs])
        tracks = np.concatenate([mt.track_ids for _, mt in pairs])
        dets = np.concatenate([mt.det_rows for _, mt in pairs])
        rows = t.row_pos[_find(pair_key(t.row_part, t.row_track), pair_key(part, tracks))]
        cols = t.col_pos[_find(pair_key(t.col_part, t.col_det), pair_key(part, dets))]
    else:
        part = rows = cols = _EMPTY_INT
    total = len(part)
    fields = {
        "centers": (np.column_stack([cols, rows]) + 0.5).astype(np.float32).reshape(-1, 2),
        "half_sizes": np.full((total, 2), 0.45, np.float32),
        "colors": solid((255, 255, 255), total),
        "radii": np.full(total, -2.0, np.float32),
    }
    return fields, np.bincount(part, minlength=n_parts), {}


#: Margin of :func:`_build_cost_extent` below the matrix, in rows, plus a share of its rows:
#: the last row's labels hang below their points by a fixed number of pixels, which is more
#: rows the more rows share the view, and the 2D view frames a little less than its content
#: at the bottom.
COST_EXTENT_BELOW_ROWS = 1.5
COST_EXTENT_BELOW_SHARE = 0.1


def _build_cost_extent(parts: list[_CostPart]) -> Built:
    """One box per matrix, drawn in the view's background colour, from the row labels to the
    last column and from the column labels to below the last row. Rerun frames a 2D view on
    its points and boxes, not on the image: without it the matrix's last row was cut in half
    (its label and values below the view's edge)."""
    t = _cost_tables(parts)
    lay = _cost_layout(t)
    x0, y0 = lay.left, lay.top  # the row labels' x, the note's y (cost_label_layout)
    x1 = t.n.astype(np.float64)
    y1 = lay.bottom
    fields = {
        "centers": np.column_stack([(x0 + x1) / 2, (y0 + y1) / 2]).astype(np.float32),
        "half_sizes": np.column_stack([(x1 - x0) / 2, (y1 - y0) / 2]).astype(np.float32),
        "colors": solid(BACKGROUND_RGB, len(parts)),
        "radii": np.full(len(parts), -1.0, np.float32),
    }
    return fields, np.ones(len(parts), np.int64), {}


def _find(keys: IntArray, wanted: IntArray) -> IntArray:
    """Index of each ``wanted`` key in ``keys`` (all present)."""
    order = np.argsort(keys, kind="stable")
    return order[np.searchsorted(keys, wanted, sorter=order)]


def list_images(folder: Path) -> dict[int, Path]:
    """frame id -> image file of a KITTI-style folder (``000010.png``), listed once."""
    out: dict[int, Path] = {}
    if folder.is_dir():
        for name in os.listdir(folder):
            stem, ext = os.path.splitext(name)
            if ext.lower() in _IMAGE_SUFFIXES and stem.isdigit():
                out[int(stem)] = folder / name
    return out


def image_problem(path: Path, *, decode: bool = True) -> str | None:
    """Why the image file at ``path`` cannot be shown, as "cannot be read: WHY" (a broken link,
    a folder by an image's name, no permission) or "cannot be decoded: WHY" (a truncated or
    corrupt PNG or JPEG, which opens but has no picture); None: it can. ``decode`` decodes
    every pixel (~10 ms for a KITTI PNG: a truncated body opens fine and fails only there);
    without it a PNG's chunks are read to the end with their checksums (~0.4 ms: a truncated or
    corrupted file fails), other formats are still decoded."""
    import struct

    from PIL import Image

    try:
        with open(path, "rb") as fh:
            fh.read(1)
    except OSError as exc:
        broken = path.is_symlink() and not path.exists()
        return f"cannot be read: {'a link to a missing file' if broken else exc.strerror or exc}"
    try:
        with Image.open(path) as image:
            if decode or image.format != "PNG":
                image.load()
            else:
                image.verify()
    except Image.DecompressionBombError as exc:
        return f"cannot be decoded: {exc}"
    except (OSError, SyntaxError, ValueError, EOFError, struct.error) as exc:
        return f"cannot be decoded: {str(exc) or type(exc).__name__}"
    return None
