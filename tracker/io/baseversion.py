"""BaseVersion JSON <-> frames: the only module that knows the file schema (docs/baseversion.md).

Reads the official MCTrack files unchanged (``{scene: [frame, ...]}``) and this project's richer
files (real timestamps, per-camera models, ground-truth track ids). Everything is validated at
this boundary; inside the tracker the data is trusted.
"""

from __future__ import annotations

import gzip
import json
import logging
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tracker.boxes import Boxes, FloatArray
from tracker.categories import CATEGORIES, category_index
from tracker.errors import InputError
from tracker.frame import Camera, Frame
from tracker.geometry import wrap_angle
from tracker.io.fileio import write_json_atomic

log = logging.getLogger(__name__)

Scenes = dict[str, list[Frame]]

REQUIRED_FRAME_KEYS = ("frame_id", "bboxes")
REQUIRED_BOX_KEYS = ("category", "detection_score", "global_xyz", "lwh", "global_yaw")
MICROS_PER_SEC = 1_000_000


@dataclass
class LoadReport:
    """What the loader skipped (never silent): unknown categories per name, and box totals."""

    skipped_categories: Counter[str] = field(default_factory=Counter)
    boxes_read: int = 0

    @property
    def boxes_skipped(self) -> int:
        return sum(self.skipped_categories.values())


# ---------------------------------------------------------------------------------------------
# reading


def read_baseversion(
    path: str | Path,
    *,
    fallback_frame_rate_hz: float | None = None,
    report: LoadReport | None = None,
) -> Scenes:
    """Load and validate a BaseVersion file.

    Parameters
    ----------
    path : the JSON file.
    fallback_frame_rate_hz : used when a frame's ``timestamp`` is null (official KITTI files):
        ``timestamp_secs = frame_id / rate``. Without it such frames get NaN timestamps.
    report : filled with counts of skipped boxes (unknown categories are a logged, counted skip).

    Raises
    ------
    InputError naming the file, scene, frame index, box index and field.
    """
    path = Path(path)
    report = report if report is not None else LoadReport()
    try:
        opener = gzip.open if path.suffix == ".gz" else open
        with opener(path, "rb") as fh:
            data = json.load(fh)
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError, EOFError, gzip.BadGzipFile) as exc:
        raise InputError(f"{path}: malformed JSON ({exc})") from None
    if isinstance(data, dict) and "results" in data and "meta" in data:
        raise InputError(
            f"{path}: this is a nuScenes results file, not BaseVersion; convert it first "
            "(mctrack convert nuscenes)"
        )
    if not isinstance(data, dict):
        raise InputError(f"{path}: top level must be an object {{scene: [frame, ...]}}")
    scenes: Scenes = {}
    for scene, frames in data.items():
        where = f"{path}: scene {scene!r}"
        if not isinstance(frames, list):
            raise InputError(f"{where}: must map to a list of frames, got {type(frames).__name__}")
        scenes[str(scene)] = _read_scene(str(scene), frames, where, fallback_frame_rate_hz, report)
    if report.boxes_skipped:
        log.warning(
            "%s: skipped %d boxes of unknown categories: %s",
            path,
            report.boxes_skipped,
            dict(sorted(report.skipped_categories.items())),
        )
    return scenes


def _read_scene(
    scene: str,
    frames: list[Any],
    where: str,
    fallback_rate: float | None,
    report: LoadReport,
) -> list[Frame]:
    out: list[Frame] = []
    for index, raw in enumerate(frames):
        at = f"{where}, frame index {index}"
        if not isinstance(raw, dict):
            raise InputError(f"{at}: a frame must be an object")
        for key in REQUIRED_FRAME_KEYS:
            if key not in raw:
                raise InputError(f"{at}: missing key '{key}'")
        frame_id = _int_field(raw["frame_id"], at, "frame_id")
        timestamp_secs = _timestamp(raw.get("timestamp"), frame_id, fallback_rate, at)
        if out:
            prev = out[-1]
            if frame_id <= prev.frame_id:
                raise InputError(
                    f"{at}: field 'frame_id' = {frame_id} is not increasing "
                    f"(previous frame_id {prev.frame_id})"
                )
            if timestamp_secs <= prev.timestamp_secs:
                raise InputError(
                    f"{at}: field 'timestamp' = {raw.get('timestamp')} is not increasing "
                    f"(previous {prev.timestamp_secs:.6f} s)"
                )
        transform = raw.get("transform_matrix")
        if transform is not None and not isinstance(transform, dict):
            raise InputError(f"{at}: field 'transform_matrix' must be an object or null")
        cameras = _read_cameras(transform, at)
        camera_names = [c.name for c in cameras]
        bboxes = raw["bboxes"]
        if not isinstance(bboxes, list):
            raise InputError(f"{at}: field 'bboxes' must be a list")
        boxes = _read_boxes(bboxes, camera_names, at, report)
        ignore_xyxy, ignore_cam = _read_ignore(raw.get("ignore_regions_image"), camera_names, at)
        token = raw.get("cur_sample_token")
        out.append(
            Frame(
                scene=scene,
                frame_id=frame_id,
                timestamp_secs=timestamp_secs,
                boxes=boxes,
                cameras=tuple(cameras),
                world_from_ego=_world_from_ego(transform, at),
                sample_token=None if token is None else str(token),
                transform_matrix=transform,
                ignore_xyxy_image=ignore_xyxy,
                ignore_camera=ignore_cam,
            )
        )
    return out


def _int_field(value: Any, at: str, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise InputError(f"{at}: field '{name}' must be an integer, got {value!r}")
    try:
        number = float(value)
    except ValueError:
        raise InputError(f"{at}: field '{name}' must be an integer, got {value!r}") from None
    if not math.isfinite(number) or number != int(number):
        raise InputError(f"{at}: field '{name}' must be an integer, got {value!r}")
    return int(number)


def _timestamp(value: Any, frame_id: int, fallback_rate: float | None, at: str) -> float:
    """Seconds. BaseVersion stores integer microseconds (nuScenes convention) or null."""
    if value is None:
        return frame_id / fallback_rate if fallback_rate else math.nan
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{at}: field 'timestamp' must be microseconds (a number) or null")
    if not math.isfinite(value):
        raise InputError(f"{at}: field 'timestamp' is not finite ({value})")
    return float(value) / MICROS_PER_SEC


def _matrix(value: Any, shapes: tuple[tuple[int, int], ...], at: str, name: str) -> FloatArray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{at}: field '{name}' is not a numeric matrix") from None
    if arr.shape not in shapes:
        raise InputError(f"{at}: field '{name}' has shape {arr.shape}, expected one of {shapes}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{at}: field '{name}' contains NaN or inf")
    return arr


def _world_from_ego(transform: dict[str, Any] | None, at: str) -> FloatArray:
    if transform and transform.get("global2ego") is not None:
        ego_from_world = _matrix(transform["global2ego"], ((4, 4),), at, "global2ego")
        return np.linalg.inv(ego_from_world)
    return np.full((4, 4), np.nan)


def _read_cameras(transform: dict[str, Any] | None, at: str) -> list[Camera]:
    """Camera models from ``transform_matrix.cameras_transform_matrix``.

    ``camera_from_world`` comes from our ``global2camera`` when present, else from the official
    chains ``lidar2camera @ global2lidar`` (KITTI) or ``ego2camera @ global2ego`` (nuScenes).
    A camera without a usable chain is left out (its boxes get camera -1) and logged.
    """
    if not transform:
        return []
    cams = transform.get("cameras_transform_matrix") or {}
    if not isinstance(cams, dict):
        raise InputError(
            f"{at}: field 'transform_matrix.cameras_transform_matrix' must be an object"
        )
    out: list[Camera] = []
    for name in sorted(cams) if "CAM_FRONT" not in cams else _front_first(cams):
        cam = cams[name]
        field_at = f"transform_matrix.cameras_transform_matrix.{name}"
        if not isinstance(cam, dict):
            raise InputError(f"{at}: field '{field_at}' must be an object")
        if cam.get("camera2image") is None:
            continue
        intr = _matrix(
            cam["camera2image"], ((3, 3), (3, 4), (4, 4)), at, f"{field_at}.camera2image"
        )
        image_from_camera = np.zeros((3, 4))
        image_from_camera[:, : intr.shape[1]] = intr[:3, :]
        if cam.get("global2camera") is not None:
            cam_from_world = _matrix(
                cam["global2camera"], ((4, 4),), at, f"{field_at}.global2camera"
            )
        elif cam.get("lidar2camera") is not None and transform.get("global2lidar") is not None:
            cam_from_world = _matrix(
                cam["lidar2camera"], ((4, 4),), at, f"{field_at}.lidar2camera"
            ) @ _matrix(transform["global2lidar"], ((4, 4),), at, "global2lidar")
        elif cam.get("ego2camera") is not None and transform.get("global2ego") is not None:
            cam_from_world = _matrix(
                cam["ego2camera"], ((4, 4),), at, f"{field_at}.ego2camera"
            ) @ _matrix(transform["global2ego"], ((4, 4),), at, "global2ego")
        else:
            log.debug("%s: camera %s has no extrinsics; left out", at, name)
            continue
        shape = cam.get("image_shape") or [0, 0]
        if not (isinstance(shape, list) and len(shape) == 2):
            raise InputError(f"{at}: field '{field_at}.image_shape' must be [width, height]")
        width, height = (_int_field(v, at, f"{field_at}.image_shape") for v in shape)
        out.append(Camera(name, image_from_camera, cam_from_world, width, height))
    return out


def _front_first(cams: dict[str, Any]) -> list[str]:
    return ["CAM_FRONT", *sorted(n for n in cams if n != "CAM_FRONT")]


def _read_ignore(value: Any, camera_names: list[str], at: str) -> tuple[FloatArray, np.ndarray]:
    if not value:
        return np.zeros((0, 4)), np.zeros(0, dtype=np.int64)
    if not isinstance(value, list):
        raise InputError(f"{at}: field 'ignore_regions_image' must be a list")
    xyxy = np.zeros((len(value), 4))
    cam = np.full(len(value), -1, dtype=np.int64)
    for i, region in enumerate(value):
        if not isinstance(region, dict) or "x1y1x2y2" not in region:
            raise InputError(f"{at}, ignore region {i}: field 'x1y1x2y2' missing")
        xyxy[i] = _matrix([region["x1y1x2y2"]], ((1, 4),), at, f"ignore_regions_image[{i}]")[0]
        name = region.get("camera_type")
        cam[i] = camera_names.index(name) if name in camera_names else -1
    return xyxy, cam


def _read_boxes(bboxes: list[Any], camera_names: list[str], at: str, report: LoadReport) -> Boxes:
    """Fast path: one array per field. On any failure, re-walk to name the exact box and field."""
    report.boxes_read += len(bboxes)
    if not bboxes:
        return Boxes.empty()
    try:
        return _boxes_fast(bboxes, camera_names, report)
    except (KeyError, TypeError, ValueError, AttributeError):
        pass
    for i, b in enumerate(bboxes):
        _check_box(b, f"{at}, box {i}")
    raise InputError(f"{at}: invalid boxes")  # _check_box raises first; kept as a guard


def _boxes_fast(bboxes: list[Any], camera_names: list[str], report: LoadReport) -> Boxes:
    cats = np.array([category_index(b["category"]) for b in bboxes], dtype=np.int64)
    known = cats >= 0
    if not known.all():
        for b, ok in zip(bboxes, known, strict=True):
            if not ok:
                report.skipped_categories[str(b["category"])] += 1
    xyz = np.array([b["global_xyz"] for b in bboxes], dtype=np.float64)
    lwh = np.array([b["lwh"] for b in bboxes], dtype=np.float64)
    yaw = np.array([b["global_yaw"] for b in bboxes], dtype=np.float64)
    score = np.array([b["detection_score"] for b in bboxes], dtype=np.float64)
    vel = np.array([b.get("global_velocity") or (0.0, 0.0) for b in bboxes], dtype=np.float64)
    raw = np.array([_opt_float(b.get("detection_score_raw")) for b in bboxes], dtype=np.float64)
    tid = np.array([b.get("track_id", -1) for b in bboxes], dtype=np.int64)
    images = [b.get("bbox_image") or {} for b in bboxes]
    xyxy = np.array([im.get("x1y1x2y2") or (np.nan,) * 4 for im in images], dtype=np.float64)
    cam = np.array(
        [
            camera_names.index(im.get("camera_type"))
            if im.get("camera_type") in camera_names
            else -1
            for im in images
        ],
        dtype=np.int64,
    )
    n = len(bboxes)
    shapes_ok = (
        xyz.shape == (n, 3)
        and lwh.shape == (n, 3)
        and yaw.shape == (n,)
        and score.shape == (n,)
        and vel.shape == (n, 2)
        and xyxy.shape == (n, 4)
    )
    values_ok = (
        shapes_ok
        and np.isfinite(xyz).all()
        and np.isfinite(lwh).all()
        and np.isfinite(yaw).all()
        and np.isfinite(score).all()
        and np.isfinite(vel).all()
        and (lwh >= 0).all()
        and ((score >= 0) & (score <= 1)).all()
        and not np.isinf(xyxy).any()
    )
    if not values_ok:
        raise ValueError("slow path names the field")
    return Boxes(
        xyz=xyz[known],
        lwh=lwh[known],
        yaw=wrap_angle(yaw[known]),
        velocity=vel[known],
        score=score[known],
        category=cats[known],
        xyxy_image=xyxy[known],
        camera=cam[known],
        track_id=tid[known],
        score_raw=raw[known],
    )


def _opt_float(value: Any) -> float:
    return math.nan if value is None else float(value)


def _check_box(b: Any, at: str) -> None:
    """Raise an InputError naming the first bad field of one box."""
    if not isinstance(b, dict):
        raise InputError(f"{at}: a box must be an object")
    for key in REQUIRED_BOX_KEYS:
        if key not in b:
            raise InputError(f"{at}: missing key '{key}'")
    if not isinstance(b["category"], str):
        raise InputError(f"{at}: field 'category' must be a string, got {b['category']!r}")
    _vector(b, "global_xyz", 3, at)
    lwh = _vector(b, "lwh", 3, at)
    if (lwh < 0).any():
        raise InputError(f"{at}: field 'lwh' has a negative size {lwh.tolist()}")
    _vector(b, "global_yaw", None, at)
    score = _vector(b, "detection_score", None, at)
    if not 0.0 <= float(score) <= 1.0:
        raise InputError(f"{at}: field 'detection_score' = {float(score)} is outside [0, 1]")
    if b.get("global_velocity") is not None:
        _vector(b, "global_velocity", 2, at)
    if b.get("detection_score_raw") is not None:
        _vector(b, "detection_score_raw", None, at, allow_nan=True)
    if "track_id" in b:
        _int_field(b["track_id"], at, "track_id")
    image = b.get("bbox_image")
    if image is not None:
        if not isinstance(image, dict):
            raise InputError(f"{at}: field 'bbox_image' must be an object or null")
        box = image.get("x1y1x2y2")
        if box is not None:
            arr = _vector(image, "x1y1x2y2", 4, at, prefix="bbox_image.")
            if not np.isfinite(arr).all():
                raise InputError(f"{at}: field 'bbox_image.x1y1x2y2' contains NaN or inf")
        cam = image.get("camera_type")
        if cam is not None and not isinstance(cam, str):
            raise InputError(f"{at}: field 'bbox_image.camera_type' must be a string or null")


def _vector(
    b: dict[str, Any],
    key: str,
    size: int | None,
    at: str,
    *,
    allow_nan: bool = False,
    prefix: str = "",
) -> np.ndarray:
    name = prefix + key
    value = b[key]
    if isinstance(value, bool) or (size is None and not isinstance(value, int | float)):
        raise InputError(f"{at}: field '{name}' must be a number, got {value!r}")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{at}: field '{name}' must be numeric, got {value!r}") from None
    expected = () if size is None else (size,)
    if arr.shape != expected:
        what = "a number" if size is None else f"a list of {size} numbers"
        raise InputError(f"{at}: field '{name}' must be {what}, got {value!r}")
    if not allow_nan and not np.isfinite(arr).all():
        raise InputError(f"{at}: field '{name}' contains NaN or inf: {value!r}")
    return arr


# ---------------------------------------------------------------------------------------------
# writing


def yaw_to_quaternion_wxyz(yaw_rad: FloatArray) -> FloatArray:
    """(N, 4) quaternions [w, x, y, z] of a rotation by yaw about +z."""
    half = np.asarray(yaw_rad, dtype=np.float64) / 2.0
    zeros = np.zeros_like(half)
    return np.stack([np.cos(half), zeros, zeros, np.sin(half)], axis=-1)


def frame_to_dict(frame: Frame) -> dict[str, Any]:
    """One frame in the BaseVersion schema (official keys plus this project's extensions)."""
    b = frame.boxes
    quats = yaw_to_quaternion_wxyz(b.yaw)
    names = [c.name for c in frame.cameras]
    boxes: list[dict[str, Any]] = []
    for i in range(len(b)):
        box: dict[str, Any] = {
            "category": CATEGORIES[b.category[i]],
            "detection_score": float(b.score[i]),
            "global_xyz": b.xyz[i].tolist(),
            "lwh": b.lwh[i].tolist(),
            "global_yaw": float(b.yaw[i]),
            "global_orientation": quats[i].tolist(),
            "global_velocity": b.velocity[i].tolist(),
            "global_acceleration": [0.0, 0.0],
            "bbox_image": {
                "camera_type": names[b.camera[i]] if b.camera[i] >= 0 else None,
                "x1y1x2y2": None if np.isnan(b.xyxy_image[i]).any() else b.xyxy_image[i].tolist(),
            },
        }
        if not math.isnan(b.score_raw[i]):
            box["detection_score_raw"] = float(b.score_raw[i])
        if b.track_id[i] >= 0:
            box["track_id"] = int(b.track_id[i])
        boxes.append(box)
    out: dict[str, Any] = {
        "frame_id": int(frame.frame_id),
        "timestamp": None
        if math.isnan(frame.timestamp_secs)
        else round(frame.timestamp_secs * MICROS_PER_SEC),
        "cur_sample_token": frame.sample_token,
        "transform_matrix": _transform_to_dict(frame),
        "bboxes": boxes,
    }
    if len(frame.ignore_xyxy_image):
        out["ignore_regions_image"] = [
            {"camera_type": names[c] if c >= 0 else None, "x1y1x2y2": xyxy.tolist()}
            for xyxy, c in zip(frame.ignore_xyxy_image, frame.ignore_camera, strict=True)
        ]
    return out


def _transform_to_dict(frame: Frame) -> dict[str, Any]:
    transform: dict[str, Any] = json.loads(json.dumps(frame.transform_matrix or {}))
    transform.setdefault("global2ego", None)
    transform.setdefault("ego2lidar", None)
    transform.setdefault("global2lidar", None)
    if np.isfinite(frame.world_from_ego).all():
        transform["global2ego"] = np.linalg.inv(frame.world_from_ego).tolist()
    cams = transform.setdefault("cameras_transform_matrix", {})
    for cam in frame.cameras:
        entry = cams.setdefault(cam.name, {})
        camera2image = np.eye(4)
        camera2image[:3, :] = cam.image_from_camera
        entry["image_shape"] = [cam.width_px, cam.height_px]
        entry["camera2image"] = camera2image.tolist()
        entry["global2camera"] = cam.camera_from_world.tolist()
    return transform


def write_baseversion(path: str | Path, scenes: Scenes) -> None:
    """Write scenes atomically (a temporary file renamed into place: complete or not at all)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {scene: [frame_to_dict(f) for f in frames] for scene, frames in scenes.items()}
    write_json_atomic(path, payload)


# ---------------------------------------------------------------------------------------------
# summary


def summarize(scenes: Scenes, report: LoadReport | None = None) -> dict[str, Any]:
    """Counts for `mctrack validate`: scenes, frames, boxes per category, time span."""
    per_category: Counter[str] = Counter()
    frames = 0
    span = 0.0
    for frame_list in scenes.values():
        frames += len(frame_list)
        for f in frame_list:
            per_category.update(CATEGORIES[c] for c in f.boxes.category)
        if len(frame_list) > 1:
            t0, t1 = frame_list[0].timestamp_secs, frame_list[-1].timestamp_secs
            if math.isfinite(t0) and math.isfinite(t1):
                span += t1 - t0
    out: dict[str, Any] = {
        "scenes": len(scenes),
        "frames": frames,
        "boxes": sum(per_category.values()),
        "boxes_per_category": dict(sorted(per_category.items())),
        "time_span_secs": round(span, 3),
    }
    if report is not None and report.boxes_skipped:
        out["skipped_unknown_categories"] = dict(sorted(report.skipped_categories.items()))
    return out
