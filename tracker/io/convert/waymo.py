"""Waymo Open Dataset, ImmortalTracker-style files → world-frame Frame sequences.

Inputs (the layout of ImmortalTracker / MCTrack's ``preprocess`` scripts, without pickle)
----------------------------------------------------------------------------------------
Every ``.npz`` is read with ``allow_pickle=False`` and a size cap
(:func:`tracker.io.fileio.load_npz`): plain numeric and fixed-width string arrays only. The
preprocessing scripts of ImmortalTracker and MCTrack write ragged per-frame lists as pickled
object arrays; loading one can run code, so such a file is refused with a one-line error that
names ``bench/waymo_flatten_npz.py``, which turns a user's own (trusted) files into this layout
once.

* ``DATA/ts_info/<segment>.json``: the frame timestamps, a list of integer microseconds.
* ``DATA/ego_info/<segment>.npz``, either
  - ``ego2global`` (F, 4, 4), and for cameras ``cam_extrinsics`` (F, 5, 4, 4, camera→vehicle)
    and ``cam_intrinsics`` (F, 5, 9: f_u, f_v, c_u, c_v, k1, k2, p1, p2, k3) in the camera order
    FRONT, FRONT_LEFT, FRONT_RIGHT, SIDE_LEFT, SIDE_RIGHT, NaN for a camera a frame lacks
    (MCTrack's ``preprocess/ego_info.py`` layout ``ego_infos``, flattened); or
  - ImmortalTracker's layout: one key per frame index (``"0"``, ``"1"``, ...) holding ego2global
    (already plain arrays); there are no cameras then.
* ``DETS/<segment>.npz``: one row per box, all frames: ``bboxes`` (N, 7 or 8) ``[x, y, z,
  heading, l, w, h(, score)]`` in the **vehicle (ego) frame**, ``types`` (N,) Waymo type codes
  (1 vehicle, 2 pedestrian, 3 sign, 4 cyclist) and ``frame_index`` (N,) the frame of each row
  (0-based, into ``ts_info``). Ground truth has the same plus ``ids`` (N,) object ids (fixed-width
  strings ``<U..`` or integers) and optionally ``velos`` (N, 2) vehicle-frame speed_x, speed_y
  (without it the GT velocity is unknown, NaN: the motion metrics then derive it from the GT
  positions, as for KITTI).

Output
------
* One frame per timestamp of ``ts_info`` (frames after the last one with detections are kept,
  empty; ImmortalTracker's detection files stop at the last frame that has a box).
* Boxes in the world frame: ``xyz = ego2global · xyz_ego``; the heading is the world direction of
  the box's x axis (``atan2`` of the rotated heading vector; the reference took it from the
  front-edge midpoint, the same angle). Types 1 → ``car``, 2 → ``pedestrian``, 4 → ``cyclist``
  (the reference said "bicycle"); the untracked types 0 (unknown) and 3 (sign) are counted and
  dropped; a code that is no Waymo type at all is counted apart and dropped with a warning naming
  the file. Velocity 0 (the detector gives none).
* Five cameras named ``CAM_FRONT``, ``CAM_FRONT_LEFT``, ``CAM_FRONT_RIGHT``, ``CAM_SIDE_LEFT``,
  ``CAM_SIDE_RIGHT`` (**fixed**: the reference's names lacked the ``CAM_`` prefix, so its
  image-plane stage never ran). Waymo camera frames are x forward, y left, z up; ours are x right,
  y down, z forward, so ``camera_from_world = OURS_FROM_WAYMO_CAMERA · inv(extrinsic) ·
  inv(ego2global)`` and ``image_from_camera = [K | 0]`` from (f_u, f_v, c_u, c_v). Lens
  distortion and the rolling shutter are ignored (a few pixels). Images: 1920x1280 (front
  three), 1920x886 (sides). Each box gets the first camera in that order that sees part of it
  (edges clipped to the near plane, as for nuScenes).
"""

from __future__ import annotations

import itertools
import json
import logging
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from tracker.boxes import Boxes, FloatArray
from tracker.categories import category_index
from tracker.errors import InputError
from tracker.frame import Camera, Frame
from tracker.io.bounds import (
    ANGLE_NOTE,
    BOUND_NOTE,
    MAX_ANGLE_RAD,
    MAX_SPEED_MPS,
    SPEED_NOTE,
    beyond_bound,
)
from tracker.io.convert.nuscenes import assign_cameras, overflowing_boxes
from tracker.io.fileio import SafeNpz, load_npz, read_text

log = logging.getLogger(__name__)

#: (our name, Waymo name, image width, height), in the reference's assignment order.
WAYMO_CAMERAS: Final[tuple[tuple[str, str, int, int], ...]] = (
    ("CAM_FRONT", "FRONT", 1920, 1280),
    ("CAM_FRONT_LEFT", "FRONT_LEFT", 1920, 1280),
    ("CAM_FRONT_RIGHT", "FRONT_RIGHT", 1920, 1280),
    ("CAM_SIDE_LEFT", "SIDE_LEFT", 1920, 886),
    ("CAM_SIDE_RIGHT", "SIDE_RIGHT", 1920, 886),
)
#: Waymo object type codes → our categories (3 = sign and 0 = unknown are not tracked).
WAYMO_TYPES: Final[dict[int, str]] = {1: "car", 2: "pedestrian", 4: "cyclist"}
#: Every Waymo object type code (``label.proto`` ``Type``); any other code is not a Waymo type.
WAYMO_TYPE_CODES: Final[dict[int, str]] = {
    0: "unknown", 1: "vehicle", 2: "pedestrian", 3: "sign", 4: "cyclist"
}  # fmt: skip

#: Our camera axes (x right, y down, z forward) from Waymo's (x forward, y left, z up).
OURS_FROM_WAYMO_CAMERA: Final[FloatArray] = np.array(
    [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)

Scenes = dict[str, list[Frame]]


@dataclass
class WaymoConversion:
    detections: Scenes
    gt: Scenes | None
    skipped_types: Counter[int] = field(default_factory=Counter)
    #: detections whose type code is no Waymo type (not 0-4): dropped, counted apart, warned
    unknown_types: Counter[int] = field(default_factory=Counter)


@dataclass(frozen=True, slots=True)
class _EgoFrame:
    world_from_ego: FloatArray
    cameras: tuple[Camera, ...]
    transform_matrix: dict[str, Any]


def _load_npz(path: Path, what: str) -> SafeNpz:
    return load_npz(path, what)  # allow_pickle=False and a size cap: input files are untrusted


def read_timestamps(path: Path) -> list[int]:
    """The segment's frame timestamps (µs) from ``ts_info/<segment>.json``."""
    if not path.is_file():
        raise InputError(f"{path}: ts_info file not found")
    try:
        values = json.loads(read_text(path))
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: malformed JSON ({exc})") from None
    if not isinstance(values, list) or not all(
        isinstance(v, int) and not isinstance(v, bool) for v in values
    ):
        raise InputError(f"{path}: expected a list of integer microsecond timestamps")
    if any(b <= a for a, b in itertools.pairwise(values)):
        raise InputError(f"{path}: timestamps are not strictly increasing")
    return values


def camera_model(name: str, extrinsic: Any, intrinsic: Any, world_from_ego: FloatArray) -> Camera:
    """Our :class:`Camera` from Waymo's camera→vehicle extrinsic and intrinsic vector."""
    _, _, width, height = next(c for c in WAYMO_CAMERAS if c[0] == name)
    vehicle_from_camera = np.asarray(extrinsic, dtype=np.float64).reshape(4, 4)
    f_u, f_v, c_u, c_v = np.asarray(intrinsic, dtype=np.float64).reshape(-1)[:4]
    image_from_camera = np.array([[f_u, 0.0, c_u, 0.0], [0.0, f_v, c_v, 0.0], [0.0, 0.0, 1.0, 0.0]])
    camera_from_world = (
        OURS_FROM_WAYMO_CAMERA @ np.linalg.inv(vehicle_from_camera) @ np.linalg.inv(world_from_ego)
    )
    return Camera(name, image_from_camera, camera_from_world, width, height)


def read_ego_info(path: Path, n_frames: int) -> list[_EgoFrame]:
    """Ego poses (and cameras, when the file has them) of every frame of a segment."""
    ego = _load_npz(path, "ego_info")
    out: list[_EgoFrame] = []
    if "ego2global" in ego.files:
        poses = _float_array(ego, "ego2global", path, (None, 4, 4))
        if len(poses) < n_frames:
            raise InputError(f"{path}: {len(poses)} frames of ego2global, ts_info has {n_frames}")
        extrinsics = intrinsics = extrinsic_rigid = None
        if "cam_extrinsics" in ego.files or "cam_intrinsics" in ego.files:
            n_cam = len(WAYMO_CAMERAS)
            extrinsics = _float_array(ego, "cam_extrinsics", path, (len(poses), n_cam, 4, 4))
            intrinsics = _float_array(ego, "cam_intrinsics", path, (len(poses), n_cam, None))
            if intrinsics.shape[2] < 4:
                raise InputError(f"{path}: cam_intrinsics needs f_u, f_v, c_u, c_v per camera")
        # once for all matrices (per matrix it was most of this function's time); the loop
        # still raises for the first bad frame and camera, in the same order as before
        pose_rigid = _rigid_mask(poses[:n_frames])
        extrinsic_rigid = _rigid_mask(extrinsics[:n_frames]) if extrinsics is not None else None
        for i in range(n_frames):
            world_from_ego, ego_from_world = _matrix4(
                poses[i], path, f"ego2global[{i}]", rigid=bool(pose_rigid[i])
            )
            cameras = []
            records: dict[str, Any] = {}
            for k, (name, _waymo, width, height) in enumerate(WAYMO_CAMERAS):
                if extrinsics is None or intrinsics is None or extrinsic_rigid is None:
                    break
                extrinsic, intrinsic = extrinsics[i, k], intrinsics[i, k]
                if not (np.isfinite(extrinsic).all() and np.isfinite(intrinsic[:4]).all()):
                    continue  # NaN: this frame has no such camera
                if not extrinsic_rigid[i, k]:
                    raise _not_rigid(path, f"cam_extrinsics[{i}, {k}] ({name})")
                if beyond_bound(extrinsic[None, :3, 3])[0]:
                    raise InputError(
                        f"{path}: cam_extrinsics[{i}, {k}] ({name}): translation "
                        f"{extrinsic[:3, 3].tolist()}: {BOUND_NOTE}"
                    )
                if not (intrinsic[:2] > 0).all():
                    raise InputError(
                        f"{path}: cam_intrinsics[{i}, {k}] ({name}): focal lengths f_u, f_v "
                        f"must be positive, got {intrinsic[:2].tolist()}"
                    )
                with np.errstate(over="ignore", invalid="ignore"):
                    cam = camera_model(name, extrinsic, intrinsic, world_from_ego)
                if not np.isfinite(cam.camera_from_world).all():  # a translation of 1e300
                    raise InputError(
                        f"{path}: cam_extrinsics[{i}, {k}] ({name}) with ego2global[{i}]: "
                        "camera_from_world is not finite (a translation too large?)"
                    )
                cameras.append(cam)
                camera2image = np.eye(4)
                camera2image[:3, :3] = cam.image_from_camera[:, :3]
                records[name] = {
                    "image_shape": [width, height],
                    # in our camera axes (x right, y down, z forward), unlike the reference
                    "ego2camera": (cam.camera_from_world @ world_from_ego).tolist(),
                    "camera2image": camera2image.tolist(),
                    "intrinsic": [float(v) if np.isfinite(v) else 0.0 for v in intrinsic],
                    "extrinsic": extrinsic.tolist(),
                    "lidar2camera": None,
                }
            out.append(
                _EgoFrame(world_from_ego, tuple(cameras), _transform(ego_from_world, records))
            )
    else:
        for i in range(n_frames):
            if str(i) not in ego.files:
                raise InputError(
                    f"{path}: no ego pose for frame {i} (neither 'ego2global' nor key '{i}')"
                )
            world_from_ego, ego_from_world = _matrix4(ego[str(i)], path, f"frame {i} ego2global")
            out.append(_EgoFrame(world_from_ego, (), _transform(ego_from_world, {})))
    return out


def _float_array(npz: SafeNpz, key: str, path: Path, shape: tuple[int | None, ...]) -> FloatArray:
    """``npz[key]`` as float64, checked against ``shape`` (None: any length)."""
    if key not in npz.files:
        raise InputError(f"{path}: missing array '{key}'")
    arr = npz[key]
    ok = arr.dtype.kind in "fiu" and arr.ndim == len(shape)
    if not ok or any(w is not None and n != w for n, w in zip(arr.shape, shape, strict=True)):
        want_text = ", ".join("N" if n is None else str(n) for n in shape)
        raise InputError(
            f"{path}: '{key}' must be numbers of shape ({want_text}), got {arr.dtype} {arr.shape}"
        )
    return arr.astype(np.float64)


def _transform(ego_from_world: FloatArray, cameras: dict[str, Any]) -> dict[str, Any]:
    return {
        "global2ego": ego_from_world.tolist(),
        "ego2lidar": None,
        "global2lidar": None,
        "cameras_transform_matrix": cameras,
    }


def _matrix4(
    value: Any, path: Path, what: str, *, rigid: bool | None = None
) -> tuple[FloatArray, FloatArray]:
    """The checked 4x4 pose ``value`` and its inverse (computed here to check it is finite,
    and kept: the caller needs it). ``rigid``: :func:`_rigid_mask` of ``value`` when the
    caller computed it for all poses at once."""
    try:
        m = np.asarray(value, dtype=np.float64).reshape(4, 4)
    except (TypeError, ValueError):
        raise InputError(f"{path}: {what} is not a 4x4 matrix") from None
    if not np.isfinite(m).all():
        raise InputError(f"{path}: {what} contains NaN or inf")
    if beyond_bound(m[None, :3, 3])[0]:  # every box of the frame would be there
        raise InputError(f"{path}: {what}: translation {m[:3, 3].tolist()}: {BOUND_NOTE}")
    if not (bool(_rigid_mask(m)) if rigid is None else rigid):
        raise _not_rigid(path, what)
    with np.errstate(over="ignore", invalid="ignore"):
        inverse = np.linalg.inv(m)
    if not np.isfinite(inverse).all():  # a translation of 1e308: its inverse overflows
        raise InputError(f"{path}: {what}: its inverse is not finite (a translation too large?)")
    return m, inverse


def _rigid_mask(m: FloatArray) -> np.ndarray:
    """Which of the (..., 4, 4) matrices ``m`` are rigid: a rotation and a translation, last
    row [0, 0, 0, 1]. A singular matrix cannot be inverted, a scaled or transposed one (a
    row-major / column-major mix-up) would put every box in the wrong place without a word.
    (``isclose(...).all(axis)`` is ``np.allclose`` per matrix; NaN or inf is never rigid.)"""
    rotation = m[..., :3, :3]
    with np.errstate(all="ignore"):  # non-finite matrices: the caller skips or names them
        return (
            np.isclose(m[..., 3, :], [0.0, 0.0, 0.0, 1.0], atol=1e-6).all(axis=-1)
            & np.isclose(np.swapaxes(rotation, -1, -2) @ rotation, np.eye(3), atol=1e-3).all(
                axis=(-2, -1)
            )
            & (np.linalg.det(rotation) > 0)
        )


def _not_rigid(path: Path, what: str) -> InputError:
    return InputError(
        f"{path}: {what} is not a rigid transform (a rotation and a translation, last row "
        "[0, 0, 0, 1])"
    )


def boxes_ego_to_world(
    boxes_ego: FloatArray, world_from_ego: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """World centres (N, 3) and headings (N,) of ego-frame ``[x, y, z, heading, ...]`` rows."""
    xyz = boxes_ego[:, :3] @ world_from_ego[:3, :3].T + world_from_ego[:3, 3]
    heading = boxes_ego[:, 3]
    direction = np.stack([np.cos(heading), np.sin(heading), np.zeros_like(heading)], axis=1)
    world_dir = direction @ world_from_ego[:3, :3].T
    return xyz, np.arctan2(world_dir[:, 1], world_dir[:, 0])


@dataclass(frozen=True, slots=True)
class _BoxTable:
    """The rows of a detection (or ground-truth) file, ordered by frame: frame ``i`` is rows
    ``bounds[i]:bounds[i + 1]`` (in file order within the frame)."""

    bboxes: FloatArray  # (N, 7 or 8), vehicle frame
    types: np.ndarray  # (N,) Waymo type codes
    bounds: np.ndarray  # (F + 1,)
    rows: np.ndarray  # (N,) each row's index in the file (for errors)
    ids: np.ndarray | None = None  # (N,) object ids as str (ground truth)
    velos: FloatArray | None = None  # (N, 2) vehicle-frame velocity (ground truth, optional)


def read_box_table(npz: SafeNpz, path: Path, n_frames: int, *, gt: bool) -> _BoxTable:
    """Check a detection / GT file's arrays (see the module docstring) and group them by frame."""
    for key in ("bboxes", "types", "frame_index", *(("ids",) if gt else ())):
        if key not in npz.files:
            if key == "frame_index" and npz["bboxes"].ndim != 2:
                raise InputError(
                    f"{path}: per-frame arrays (the pickled ImmortalTracker/MCTrack layout); "
                    "flatten them with: python bench/waymo_flatten_npz.py IN_FOLDER OUT_FOLDER"
                )
            raise InputError(f"{path}: missing array '{key}'")
    bboxes = npz["bboxes"]
    if bboxes.dtype.kind not in "fiu" or bboxes.ndim != 2 or bboxes.shape[1] not in (7, 8):
        raise InputError(
            f"{path}: 'bboxes' must be numbers of shape (N, 7 or 8), got {bboxes.dtype} "
            f"{bboxes.shape}"
        )
    n = len(bboxes)
    bboxes = bboxes.astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(bboxes).all(axis=1))
    if len(bad):
        raise InputError(f"{path}: bboxes row {bad[0]}: must be finite [x,y,z,o,l,w,h(,score)]")
    # as a BaseVersion box's lwh (a flat box has a height of 0, never a length or width of 0)
    bad = np.flatnonzero((bboxes[:, 4:6] <= 0).any(axis=1) | (bboxes[:, 6] < 0))
    if len(bad):
        k = bad[0]
        raise InputError(
            f"{path}: bboxes row {k}: l, w, h = {bboxes[k, 4:7].tolist()}: length and width "
            "must be > 0, height >= 0"
        )

    def column(key: str, kinds: str) -> np.ndarray:
        arr = npz[key]
        if arr.dtype.kind not in kinds or arr.shape != (n,):
            raise InputError(
                f"{path}: '{key}' must be one value per box ({n},) of kind {kinds!r}, got "
                f"{arr.dtype} {arr.shape}"
            )
        return arr

    types = column("types", "iu").astype(np.int64)
    frame_index = column("frame_index", "iu").astype(np.int64)
    outside = np.flatnonzero((frame_index < 0) | (frame_index >= n_frames))
    if len(outside):
        k = outside[0]
        raise InputError(
            f"{path}: frame_index row {k}: frame {frame_index[k]}, but ts_info has {n_frames}"
        )
    for columns, names in ((slice(0, 3), "x, y, z"), (slice(4, 7), "l, w, h")):
        far = np.flatnonzero(beyond_bound(bboxes[:, columns]))
        if len(far):
            k = far[0]
            raise InputError(
                f"{path}: bboxes row {k} (frame {frame_index[k]}): {names} = "
                f"{bboxes[k, columns].tolist()}: {BOUND_NOTE}"
            )
    # (beyond the heading bound a float's spacing nears a turn: the heading would be arbitrary)
    far = np.flatnonzero(beyond_bound(bboxes[:, 3], MAX_ANGLE_RAD))
    if len(far):
        k = far[0]
        raise InputError(
            f"{path}: bboxes row {k} (frame {frame_index[k]}): heading = {bboxes[k, 3]:g}: "
            f"{ANGLE_NOTE}"
        )
    order = np.argsort(frame_index, kind="stable")
    bounds = np.searchsorted(frame_index[order], np.arange(n_frames + 1))
    ids = velos = None
    if gt:
        ids = column("ids", "iuU").astype(str)
        first_row: dict[tuple[int, str], int] = {}
        for k, key in enumerate(zip(frame_index.tolist(), ids.tolist(), strict=True)):
            if first_row.setdefault(key, k) != k:  # one object, two boxes: no single truth
                raise InputError(
                    f"{path}: ids row {k}: object {key[1]!r} is in frame {key[0]} twice "
                    f"(rows {first_row[key]} and {k})"
                )
        ids = ids[order]
        if "velos" in npz.files:
            velos = npz["velos"]
            if velos.dtype.kind not in "fiu" or velos.shape != (n, 2):
                raise InputError(f"{path}: 'velos' must be numbers of shape ({n}, 2)")
            velos = velos.astype(np.float64)
            bad = np.flatnonzero(~np.isfinite(velos).all(axis=1))
            if len(bad):
                raise InputError(f"{path}: velos row {bad[0]}: must be finite [vx, vy]")
            far = np.flatnonzero(beyond_bound(velos, MAX_SPEED_MPS))
            if len(far):
                k = far[0]
                raise InputError(
                    f"{path}: velos row {k} (frame {frame_index[k]}): vx, vy = "
                    f"{velos[k].tolist()}: {SPEED_NOTE}"
                )
            velos = velos[order]
    return _BoxTable(bboxes[order], types[order], bounds, order, ids, velos)


def _segment_boxes(
    table: _BoxTable,
    i: int,
    path: Path,
    world_from_ego: FloatArray,
    cameras: Sequence[Camera],
    skipped: Counter[int],
    ids: dict[str, int] | None,
) -> Boxes:
    """Frame ``i`` of a detection (or, with ``ids``, ground-truth) file as world Boxes."""
    a, b = int(table.bounds[i]), int(table.bounds[i + 1])
    if a == b:
        return Boxes.empty()
    arr = table.bboxes[a:b]
    codes = table.types[a:b]
    names = [WAYMO_TYPES.get(int(c)) for c in codes]
    for c, n in zip(codes, names, strict=True):
        if n is None:
            skipped[int(c)] += 1  # (the caller tells the untracked types from invalid codes)
    keep = np.array([n is not None for n in names], dtype=bool)
    arr = arr[keep]
    with np.errstate(over="ignore", invalid="ignore"):
        xyz, yaw = boxes_ego_to_world(arr, world_from_ego)
    overflow = overflowing_boxes(xyz, arr[:, 4:7], yaw, cameras)
    if len(overflow):
        k = np.arange(a, b)[keep][overflow[0]]
        row = int(table.rows[k])
        raise InputError(
            f"{path}: bboxes row {row}: {table.bboxes[k, :7].tolist()} with ego2global[{i}] "
            "is not finite in the world or camera frames (too large)"
        )
    far = np.flatnonzero(beyond_bound(xyz))  # (the row and the pose within it, not their sum)
    if len(far):
        k = np.arange(a, b)[keep][far[0]]
        raise InputError(
            f"{path}: bboxes row {int(table.rows[k])} (frame {i}) with ego2global[{i}]: x, y, z "
            f"= {xyz[far[0]].tolist()} in the world frame: {BOUND_NOTE}"
        )
    velocity = None
    track_id = None
    if ids is not None and table.ids is not None:
        track_id = [ids.setdefault(str(v), len(ids)) for v in table.ids[a:b][keep]]
        if table.velos is not None:
            velocity = table.velos[a:b][keep] @ world_from_ego[:2, :2].T  # vehicle → world axes
        else:  # unknown, not 0: the motion metrics would score a measured standstill
            velocity = np.full((int(keep.sum()), 2), np.nan)
    score = arr[:, 7] if arr.shape[1] == 8 and ids is None else np.ones(len(arr))
    outside = np.flatnonzero((score < 0) | (score > 1))
    if len(outside):
        k = np.arange(a, b)[keep][outside[0]]
        raise InputError(
            f"{path}: bboxes row {int(table.rows[k])} (frame {i}): score "
            f"{float(score[outside[0]])!r} must be in [0, 1]"
        )
    boxes = Boxes.create(
        xyz=xyz,
        lwh=arr[:, 4:7],
        yaw=yaw,
        velocity=velocity,
        score=score,
        category=[category_index(n) for n in names if n is not None],
        track_id=track_id,
    )
    if cameras and len(boxes):
        camera, xyxy = assign_cameras(boxes.xyz, boxes.lwh, boxes.yaw, cameras)
        boxes = boxes.replace(camera=camera, xyxy_image=xyxy)
    return boxes


def _frame(scene: str, frame_id: int, t_micros: int, ego: _EgoFrame, boxes: Boxes) -> Frame:
    return Frame(
        scene=scene,
        frame_id=frame_id,
        timestamp_secs=t_micros / 1e6,
        boxes=boxes,
        cameras=ego.cameras,
        world_from_ego=ego.world_from_ego,
        transform_matrix=ego.transform_matrix,
    )


def segment_names(
    data_root: str | Path, detections: str | Path, segments: Sequence[str] | None = None
) -> list[str]:
    """The segments to convert: ``segments``, or every ``<segment>.npz`` detection file.

    Raises
    ------
    InputError for a missing folder, no detection files, or a name that is not a plain file
    name (it must not lead outside the folders).
    """
    data_root, det_dir = Path(data_root), Path(detections)
    if not det_dir.is_dir():
        raise InputError(f"{det_dir}: detections folder not found")
    for sub in ("ts_info", "ego_info"):
        if not (data_root / sub).is_dir():
            raise InputError(f"{data_root / sub}: folder not found (expected {sub}/<segment>)")
    names = list(segments) if segments else sorted(p.stem for p in det_dir.glob("*.npz"))
    if not names:
        raise InputError(f"{det_dir}: no <segment>.npz detection files")
    bad = [n for n in names if Path(n).name != n or n in ("", ".", "..")]
    if bad:
        raise InputError(f"segments: not segment names: {bad}")
    return names


def convert_waymo(
    data_root: str | Path,
    detections: str | Path,
    *,
    gt: str | Path | None = None,
    segments: Sequence[str] | None = None,
) -> WaymoConversion:
    """Convert ImmortalTracker-style Waymo files (see the module docstring).

    Parameters
    ----------
    data_root : folder with ``ts_info/`` and ``ego_info/``.
    detections : folder of ``<segment>.npz`` detection files.
    gt : optional folder of ``<segment>.npz`` ground-truth files (with ``ids``).
    segments : segment names (file stems); default: every detection file.

    Raises
    ------
    InputError naming the missing or malformed file and frame.
    """
    data_root, det_dir = Path(data_root), Path(detections)
    names = segment_names(data_root, det_dir, segments)
    skipped: Counter[int] = Counter()
    unknown: Counter[int] = Counter()
    det_scenes: Scenes = {}
    gt_scenes: Scenes | None = {} if gt is not None else None
    for name in names:
        timestamps = read_timestamps(data_root / "ts_info" / f"{name}.json")
        ego = read_ego_info(data_root / "ego_info" / f"{name}.npz", len(timestamps))
        det_path = det_dir / f"{name}.npz"
        dets = read_box_table(
            _load_npz(det_path, "detections"), det_path, len(timestamps), gt=False
        )
        gt_path = Path(gt) / f"{name}.npz" if gt is not None else None
        gt_table = (
            read_box_table(_load_npz(gt_path, "ground-truth"), gt_path, len(timestamps), gt=True)
            if gt_path is not None
            else None
        )
        ids: dict[str, int] = {}
        det_frames, gt_frames = [], []
        det_skipped: Counter[int] = Counter()
        gt_skipped: Counter[int] = Counter()
        for i, (t_micros, e) in enumerate(zip(timestamps, ego, strict=True)):
            boxes = _segment_boxes(
                dets, i, det_path, e.world_from_ego, e.cameras, det_skipped, None
            )
            det_frames.append(_frame(name, i, t_micros, e, boxes))
            if gt_table is not None and gt_path is not None:
                boxes = _segment_boxes(
                    gt_table, i, gt_path, e.world_from_ego, e.cameras, gt_skipped, ids
                )
                gt_frames.append(_frame(name, i, t_micros, e, boxes))
        unknown.update(_invalid_type_codes(det_skipped, det_path))
        _invalid_type_codes(gt_skipped, gt_path)  # (the GT's untracked types are not counted)
        skipped.update(det_skipped)
        det_scenes[name] = det_frames
        if gt_scenes is not None:
            gt_scenes[name] = gt_frames
    if skipped:
        log.info("skipped detections of untracked Waymo types: %s", dict(sorted(skipped.items())))
    return WaymoConversion(det_scenes, gt_scenes, skipped, unknown)


def _invalid_type_codes(skipped: Counter[int], path: Path | None) -> Counter[int]:
    """Move the codes of ``skipped`` that are no Waymo type (not 0-4) out of it, warning with
    the file's name: a corrupt or foreign file, not an untracked type like a sign."""
    invalid = Counter({c: n for c, n in skipped.items() if c not in WAYMO_TYPE_CODES})
    for code in invalid:
        del skipped[code]
    if invalid:
        log.warning(
            "%s: dropped boxes whose type code is no Waymo type (0-4: %s): %s",
            path,
            ", ".join(WAYMO_TYPE_CODES.values()),
            dict(sorted(invalid.items())),
        )
    return invalid


def flatten_per_frame(arrays: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """The pickle-free layout of one preprocessing file whose arrays are already in memory.

    ``arrays``: the members of an ImmortalTracker / MCTrack file as loaded by their owner
    (``bench/waymo_flatten_npz.py`` loads the user's own trusted files): ``ego_infos`` (per frame
    ``[[ego2global, 5 extrinsics, 5 intrinsics, 5 lidar extrinsics]]``) becomes ``ego2global``,
    ``cam_extrinsics`` and ``cam_intrinsics`` (NaN for a missing camera); per-frame lists
    ``bboxes``, ``types`` (and ``ids``, ``velos``) become one row per box with ``frame_index``.
    Other members (e.g. ImmortalTracker's per-frame ego keys) are kept as plain arrays.
    """
    out: dict[str, np.ndarray] = {}
    rest = dict(arrays)
    if "ego_infos" in rest:
        infos = rest.pop("ego_infos")
        n, n_cam = len(infos), len(WAYMO_CAMERAS)
        out["ego2global"] = np.stack(
            [np.asarray(infos[i][0][0], dtype=np.float64).reshape(4, 4) for i in range(n)]
        ).reshape(n, 4, 4)
        extrinsics = np.full((n, n_cam, 4, 4), np.nan)
        intrinsics = np.full((n, n_cam, 9), np.nan)
        for i in range(n):
            row = infos[i][0]
            for k in range(n_cam):
                if row[1 + k] is not None and row[6 + k] is not None:
                    extrinsics[i, k] = np.asarray(row[1 + k], dtype=np.float64).reshape(4, 4)
                    values = np.asarray(row[6 + k], dtype=np.float64).reshape(-1)[:9]
                    intrinsics[i, k, : len(values)] = values
        out["cam_extrinsics"], out["cam_intrinsics"] = extrinsics, intrinsics
    if "bboxes" in rest:
        per_frame = {k: rest.pop(k) for k in ("bboxes", "types", "ids", "velos") if k in rest}
        frames = range(len(per_frame["bboxes"]))
        rows = [
            np.asarray([] if per_frame["bboxes"][i] is None else per_frame["bboxes"][i])
            for i in frames
        ]
        counts = [len(r) for r in rows]
        width = max((r.shape[1] for r in rows if r.ndim == 2 and len(r)), default=8)
        out["bboxes"] = np.concatenate(
            [np.asarray(r, dtype=np.float64).reshape(-1, width) for r in rows]
            or [np.zeros((0, width))]
        )
        out["frame_index"] = np.repeat(np.arange(len(rows), dtype=np.int64), counts)
        for key, dtype in (("types", np.int64), ("ids", str), ("velos", np.float64)):
            if key not in per_frame:
                continue
            parts = [np.asarray([] if v is None else list(v)).astype(dtype) for v in per_frame[key]]
            flat = np.concatenate(parts) if parts else np.zeros(0, dtype)
            out[key] = flat.reshape(-1, 2) if key == "velos" else flat
    for key, value in rest.items():
        out[key] = np.asarray(value)
    return out
