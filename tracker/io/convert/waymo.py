"""Waymo Open Dataset, ImmortalTracker-style files → world-frame Frame sequences.

Inputs (the layout of ImmortalTracker / MCTrack's ``preprocess`` scripts, one file per segment)
----------------------------------------------------------------------------------------------
* ``DATA/ts_info/<segment>.json``: the frame timestamps, a list of integer microseconds.
* ``DATA/ego_info/<segment>.npz``, either
  - MCTrack's layout (``preprocess/ego_info.py``): ``ego_infos`` with, per frame, ``[[ego2global
    (4x4), 5 camera extrinsics (camera→vehicle, 4x4), 5 intrinsics (f_u, f_v, c_u, c_v, k1, k2,
    p1, p2, k3), 5 lidar extrinsics]]`` in the camera order FRONT, FRONT_LEFT, FRONT_RIGHT,
    SIDE_LEFT, SIDE_RIGHT; or
  - ImmortalTracker's layout: one key per frame index (``"0"``, ``"1"``, ...) holding ego2global;
    there are no cameras then.
* ``DETS/<segment>.npz``: ``bboxes`` (per frame, a list of ``[x, y, z, heading, l, w, h, score]``
  in the **vehicle (ego) frame**) and ``types`` (per frame, Waymo type codes: 1 vehicle,
  2 pedestrian, 3 sign, 4 cyclist). Ground truth has the same layout plus ``ids`` (per frame,
  the object id strings) and optionally ``velos`` (vehicle-frame speed_x, speed_y).
  These files are pickled object arrays (ragged lists): only read files you trust.

Output
------
* One frame per timestamp of ``ts_info`` (frames after the last one with detections are kept,
  empty; ImmortalTracker's detection files stop at the last frame that has a box).
* Boxes in the world frame: ``xyz = ego2global · xyz_ego``; the heading is the world direction of
  the box's x axis (``atan2`` of the rotated heading vector; the reference took it from the
  front-edge midpoint, the same angle). Types 1 → ``car``, 2 → ``pedestrian``, 4 → ``cyclist``
  (the reference said "bicycle"); other types are counted and dropped. Velocity 0 (the detector
  gives none).
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
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from tracker.boxes import Boxes, FloatArray
from tracker.categories import category_index
from tracker.errors import InputError
from tracker.frame import Camera, Frame
from tracker.io.convert.nuscenes import assign_cameras
from tracker.io.fileio import SafeNpz, load_npz

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


@dataclass(frozen=True, slots=True)
class _EgoFrame:
    world_from_ego: FloatArray
    cameras: tuple[Camera, ...]
    transform_matrix: dict[str, Any]


def _load_npz(path: Path, what: str) -> SafeNpz:
    return load_npz(path, what)  # no unrestricted pickle: input files are untrusted


def read_timestamps(path: Path) -> list[int]:
    """The segment's frame timestamps (µs) from ``ts_info/<segment>.json``."""
    if not path.is_file():
        raise InputError(f"{path}: ts_info file not found")
    try:
        values = json.loads(path.read_text())
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
    """Ego poses (and cameras, for MCTrack's layout) of every frame of a segment."""
    ego = _load_npz(path, "ego_info")
    out: list[_EgoFrame] = []
    if "ego_infos" in ego.files:
        infos = ego["ego_infos"]
        if len(infos) < n_frames:
            raise InputError(f"{path}: {len(infos)} frames of ego_infos, ts_info has {n_frames}")
        for i in range(n_frames):
            row = infos[i][0]
            world_from_ego = _matrix4(row[0], path, f"ego_infos[{i}] ego2global")
            cameras = []
            records: dict[str, Any] = {}
            for k, (name, _waymo, width, height) in enumerate(WAYMO_CAMERAS):
                extrinsic, intrinsic = row[1 + k], row[6 + k]
                if extrinsic is None or intrinsic is None:
                    continue
                cam = camera_model(name, extrinsic, intrinsic, world_from_ego)
                cameras.append(cam)
                camera2image = np.eye(4)
                camera2image[:3, :3] = cam.image_from_camera[:, :3]
                records[name] = {
                    "image_shape": [width, height],
                    # in our camera axes (x right, y down, z forward), unlike the reference
                    "ego2camera": (cam.camera_from_world @ world_from_ego).tolist(),
                    "camera2image": camera2image.tolist(),
                    "intrinsic": np.asarray(intrinsic, dtype=np.float64).tolist(),
                    "extrinsic": np.asarray(extrinsic, dtype=np.float64).reshape(4, 4).tolist(),
                    "lidar2camera": None,
                }
            out.append(
                _EgoFrame(world_from_ego, tuple(cameras), _transform(world_from_ego, records))
            )
    else:
        for i in range(n_frames):
            if str(i) not in ego.files:
                raise InputError(
                    f"{path}: no ego pose for frame {i} (neither 'ego_infos' nor key '{i}')"
                )
            world_from_ego = _matrix4(ego[str(i)], path, f"frame {i} ego2global")
            out.append(_EgoFrame(world_from_ego, (), _transform(world_from_ego, {})))
    return out


def _transform(world_from_ego: FloatArray, cameras: dict[str, Any]) -> dict[str, Any]:
    return {
        "global2ego": np.linalg.inv(world_from_ego).tolist(),
        "ego2lidar": None,
        "global2lidar": None,
        "cameras_transform_matrix": cameras,
    }


def _matrix4(value: Any, path: Path, what: str) -> FloatArray:
    try:
        m = np.asarray(value, dtype=np.float64).reshape(4, 4)
    except (TypeError, ValueError):
        raise InputError(f"{path}: {what} is not a 4x4 matrix") from None
    if not np.isfinite(m).all():
        raise InputError(f"{path}: {what} contains NaN or inf")
    return m


def boxes_ego_to_world(
    boxes_ego: FloatArray, world_from_ego: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """World centres (N, 3) and headings (N,) of ego-frame ``[x, y, z, heading, ...]`` rows."""
    xyz = boxes_ego[:, :3] @ world_from_ego[:3, :3].T + world_from_ego[:3, 3]
    heading = boxes_ego[:, 3]
    direction = np.stack([np.cos(heading), np.sin(heading), np.zeros_like(heading)], axis=1)
    world_dir = direction @ world_from_ego[:3, :3].T
    return xyz, np.arctan2(world_dir[:, 1], world_dir[:, 0])


def _frame_rows(npz: Any, key: str, i: int) -> list[Any]:
    values = npz[key]
    if i >= len(values):
        return []
    row = values[i]
    return [] if row is None else list(row)


def _segment_boxes(
    npz: Any,
    i: int,
    path: Path,
    world_from_ego: FloatArray,
    cameras: Sequence[Camera],
    skipped: Counter[int],
    ids: dict[str, int] | None,
) -> Boxes:
    """Frame ``i`` of a detection (or, with ``ids``, ground-truth) file as world Boxes."""
    rows = _frame_rows(npz, "bboxes", i)
    types = _frame_rows(npz, "types", i)
    if len(rows) != len(types):
        raise InputError(f"{path}: frame {i}: {len(rows)} bboxes but {len(types)} types")
    if not rows:
        return Boxes.empty()
    try:
        arr = np.asarray(rows, dtype=np.float64).reshape(len(rows), -1)
    except ValueError:
        raise InputError(f"{path}: frame {i}: bboxes must be rows of 7 or 8 numbers") from None
    if arr.shape[1] not in (7, 8) or not np.isfinite(arr).all():
        raise InputError(f"{path}: frame {i}: bboxes must be finite [x,y,z,o,l,w,h(,score)]")
    codes = np.asarray(types).astype(np.int64).reshape(-1)
    names = [WAYMO_TYPES.get(int(c)) for c in codes]
    for c, n in zip(codes, names, strict=True):
        if n is None:
            skipped[int(c)] += 1
    keep = np.array([n is not None for n in names], dtype=bool)
    arr = arr[keep]
    xyz, yaw = boxes_ego_to_world(arr, world_from_ego)
    velocity = None
    track_id = None
    if ids is not None:
        raw_ids = [str(v) for v, k in zip(_frame_rows(npz, "ids", i), keep, strict=True) if k]
        track_id = [ids.setdefault(v, len(ids)) for v in raw_ids]
        if "velos" in npz.files:
            velos = np.asarray(_frame_rows(npz, "velos", i), dtype=np.float64).reshape(-1, 2)
            velocity = velos[keep] @ world_from_ego[:2, :2].T  # vehicle → world axes
    score = arr[:, 7] if arr.shape[1] == 8 and ids is None else np.ones(len(arr))
    if ((score < 0) | (score > 1)).any():
        raise InputError(f"{path}: frame {i}: scores must be in [0, 1]")
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
    det_scenes: Scenes = {}
    gt_scenes: Scenes | None = {} if gt is not None else None
    for name in names:
        timestamps = read_timestamps(data_root / "ts_info" / f"{name}.json")
        ego = read_ego_info(data_root / "ego_info" / f"{name}.npz", len(timestamps))
        det_path = det_dir / f"{name}.npz"
        dets = _load_npz(det_path, "detections")
        gt_path = Path(gt) / f"{name}.npz" if gt is not None else None
        gt_npz = _load_npz(gt_path, "ground-truth") if gt_path is not None else None
        for npz, path in ((dets, det_path), (gt_npz, gt_path)):
            if npz is None or path is None:
                continue
            for key in ("bboxes", "types"):
                if key not in npz.files:
                    raise InputError(f"{path}: missing array '{key}'")
            if len(npz["bboxes"]) > len(timestamps):
                raise InputError(
                    f"{path}: {len(npz['bboxes'])} frames, but ts_info has {len(timestamps)}"
                )
        if gt_npz is not None and "ids" not in gt_npz.files:
            raise InputError(f"{gt_path}: ground truth needs the 'ids' array")
        ids: dict[str, int] = {}
        det_frames, gt_frames = [], []
        for i, (t_micros, e) in enumerate(zip(timestamps, ego, strict=True)):
            boxes = _segment_boxes(dets, i, det_path, e.world_from_ego, e.cameras, skipped, None)
            det_frames.append(_frame(name, i, t_micros, e, boxes))
            if gt_npz is not None and gt_path is not None:
                boxes = _segment_boxes(
                    gt_npz, i, gt_path, e.world_from_ego, e.cameras, Counter(), ids
                )
                gt_frames.append(_frame(name, i, t_micros, e, boxes))
        det_scenes[name] = det_frames
        if gt_scenes is not None:
            gt_scenes[name] = gt_frames
    if skipped:
        log.info("skipped detections of untracked Waymo types: %s", dict(sorted(skipped.items())))
    return WaymoConversion(det_scenes, gt_scenes, skipped)
