"""BaseVersion JSON <-> frames: the only module that knows the file schema (docs/baseversion.md).

Reads the official MCTrack files unchanged (``{scene: [frame, ...]}``) and this project's richer
files (real timestamps, per-camera models, ground-truth track ids). Everything is validated at
this boundary; inside the tracker the data is trusted.
"""

from __future__ import annotations

import gzip
import itertools
import json
import logging
import math
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from tracker.boxes import Boxes, FloatArray
from tracker.categories import CATEGORIES, category_index
from tracker.errors import InputError
from tracker.events import TrackStatus
from tracker.frame import Camera, Frame
from tracker.geometry import wrap_angle
from tracker.io.bounds import (
    ANGLE_NOTE,
    BOUND_NOTE,
    MAX_ANGLE_RAD,
    MAX_SPEED_MPS,
    SPEED_NOTE,
    beyond_bound,
)
from tracker.io.fileio import (
    MAX_INPUT_BYTES_ENV,
    max_input_bytes,
    name_is_escaped,
    safe_filename,
    write_json_atomic,
)

log = logging.getLogger(__name__)

Scenes = dict[str, list[Frame]]

REQUIRED_FRAME_KEYS = ("frame_id", "bboxes")
REQUIRED_BOX_KEYS = ("category", "detection_score", "global_xyz", "lwh", "global_yaw")
MAX_STATUS = int(max(TrackStatus))  # tracks files: 1 confirmed, 2 coasting are written
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

# Integers in the schema fit in int64 (ids, frame ids) or are exact in float64 (timestamps, µs);
# longer literals are refused in the parser (before Python's 4,300-digit conversion limit).
MAX_INT_DIGITS = 19
INT64_MAX = 2**63 - 1
MAX_EXACT_INT = 2**53
MAX_TRANSFORM_DEPTH = 8  # transform_matrix is copied to outputs: bounded, finite, encodable
MAX_SCENE_NAME_CHARS = 200  # scene names become file names (at most 255 bytes on most systems)
# A camera image's width and height: boxes are clipped to [0, width - 1], so 1 px holds none;
# no camera takes images a million pixels wide (the widest sensors are ~20 000 px)
MIN_IMAGE_PX, MAX_IMAGE_PX = 2, 1_000_000


class _Refused(ValueError):
    """Raised inside the JSON parser's hooks; turned into an InputError with a location."""


def read_input_bytes(path: Path, cap: int | None = None) -> bytes:
    """The file's bytes, gunzipped for ``.gz``, refused (InputError) beyond ``cap`` bytes."""
    cap = max_input_bytes() if cap is None else cap
    hint = f"(the cap; raise it with {MAX_INPUT_BYTES_ENV})"
    try:
        if path.suffix != ".gz":
            size = path.stat().st_size
            if size > cap:
                raise InputError(f"{path}: {size} bytes is more than {cap} {hint}")
            return path.read_bytes()
        chunks: list[bytes] = []
        total = 0
        with gzip.open(path, "rb") as fh:
            while chunk := fh.read(min(1 << 24, cap + 1 - total)):
                chunks.append(chunk)
                total += len(chunk)
                if total > cap:
                    raise InputError(f"{path}: decompresses to more than {cap} bytes {hint}")
        return b"".join(chunks)
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, not a file") from None
    except (EOFError, gzip.BadGzipFile, zlib.error) as exc:
        raise InputError(f"{path}: corrupt gzip data ({exc})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None


def _object_no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out = dict(pairs)
    if len(out) != len(pairs):
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                raise _Refused(f"duplicate key {key!r} in an object")
            seen.add(key)
    return out


def _parse_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise _Refused(f"integer with {len(text.lstrip('-'))} digits (at most {MAX_INT_DIGITS})")
    return int(text)


def parse_json_bytes(path: Path, raw: bytes) -> Any:
    """Strict, depth-safe JSON: duplicate keys and overlong integers are refused; every failure
    is an InputError naming the file (and the line and column where the parser knows them), an
    empty file (or all whitespace) one of its own."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    if not text.strip():  # json's 'Expecting value: line 1 column 1' reads as a syntax error
        if raw:
            how = "whitespace only"
        else:
            how = "gunzipped: 0 bytes" if path.suffix == ".gz" else "0 bytes"
        raise InputError(f"{path}: the file is empty ({how}), no JSON in it")
    try:
        return json.loads(text, object_pairs_hook=_object_no_duplicates, parse_int=_parse_int)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: malformed JSON ({exc})") from None
    except _Refused as exc:
        raise InputError(f"{path}: {exc}") from None
    except RecursionError:
        raise InputError(f"{path}: JSON nested too deeply") from None


def read_baseversion(
    path: str | Path,
    *,
    fallback_frame_rate_hz: float | None = None,
    report: LoadReport | None = None,
    max_bytes: int | None = None,
) -> Scenes:
    """Load and validate a BaseVersion file.

    Parameters
    ----------
    path : the JSON file (``.json`` or ``.json.gz``).
    fallback_frame_rate_hz : used when a frame's ``timestamp`` is null (official KITTI files):
        ``timestamp_secs = frame_id / rate``. Without it such frames get NaN timestamps.
    report : filled with counts of skipped boxes (unknown categories are a logged, counted skip).
    max_bytes : decompressed-size cap (default :func:`max_input_bytes`).

    Raises
    ------
    InputError naming the file, scene, frame index, box index and field (the first error).
    """
    errors = _Errors(limit=0)
    return _read(Path(path), fallback_frame_rate_hz, report, max_bytes, errors)


@dataclass
class Validation:
    """What :func:`validate_baseversion` found: the first ``max_errors`` messages and the total."""

    errors: list[str]
    error_count: int
    scenes: Scenes
    report: LoadReport

    @property
    def ok(self) -> bool:
        return self.error_count == 0


def validate_baseversion(
    path: str | Path,
    *,
    max_errors: int = 50,
    fallback_frame_rate_hz: float | None = None,
    max_bytes: int | None = None,
) -> Validation:
    """Check a whole file, collecting every error (messages kept up to ``max_errors``).

    A frame with an error is left out of ``scenes`` and the check goes on with the next one.
    A file that cannot be parsed at all gives one error. Accepts exactly what
    :func:`read_baseversion` accepts (and so what ``mctrack track`` processes to the end).
    """
    errors = _Errors(limit=max(1, max_errors))
    report = LoadReport()
    scenes: Scenes = {}
    try:
        scenes = _read(Path(path), fallback_frame_rate_hz, report, max_bytes, errors)
    except InputError as exc:  # unparseable file or top-level shape: nothing more to check
        errors.add(str(exc))
    return Validation(errors.messages, errors.count, scenes, report)


class _Recorded(InputError):
    """A frame's errors were already recorded: leave the frame out, add nothing."""


class _Errors:
    """limit 0: raise the first error; else record up to ``limit`` messages and count them all."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.messages: list[str] = []
        self.count = 0

    def add(self, message: str) -> None:
        if not self.limit:
            raise InputError(message)
        self.count += 1
        if len(self.messages) < self.limit:
            self.messages.append(message)


def _read(
    path: Path,
    fallback_frame_rate_hz: float | None,
    report: LoadReport | None,
    max_bytes: int | None,
    errors: _Errors,
) -> Scenes:
    report = report if report is not None else LoadReport()
    data = parse_json_bytes(path, read_input_bytes(path, max_bytes))
    if isinstance(data, dict) and "results" in data and "meta" in data:
        raise InputError(
            f"{path}: this is a nuScenes results file, not BaseVersion; convert it first "
            "(mctrack convert nuscenes)"
        )
    if not isinstance(data, dict):
        raise InputError(f"{path}: top level must be an object {{scene: [frame, ...]}}")
    scenes: Scenes = {}
    for scene, frames in data.items():
        where = f"{path}: scene {_quote(scene)}"
        problem = scene_name_problem(scene)
        if problem:
            errors.add(f"{where}: scene name {problem}")
            continue
        if not isinstance(frames, list):
            errors.add(f"{where}: must map to a list of frames, got {type(frames).__name__}")
            continue
        scenes[scene] = _read_scene(scene, frames, where, fallback_frame_rate_hz, report, errors)
    if report.boxes_skipped:
        log.warning(
            "%s: skipped %d boxes of unknown categories: %s",
            path,
            report.boxes_skipped,
            dict(sorted(report.skipped_categories.items())),
        )
    return scenes


def _quote(text: str) -> str:
    """repr() that is always printable and encodable (lone surrogates, NUL, controls escaped)."""
    return ascii(text) if len(text) <= 80 else ascii(text[:80]) + "..."


def scene_name_problem(name: str) -> str | None:
    """Why a scene name cannot be used at all (None when it can).

    Names with path separators, ``..`` or a leading dot are usable: file names built from them
    are escaped by :func:`tracker.io.fileio.safe_filename`. Empty names, NUL, control characters,
    lone surrogates and overlong names are refused.
    """
    if not name:
        return "is empty"
    if len(name) > MAX_SCENE_NAME_CHARS:
        return f"is longer than {MAX_SCENE_NAME_CHARS} characters"
    if any(ord(c) < 32 or ord(c) == 127 for c in name):
        return "contains a NUL or control character"
    if not _encodable(name):
        return "contains a lone surrogate (not encodable text)"
    return None


def _read_scene(
    scene: str,
    frames: list[Any],
    where: str,
    fallback_rate: float | None,
    report: LoadReport,
    errors: _Errors,
) -> list[Frame]:
    out: list[Frame] = []
    for index, raw in enumerate(frames):
        at = f"{where}, frame index {index}"
        try:
            frame = _read_frame(scene, raw, at, fallback_rate, report, errors)
            if out:
                _check_order(out[-1], frame, raw, at)
        except _Recorded:
            continue
        except InputError as exc:
            errors.add(str(exc))
            continue
        out.append(frame)
    return out


def _check_order(prev: Frame, frame: Frame, raw: dict[str, Any], at: str) -> None:
    if frame.frame_id <= prev.frame_id:
        raise InputError(
            f"{at}: field 'frame_id' = {frame.frame_id} is not increasing "
            f"(previous frame_id {prev.frame_id})"
        )
    if frame.timestamp_secs <= prev.timestamp_secs:
        raise InputError(
            f"{at}: field 'timestamp' = {raw.get('timestamp')} is not increasing "
            f"(previous {prev.timestamp_secs:.6f} s)"
        )


def _read_frame(
    scene: str,
    raw: Any,
    at: str,
    fallback_rate: float | None,
    report: LoadReport,
    errors: _Errors,
) -> Frame:
    if not isinstance(raw, dict):
        raise InputError(f"{at}: a frame must be an object")
    for key in REQUIRED_FRAME_KEYS:
        if key not in raw:
            raise InputError(f"{at}: missing key '{key}'")
    frame_id = _int_field(raw["frame_id"], at, "frame_id", low=0, high=INT64_MAX)
    timestamp_secs = _timestamp(raw.get("timestamp"), frame_id, fallback_rate, at)
    transform = raw.get("transform_matrix")
    if transform is not None and not isinstance(transform, dict):
        raise InputError(f"{at}: field 'transform_matrix' must be an object or null")
    _check_passthrough(transform, at, "transform_matrix", 0)
    cameras = _read_cameras(transform, at)
    camera_names = [c.name for c in cameras]
    bboxes = raw["bboxes"]
    if not isinstance(bboxes, list):
        raise InputError(f"{at}: field 'bboxes' must be a list")
    # A box or ignore region may name any camera the frame lists, also one left out for want of
    # a model (read as no camera). A frame listing none (cameras stripped) has no image plane to
    # check against: its boxes' and regions' camera_type is read as no camera.
    frame_cameras = frozenset((transform or {}).get("cameras_transform_matrix") or ())
    boxes = _read_boxes(bboxes, camera_names, frame_cameras, at, report, errors)
    ignore_xyxy, ignore_cam = _read_ignore(
        raw.get("ignore_regions_image"), camera_names, frame_cameras, at
    )
    token = raw.get("cur_sample_token")
    if token is not None and not isinstance(token, str):
        raise InputError(f"{at}: field 'cur_sample_token' must be a string or null")
    return Frame(
        scene=scene,
        frame_id=frame_id,
        timestamp_secs=timestamp_secs,
        boxes=boxes,
        cameras=tuple(cameras),
        world_from_ego=_world_from_ego(transform, at),
        sample_token=token,
        transform_matrix=transform,
        ignore_xyxy_image=ignore_xyxy,
        ignore_camera=ignore_cam,
    )


def _check_passthrough(value: Any, at: str, name: str, depth: int) -> None:
    """``transform_matrix`` is copied into output files: bounded depth, finite numbers,
    encodable strings (else the writer would fail after the whole run)."""
    if depth > MAX_TRANSFORM_DEPTH:
        raise InputError(f"{at}: field '{name}' is nested deeper than {MAX_TRANSFORM_DEPTH}")
    if isinstance(value, dict):
        for key, item in value.items():
            if not _encodable(key):
                raise InputError(f"{at}: field '{name}' has a key with a lone surrogate")
            _check_passthrough(item, at, f"{name}.{_safe_key(key)}", depth + 1)
    elif isinstance(value, list):
        for item in value:
            _check_passthrough(item, at, name, depth + 1)
    elif isinstance(value, float) and not math.isfinite(value):
        raise InputError(f"{at}: field '{name}' contains NaN or inf")
    elif isinstance(value, str) and not _encodable(value):
        raise InputError(f"{at}: field '{name}' contains a lone surrogate")


def _encodable(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _safe_key(key: str) -> str:
    return key if key.isprintable() and len(key) <= 40 else _quote(key)


def _int_field(
    value: Any, at: str, name: str, *, low: int = -INT64_MAX, high: int = INT64_MAX
) -> int:
    """A JSON integer (not a float, string or bool) within [low, high]."""
    if type(value) is not int:
        raise InputError(f"{at}: field '{name}' must be an integer, got {_short(value)}")
    if not low <= value <= high:
        raise InputError(f"{at}: field '{name}' = {value} is outside [{low}, {high}]")
    return value


def _short(value: Any) -> str:
    """A printable, encodable, bounded repr for error messages (input may hold anything)."""
    text = repr(value)
    text = text[:60] + "..." if len(text) > 60 else text
    return text.encode("ascii", "backslashreplace").decode()


def _timestamp(value: Any, frame_id: int, fallback_rate: float | None, at: str) -> float:
    """Seconds. BaseVersion stores integer microseconds (nuScenes convention) or null."""
    if value is None:
        if not fallback_rate:
            return math.nan
        # the time a written tracks file stores (integer µs) must read back, as a given one does
        if frame_id / fallback_rate * MICROS_PER_SEC > MAX_EXACT_INT:
            raise InputError(
                f"{at}: field 'frame_id' = {frame_id}: its time at the fallback rate of "
                f"{fallback_rate:g} Hz (the timestamp is null) is outside ±2^53 µs"
            )
        return frame_id / fallback_rate
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{at}: field 'timestamp' must be microseconds (a number) or null")
    if isinstance(value, float) and not math.isfinite(value):
        raise InputError(f"{at}: field 'timestamp' is not finite ({value})")
    if abs(value) > MAX_EXACT_INT:
        raise InputError(f"{at}: field 'timestamp' = {value} is outside ±2^53 µs")
    return float(value) / MICROS_PER_SEC


def _matrix(value: Any, shapes: tuple[tuple[int, int], ...], at: str, name: str) -> FloatArray:
    if not isinstance(value, list) or not all(
        isinstance(row, list) and set(map(type, row)) <= {int, float} for row in value
    ):
        raise InputError(f"{at}: field '{name}' is not a numeric matrix (lists of numbers)")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{at}: field '{name}' is not a numeric matrix") from None
    if arr.shape not in shapes:
        raise InputError(f"{at}: field '{name}' has shape {arr.shape}, expected one of {shapes}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{at}: field '{name}' contains NaN or inf")
    return arr


def _pose(value: Any, at: str, name: str) -> FloatArray:
    """A 4x4 pose of ``transform_matrix`` whose translation is within the bound of
    :mod:`tracker.io.bounds` (at 1e300 m, the ego or a camera is no place on Earth, and the
    distances and projections from it overflow)."""
    pose = _matrix(value, ((4, 4),), at, name)
    if beyond_bound(pose[None, :3, 3])[0]:
        raise InputError(
            f"{at}: field '{name}' has translation {pose[:3, 3].tolist()}: {BOUND_NOTE}"
        )
    return pose


def _world_from_ego(transform: dict[str, Any] | None, at: str) -> FloatArray:
    if transform and transform.get("global2ego") is not None:
        ego_from_world = _pose(transform["global2ego"], at, "global2ego")
        try:
            world_from_ego = np.linalg.inv(ego_from_world)
        except np.linalg.LinAlgError:
            raise InputError(f"{at}: field 'global2ego' is singular (not a pose)") from None
        if not np.isfinite(world_from_ego).all():
            raise InputError(f"{at}: field 'global2ego' is singular (not a pose)")
        if beyond_bound(world_from_ego[None, :3, 3])[0]:  # (nearly singular: a far ego)
            raise InputError(
                f"{at}: field 'global2ego' puts the ego at {world_from_ego[:3, 3].tolist()}: "
                f"{BOUND_NOTE}"
            )
        return world_from_ego
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
            cam_from_world = _pose(cam["global2camera"], at, f"{field_at}.global2camera")
        elif cam.get("lidar2camera") is not None and transform.get("global2lidar") is not None:
            cam_from_world = _pose(cam["lidar2camera"], at, f"{field_at}.lidar2camera") @ _pose(
                transform["global2lidar"], at, "global2lidar"
            )
        elif cam.get("ego2camera") is not None and transform.get("global2ego") is not None:
            cam_from_world = _pose(cam["ego2camera"], at, f"{field_at}.ego2camera") @ _pose(
                transform["global2ego"], at, "global2ego"
            )
        else:
            log.debug("%s: camera %s has no extrinsics; left out", at, name)
            continue
        if beyond_bound(cam_from_world[None, :3, 3])[0]:  # (each within it, not the chain)
            raise InputError(
                f"{at}: field '{field_at}': camera_from_world has translation "
                f"{cam_from_world[:3, 3].tolist()}: {BOUND_NOTE}"
            )
        width, height = _image_shape(cam.get("image_shape"), at, f"{field_at}.image_shape")
        out.append(Camera(name, image_from_camera, cam_from_world, width, height))
    return out


def _image_shape(value: Any, at: str, name: str) -> tuple[int, int]:
    """A usable camera's ``[width, height]``: whole pixels, each at least 2. Boxes are projected
    and clipped to ``[0, width - 1] x [0, height - 1]``: without a size (read as 0 once) every
    projection was clipped away, so the image-plane stage matched nothing and the KITTI results
    were empty, silently."""
    if value is None:
        raise InputError(
            f"{at}: field '{name}' is missing: a camera with a projection and extrinsics "
            "needs its image size [width, height] in pixels (boxes are projected into it)"
        )
    if not (isinstance(value, list) and len(value) == 2):
        raise InputError(f"{at}: field '{name}' must be [width, height], got {_short(value)}")
    if not all(type(v) is int and MIN_IMAGE_PX <= v <= MAX_IMAGE_PX for v in value):
        raise InputError(
            f"{at}: field '{name}' = {_short(value)}: width and height must be whole pixels "
            f"in [{MIN_IMAGE_PX}, {MAX_IMAGE_PX}]"
        )
    return value[0], value[1]


def _front_first(cams: dict[str, Any]) -> list[str]:
    return ["CAM_FRONT", *sorted(n for n in cams if n != "CAM_FRONT")]


def _read_ignore(
    value: Any, camera_names: list[str], frame_cameras: frozenset[str], at: str
) -> tuple[FloatArray, np.ndarray]:
    """Ignore regions, each in a camera the frame lists (checked as a box's ``camera_type``:
    a region in an unlisted camera was read as no camera, silently)."""
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
        if name is not None and not isinstance(name, str):
            raise InputError(
                f"{at}: field 'ignore_regions_image[{i}].camera_type' must be a string or null"
            )
        if name and frame_cameras and name not in frame_cameras:
            has = ", ".join(map(_short, sorted(frame_cameras)))
            raise InputError(
                f"{at}: field 'ignore_regions_image[{i}].camera_type' = {_short(name)} names no "
                f"camera of this frame (its transform_matrix.cameras_transform_matrix has {has})"
            )
        cam[i] = camera_names.index(name) if name in camera_names else -1
    return xyxy, cam


def _read_boxes(
    bboxes: list[Any],
    camera_names: list[str],
    frame_cameras: frozenset[str],
    at: str,
    report: LoadReport,
    errors: _Errors,
) -> Boxes:
    """Fast path: one array per field. On any failure, re-walk to name every bad box and field."""
    if not bboxes:
        return Boxes.empty()
    try:
        boxes = _boxes_fast(bboxes, camera_names, frame_cameras, report)
        report.boxes_read += len(bboxes)
        return boxes
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError):
        pass
    recorded = False
    for i, b in enumerate(bboxes):
        try:
            _check_box(b, frame_cameras, f"{at}, box {i}")
        except InputError as exc:
            errors.add(str(exc))  # raises the first when not collecting
            recorded = True
    if recorded:
        raise _Recorded(f"{at}: invalid boxes")  # the frame is left out; errors are recorded
    raise InputError(f"{at}: invalid boxes")  # a guard: the fast path refused, the check did not


_NUMBER_TYPES = {int, float}


def _numbers(rows: list[Any]) -> bool:
    """Every row is a list of JSON numbers (no strings, booleans or nested lists)."""
    return (
        set(map(type, rows)) <= {list}
        and set(map(type, itertools.chain.from_iterable(rows))) <= _NUMBER_TYPES
    )


def _boxes_fast(
    bboxes: list[Any], camera_names: list[str], frame_cameras: frozenset[str], report: LoadReport
) -> Boxes:
    names = [b["category"] for b in bboxes]
    if set(map(type, names)) != {str}:
        raise ValueError("category must be a string")
    cats = np.array([category_index(n) for n in names], dtype=np.int64)
    known = cats >= 0
    xyz_rows = [b["global_xyz"] for b in bboxes]
    lwh_rows = [b["lwh"] for b in bboxes]
    yaw_list = [b["global_yaw"] for b in bboxes]
    score_list = [b["detection_score"] for b in bboxes]
    # absent: 0 (KITTI, official files); null: no estimate (NaN, not measured by the tracker)
    vel_rows = [_velocity_row(b) for b in bboxes]
    raw_list = [b.get("detection_score_raw") for b in bboxes]
    tid_list = [b.get("track_id", -1) for b in bboxes]
    images = [b.get("bbox_image") or {} for b in bboxes]
    given = [im.get("x1y1x2y2") for im in images]
    xyxy_rows = [v if v is not None else [math.nan] * 4 for v in given]
    cam_names = [im.get("camera_type") for im in images]
    status_list = [b["status"] for b in bboxes if "status" in b]  # (tracks files)
    # JSON booleans and strings would pass numpy's float conversion: check the types first
    if not (
        _numbers(xyz_rows)
        and _numbers(lwh_rows)
        and _numbers(vel_rows)
        and _numbers(xyxy_rows)
        and set(map(type, yaw_list)) <= _NUMBER_TYPES
        and set(map(type, score_list)) <= _NUMBER_TYPES
        and set(map(type, raw_list)) <= {int, float, type(None)}
        and set(map(type, tid_list)) <= {int}
        and set(map(type, cam_names)) <= {str, type(None)}
        and set(map(type, status_list)) <= {int}
        and (not frame_cameras or set(cam_names) - {None, ""} <= frame_cameras)
        and all(0 <= s <= MAX_STATUS for s in status_list)
    ):
        raise TypeError("slow path names the field")
    xyz = np.array(xyz_rows, dtype=np.float64)
    lwh = np.array(lwh_rows, dtype=np.float64)
    yaw = np.array(yaw_list, dtype=np.float64)
    score = np.array(score_list, dtype=np.float64)
    vel = np.array(vel_rows, dtype=np.float64)
    raw = np.array([math.nan if v is None else v for v in raw_list], dtype=np.float64)
    if any(not -1 <= t <= INT64_MAX for t in tid_list):
        raise ValueError("slow path names the field")
    tid = np.array(tid_list, dtype=np.int64)
    xyxy = np.array(xyxy_rows, dtype=np.float64)
    index = {name: i for i, name in enumerate(camera_names)}
    cam = np.array([index.get(c, -1) if c else -1 for c in cam_names], dtype=np.int64)
    n = len(bboxes)
    shapes_ok = (
        xyz.shape == (n, 3) and lwh.shape == (n, 3) and vel.shape == (n, 2) and xyxy.shape == (n, 4)
    )
    values_ok = (
        shapes_ok
        and np.isfinite(xyz).all()
        and np.isfinite(lwh).all()
        and np.isfinite(yaw).all()
        and not beyond_bound(yaw, MAX_ANGLE_RAD).any()
        and np.isfinite(score).all()
        and np.isfinite(vel[[b.get("global_velocity") is not None for b in bboxes]]).all()
        and (lwh[:, :2] > 0).all()
        and (lwh[:, 2] >= 0).all()
        and not beyond_bound(xyz).any()
        and not beyond_bound(lwh).any()
        and not beyond_bound(vel, MAX_SPEED_MPS).any()
        and ((score >= 0) & (score <= 1)).all()
        and np.isfinite(xyxy[[v is not None for v in given]]).all()
        and not (xyxy[:, 2:] < xyxy[:, :2]).any()  # (NaN rows: no box, False)
        and not np.isinf(raw).any()
    )
    if not values_ok:
        raise ValueError("slow path names the field")
    if not known.all():
        for name, ok in zip(names, known, strict=True):
            if not ok:
                report.skipped_categories[name] += 1
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


_ZERO_VELOCITY: Final = [0.0, 0.0]
_NO_VELOCITY: Final = [math.nan, math.nan]


def _velocity_row(b: dict[str, Any]) -> Any:
    if "global_velocity" not in b:
        return _ZERO_VELOCITY
    value = b["global_velocity"]
    return _NO_VELOCITY if value is None else value


def _opt_float(value: Any) -> float:
    return math.nan if value is None else float(value)


def _check_box(b: Any, frame_cameras: frozenset[str], at: str) -> None:
    """Raise an InputError naming the first bad field of one box."""
    if not isinstance(b, dict):
        raise InputError(f"{at}: a box must be an object")
    for key in REQUIRED_BOX_KEYS:
        if key not in b:
            raise InputError(f"{at}: missing key '{key}'")
    if not isinstance(b["category"], str):
        raise InputError(f"{at}: field 'category' must be a string, got {_short(b['category'])}")
    xyz = _vector(b, "global_xyz", 3, at)
    lwh = _vector(b, "lwh", 3, at)
    if not ((lwh[:2] > 0).all() and lwh[2] >= 0):
        raise InputError(
            f"{at}: field 'lwh' = {lwh.tolist()}: length and width must be > 0, height >= 0"
        )
    for key, value in (("global_xyz", xyz), ("lwh", lwh)):
        if beyond_bound([value])[0]:
            raise InputError(f"{at}: field '{key}' = {value.tolist()}: {BOUND_NOTE}")
    yaw = float(_vector(b, "global_yaw", None, at))
    if abs(yaw) > MAX_ANGLE_RAD:
        raise InputError(f"{at}: field 'global_yaw' = {yaw:g}: {ANGLE_NOTE}")
    score = _vector(b, "detection_score", None, at)
    if not 0.0 <= float(score) <= 1.0:
        raise InputError(f"{at}: field 'detection_score' = {float(score)} is outside [0, 1]")
    if b.get("global_velocity") is not None:
        velocity = _vector(b, "global_velocity", 2, at)
        if beyond_bound([velocity], MAX_SPEED_MPS)[0]:
            raise InputError(f"{at}: field 'global_velocity' = {velocity.tolist()}: {SPEED_NOTE}")
    if b.get("detection_score_raw") is not None:
        _vector(b, "detection_score_raw", None, at, allow_nan=True)
    if "track_id" in b:
        _int_field(b["track_id"], at, "track_id", low=-1)
    if "status" in b:  # (read by tracks-file readers as a number: "1" passed as 1)
        _int_field(b["status"], at, "status", low=0, high=MAX_STATUS)
    image = b.get("bbox_image")
    if image is not None:
        if not isinstance(image, dict):
            raise InputError(f"{at}: field 'bbox_image' must be an object or null")
        box = image.get("x1y1x2y2")
        if box is not None:
            x1, y1, x2, y2 = _vector(image, "x1y1x2y2", 4, at, prefix="bbox_image.").tolist()
            if x2 < x1 or y2 < y1:
                raise InputError(
                    f"{at}: field 'bbox_image.x1y1x2y2' = {[x1, y1, x2, y2]}: "
                    "must be [x1, y1, x2, y2] with x1 <= x2 and y1 <= y2"
                )
        cam = image.get("camera_type")
        if cam is not None and not isinstance(cam, str):
            raise InputError(f"{at}: field 'bbox_image.camera_type' must be a string or null")
        if cam and frame_cameras and cam not in frame_cameras:
            has = ", ".join(map(_short, sorted(frame_cameras)))
            raise InputError(
                f"{at}: field 'bbox_image.camera_type' = {_short(cam)} names no camera of "
                f"this frame (its transform_matrix.cameras_transform_matrix has {has})"
            )


def _vector(
    b: dict[str, Any],
    key: str,
    size: int | None,
    at: str,
    *,
    allow_nan: bool = False,
    prefix: str = "",
) -> np.ndarray:
    """A JSON number (``size`` None) or a list of ``size`` JSON numbers; booleans and strings
    are refused (numpy would read ``"2.5"`` and ``true`` as numbers)."""
    name = prefix + key
    value = b[key]
    what = "a number" if size is None else f"a list of {size} numbers"
    if size is None:
        ok = type(value) in _NUMBER_TYPES
    else:
        ok = isinstance(value, list) and len(value) == size and _numbers([value])
    if not ok:
        raise InputError(f"{at}: field '{name}' must be {what}, got {_short(value)}")
    arr = np.asarray(value, dtype=np.float64)
    if not allow_nan and not np.isfinite(arr).all():
        raise InputError(f"{at}: field '{name}' contains NaN or inf: {_short(value)}")
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
            # NaN (no estimate) as null: JSON has no NaN, and null reads back as NaN
            "global_velocity": None if np.isnan(b.velocity[i]).any() else b.velocity[i].tolist(),
            "global_acceleration": [0.0, 0.0],
            "bbox_image": {
                # a track's camera comes from the frame of its last detection: this frame
                # may have fewer cameras (cameras are per frame in the input)
                "camera_type": names[b.camera[i]] if 0 <= b.camera[i] < len(names) else None,
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
    escaped = {s: safe_filename(s) for s in scenes if name_is_escaped(s)}
    if escaped:  # path separators, "..", a leading dot...: written under an escaped file name
        out["scene_names_escaped_in_file_names"] = escaped
    return out
