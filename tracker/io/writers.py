"""Result writers: KITTI tracking text files and the tracks file (BaseVersion + motion), and
the tracks file's reader.

Every file is written to a temporary name and renamed into place: complete or not at all.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
import math
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.camera import clip_boxes_to_image, project_boxes_upright
from tracker.categories import CATEGORIES
from tracker.config import ImageBoxes
from tracker.cost import iou_xyxy
from tracker.errors import InputError
from tracker.events import TrackOutput, TrackStatus
from tracker.frame import Camera, Frame
from tracker.fusion import OWN_BOX_IOU
from tracker.geometry import wrap_angle
from tracker.io.baseversion import frame_to_dict, read_baseversion
from tracker.io.fileio import compact_json, write_bytes_atomic, write_json_atomic, write_text_atomic

KITTI_CLASS_NAMES = {"car": "Car", "pedestrian": "Pedestrian", "cyclist": "Cyclist"}


def kitti_label_fields(
    boxes: Boxes, camera: Camera, *, width_scale: FloatArray | None = None, unclipped: bool = False
) -> tuple[FloatArray, ...]:
    """KITTI label fields of world boxes seen by a (rectified) camera.

    Returns ``fields (N, 8)`` = alpha, h, w, l, x, y, z, rotation_y (location = bottom centre in
    the camera, y down), the 2D box ``xyxy (N, 4)`` and ``visible (N,)`` (with ``unclipped``,
    then the 2D boxes before clipping to the image). The 2D box projects
    the box *upright in camera axes*, as KITTI annotates it and the reference writer does:
    projecting the z-up world box would tilt it by the ego's pitch/roll relative to the world.
    """
    location, hwl, rotation_y, xyxy, visible = project_boxes_upright(boxes, camera)
    scale = np.ones(len(boxes)) if width_scale is None else width_scale[boxes.category]
    narrow = np.flatnonzero(scale != 1.0)  # (only these: the others stay bit-identical)
    if len(narrow):
        xyxy[narrow] = narrow_about_centre(xyxy[narrow], scale[narrow])
    whole = xyxy.copy()
    xyxy, visible = clip_boxes_to_image(xyxy, visible, camera)
    alpha = wrap_angle(rotation_y - np.arctan2(location[:, 0], location[:, 2]))
    fields = np.column_stack([alpha, hwl, location, rotation_y])
    if unclipped:
        return fields, xyxy, visible, whole
    return fields, xyxy, visible


def narrow_about_centre(xyxy: FloatArray, scale: FloatArray) -> FloatArray:
    """2D boxes (N, 4) with their widths scaled by ``scale`` (N,) about their centres."""
    out = np.array(xyxy, dtype=float)
    centre, half = (out[:, 0] + out[:, 2]) / 2, (out[:, 2] - out[:, 0]) / 2 * scale
    out[:, 0], out[:, 2] = centre - half, centre + half
    return out


class ImageBoxStats:
    """Which detection 2D boxes are their own, and the width that brings them to the writer's.

    A detection's 2D box is *its own* when it differs from its 3D box's projection (IoU <
    :data:`OWN_BOX_IOU`): an image head's box, or one left where it was while its 3D box moved.
    A box that is the projection adds nothing to the tracked box's projection. ``width_scale``
    per category is ``min(1, s / ratio)``, ``s`` the category's ``image_width_scale`` and
    ``ratio`` the geometric mean of own-box width over projected width in the frames so far: a
    box as wide as the projection is narrowed like it, a box already as narrow as the
    annotations (an image head trained on them) is left alone.
    """

    def __init__(self, width_scale: FloatArray) -> None:
        self.target = np.asarray(width_scale, dtype=float)
        self.seen = np.zeros(len(self.target))
        self.log_ratio = np.zeros(len(self.target))

    def update(self, detections: Boxes, camera: Camera, camera_index: int) -> np.ndarray:
        """One frame's detections: (N,) bool, which have a 2D box of their own in ``camera``
        (the frame's camera ``camera_index``); their widths join the running ratio."""
        own = np.zeros(len(detections), dtype=bool)
        if not len(detections):
            return own
        fields, proj, visible = kitti_label_fields(detections, camera)
        det = detections.xyxy_image
        det_w, proj_w = det[:, 2] - det[:, 0], proj[:, 2] - proj[:, 0]
        # a 3D box reaching behind the camera has no proper projection: the 2D boxes detectors
        # write for those (VirConv, SECOND-IoU: whole-image or misplaced boxes) are no evidence;
        # nor is a box whose 3D box projects outside the image (that track is not written)
        in_front = fields[:, 6] - 0.5 * np.hypot(fields[:, 2], fields[:, 3]) > 0.0
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(det).all(axis=1) & (det_w > 0) & (det[:, 3] > det[:, 1])
            ok &= (detections.camera == camera_index) & in_front & visible & (proj_w > 0)
        own[ok] = iou_xyxy(det[ok], proj[ok]) < OWN_BOX_IOU
        np.add.at(self.seen, detections.category[own], 1.0)
        np.add.at(self.log_ratio, detections.category[own], np.log(det_w[own] / proj_w[own]))
        return own

    def width_scale(self) -> FloatArray:
        """(n_categories,) the width factor for own boxes (the class's scale where none seen)."""
        ratio = np.exp(self.log_ratio / np.maximum(self.seen, 1.0))
        return np.minimum(1.0, self.target / ratio)


class CarriedBoxes:
    """The 2D box a coasting track writes after a frame it wrote its detection's own box.

    Per track, the last written box and the track's projected box in that frame. While the
    track coasts, the own box is carried as the projection moves: shifted with its centre and
    scaled with its size, so it keeps its offset from the projection (where an image head's box
    is better than the projection of the tracked box, it stays better for a few frames). A
    track's memory is cleared when it writes a box that is not its own. Uses past frames only:
    online output stays online.
    """

    def __init__(self) -> None:
        self._own: dict[int, tuple[FloatArray, FloatArray]] = {}

    def remember(
        self, track_ids: np.ndarray, own_xyxy: FloatArray, proj_xyxy: FloatArray, other: np.ndarray
    ) -> None:
        """This frame's own boxes (and the projections) of ``track_ids``; ``other``: the ids
        of tracks matched to a detection without one (forgotten)."""
        for tid in other.tolist():
            self._own.pop(tid, None)
        for tid, own, proj in zip(track_ids.tolist(), own_xyxy, proj_xyxy, strict=True):
            self._own[tid] = (own, proj)

    def carry(self, track_ids: np.ndarray, proj_xyxy: FloatArray) -> tuple[np.ndarray, FloatArray]:
        """For coasting tracks with their projections now: (indices into ``track_ids`` that
        have a box to carry, those boxes)."""
        found = [
            (i, self._own[tid]) for i, tid in enumerate(track_ids.tolist()) if tid in self._own
        ]
        if not found:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 4))
        idx = np.array([i for i, _ in found], dtype=np.int64)
        own = np.array([box for _, (box, _) in found])
        then = np.array([proj for _, (_, proj) in found])
        now = np.asarray(proj_xyxy, dtype=float)[idx]
        size_then = then[:, 2:] - then[:, :2]
        ok = np.isfinite(now).all(axis=1) & (size_then > 0).all(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = (now[:, 2:] - now[:, :2]) / size_then  # (w, h) now / then
        centre_then, centre_now = (then[:, :2] + then[:, 2:]) / 2, (now[:, :2] + now[:, 2:]) / 2
        corner_min = centre_now + (own[:, :2] - centre_then) * scale
        corner_max = centre_now + (own[:, 2:] - centre_then) * scale
        return idx[ok], np.hstack([corner_min, corner_max])[ok]


def kitti_lines(
    output: TrackOutput, camera: Camera, detections: Boxes | None = None, **options: Any
) -> list[str]:
    """label_02 lines of one frame: :func:`kitti_rows` (same arguments), formatted."""
    rows = kitti_rows(output, camera, detections, **options)
    return [] if rows is None else format_kitti_lines(output, *rows[:3])


def kitti_rows(
    output: TrackOutput,
    camera: Camera,
    detections: Boxes | None = None,
    *,
    width_scale: FloatArray | None = None,
    own_rows: np.ndarray | None = None,
    detection_width_scale: FloatArray | None = None,
    carried: CarriedBoxes | None = None,
) -> tuple[FloatArray, FloatArray, np.ndarray, FloatArray, IntArray, FloatArray] | None:
    """One frame's rows as :func:`kitti_lines` writes them, before formatting: ``fields``,
    the written ``xyxy``, ``visible``, the projections ``proj`` (N, 4), the rows that wrote
    their detection's own box (indices) and ``in_view`` (N,), the fraction of each projection's
    width inside the image; None for a frame without tracks. Boxes not visible in
    the image are left out (KITTI GT only annotates objects in the camera view, so anything else
    would count as a false positive).

    ``width_scale`` (per global category index, ``TrackerConfig.image_width_scales()``) narrows
    each projected 2D box about its centre (before clipping to the image). With ``detections``
    (the frame's input boxes), a track matched this frame reports its detection's own 2D box
    instead, where ``own_rows`` (per detection; None: every detection) says so, its width
    scaled about its centre by ``detection_width_scale`` (per detection; None: 1). With
    ``carried`` (the sequence's :class:`CarriedBoxes`, frames in order), a coasting track
    reports its last own box carried along.
    """
    boxes = output.boxes
    if not len(boxes):
        return None
    fields, xyxy, visible, whole = kitti_label_fields(
        boxes, camera, width_scale=width_scale, unclipped=True
    )
    proj, idx = xyxy, np.zeros(0, dtype=np.int64)
    if detections is not None:
        rows = output.det_row
        has = rows >= 0
        if own_rows is not None:
            has[has] = own_rows[rows[has]]
        det_xyxy = detections.xyxy_image[rows[has]]
        ok = np.isfinite(det_xyxy).all(axis=1)
        idx = np.flatnonzero(has)[ok]
        det_xyxy = det_xyxy[ok]
        if detection_width_scale is not None:
            det_xyxy = narrow_about_centre(det_xyxy, detection_width_scale[rows[idx]])
        proj, xyxy = xyxy, xyxy.copy()
        xyxy[idx] = det_xyxy
        visible = visible.copy()
        visible[idx] = True
        if carried is not None:
            ids = boxes.track_id
            coasting = np.flatnonzero(rows < 0)
            at, moved = carried.carry(ids[coasting], proj[coasting])
            # into the image, as every written box; one left with no area keeps the projection
            moved, inside = clip_boxes_to_image(moved, np.ones(len(at), dtype=bool), camera)
            xyxy[coasting[at[inside]]] = moved[inside]
            other = np.setdiff1d(np.flatnonzero(rows >= 0), idx)
            carried.remember(ids[idx], det_xyxy, proj[idx], ids[other])
    with np.errstate(invalid="ignore", divide="ignore"):
        in_view = (proj[:, 2] - proj[:, 0]) / (whole[:, 2] - whole[:, 0])
    return fields, xyxy, visible, proj, idx, np.nan_to_num(in_view)


def window_means(
    frame: IntArray,
    group: IntArray,
    values: FloatArray,
    half: int,
    at: tuple[IntArray, IntArray] | None = None,
) -> FloatArray:
    """Each row's mean of ``values`` (n, k) over the rows of its ``group`` whose ``frame`` lies
    within ``half`` of its own (one row per group and frame), by cumulative sums per group.
    With ``at`` = (frames, groups) of other points, the means at those points instead (NaN
    where their group has no row within ``half``)."""
    frame, group = np.asarray(frame), np.asarray(group)
    values = np.asarray(values, dtype=np.float64)
    q_frame, q_group = (frame, group) if at is None else (np.asarray(at[0]), np.asarray(at[1]))
    out = np.full((len(q_frame), values.shape[1]), np.nan)
    order = np.lexsort((frame, group))
    starts = np.flatnonzero(np.r_[True, np.diff(group[order]) != 0])
    by_group = np.argsort(q_group, kind="stable")  # a group's queries: one slice of these
    q_sorted = q_group[by_group]
    for run in np.split(order, starts[1:]):
        queries = run
        if at is not None:
            g = group[run[0]]
            queries = by_group[np.searchsorted(q_sorted, g) : np.searchsorted(q_sorted, g, "right")]
        f, q = frame[run], q_frame[queries]
        lo = np.searchsorted(f, q - half, side="left")
        hi = np.searchsorted(f, q + half, side="right")
        csum = np.vstack([np.zeros(values.shape[1]), np.cumsum(values[run], axis=0)])
        with np.errstate(invalid="ignore", divide="ignore"):
            out[queries] = (csum[hi] - csum[lo]) / (hi - lo)[:, None]
    return out


def format_kitti_lines(
    output: TrackOutput, fields: FloatArray, xyxy: FloatArray, visible: np.ndarray
) -> list[str]:
    """One frame's label_02 lines of the visible rows."""
    boxes = output.boxes
    lines = []
    for i in np.flatnonzero(visible):
        name = KITTI_CLASS_NAMES.get(CATEGORIES[boxes.category[i]], CATEGORIES[boxes.category[i]])
        a, h, w, length, x, y, z, ry = fields[i]
        x1, y1, x2, y2 = xyxy[i]
        lines.append(
            f"{output.frame_id} {boxes.track_id[i]} {name} -1 -1 {a:.4f} "
            f"{x1:.4f} {y1:.4f} {x2:.4f} {y2:.4f} {h:.4f} {w:.4f} {length:.4f} "
            f"{x:.4f} {y:.4f} {z:.4f} {ry:.4f} {boxes.score[i]:.4f}\n"
        )
    return lines


def write_kitti_sequence(
    path: Path,
    outputs: Sequence[TrackOutput],
    frames: Sequence[Frame],
    camera_name: str = "CAM_FRONT",
    *,
    image_boxes: ImageBoxes | str = ImageBoxes.PROJECTION,
    width_scale: FloatArray | None = None,
    own_box_window: int = 0,
) -> int:
    """Write one sequence's KITTI tracking result file; returns the number of lines.

    ``width_scale``: see :func:`kitti_lines`. ``image_boxes`` (``TrackerConfig.image_boxes``):
    the 2D box of a track matched in a frame is its projection, its detection's 2D box, or
    (auto) its detection's box where that box is its own, not its 3D box's projection
    (:class:`ImageBoxStats`; the width convention is learnt from the frames up to the one
    written, so online output stays online); with auto, a coasting track carries its last own
    box along (:class:`CarriedBoxes`). ``outputs`` are in frame order."""
    mode = ImageBoxes(image_boxes)
    by_frame = {f.frame_id: f for f in frames}
    stats = ImageBoxStats(np.ones(len(CATEGORIES)) if width_scale is None else width_scale)
    carried = CarriedBoxes() if mode is ImageBoxes.AUTO else None
    lines: list[str] = []
    collected: list[tuple[TrackOutput, tuple, Camera]] = []  # (own_box_window) frames' rows
    for out in outputs:
        frame = by_frame[out.frame_id]
        index = frame.camera_index(camera_name)
        if index < 0:
            raise ValueError(f"scene {frame.scene} frame {frame.frame_id}: no {camera_name} model")
        camera = frame.cameras[index]
        if mode is ImageBoxes.PROJECTION:
            lines.extend(kitti_lines(out, camera, width_scale=width_scale))
            continue
        dets = frame.boxes
        own = stats.update(dets, camera, index)
        # an own box takes the learnt width factor, a projection the class's (detection mode)
        scale = np.where(own, stats.width_scale()[dets.category], stats.target[dets.category])
        rows = kitti_rows(
            out, camera, dets, width_scale=width_scale,
            own_rows=(dets.camera == index) if mode is ImageBoxes.DETECTION else own,
            detection_width_scale=scale, carried=carried,
        )  # fmt: skip
        if rows is None:
            continue
        if own_box_window >= 3:
            collected.append((out, rows, camera))
        else:
            lines.extend(format_kitti_lines(out, *rows[:3]))
    if collected:
        smooth_own_boxes(collected, own_box_window)
        for out, rows, _ in collected:
            lines.extend(format_kitti_lines(out, *rows[:3]))
    write_text_atomic(path, lines)
    return len(lines)


def smooth_own_boxes(collected: list[tuple[TrackOutput, tuple, Camera]], window: int) -> None:
    """Offline: each track's written own boxes (an image head's, not projections) with their
    offset from the track's projection averaged over ``window`` frames centred on each.

    An own box is the projection's box moved and scaled: ``own = c + r * s`` per corner, with
    ``c`` and ``s`` the projection's centre and size and ``r`` the relative offset. The
    projection carries the motion (its 3D box is smoothed offline); ``r`` is the image head's
    disagreement with it, which changes slowly, while each box's own error does not: averaging
    ``r`` over the track's own boxes within the window keeps the first and averages the second.
    A row whose projection the image edge cuts to less than half its width keeps its own box
    and stays out of the averages: a sliver would give any own box a huge offset (and the whole
    projection, unclipped, moves away from an image head's box as the object leaves the view:
    measured, car HOTA -1.6 with RRC's boxes). A coasting or interpolated row that carries its
    track's last own box (:class:`CarriedBoxes`) takes the average offset around its own frame
    instead, where the window holds own boxes of its track. In place on the collected rows'
    written boxes."""
    frame_no, tid, rel = [], [], []  # the own boxes' offsets: the samples averaged
    targets = []  # per frame: the rows rewritten (own, then carried), their c and s
    for k, (out, (_, xyxy, _, proj, idx, in_view), _) in enumerate(collected):
        centre = np.hstack([(proj[:, :2] + proj[:, 2:]) / 2] * 2)
        size = np.hstack([proj[:, 2:] - proj[:, :2]] * 2)
        ok = np.isfinite(centre).all(axis=1) & (size > 0).all(axis=1) & (in_view >= 0.5)
        own = idx[ok[idx]]
        # coasting rows that carry their track's last own box (CarriedBoxes)
        carried = np.flatnonzero(ok & (out.det_row < 0) & np.any(xyxy != proj, axis=1))
        rows = np.concatenate([own, carried])
        if len(rows):
            targets.append((k, rows, centre[rows], size[rows]))
        frame_no.append(np.full(len(own), out.frame_id))
        tid.append(out.boxes.track_id[own])
        rel.append((xyxy[own] - centre[own]) / size[own])
    frame_no, tid, rel = np.concatenate(frame_no), np.concatenate(tid), np.concatenate(rel)
    if not len(rel) or not targets:
        return
    queries = (
        np.concatenate([np.full(len(rows), collected[k][0].frame_id) for k, rows, *_ in targets]),
        np.concatenate([collected[k][0].boxes.track_id[rows] for k, rows, *_ in targets]),
    )
    # NaN for a carried row whose track has no own box within the window: it keeps its box
    smoothed = window_means(frame_no, tid, rel, window // 2, at=queries)
    at = 0
    for k, rows, centre, size in targets:  # (the rows in the order they were collected)
        _, (_, xyxy, *_), camera = collected[k]
        r = smoothed[at : at + len(rows)]
        at += len(rows)
        box, ok = clip_boxes_to_image(centre + r * size, np.isfinite(r).all(axis=1), camera)
        xyxy[rows[ok]] = box[ok]


def write_tracks_file(
    path: Path, results: dict[str, tuple[Sequence[Frame], Sequence[TrackOutput]]]
) -> None:
    """The tracks file: a valid BaseVersion file whose boxes are the tracker output.

    Each box carries ``track_id``, the filtered ``global_velocity`` (m/s) and
    ``global_acceleration`` (m/s²), ``status`` and ``det_row`` (the row of the input frame's
    detections matched this frame, -1 when coasting), and where the tracker computed them and the
    row has a detection, the paper's velocity baselines ``global_velocity_diff`` and
    ``global_velocity_curve`` (m/s; the reference's field names); frames keep the input's camera
    models, so the file loads with :func:`tracker.io.baseversion.read_baseversion` for evaluation
    and viewing, and with :func:`read_tracks_file` as tracker output.
    """
    payload = {scene: tracks_scene_records(scene, f, o) for scene, (f, o) in results.items()}
    write_json_atomic(Path(path), payload)


def tracks_scene_records(
    scene: str, frames: Sequence[Frame], outputs: Sequence[TrackOutput]
) -> list[dict[str, Any]]:
    """One scene of the tracks file (:func:`write_tracks_file`): its list of frame records."""
    by_frame = {f.frame_id: f for f in frames}
    scene_frames = []
    for out in outputs:
        src = by_frame[out.frame_id]
        frame = Frame(
            scene=scene,
            frame_id=out.frame_id,
            timestamp_secs=out.time_secs,
            boxes=out.boxes,
            cameras=src.cameras,
            world_from_ego=src.world_from_ego,
            sample_token=src.sample_token,
            transform_matrix=src.transform_matrix,
        )
        record = frame_to_dict(frame)
        for k, (box, acc, status, det_row) in enumerate(
            zip(record["bboxes"], out.acceleration, out.status, out.det_row, strict=True)
        ):
            box["global_acceleration"] = [None if not np.isfinite(a) else float(a) for a in acc]
            box["status"] = int(status)
            box["det_row"] = int(det_row)
            if out.baselines is not None and np.isfinite(out.baselines[k]).all():
                box["global_velocity_diff"] = [float(v) for v in out.baselines[k, 0]]
                box["global_velocity_curve"] = [float(v) for v in out.baselines[k, 1]]
        scene_frames.append(record)
    return scene_frames


def tracks_scene_json(scene: str, frames: Sequence[Frame], outputs: Sequence[TrackOutput]) -> bytes:
    """One scene's part of the tracks file, encoded exactly as :func:`write_tracks_file` does."""
    return compact_json(tracks_scene_records(scene, frames, outputs))


def write_tracks_parts(path: Path, parts: Iterable[tuple[str, Path]]) -> None:
    """Assemble the tracks file from per-scene parts (:func:`tracks_scene_json` files), in order.

    The bytes equal :func:`write_tracks_file`'s for the same scenes: a compact JSON object is
    ``{"key":value,...}``, so the parts are joined, not parsed again.
    """

    def chunks() -> Iterator[bytes]:
        yield b"{"
        for i, (scene, part) in enumerate(parts):
            yield (b"," if i else b"") + compact_json(scene) + b":"
            yield part.read_bytes()
        yield b"}"

    if str(path).endswith(".gz"):
        write_bytes_atomic(path, gzip.compress(b"".join(chunks()), mtime=0))
    else:
        write_bytes_atomic(path, chunks())


def read_tracks_file(
    path: str | Path,
) -> tuple[dict[str, list[Frame]], dict[str, list[TrackOutput]]]:
    """Load a tracks file (:func:`write_tracks_file`, ``.json`` or ``.json.gz``).

    Returns the frames (boxes = tracker output, with the camera models) and the tracker output
    per scene. Fields an older or foreign file lacks get their "missing" value: ``status``
    CONFIRMED, ``det_row`` -1, acceleration NaN, ``stage`` 0, and ``baselines`` None for a
    scene where no box carries them (NaN for a box without them in a scene where others do).

    Raises
    ------
    InputError (from :func:`tracker.io.baseversion.read_baseversion`) for an invalid file.
    """
    scenes = read_baseversion(path)
    opener = gzip.open if str(path).endswith(".gz") else open
    with opener(path, "rb") as fh:
        raw = json.load(fh)
    outputs: dict[str, list[TrackOutput]] = {}
    for scene, frames in scenes.items():
        scene_out = []
        for frame, record in zip(frames, raw[scene], strict=True):
            bboxes = record["bboxes"]
            if len(bboxes) != len(frame.boxes):  # an unknown category was skipped on reading
                raise InputError(
                    f"{path}: scene {scene!r} frame {frame.frame_id}: "
                    f"{len(bboxes) - len(frame.boxes)} boxes of unknown categories"
                )
            field = _TrackFields(f"{path}: scene {scene!r} frame {frame.frame_id}", bboxes)
            scene_out.append(
                TrackOutput(
                    scene=scene,
                    frame_id=frame.frame_id,
                    time_secs=frame.timestamp_secs,
                    boxes=frame.boxes,
                    acceleration=field.pairs("global_acceleration"),
                    status=np.array(  # (checked by read_baseversion)
                        [b.get("status", TrackStatus.CONFIRMED) for b in bboxes], dtype=np.int8
                    ),
                    det_row=field.integers("det_row", -1, minimum=-1),
                    stage=np.zeros(len(bboxes), dtype=np.int8),
                    baselines=np.stack(
                        [field.pairs("global_velocity_diff"), field.pairs("global_velocity_curve")],
                        axis=1,
                    ),
                )
            )
        if not any(
            key in b
            for record in raw[scene]
            for b in record["bboxes"]
            for key in ("global_velocity_diff", "global_velocity_curve")
        ):  # (a file from before the tracker kept them: the evaluation computes them itself)
            scene_out = [dataclasses.replace(o, baselines=None) for o in scene_out]
        outputs[scene] = scene_out
    return scenes, outputs


class _TrackFields:
    """A tracks file frame's per-box tracker fields, each checked (the file is untrusted)."""

    def __init__(self, where: str, bboxes: list[dict[str, Any]]) -> None:
        self.where, self.bboxes = where, bboxes

    def _bad(self, k: int, key: str, what: str) -> InputError:
        return InputError(f"{self.where} box {k}: field {key!r} must be {what}")

    def pairs(self, key: str) -> FloatArray:
        """(K, 2) floats; NaN where absent or null."""
        out = np.full((len(self.bboxes), 2), np.nan)
        for k, box in enumerate(self.bboxes):
            value = box.get(key)
            if value is None:
                continue
            if not isinstance(value, list) or len(value) != 2:
                raise self._bad(k, key, "a list of 2 numbers or nulls")
            for j, v in enumerate(value):
                if v is None:
                    continue
                if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                    raise self._bad(k, key, "a list of 2 finite numbers or nulls")
                out[k, j] = v
        return out

    def integers(self, key: str, missing: int, minimum: int) -> IntArray:
        """(K,) integers >= ``minimum``; ``missing`` where absent."""
        out = np.full(len(self.bboxes), missing, dtype=np.int64)
        for k, box in enumerate(self.bboxes):
            value = box.get(key, missing)
            if (
                isinstance(value, bool)
                or not isinstance(value, int)
                or not minimum <= value < 2**62
            ):
                raise self._bad(k, key, f"an integer >= {minimum}")
            out[k] = value
        return out
