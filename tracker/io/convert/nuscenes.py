"""nuScenes: detection results + the dataset's metadata tables → world-frame Frame sequences.

Inputs
------
* ``DATAROOT/<version>/*.json``: the metadata tables (``v1.0-trainval``, ``v1.0-mini``,
  ``v1.0-test``), read with the official ``nuscenes-devkit`` (``NuScenes``), which also provides
  the official split definitions (``val``, ``mini_val``, ``test``, ..., or a custom split from
  ``DATAROOT/<version>/splits.json``) and the ground-truth velocity (``box_velocity``).
* A detection results file in the standard nuScenes submission format
  ``{"meta": {...}, "results": {sample_token: [box, ...]}}`` with boxes
  ``{translation, size (w, l, h), rotation (w, x, y, z), velocity, detection_name,
  detection_score}`` in the global frame.

Output (one :class:`~tracker.frame.Frame` per sample, scenes in split order)
--------------------------------------------------------------------------------
* ``frame_id`` 0.. in sample order, ``timestamp_secs`` from the sample timestamp (µs),
  ``sample_token``.
* ``world_from_ego``: the ego pose at the LIDAR_TOP keyframe.
* Six :class:`~tracker.frame.Camera` models per frame. ``camera_from_world`` uses the ego pose
  at *that camera's own* sample_data timestamp and its calibrated sensor (the cameras fire up to
  ~40 ms apart, while the ego may move 0.5 m in that time); ``image_from_camera = [K | 0]``.
  nuScenes camera axes already are ours (x right, y down, z forward).
* Boxes: ``lwh = (size[1], size[0], size[2])``, yaw from the quaternion, the detector velocity,
  the score. Only the seven tracking classes are kept (the other detection classes are counted
  and logged). Each box gets the first camera of FRONT, FRONT_RIGHT, FRONT_LEFT, BACK,
  BACK_LEFT, BACK_RIGHT in which part of it is visible, and its 2D box there.
  **Fixed:** the reference projects corners behind a camera through the perspective division
  (sign flip) and so "sees" objects behind it; here box edges are clipped to the near plane
  first (:func:`tracker.camera.project_boxes`), so a box behind a camera is never assigned to it.
* Ground truth (optional): the sample annotations of the tracking classes with at least one
  lidar or radar point (the official evaluation drops the others), ``track_id`` = the index of
  the instance in the ``instance`` table (stable across runs), the devkit's ``box_velocity``
  (centred difference; unknown, NaN, where the devkit returns NaN: an instance annotated once,
  or its neighbouring annotations too far apart in time. BaseVersion writes null, and the
  motion metrics leave the box out and count it).
"""

from __future__ import annotations

import json
import logging
import math
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.camera import _homogeneous_image, project_boxes
from tracker.categories import category_index
from tracker.errors import InputError
from tracker.frame import Camera, Frame
from tracker.geometry import corners_3d, wrap_angle
from tracker.io.bounds import BOUND_NOTE, MAX_SPEED_MPS, SPEED_NOTE, beyond_bound
from tracker.io.nuscenes_writer import DEFAULT_META

log = logging.getLogger(__name__)

#: Camera order of the reference's assignment (the first camera that sees the box wins).
NUSCENES_CAMERAS: Final[tuple[str, ...]] = (
    "CAM_FRONT",
    "CAM_FRONT_RIGHT",
    "CAM_FRONT_LEFT",
    "CAM_BACK",
    "CAM_BACK_LEFT",
    "CAM_BACK_RIGHT",
)
LIDAR_CHANNEL: Final = "LIDAR_TOP"
DEFAULT_IMAGE_SIZE: Final = (1600, 900)

#: Tables the devkit loads (``NuScenes.table_names``); every one must exist.
REQUIRED_TABLES: Final[tuple[str, ...]] = (
    "category",
    "attribute",
    "visibility",
    "instance",
    "sensor",
    "calibrated_sensor",
    "ego_pose",
    "log",
    "scene",
    "sample",
    "sample_data",
    "sample_annotation",
    "map",
)

#: The nuScenes tracking classes (devkit ``tracking_nips_2019``); all are in our vocabulary.
TRACKING_NAMES: Final[tuple[str, ...]] = (
    "bicycle",
    "bus",
    "car",
    "motorcycle",
    "pedestrian",
    "trailer",
    "truck",
)

#: The detection classes without a tracking class (devkit ``detection_cvpr_2019``): dropped
#: and counted. Any other name outside TRACKING_NAMES is no nuScenes class (a misspelling,
#: ``Car``, a category ``vehicle.car``): dropped too, but counted apart and warned about.
NON_TRACKING_NAMES: Final[tuple[str, ...]] = ("barrier", "construction_vehicle", "traffic_cone")

#: nuScenes category → tracking class (identical to devkit ``category_to_tracking_name``).
CATEGORY_TO_TRACKING_NAME: Final[dict[str, str]] = {
    "vehicle.bicycle": "bicycle",
    "vehicle.bus.bendy": "bus",
    "vehicle.bus.rigid": "bus",
    "vehicle.car": "car",
    "vehicle.motorcycle": "motorcycle",
    "human.pedestrian.adult": "pedestrian",
    "human.pedestrian.child": "pedestrian",
    "human.pedestrian.construction_worker": "pedestrian",
    "human.pedestrian.police_officer": "pedestrian",
    "vehicle.trailer": "trailer",
    "vehicle.truck": "truck",
}

#: Which table version each predefined split belongs to (the devkit asserts the same).
SPLIT_VERSION_SUFFIX: Final[dict[str, str]] = {
    "train": "trainval",
    "val": "trainval",
    "train_detect": "trainval",
    "train_track": "trainval",
    "mini_train": "mini",
    "mini_val": "mini",
    "test": "test",
}

DEVKIT_INSTALL_HINT: Final = (
    "the nuScenes support needs the official devkit: "
    "pip install -e '.[nuscenes]' && pip install --no-deps nuscenes-devkit==1.2.0 "
    "(docs/nuscenes_waymo.md)"
)

Scenes = dict[str, list[Frame]]


@dataclass
class NuScenesConversion:
    """What :func:`convert_nuscenes` returns."""

    detections: Scenes
    gt: Scenes | None
    meta: dict[str, Any]  # the detection file's "meta" (copied into the tracking submission)
    skipped_detections: Counter[str] = field(default_factory=Counter)  # non-tracking classes
    gt_velocity_unknown: int = 0  # GT boxes whose devkit velocity was NaN (kept NaN)
    velocity_unknown: int = 0  # detections without a velocity (absent, null, NaN: kept NaN)
    unknown_detections: Counter[str] = field(default_factory=Counter)  # no nuScenes class
    below_score_min: int = 0  # detections dropped scoring below score_min


# ---------------------------------------------------------------------------------------------
# devkit access


def require_devkit() -> None:
    """Raise an :class:`InputError` with the install line when the devkit is missing."""
    try:
        import nuscenes  # noqa: F401
    except ImportError:
        raise InputError(DEVKIT_INSTALL_HINT) from None


def check_tables(dataroot: str | Path, version: str) -> Path:
    """The table folder ``DATAROOT/<version>``; every missing table is named in the error."""
    root = Path(dataroot)
    if not root.is_dir():
        raise InputError(f"{root}: nuScenes dataroot not found")
    table_dir = root / version
    if not table_dir.is_dir():
        present = sorted(p.name for p in root.iterdir() if p.is_dir() and p.name.startswith("v"))
        raise InputError(
            f"{table_dir}: no table folder for version {version!r} (found: {present or 'none'})"
        )
    missing = [t for t in REQUIRED_TABLES if not (table_dir / f"{t}.json").is_file()]
    if missing:
        raise InputError(
            f"{table_dir}: missing nuScenes tables: {', '.join(f'{t}.json' for t in missing)}"
        )
    return table_dir


def load_nuscenes(dataroot: str | Path, version: str) -> Any:
    """The devkit's ``NuScenes`` database, with clear errors for missing or broken tables."""
    require_devkit()
    check_tables(dataroot, version)
    from nuscenes import NuScenes

    try:
        return NuScenes(version=version, dataroot=str(dataroot), verbose=False)
    except AssertionError as exc:  # the devkit asserts, e.g. "map mask ... does not exist"
        raise InputError(f"{dataroot}/{version}: nuScenes devkit: {exc}") from None
    except (KeyError, TypeError, AttributeError, IndexError, ValueError) as exc:
        # (JSONDecodeError and UnicodeDecodeError are ValueErrors) the devkit says neither the
        # table nor the record: find them
        problem = table_problem(Path(dataroot) / version)
        raise InputError(
            problem or f"{dataroot}/{version}: malformed nuScenes tables ({exc!r})"
        ) from None


#: The token fields the devkit follows while loading (``NuScenes.__make_reverse_index__``):
#: (table, field, the table it names).
_LOAD_LINKS: Final[tuple[tuple[str, str, str], ...]] = (
    ("sample_annotation", "instance_token", "instance"),
    ("instance", "category_token", "category"),
    ("sample_data", "calibrated_sensor_token", "calibrated_sensor"),
    ("calibrated_sensor", "sensor_token", "sensor"),
    ("sample_data", "sample_token", "sample"),
    ("sample_annotation", "sample_token", "sample"),
)

#: Other fields the devkit reads while loading, and what they must be.
_LOAD_FIELDS: Final[tuple[tuple[str, str, type], ...]] = (
    ("category", "name", str),
    ("sensor", "channel", str),
    ("sensor", "modality", str),
    ("sample_data", "is_key_frame", bool),
    ("map", "filename", str),
    ("map", "log_tokens", list),
)


def table_problem(table_dir: Path) -> str | None:
    """The first problem of the tables that stops the devkit loading them, naming the table
    file (and the record and field): malformed JSON, not a list of records, a token that is
    no string, a field it reads missing or of the wrong type, a token naming no record, a
    map's ``log_tokens`` entry that is no string, a log in no map (with the map's tokens that
    name no log, the likelier typo; alone they are no problem: mini's map names logs it
    lacks). None if none is found. Reads every table again: only after the devkit failed."""
    tables: dict[str, list[dict[str, Any]]] = {}
    for name in REQUIRED_TABLES:
        path = table_dir / f"{name}.json"
        try:
            with open(path, "rb") as fh:
                rows = json.load(fh)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            return f"{path}: malformed JSON ({exc})"
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            return f"{path}: not a nuScenes table (a JSON list of records)"
        for index, record in enumerate(rows):
            if not isinstance(record.get("token"), str):
                return (
                    f"{path}: record {index}: field 'token' must be a string, got "
                    f"{record.get('token')!r}"
                )
        tables[name] = rows

    def at(table: str, record: dict[str, Any]) -> str:
        return f"{table_dir / f'{table}.json'}: {table} {record['token']!r}"

    for table, key, kind in _LOAD_FIELDS:
        for record in tables[table]:
            if not isinstance(record.get(key), kind):
                return (
                    f"{at(table, record)}: field {key!r} must be a {kind.__name__}, got "
                    f"{record.get(key)!r}"
                )
    tokens = {name: {r["token"] for r in rows} for name, rows in tables.items()}
    for table, key, target in _LOAD_LINKS:
        for record in tables[table]:
            value = record.get(key)
            if not isinstance(value, str) or value not in tokens[target]:
                return (
                    f"{at(table, record)}: field {key!r} = {value!r} is not the token of a "
                    f"{target} record"
                )
    if not tables["map"]:
        return f"{table_dir / 'map.json'}: no map record"
    # (the devkit indexes logs by these: an unhashable one fails it; one naming no log does
    # not, and the official v1.0-mini map lists the full dataset's logs)
    for record in tables["map"]:
        for token in record["log_tokens"]:
            if not isinstance(token, str):
                return f"{at('map', record)}: field 'log_tokens' holds {token!r}, not a log token"
    mapped = {t for record in tables["map"] for t in record["log_tokens"]}
    for record in tables["log"]:
        if record["token"] not in mapped:
            said = f"{at('log', record)}: in the field 'log_tokens' of no map record (map.json"
            unknown = sorted(t for t in mapped if t not in tokens["log"])
            if unknown:
                said += f"; it names {len(unknown)} of no log, first {unknown[0]!r}: a typo?"
            return said + ")"
    return None


def split_scene_names(nusc: Any, split: str) -> list[str]:
    """Scene names of an official split (or a custom one from ``splits.json``)."""
    from nuscenes.utils.splits import get_scenes_of_split

    suffix = SPLIT_VERSION_SUFFIX.get(split)
    if suffix is not None and not nusc.version.endswith(suffix):
        raise InputError(
            f"split {split!r} belongs to the v1.0-{suffix} tables, not {nusc.version!r}"
        )
    try:
        return list(get_scenes_of_split(split_name=split, nusc=nusc))
    except (ValueError, AssertionError) as exc:
        raise InputError(f"split {split!r}: {exc}") from None


# ---------------------------------------------------------------------------------------------
# geometry helpers


def quaternion_to_matrix(q_wxyz: Sequence[float]) -> FloatArray:
    """3x3 rotation of a unit quaternion [w, x, y, z] (normalised first)."""
    w, x, y, z = np.asarray(q_wxyz, dtype=np.float64) / np.linalg.norm(q_wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def pose_matrix(translation: Sequence[float], rotation_wxyz: Sequence[float]) -> FloatArray:
    """4x4 ``parent_from_child`` of a nuScenes pose record (ego_pose, calibrated_sensor)."""
    m = np.eye(4)
    m[:3, :3] = quaternion_to_matrix(rotation_wxyz)
    m[:3, 3] = np.asarray(translation, dtype=np.float64)
    return m


def yaw_from_quaternions(q_wxyz: FloatArray) -> FloatArray:
    """(N,) heading about +z of (N, 4) quaternions [w, x, y, z], as the reference converter.

    The formula holds for unit quaternions only (a norm of 2 turns 90° into 127°); others are
    normalised first, as the devkit's evaluation does. Unit ones (to 1e-6: float32 rounding)
    are used as given, so their headings stay bit for bit those of the reference.
    """
    q = np.asarray(q_wxyz, dtype=np.float64).reshape(-1, 4)
    norm = np.linalg.norm(q, axis=1)
    off = np.abs(norm - 1.0) > 1e-6
    if off.any():
        q = q.copy()
        q[off] /= norm[off, None]
    w, x, y, z = q.T
    return wrap_angle(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def assign_cameras(
    xyz: FloatArray, lwh: FloatArray, yaw: FloatArray, cameras: Sequence[Camera]
) -> tuple[IntArray, FloatArray]:
    """The first camera (in ``cameras`` order) that sees part of each box, and the 2D box there.

    Box edges are clipped to the camera's near plane before projection, so a box behind a camera
    is never assigned to it (the reference's sign-flip bug).

    Returns
    -------
    camera : (N,) index into ``cameras``, -1 when no camera sees the box.
    xyxy_image : (N, 4) pixels in that camera, NaN when none.
    """
    n = len(yaw)
    camera = np.full(n, -1, dtype=np.int64)
    xyxy_image = np.full((n, 4), np.nan)
    for index, cam in enumerate(cameras):
        todo = camera < 0
        if not todo.any():
            break
        xyxy, visible = project_boxes((xyz[todo], lwh[todo], yaw[todo]), cam)
        rows = np.flatnonzero(todo)[visible]
        camera[rows] = index
        xyxy_image[rows] = xyxy[visible]
    return camera, xyxy_image


def overflowing_boxes(
    xyz: FloatArray, lwh: FloatArray, yaw: FloatArray, cameras: Sequence[Camera]
) -> IntArray:
    """Rows whose corners, in the world or in any camera's image coordinates, are not finite:
    coordinates so large (1e300) that the transforms overflow. They are named as errors by the
    callers (projecting them gave numpy overflow warnings and boxes no camera could see)."""
    with np.errstate(over="ignore", invalid="ignore"):
        corners = corners_3d(xyz, lwh, yaw)  # (N, 8, 3)
        bad = ~np.isfinite(corners).all(axis=(1, 2))
        # |M[:, :3] @ c + M[:, 3]| <= max|c| * max row-sum |M[:, :3]| + max|M[:, 3]|: below
        # 1e300 for every camera, no product can overflow (and the usual data skips the
        # projections). A NaN or inf corner or matrix entry makes the bound NaN or inf.
        extent = np.abs(corners).max(initial=0.0)
        if all(
            extent * np.abs(m[:, :3]).sum(axis=1).max() + np.abs(m[:, 3]).max() < 1e300
            for m in (cam.image_from_world for cam in cameras)
        ):
            return np.flatnonzero(bad)
        for cam in cameras:
            bad |= ~np.isfinite(_homogeneous_image(corners, cam)).all(axis=(1, 2))
    return np.flatnonzero(bad)


def _check_finite_pose(matrices: Mapping[str, FloatArray], where: str) -> None:
    """The pose products of a sample must be finite (a translation of 1e300 overflows)."""
    for what, m in matrices.items():
        if not np.isfinite(m).all():
            raise InputError(f"{where}: {what} is not finite (a translation too large?)")


# ---------------------------------------------------------------------------------------------
# detections file


def read_detection_results(path: str | Path) -> tuple[dict[str, list[Any]], dict[str, Any]]:
    """``(results, meta)`` of a nuScenes detection (or tracking) results file."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            data = json.load(fh)
    except FileNotFoundError:
        raise InputError(f"{path}: detections file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: malformed JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("results"), dict):
        raise InputError(
            f"{path}: not a nuScenes results file (expected {{'results': {{sample_token: "
            "[box, ...]}, 'meta': {...}}})"
        )
    meta = _read_meta(data, path)
    for token, boxes in data["results"].items():
        if not isinstance(boxes, list):
            raise InputError(f"{path}: results[{token!r}] must be a list of boxes")
    return data["results"], meta


def _read_meta(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """The file's ``meta`` (its modality flags go into the tracking submission). A flag must be
    a JSON boolean: ``"false"`` was written as true. A missing ``meta`` or flag gets the
    LiDAR-only default, said in a log line."""
    if "meta" not in data:
        log.info("%s: no 'meta': the submission gets the defaults %s", path, DEFAULT_META)
        return {}
    meta = data["meta"]
    if not isinstance(meta, dict):
        raise InputError(
            f"{path}: field 'meta' must be an object of flags ({', '.join(DEFAULT_META)}), "
            f"got {type(meta).__name__}"
        )
    for key in DEFAULT_META:
        if key in meta and not isinstance(meta[key], bool):
            raise InputError(f"{path}: field 'meta.{key}' must be true or false, got {meta[key]!r}")
    missing = {k: v for k, v in DEFAULT_META.items() if k not in meta}
    if missing:
        log.info("%s: 'meta' has no %s: the submission gets %s", path, ", ".join(missing), missing)
    return dict(meta)


def _detection_boxes(
    raw: list[Any],
    token: str,
    path: Path,
    score_min: float,
    skipped: Counter[str],
    unknown: Counter[str],
    cameras: Sequence[Camera] = (),
) -> tuple[Boxes, int, int]:
    """Boxes of one sample's detections (tracking classes only; the others counted in
    ``skipped``, names of no nuScenes class in ``unknown``), validated, and how many of
    them have no velocity estimate (absent, null or NaN: kept NaN, so the tracker does not
    measure it and BaseVersion writes null) or were dropped scoring below ``score_min``."""
    keep: list[dict[str, Any]] = []
    rows: list[int] = []
    velocities: list[tuple[float, float]] = []
    scores: list[float] = []
    no_velocity = below = 0
    for i, box in enumerate(raw):
        at = f"{path}: results[{token!r}][{i}]"
        if not isinstance(box, dict):
            raise InputError(f"{at}: a box must be an object")
        for key in ("translation", "size", "rotation", "detection_name", "detection_score"):
            if key not in box:
                raise InputError(f"{at}: missing key '{key}'")
        token_in_box = box.get("sample_token", token)
        if token_in_box != token:
            raise InputError(
                f"{at}: field 'sample_token' = {token_in_box!r} differs from its results key"
            )
        name = box["detection_name"]
        if not isinstance(name, str):
            raise InputError(f"{at}: field 'detection_name' must be a string, got {name!r}")
        if name not in TRACKING_NAMES:
            if name in NON_TRACKING_NAMES:
                skipped[name] += 1
            else:
                unknown[name] += 1
            continue
        score = box["detection_score"]
        if not isinstance(score, int | float) or isinstance(score, bool):  # true is not 1.0
            raise InputError(f"{at}: field 'detection_score' must be a number, got {score!r}")
        score = float(score)
        if not 0.0 <= score <= 1.0:
            raise InputError(f"{at}: field 'detection_score' = {score} is outside [0, 1]")
        if score < score_min:
            below += 1
            continue
        _check_translation(box["translation"], at)
        _check_numbers(box["rotation"], "rotation", 4, at)
        _check_size(box["size"], at)
        velocity, known = _velocity(box.get("velocity"), at)
        no_velocity += not known
        velocities.append(velocity)
        scores.append(score)
        keep.append(box)
        rows.append(i)
    if not keep:
        return Boxes.empty(), 0, below
    size = np.array([b["size"] for b in keep], dtype=np.float64)
    xyz = np.array([b["translation"] for b in keep], dtype=np.float64)
    rotation = np.array([b["rotation"] for b in keep], dtype=np.float64)
    _check_quaternions(rotation, lambda row: f"{path}: results[{token!r}][{rows[row]}]")
    yaw = yaw_from_quaternions(rotation)
    overflow = overflowing_boxes(xyz, size[:, [1, 0, 2]], yaw, cameras)
    if len(overflow):
        i = rows[overflow[0]]
        raise InputError(
            f"{path}: results[{token!r}][{i}]: fields 'translation', 'size' = "
            f"{raw[i]['translation']}, {raw[i]['size']}: not finite in the world or camera "
            "frames (too large)"
        )
    return (
        Boxes.create(
            xyz=xyz,
            lwh=size[:, [1, 0, 2]],
            yaw=yaw,
            velocity=np.array(velocities),
            score=np.array(scores),
            category=[category_index(b["detection_name"]) for b in keep],
        ),
        no_velocity,
        below,
    )


def _check_numbers(value: Any, key: str, size: int, at: str) -> FloatArray:
    """``value`` as an array; InputError (``at``: the file and record) naming field ``key``
    unless it is ``size`` finite numbers."""
    array = np.asarray(value, dtype=np.float64) if _numeric(value) else None
    if array is None or array.shape != (size,) or not np.isfinite(array).all():
        raise InputError(f"{at}: field '{key}' must be {size} finite numbers")
    return array


def _check_quaternions(rotation: FloatArray, at: Callable[[int], str]) -> None:
    """InputError naming the first zero row of (N, 4) quaternions (``at(row)``: its file and
    record); others are normalised by :func:`yaw_from_quaternions`."""
    # the norm, not any(): a tiny quaternion's norm underflows to 0, and it has no heading
    zero = np.flatnonzero(~(np.linalg.norm(rotation, axis=1) > 0))
    if len(zero):
        raise InputError(
            f"{at(int(zero[0]))}: field 'rotation' is the zero quaternion (no heading)"
        )


def _check_size(value: Any, at: str) -> None:
    """InputError (``at``: the file and record) unless ``value`` is a box's ``size`` (w, l, h):
    3 finite numbers, width and length > 0, height >= 0, none beyond the bound of
    :mod:`tracker.io.bounds` (as a BaseVersion box's lwh)."""
    size = _check_numbers(value, "size", 3, at)
    width, length, height = size
    if not (width > 0 and length > 0 and height >= 0):
        raise InputError(f"{at}: field 'size' = {value}: width and length must be > 0, height >= 0")
    _check_bound(size, "size", at)


def _check_translation(value: Any, at: str) -> None:
    """InputError (``at``: the file and record) unless ``value`` is a box's ``translation``: 3
    finite numbers within the bound of :mod:`tracker.io.bounds` (as a BaseVersion box's xyz)."""
    _check_bound(_check_numbers(value, "translation", 3, at), "translation", at)


def _check_bound(values: FloatArray, key: str, at: str) -> None:
    if beyond_bound(values[None])[0]:
        raise InputError(f"{at}: field '{key}' = {values.tolist()}: {BOUND_NOTE}")


def _numeric(value: Any) -> bool:
    return isinstance(value, list | tuple) and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value
    )


def _velocity(value: Any, at: str) -> tuple[tuple[float, float], bool]:
    """``([vx, vy], known)``: absent, null or with a NaN (the devkit's "no estimate", as for
    annotations) → [NaN, NaN], not known (a half-known velocity is no estimate either; not 0,
    which the tracker would measure as "standing still"). The format
    has exactly two values (the devkit asserts it); an infinite one is no estimate of anything:
    an error, as is one beyond the velocity bound of :mod:`tracker.io.bounds`."""
    if value is None:
        return (math.nan, math.nan), False
    if not _numeric(value) or len(value) != 2:
        raise InputError(f"{at}: field 'velocity' must be [vx, vy], got {value!r}")
    vx, vy = float(value[0]), float(value[1])
    if math.isinf(vx) or math.isinf(vy):
        raise InputError(f"{at}: field 'velocity' = {value!r} is infinite")
    if math.isnan(vx) or math.isnan(vy):
        return (math.nan, math.nan), False
    if beyond_bound([[vx, vy]], MAX_SPEED_MPS)[0]:
        raise InputError(f"{at}: field 'velocity' = {value!r}: {SPEED_NOTE}")
    return (vx, vy), True


# ---------------------------------------------------------------------------------------------
# frames


@dataclass(frozen=True, slots=True)
class _SampleGeometry:
    world_from_ego: FloatArray
    cameras: tuple[Camera, ...]
    transform_matrix: dict[str, Any]


def _record_pose(nusc: Any, table: str, record: dict[str, Any]) -> FloatArray:
    """``pose_matrix`` of an ego_pose or calibrated_sensor record, its fields checked: a zero
    or non-finite quaternion has no rotation (it made NaN matrices, found much later), a
    translation beyond the bound of :mod:`tracker.io.bounds` is no place on Earth."""

    def where() -> str:  # built only for an error (this runs for every sample's records)
        return (
            f"{Path(nusc.dataroot) / nusc.version / f'{table}.json'}: {table} {record['token']!r}"
        )

    values = {}
    for key, size in (("translation", 3), ("rotation", 4)):
        value = record.get(key)
        array = np.asarray(value, dtype=np.float64) if _numeric(value) else None
        if array is None or array.shape != (size,) or not np.isfinite(array).all():
            raise InputError(
                f"{where()}: field '{key}' must be {size} finite numbers, got {value!r}"
            )
        values[key] = array
    if not np.linalg.norm(values["rotation"]) > 0:
        raise InputError(f"{where()}: field 'rotation' is the zero quaternion (no rotation)")
    if beyond_bound(values["translation"][None])[0]:  # every box of the sample would be there
        _check_bound(values["translation"], "translation", where())
    return pose_matrix(values["translation"], values["rotation"])


def _table_record(nusc: Any, table: str, record: dict[str, Any]) -> str:
    """``TABLE_FILE: table 'token'``: where a table record's errors point."""
    return f"{Path(nusc.dataroot) / nusc.version / f'{table}.json'}: {table} {record['token']!r}"


def _int_field(nusc: Any, table: str, record: dict[str, Any], key: str) -> int:
    """``record[key]``, an integer (not a bool, not a string of digits) >= 0; InputError naming
    the table file, the record and the field otherwise (it crashed later, as a TypeError)."""
    value = record.get(key)
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        raise InputError(
            f"{_table_record(nusc, table, record)}: field {key!r} must be an integer >= 0, "
            f"got {value!r}"
        )
    return value


def _linked(
    nusc: Any, table: str, record: dict[str, Any], key: str, target: str, *, end: bool = False
) -> dict[str, Any] | None:
    """The ``target`` record named by token field ``key`` of ``record`` (None for the empty
    token when ``end``: the end of a chain); InputError naming the table file, the record and
    the field unless it is the token (a string) of a ``target`` record."""
    value = record.get(key)
    if end and value == "":
        return None
    if not isinstance(value, str) or value not in nusc._token2ind[target]:
        raise InputError(
            f"{_table_record(nusc, table, record)}: field {key!r} = {value!r} is not the token "
            f"of a {target} record"
        )
    return nusc.get(target, value)


def _camera_intrinsic(nusc: Any, cs: dict[str, Any], channel: str) -> FloatArray:
    """The 3x3 intrinsic of a camera's calibrated_sensor record (finite numbers), or InputError
    naming the table file, the record and the field."""
    value = cs.get("camera_intrinsic")
    if isinstance(value, list) and len(value) == 3 and all(_numeric(row) for row in value):
        intrinsic = np.asarray(value, dtype=np.float64)
        if intrinsic.shape == (3, 3) and np.isfinite(intrinsic).all():
            return intrinsic
    raise InputError(
        f"{_table_record(nusc, 'calibrated_sensor', cs)} ({channel}): field 'camera_intrinsic' "
        f"must be 3x3 finite numbers, got {value!r}"
    )


def _image_size(nusc: Any, sd: dict[str, Any], key: str, default: int) -> int:
    """A camera sample_data's ``width`` or ``height``: absent, null or 0 → ``default``."""
    if sd.get(key) is None:
        return default
    return _int_field(nusc, "sample_data", sd, key) or default


def _sample_geometry(nusc: Any, sample: dict[str, Any]) -> _SampleGeometry:
    """Ego pose (LIDAR_TOP keyframe), the six camera models and the official transform object."""
    data = sample["data"]
    if LIDAR_CHANNEL not in data:  # the devkit fills 'data' from sample_data's key frames
        table = Path(nusc.dataroot) / nusc.version / "sample_data.json"
        raise InputError(
            f"{table}: no key-frame {LIDAR_CHANNEL} record of sample {sample['token']!r} "
            "(field 'sample_token', 'is_key_frame')"
        )
    lidar_sd = nusc.get("sample_data", data[LIDAR_CHANNEL])
    ego = _linked(nusc, "sample_data", lidar_sd, "ego_pose_token", "ego_pose")
    lidar_cs = nusc.get("calibrated_sensor", lidar_sd["calibrated_sensor_token"])  # (the devkit's)
    world_from_ego = _record_pose(nusc, "ego_pose", ego)
    ego_from_lidar = _record_pose(nusc, "calibrated_sensor", lidar_cs)
    table_dir = Path(nusc.dataroot) / nusc.version
    with np.errstate(over="ignore", invalid="ignore"):
        world_from_lidar = world_from_ego @ ego_from_lidar
        ego_from_world = np.linalg.inv(world_from_ego)
        lidar_from_ego = np.linalg.inv(ego_from_lidar)
        lidar_from_world = lidar_from_ego @ ego_from_world
    _check_finite_pose(
        {
            "world_from_lidar": world_from_lidar,
            "ego_from_world": ego_from_world,
            "lidar_from_ego": lidar_from_ego,
            "lidar_from_world": lidar_from_world,
        },
        f"{table_dir / 'ego_pose.json'}: ego_pose {ego['token']!r} with "
        f"{table_dir / 'calibrated_sensor.json'}: calibrated_sensor {lidar_cs['token']!r} "
        f"({LIDAR_CHANNEL})",
    )
    cameras: list[Camera] = []
    camera_records: dict[str, Any] = {}
    for name in NUSCENES_CAMERAS:
        if name not in data:
            continue
        sd = nusc.get("sample_data", data[name])
        cs = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
        cam_ego = _linked(nusc, "sample_data", sd, "ego_pose_token", "ego_pose")
        intrinsic = _camera_intrinsic(nusc, cs, name)
        ego_from_camera = _record_pose(nusc, "calibrated_sensor", cs)
        world_from_cam_ego = _record_pose(nusc, "ego_pose", cam_ego)
        with np.errstate(over="ignore", invalid="ignore"):
            world_from_camera = world_from_cam_ego @ ego_from_camera
            camera_from_world = np.linalg.inv(world_from_camera)
            camera_from_lidar = camera_from_world @ world_from_lidar
        _check_finite_pose(
            {
                "world_from_camera": world_from_camera,
                "camera_from_world": camera_from_world,
                "camera_from_lidar": camera_from_lidar,
            },
            f"{table_dir / 'ego_pose.json'}: ego_pose {cam_ego['token']!r} with "
            f"{table_dir / 'calibrated_sensor.json'}: calibrated_sensor {cs['token']!r} ({name})",
        )
        image_from_camera = np.zeros((3, 4))
        image_from_camera[:, :3] = intrinsic
        width = _image_size(nusc, sd, "width", DEFAULT_IMAGE_SIZE[0])
        height = _image_size(nusc, sd, "height", DEFAULT_IMAGE_SIZE[1])
        filename = sd.get("filename")
        if filename is not None and not isinstance(filename, str):
            raise InputError(
                f"{_table_record(nusc, 'sample_data', sd)}: field 'filename' must be a path "
                f"(a string), got {filename!r}"
            )
        cameras.append(Camera(name, image_from_camera, camera_from_world, width, height))
        camera2image = np.eye(4)
        camera2image[:3, :3] = intrinsic
        camera_records[name] = {
            "image_shape": [width, height],
            "ego2camera": np.linalg.inv(ego_from_camera).tolist(),
            "camera2image": camera2image.tolist(),
            "lidar2camera": camera_from_lidar.tolist(),
            "camera_token": sd["token"],
            "camera_path": filename,
        }
    transform = {
        "global2ego": ego_from_world.tolist(),
        "ego2lidar": lidar_from_ego.tolist(),
        "global2lidar": lidar_from_world.tolist(),
        "cameras_transform_matrix": camera_records,
    }
    return _SampleGeometry(world_from_ego, tuple(cameras), transform)


def _scene_samples(nusc: Any, scene: dict[str, Any]) -> list[dict[str, Any]]:
    """The scene's samples, following ``next`` from its first sample. A chain that loops back
    (would never end) or runs into another scene's samples (they would be tracked as this
    scene's) is an error naming the sample and the field that leads there, as is a timestamp
    not after the previous sample's."""
    samples: list[dict[str, Any]] = []
    seen: set[str] = set()
    sample = _linked(nusc, "scene", scene, "first_sample_token", "sample")
    while sample is not None:
        token = sample["token"]
        _int_field(nusc, "sample", sample, "timestamp")
        via = (
            f"field 'next' of sample {samples[-1]['token']!r}"
            if samples
            else f"field 'first_sample_token' of scene {scene['name']!r}"
        )
        where = f"{Path(nusc.dataroot) / nusc.version / 'sample.json'}: sample {token!r}"
        if token in seen:
            raise InputError(f"{where}: reached again through {via} (the samples form a loop)")
        if sample.get("scene_token") != scene["token"]:
            raise InputError(
                f"{where}: of another scene (field 'scene_token'), reached through {via} of "
                f"scene {scene['name']!r}"
            )
        if samples and not sample["timestamp"] > samples[-1]["timestamp"]:
            # the tracker needs time order (a converted file with it would be refused later)
            raise InputError(
                f"{where}: field 'timestamp' = {sample['timestamp']} is not after the previous "
                f"sample's ({samples[-1]['timestamp']}) in scene {scene['name']!r}"
            )
        seen.add(token)
        samples.append(sample)
        sample = _linked(nusc, "sample", sample, "next", "sample", end=True)
    return samples


def _with_cameras(boxes: Boxes, cameras: Sequence[Camera]) -> Boxes:
    if not len(boxes) or not cameras:
        return boxes
    camera, xyxy = assign_cameras(boxes.xyz, boxes.lwh, boxes.yaw, cameras)
    return boxes.replace(camera=camera, xyxy_image=xyxy)


def _check_annotations(nusc: Any, samples: Sequence[dict[str, Any]]) -> None:
    """The box fields of the samples' tracking-class annotations, checked as a detection's: the
    devkit loads them unchecked (a zero size was written, a NaN translation or a zero quaternion
    failed the writing, a short one the velocity). Those without points too: the velocity of
    an annotation reads its neighbours' translations, and the official evaluation loads all."""
    table = Path(nusc.dataroot) / nusc.version / "sample_annotation.json"
    where: list[str] = []
    rotations: list[FloatArray] = []
    for sample in samples:
        for token in sample["anns"]:
            ann = nusc.get("sample_annotation", token)
            if not isinstance(ann["category_name"], str):  # (the devkit's, from category.json)
                category = nusc.get("instance", ann["instance_token"])["category_token"]
                raise InputError(
                    f"{_table_record(nusc, 'category', nusc.get('category', category))}: field "
                    f"'name' must be a string, got {ann['category_name']!r}"
                )
            if ann["category_name"] not in CATEGORY_TO_TRACKING_NAME:
                continue
            at = f"{table}: sample_annotation {token!r} of sample {sample['token']!r}"
            for key in ("num_lidar_pts", "num_radar_pts"):  # (absent: counted as points)
                if key in ann:
                    _int_field(nusc, "sample_annotation", ann, key)
            for key in ("prev", "next"):  # (the devkit's box_velocity follows them)
                _linked(nusc, "sample_annotation", ann, key, "sample_annotation", end=True)
            _check_translation(ann.get("translation"), at)
            rotations.append(_check_numbers(ann.get("rotation"), "rotation", 4, at))
            _check_size(ann.get("size"), at)
            where.append(at)
    if rotations:
        _check_quaternions(np.array(rotations), lambda row: where[row])


def _gt_boxes(nusc: Any, sample: dict[str, Any], keep_empty: bool) -> tuple[Boxes, int]:
    """GT boxes of one sample (its annotations checked by :func:`_check_annotations`) and the
    number whose velocity is unknown (the devkit's NaN, kept: 0 would be a measured standstill
    in the motion metrics)."""
    rows: list[dict[str, Any]] = []
    for ann_token in sample["anns"]:
        ann = nusc.get("sample_annotation", ann_token)
        name = CATEGORY_TO_TRACKING_NAME.get(ann["category_name"])
        if name is None:
            continue
        if not keep_empty and ann.get("num_lidar_pts", 1) + ann.get("num_radar_pts", 0) <= 0:
            continue
        rows.append({**ann, "tracking_name": name})
    if not rows:
        return Boxes.empty(), 0
    velocity = np.array([nusc.box_velocity(a["token"])[:2] for a in rows], dtype=np.float64)
    unknown = ~np.isfinite(velocity).all(axis=1)
    velocity[unknown] = np.nan  # (a half-known velocity is no measurement either)
    far = np.flatnonzero(beyond_bound(velocity, MAX_SPEED_MPS))
    if len(far):  # (its annotations within the box bound, but 1e8 m apart in 0.5 s)
        ann = rows[far[0]]
        table = Path(nusc.dataroot) / nusc.version / "sample_annotation.json"
        raise InputError(
            f"{table}: sample_annotation {ann['token']!r} of sample {sample['token']!r}: its "
            f"velocity (the devkit's box_velocity, from the translations and times of the "
            f"instance's neighbouring annotations) = {velocity[far[0]].tolist()}: {SPEED_NOTE}"
        )
    size = np.array([a["size"] for a in rows], dtype=np.float64)
    boxes = Boxes.create(
        xyz=np.array([a["translation"] for a in rows], dtype=np.float64),
        lwh=size[:, [1, 0, 2]],
        yaw=yaw_from_quaternions(np.array([a["rotation"] for a in rows], dtype=np.float64)),
        velocity=velocity,
        score=np.ones(len(rows)),
        category=[category_index(a["tracking_name"]) for a in rows],
        track_id=[nusc.getind("instance", a["instance_token"]) for a in rows],
    )
    return boxes, int(unknown.sum())


def _frame(
    scene: str, frame_id: int, sample: dict[str, Any], geometry: _SampleGeometry, boxes: Boxes
) -> Frame:
    return Frame(
        scene=scene,
        frame_id=frame_id,
        timestamp_secs=sample["timestamp"] / 1e6,
        boxes=_with_cameras(boxes, geometry.cameras),
        cameras=geometry.cameras,
        world_from_ego=geometry.world_from_ego,
        sample_token=sample["token"],
        transform_matrix=geometry.transform_matrix,
    )


def convert_nuscenes(
    dataroot: str | Path,
    *,
    version: str,
    detections: str | Path,
    split: str,
    with_gt: bool = False,
    score_min: float = 0.0,
    keep_empty_gt: bool = False,
    check_gt: bool = False,
    nusc: Any = None,
) -> NuScenesConversion:
    """Convert a detection results file of one split to frames (and the split's GT).

    Parameters
    ----------
    dataroot : the nuScenes root holding ``<version>/`` (and ``maps/``).
    version : ``v1.0-trainval``, ``v1.0-mini`` or ``v1.0-test``.
    detections : the detection results JSON (nuScenes submission format).
    split : ``val``, ``mini_val``, ``test``, ... or a custom split of ``splits.json``.
    with_gt : also convert the sample annotations (not for ``test``).
    score_min : drop detections scoring below this at conversion, in [0, 1] (keeps files small;
        the tracker's own thresholds still apply); how many is logged.
    keep_empty_gt : keep GT boxes without lidar/radar points (the official eval drops them).
    check_gt : check the split's annotations as ``with_gt`` does, without converting them
        (before the official evaluation, which reads them unchecked).
    nusc : an already loaded devkit ``NuScenes`` (tests, repeated calls).

    Raises
    ------
    InputError naming the missing table, the unknown sample token, or the sample outside the
    split (with its scene), or the bad detection or annotation field.
    """
    if not 0.0 <= score_min <= 1.0:  # (NaN filtered nothing, above 1 everything)
        raise InputError(f"score_min must be in [0, 1], got {score_min}")
    if nusc is None:
        nusc = load_nuscenes(dataroot, version)
    else:
        require_devkit()
    det_path = Path(detections)
    results, meta = read_detection_results(det_path)
    scenes = split_scenes(nusc, split)
    _check_result_tokens(nusc, results, {s["name"] for s in scenes}, split, det_path)
    skipped: Counter[str] = Counter()
    unknown_names: Counter[str] = Counter()
    det_scenes: Scenes = {}
    gt_scenes: Scenes | None = {} if with_gt else None
    unknown_velocity = 0
    velocity_nan = 0
    below_score_min = kept = 0
    missing_samples = 0
    for scene in scenes:
        det_frames: list[Frame] = []
        gt_frames: list[Frame] = []
        samples = _scene_samples(nusc, scene)
        if with_gt or check_gt:
            _check_annotations(nusc, samples)
        for frame_id, sample in enumerate(samples):
            geometry = _sample_geometry(nusc, sample)
            raw = results.get(sample["token"])
            if raw is None:
                missing_samples += 1
                raw = []
            boxes, no_velocity, below = _detection_boxes(
                raw, sample["token"], det_path, score_min, skipped, unknown_names, geometry.cameras
            )
            velocity_nan += no_velocity
            below_score_min += below
            kept += len(boxes)

            det_frames.append(_frame(scene["name"], frame_id, sample, geometry, boxes))
            if gt_scenes is not None:
                gt, unknown = _gt_boxes(nusc, sample, keep_empty_gt)
                unknown_velocity += unknown
                gt_frames.append(_frame(scene["name"], frame_id, sample, geometry, gt))
        det_scenes[scene["name"]] = det_frames
        if gt_scenes is not None:
            gt_scenes[scene["name"]] = gt_frames
    if skipped:
        log.info("skipped detections of non-tracking classes: %s", dict(sorted(skipped.items())))
    if below_score_min:
        log.log(
            logging.INFO if kept else logging.WARNING,
            "%s: %d detections scoring below %g (score_min) dropped, %d kept",
            det_path,
            below_score_min,
            score_min,
            kept,
        )
    if unknown_names:
        log.warning(
            "%s: %d detections with a detection_name that is no nuScenes class dropped: %s "
            "(a misspelt class? the classes are %s)",
            det_path,
            unknown_names.total(),
            dict(unknown_names.most_common()),
            ", ".join(sorted(TRACKING_NAMES + NON_TRACKING_NAMES)),
        )
    if missing_samples:
        log.warning(
            "%s: %d samples of split %s have no entry (converted as empty frames)",
            det_path,
            missing_samples,
            split,
        )
    if unknown_velocity:
        log.info(
            "%d ground-truth boxes have no velocity (the devkit's NaN: an instance annotated "
            "once, or its annotations too far apart): kept unknown (null), left out of the "
            "motion metrics' velocity errors",
            unknown_velocity,
        )
    if velocity_nan:
        log.warning(
            "%s: %d detections without a velocity estimate (absent, null or NaN) are tracked "
            "without a velocity measurement (written as null)",
            det_path,
            velocity_nan,
        )
    return NuScenesConversion(
        det_scenes,
        gt_scenes,
        meta,
        skipped,
        unknown_velocity,
        velocity_nan,
        unknown_names,
        below_score_min,
    )


def split_scenes(nusc: Any, split: str) -> list[dict[str, Any]]:
    """The scene records of a split in table order (as the devkit); scenes of the split absent
    from the tables are skipped (logged), none present is an error."""
    for scene in nusc.scene:
        if not isinstance(scene.get("name"), str):  # (the splits are lists of names)
            raise InputError(
                f"{_table_record(nusc, 'scene', scene)}: field 'name' must be a string, "
                f"got {scene.get('name')!r}"
            )
    names = split_scene_names(nusc, split)
    present = {s["name"] for s in nusc.scene}
    absent = [n for n in names if n not in present]
    if absent and len(absent) == len(names):
        raise InputError(
            f"split {split!r}: none of its {len(names)} scenes is in {nusc.version} at "
            f"{nusc.dataroot} (e.g. {absent[0]!r})"
        )
    if absent:
        log.warning("split %s: %d scenes not in the tables, skipped", split, len(absent))
    wanted = set(names)
    return [s for s in nusc.scene if s["name"] in wanted]


def check_ground_truth(nusc: Any, split: str) -> None:
    """Check a split's tables as :func:`convert_nuscenes` does (``check_gt``) before the official
    evaluation reads them unchecked: each scene's sample chain, its samples' poses and its
    tracking-class annotations' box fields. Raises the same :class:`InputError`, naming the
    table, the record and the field (the devkit ended in a traceback, or scored them)."""
    for scene in split_scenes(nusc, split):
        samples = _scene_samples(nusc, scene)
        _check_annotations(nusc, samples)
        for sample in samples:
            _sample_geometry(nusc, sample)


def _check_result_tokens(
    nusc: Any, results: Mapping[str, Any], wanted: set[str], split: str, path: Path
) -> None:
    """Every results key must be a sample of the tables and of the split (named if not)."""
    sample_index = nusc._token2ind["sample"]
    unknown = [t for t in results if t not in sample_index]
    if unknown:
        raise InputError(
            f"{path}: sample token {unknown[0]!r} is not in the {nusc.version} tables at "
            f"{nusc.dataroot}" + (f" ({len(unknown) - 1} more unknown)" if len(unknown) > 1 else "")
        )
    outside = []
    for token in results:
        scene = nusc.get("scene", nusc.get("sample", token)["scene_token"])
        if scene["name"] not in wanted:
            outside.append((token, scene["name"]))
    if outside:
        token, name = outside[0]
        more = f" ({len(outside) - 1} more outside the split)" if len(outside) > 1 else ""
        raise InputError(
            f"{path}: sample token {token!r} belongs to scene {name!r}, which is not in split "
            f"{split!r}{more}"
        )
