"""KITTI tracking → :class:`~tracker.frame.Frame` sequences in a z-up world frame.

Frames
------
KITTI 3D boxes (labels and detections) live in the *rectified reference camera* frame ("rect":
x right, y down, z forward; the frame ``R0_rect`` maps camera 0 into). ``P2`` projects rect
coordinates into image 2 (it contains camera 2's 6 cm baseline), so every
:class:`~tracker.frame.Camera` we build has ``image_from_camera = P2`` unchanged and
``camera_from_world = inv(world_from_rect)``: the Camera's "camera" frame is rect.

The world frame is z up, built per sequence from one of three pose sources:

* ``pose_format="camera"`` (the kit's ORB-SLAM3 poses, ``training/pose_orbslam3``): line *i* is
  the pose of the left colour camera (camera 2) at frame *i* relative to frame 0,
  ``x_cam2_0 = R x_cam2_i + t``. Then ``world_from_rect_i = W @ inv(C) @ pose_i @ C`` where
  ``C = cam2_from_rect`` is the baseline translation recovered from ``P2`` and ``W`` turns camera
  axes into x forward / y left / z up (``x_w = z_c, y_w = -x_c, z_w = -y_c``). The world origin
  is the rect camera at frame 0, x along its optical axis.
* ``pose_format="lidar"`` (the CasTrack/MCTrack ``pose/<seq>.txt`` convention, oxts-derived):
  line *i* maps velodyne → world, so ``world_from_rect_i = pose_i @ inv(R0_rect @ Tr_velo_to_cam)``.
* no poses: ``world_from_rect_i = W`` for every frame, i.e. the world is the *current* camera frame
  turned z up. Positions and velocities are then relative to the moving ego vehicle, and parked
  cars appear to move.

``Frame.world_from_ego = world_from_rect_i``: the ego is the rectified camera (camera axes,
x right / y down / z forward), not a z-up vehicle frame.

Time
----
KITTI tracking has no timestamps in the kit; it is recorded at 10 Hz, so
``timestamp_secs = frame_id * 0.1``. Every frame ``0 .. n-1`` is emitted, including frames without
boxes (the reference converter drops them, which shortens dt across gaps).

Scores
------
``score_raw`` is the detector's value as written in the file (PointRCNN: a logit in about
-0.85..16.3). ``score = sigmoid(score_raw)``, as in the reference, which applies the sigmoid to
every KITTI detector; the tracker's score thresholds apply to this calibrated ``score``.

Velocity
--------
KITTI annotates none and its detectors estimate none. Ground-truth velocities are unknown (NaN,
``global_velocity: null`` in BaseVersion; they were 0, which reads as a measured standstill): the
motion metrics derive them from the GT positions. Detections keep 0 (the tracker measures no
KITTI detector velocity, and the motion metrics take a detector whose velocities are all 0 as
one without a velocity).
"""

from __future__ import annotations

import logging
import struct
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.camera import WORLD_FROM_CAMERA_AXES, boxes_world_to_rect  # noqa: F401 (re-exported)
from tracker.categories import CATEGORIES, category_index
from tracker.errors import InputError
from tracker.frame import Camera, Frame
from tracker.geometry import wrap_angle
from tracker.io.bounds import ANGLE_NOTE, BOUND_NOTE, MAX_ANGLE_RAD, beyond_bound
from tracker.io.fileio import read_text

LOG = logging.getLogger(__name__)

# The validation split of AB3DMOT/PC3T/CasTrack (labels exist for these 11; the other 10 training
# sequences overlap the detectors' training data).
VALIDATION_SEQS = (
    "0001",
    "0006",
    "0008",
    "0010",
    "0012",
    "0013",
    "0014",
    "0015",
    "0016",
    "0018",
    "0019",
)
TRAINING_SEQS = tuple(f"{i:04d}" for i in range(21))

FRAME_PERIOD_SECS = 0.1  # KITTI raw recordings run at 10 Hz
CAMERA_NAME = "CAM_FRONT"

#: AB3DMOT detection type codes.
AB3DMOT_TYPE_CODES: Mapping[int, str] = {1: "pedestrian", 2: "car", 3: "cyclist"}
#: Per-class detection folders of the kit (``detections/pointrcnn/training/Car/0001.txt``).
CLASS_FOLDERS: Mapping[str, str] = {"car": "Car", "pedestrian": "Pedestrian", "cyclist": "Cyclist"}
#: KITTI type strings → our category names ("Person" is KITTI tracking's sitting person).
KITTI_TYPES: Mapping[str, str] = {
    "Car": "car",
    "Van": "van",
    "Truck": "truck",
    "Pedestrian": "pedestrian",
    "Person": "person_sitting",
    "Person_sitting": "person_sitting",
    "Cyclist": "cyclist",
    "Tram": "tram",
    "Misc": "misc",
}
DONTCARE = "DontCare"

#: Image size (width, height) by the recording day, keyed by P2's (fx, cx, cy) rounded to 3
#: decimals. Sizes are the KITTI raw ``S_rect_02`` values; the first four are confirmed by the
#: kit (PNG headers for 09_26 and 09_28; detections/labels clipped at width-1/height-1 for all
#: 21 training sequences), 2011_09_30 (two test sequences) is from KITTI raw only.
IMAGE_SIZE_BY_P2: Mapping[tuple[float, float, float], tuple[int, int]] = {
    (721.538, 609.559, 172.854): (1242, 375),  # 2011_09_26, training 0000-0013
    (707.049, 604.081, 180.507): (1224, 370),  # 2011_09_28, training 0014-0017
    (718.335, 600.389, 181.512): (1238, 374),  # 2011_09_29, training 0018-0019
    (718.856, 607.193, 185.216): (1241, 376),  # 2011_10_03, training 0020
    (707.091, 601.887, 183.110): (1226, 370),  # 2011_09_30 (testing only)
}

LABEL_COLUMNS = (
    "frame", "track_id", "type", "truncated", "occluded", "alpha", "x1", "y1", "x2", "y2",
    "h", "w", "l", "x", "y", "z", "rotation_y", "score",
)  # fmt: skip
AB3DMOT_COLUMNS = (
    "frame", "type", "x1", "y1", "x2", "y2", "score", "h", "w", "l", "x", "y", "z", "rot_y",
    "alpha",
)  # fmt: skip
OBJECT_COLUMNS = LABEL_COLUMNS[2:]  # KITTI object label + score, one file per frame
#: KITTI tracking result format as detections are distributed (CasTrack/PC3T, VirConvTrack,
#: RobMOT, DeepFusionMOT): label_02 without the track id, plus a score; one file per sequence.
TRACKING_DET_COLUMNS = ("frame", *OBJECT_COLUMNS)


@dataclass
class SkippedRows:
    """Detection rows a conversion leaves out, by class name: classes no category knows (each
    file's also logged as a warning), known classes outside the ``classes`` tracked, and rows
    that repeat another exactly (logged; the first is kept)."""

    unknown: Counter[str] = field(default_factory=Counter)
    not_tracked: Counter[str] = field(default_factory=Counter)
    duplicates: Counter[str] = field(default_factory=Counter)


PoseFormat = Literal["camera", "lidar"]
DetectionsLayout = Literal["auto", "ab3dmot", "kitti_tracking", "kitti_object"]


# --------------------------------------------------------------------------------------------
# Calibration and poses


@dataclass(frozen=True, slots=True)
class KittiCalib:
    """One sequence's calibration; matrices named ``target_from_source``.

    Attributes
    ----------
    path : the calib file.
    image_from_rect : (3, 4) ``P2``, rectified reference camera → image 2 pixels.
    rect_from_cam0 : (4, 4) ``R0_rect`` padded, or None when absent.
    cam0_from_velo : (4, 4) ``Tr_velo_to_cam`` padded, or None when absent.
    velo_from_imu : (4, 4) ``Tr_imu_to_velo`` padded, or None when absent or malformed (unused).
    projections : (3, 4) ``P0`` .. ``P3`` by name (all but ``P2`` unused here, and left out
        when malformed).
    """

    path: Path
    image_from_rect: FloatArray
    rect_from_cam0: FloatArray | None
    cam0_from_velo: FloatArray | None
    velo_from_imu: FloatArray | None
    projections: Mapping[str, FloatArray]

    @property
    def rect_from_velo(self) -> FloatArray:
        """(4, 4) ``R0_rect @ Tr_velo_to_cam`` (the reference's ``lidar2camera``)."""
        if self.rect_from_cam0 is None:
            raise InputError("missing key 'R0_rect' (or 'R_rect')", path=self.path, field="R0_rect")
        if self.cam0_from_velo is None:
            raise InputError(
                "missing key 'Tr_velo_to_cam' (or 'Tr_velo_cam')",
                path=self.path,
                field="Tr_velo_to_cam",
            )
        return self.rect_from_cam0 @ self.cam0_from_velo

    @property
    def cam2_from_rect(self) -> FloatArray:
        """(4, 4) translation from rect to camera 2 (P2 = K [I | t] after rectification)."""
        t = np.linalg.solve(self.image_from_rect[:, :3], self.image_from_rect[:, 3])
        out = np.eye(4)
        out[:3, 3] = t
        return out


_CALIB_KEYS = {
    "R0_rect": "R0_rect", "R_rect": "R0_rect",
    "Tr_velo_to_cam": "Tr_velo_to_cam", "Tr_velo_cam": "Tr_velo_to_cam",
    "Tr_imu_to_velo": "Tr_imu_to_velo", "Tr_imu_velo": "Tr_imu_to_velo",
    "P0": "P0", "P1": "P1", "P2": "P2", "P3": "P3",
}  # fmt: skip
_CALIB_SIZES = {"R0_rect": 9, "Tr_velo_to_cam": 12, "Tr_imu_to_velo": 12}
# read for the record (KittiCalib.projections, velo_from_imu), used by nothing in the conversion
_CALIB_UNUSED = frozenset({"P0", "P1", "P3", "Tr_imu_to_velo"})


def _pad_4x4(matrix: FloatArray) -> FloatArray:
    out = np.eye(4)
    out[: matrix.shape[0], : matrix.shape[1]] = matrix
    return out


def read_kitti_calib(path: str | Path) -> KittiCalib:
    """Parse a KITTI calib file, accepting both key spellings.

    The object benchmark (and AB3DMOT's copies) write ``R0_rect:``, ``Tr_velo_to_cam:``,
    ``Tr_imu_to_velo:``; the official tracking files write ``R_rect``, ``Tr_velo_cam``,
    ``Tr_imu_velo`` (no colon). Unknown keys are ignored. The matrices the conversion uses
    (``P2``, ``R0_rect``, ``Tr_velo_to_cam``) are checked: a missing ``P2``, a wrong value
    count, a bad number, a ``P2`` that is not a camera or a translation beyond the bound raise
    :class:`InputError` naming the file, line and key. The others (``P0``, ``P1``, ``P3``,
    ``Tr_imu_to_velo``) are read for the record and checked the same way, but a malformed one
    is left out with a logged warning: a sequence is not refused over a matrix nothing reads.
    A key given twice (in either spelling) is refused naming its second line when the
    conversion uses it (which line holds the camera is not ours to guess); an unused one keeps
    its first line, with a logged warning.
    """
    path = Path(path)
    values: dict[str, FloatArray] = {}
    lines: dict[str, int] = {}  # (every key's first line, a malformed one's too)
    for line_no, line in enumerate(read_text(path).splitlines(), start=1):
        tokens = line.split()
        if not tokens:
            continue
        key = _CALIB_KEYS.get(tokens[0].rstrip(":"))
        if key is None:
            continue
        if key in lines:
            error = InputError(
                f"repeated key (first on line {lines[key]})", path=path, line=line_no, field=key
            )
            if key not in _CALIB_UNUSED:
                raise error
            LOG.warning("%s (not used by the conversion: this line ignored)", error)
            continue
        lines[key] = line_no
        try:
            matrix = _calib_matrix(tokens[1:], key)
            if key != "R0_rect":
                _check_calib_matrix(matrix, key)
        except ValueError as exc:
            error = InputError(str(exc), path=path, line=line_no, field=key)
            if key not in _CALIB_UNUSED:
                raise error from None
            LOG.warning("%s (not used by the conversion: left out)", error)
            continue
        values[key] = matrix
    if "P2" not in values:
        raise InputError("missing key 'P2'", path=path, field="P2")
    padded = {k: _pad_4x4(values[k]) for k in _CALIB_SIZES if k in values}
    return KittiCalib(
        path=path,
        image_from_rect=values["P2"],
        rect_from_cam0=padded.get("R0_rect"),
        cam0_from_velo=padded.get("Tr_velo_to_cam"),
        velo_from_imu=padded.get("Tr_imu_to_velo"),
        projections={k: v for k, v in values.items() if k.startswith("P")},
    )


def _calib_matrix(tokens: Sequence[str], key: str) -> FloatArray:
    """One calib line's values as its matrix; ValueError saying what is wrong."""
    expected = _CALIB_SIZES.get(key, 12)
    if len(tokens) != expected:
        raise ValueError(f"expected {expected} values, got {len(tokens)}")
    try:
        numbers = np.array(tokens, dtype=np.float64)
    except ValueError as exc:
        raise ValueError(f"not a number ({exc})") from None
    if not np.isfinite(numbers).all():
        raise ValueError("non-finite value")
    return numbers.reshape(3, 3) if expected == 9 else numbers.reshape(3, 4)


def _check_calib_matrix(matrix: FloatArray, key: str) -> None:
    """A projection ``P0`` .. ``P3`` is a camera (its left 3x3 invertible: else
    :attr:`KittiCalib.cam2_from_rect` failed in a traceback) whose translation ``K⁻¹ P[:, 3]``
    is within the bound of :mod:`tracker.io.bounds`, as ``Tr_velo_to_cam``'s (applied to every
    box) and ``Tr_imu_to_velo``'s translations are; ValueError saying what is wrong."""
    if key.startswith("P"):
        try:
            with np.errstate(all="ignore"):
                translation = np.linalg.solve(matrix[:, :3], matrix[:, 3])
        except np.linalg.LinAlgError:
            raise ValueError("its left 3x3 (the intrinsics) is singular: not a camera") from None
        what = f"the camera's translation K⁻¹ {key}[:, 3]"
    else:
        translation, what = matrix[:, 3], "translation"
    if not np.isfinite(translation).all() or beyond_bound(translation[None])[0]:
        raise ValueError(f"{what} {translation.tolist()} is {BOUND_NOTE}")


def read_kitti_poses(path: str | Path) -> FloatArray:
    """(F, 4, 4) poses, one row-major 3x4 ``[R | t]`` (12 floats) per non-empty line."""
    path = Path(path)
    table = _read_table([path], columns=tuple(f"pose[{i // 4},{i % 4}]" for i in range(12)))
    poses = np.tile(np.eye(4), (len(table.line), 1, 1))
    poses[:, :3, :] = table.floats(range(12)).reshape(-1, 3, 4)
    # line i is frame i; a translation of 1e300 would put every box of its frame there
    _check_bound(table, poses[:, :3, 3], [3, 7, 11], np.arange(len(poses)))
    # a pose is a rigid motion: R orthonormal with det +1 (ORB-SLAM3's files hold to 1e-6; a
    # scaled, reflected or hand-edited matrix would move every box of its frame)
    rotation = poses[:, :3, :3]
    off = np.abs(np.einsum("nji,njk->nik", rotation, rotation) - np.eye(3)).max(axis=(1, 2))
    off = np.maximum(off, np.abs(np.linalg.det(rotation) - 1.0))  # no poses: shape (0,)
    if (off > POSE_RIGID_TOLERANCE).any():
        row = int(np.argmax(off > POSE_RIGID_TOLERANCE))
        bad_path, line = table.where(row)
        raise InputError(
            f"not a rigid motion: its rotation is off orthonormal (det +1) by {off[row]:.3g}",
            path=bad_path, line=line, field="pose",
        )  # fmt: skip
    return poses


#: How far a pose's rotation may be from orthonormal with det +1 (rounding in the file).
POSE_RIGID_TOLERANCE = 1e-3


def image_size_px(calib: KittiCalib, image_dir: Path | None = None) -> tuple[int, int]:
    """(width, height) of image 2: from a PNG header in ``image_dir`` when there is one, else
    from the recording day recognised by ``P2`` (:data:`IMAGE_SIZE_BY_P2`), else a guess of
    twice the principal point (logged as a warning)."""
    if image_dir is not None and image_dir.is_dir():
        for png in sorted(image_dir.glob("*.png")):
            with png.open("rb") as f:
                header = f.read(24)
            if header[:8] == b"\x89PNG\r\n\x1a\n" and header[12:16] == b"IHDR":
                width, height = struct.unpack(">II", header[16:24])
                return int(width), int(height)
    p2 = calib.image_from_rect
    key = (round(p2[0, 0], 3), round(p2[0, 2], 3), round(p2[1, 2], 3))
    if key in IMAGE_SIZE_BY_P2:
        return IMAGE_SIZE_BY_P2[key]
    guess = (round(2 * p2[0, 2]), round(2 * p2[1, 2]))
    LOG.warning(
        "%s: unknown camera (fx, cx, cy)=%s; guessing image size %s", calib.path, key, guess
    )
    return guess


def world_from_rect_poses(
    calib: KittiCalib, poses: FloatArray | None, *, pose_format: PoseFormat, num_frames: int
) -> FloatArray:
    """(F, 4, 4) ``world_from_rect`` per frame (see the module docstring for the three cases)."""
    if poses is None:
        return np.broadcast_to(WORLD_FROM_CAMERA_AXES, (num_frames, 4, 4)).copy()
    poses = poses[:num_frames]
    if pose_format == "camera":
        cam2_from_rect = calib.cam2_from_rect
        rect_from_cam2 = np.linalg.inv(cam2_from_rect)
        return WORLD_FROM_CAMERA_AXES @ rect_from_cam2 @ poses @ cam2_from_rect
    if pose_format == "lidar":
        return poses @ np.linalg.inv(calib.rect_from_velo)
    raise ValueError(f"pose_format must be 'camera' or 'lidar', got {pose_format!r}")


# --------------------------------------------------------------------------------------------
# Text tables


@dataclass(frozen=True, slots=True)
class _Table:
    """Tokens of one or more text files, column-major, with provenance for error messages."""

    columns: tuple[str, ...]
    tokens: list[tuple[str, ...]]  # one tuple per column
    paths: list[Path]
    source: IntArray  # (N,) index into paths
    line: IntArray  # (N,) 1-based line number

    def where(self, row: int) -> tuple[Path, int]:
        return self.paths[self.source[row]], int(self.line[row])

    def floats(self, columns: Iterable[int]) -> FloatArray:
        """(N, k) finite floats of the columns; else InputError naming file, line and field."""
        columns = list(columns)
        n = len(self.line)
        out = np.empty((n, len(columns)))
        for j, c in enumerate(columns):
            try:
                out[:, j] = np.array(self.tokens[c], dtype=np.float64) if n else []
            except ValueError:
                for row, token in enumerate(self.tokens[c]):
                    try:
                        float(token)
                    except ValueError:
                        path, line = self.where(row)
                        raise InputError(
                            f"not a number: {token.strip()!r}",
                            path=path,
                            line=line,
                            field=self.columns[c],
                        ) from None
                out[:, j] = [float(token) for token in self.tokens[c]]  # numpy was stricter
            bad = ~np.isfinite(out[:, j])
            if bad.any():
                row = int(np.argmax(bad))
                path, line = self.where(row)
                token = self.tokens[c][row].strip()
                raise InputError(
                    f"non-finite value {token!r} (NaN/inf)",
                    path=path,
                    line=line,
                    field=self.columns[c],
                )
        return out

    def ints(self, column: int) -> IntArray:
        """(N,) integers of one column (written as ints or integral floats)."""
        values = self.floats([column])[:, 0]
        bad = values != np.round(values)
        if bad.any():
            row = int(np.argmax(bad))
            path, line = self.where(row)
            raise InputError(
                f"expected an integer, got {self.tokens[column][row].strip()!r}",
                path=path, line=line, field=self.columns[column],
            )  # fmt: skip
        return values.astype(np.int64)

    def strings(self, column: int) -> NDArray[np.str_]:
        return (
            np.array(self.tokens[column], dtype=str) if len(self.line) else np.zeros(0, dtype=str)
        )


def _read_table(
    paths: Sequence[Path],
    *,
    columns: tuple[str, ...],
    sep: str | None = None,
    counts: Sequence[int] | None = None,
    hints: Mapping[int, str] | None = None,
) -> _Table:
    """Split text files into tokens; every non-empty line must have one of ``counts`` columns
    (default ``len(columns)``) and all lines of one call the same count. ``hints``: what a
    line of a wrong count most likely is, added to the error."""
    counts = tuple(counts or (len(columns),))
    rows: list[list[str]] = []
    source: list[int] = []
    lines: list[int] = []
    for index, path in enumerate(paths):
        for line_no, text in enumerate(read_text(path).splitlines(), start=1):
            if not text.strip():
                continue
            row = text.split(sep)
            if sep is not None and row[-1].strip() == "":
                row.pop()  # tolerate a trailing separator
            if len(row) not in counts or (rows and len(row) != len(rows[0])):
                want = (
                    len(rows[0]) if rows and len(row) in counts else " or ".join(map(str, counts))
                )
                hint = (hints or {}).get(len(row))
                raise InputError(
                    f"expected {want} columns, got {len(row)}" + (f" ({hint})" if hint else ""),
                    path=path,
                    line=line_no,
                    field="columns",
                )
            rows.append(row)
            source.append(index)
            lines.append(line_no)
    ncol = len(rows[0]) if rows else min(counts)
    tokens = [tuple(col) for col in zip(*rows, strict=True)] if rows else [() for _ in range(ncol)]
    return _Table(
        columns=columns,
        tokens=tokens,
        paths=list(paths),
        source=np.array(source, dtype=np.int64),
        line=np.array(lines, dtype=np.int64),
    )


# --------------------------------------------------------------------------------------------
# Labels and detections as structures of arrays


@dataclass(frozen=True, slots=True)
class KittiObjects:
    """KITTI boxes as parsed from text, still in the rect camera frame (one row per line).

    Attributes
    ----------
    frame : (N,) frame index.
    track_id : (N,) track id (-1 for detections and DontCare).
    type_name : (N,) the file's class name (``"Car"``, ``"DontCare"``, ...).
    category : (N,) index into :data:`tracker.categories.CATEGORIES`, -1 for DontCare/unknown.
    truncated, occluded : (N,) KITTI truncation (float) and occlusion (int); -1 when absent.
    xyxy_image : (N, 4) 2D box in image 2, pixels.
    hwl : (N, 3) height, width, length, metres.
    xyz_bottom_rect : (N, 3) bottom-centre in the rect camera frame, metres.
    rotation_y : (N,) KITTI ``rotation_y`` about the camera y axis, radians.
    score_raw : (N,) the file's score (NaN for labels without one).
    paths, source, line : where each row was read (``paths[source[i]]``, 1-based ``line[i]``),
        for error messages; empty for objects built in code.
    """

    frame: IntArray
    track_id: IntArray
    type_name: NDArray[np.str_]
    category: IntArray
    truncated: FloatArray
    occluded: IntArray
    xyxy_image: FloatArray
    hwl: FloatArray
    xyz_bottom_rect: FloatArray
    rotation_y: FloatArray
    score_raw: FloatArray
    paths: tuple[Path, ...] = ()
    source: IntArray | None = None
    line: IntArray | None = None

    def __len__(self) -> int:
        return len(self.frame)

    def select(self, mask: NDArray[np.bool_]) -> KittiObjects:
        rows = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "paths"}
        masked = {k: None if v is None else v[mask] for k, v in rows.items()}
        return KittiObjects(**masked, paths=self.paths)

    def where(self, row: int) -> tuple[Path | None, int | None]:
        """The file and 1-based line row ``row`` was read from (None, None if built in code)."""
        if self.source is None or self.line is None:
            return None, None
        return self.paths[self.source[row]], int(self.line[row])


def _kitti_type_categories(type_names: NDArray[np.str_], where: str) -> IntArray:
    """Category index per KITTI type string; unknown names are counted and logged, -1."""
    unique, inverse = np.unique(type_names, return_inverse=True)
    lookup = np.array(
        [
            category_index(KITTI_TYPES.get(name, name)) if name != DONTCARE else -1
            for name in unique
        ],
        dtype=np.int64,
    )
    counts = np.bincount(inverse.reshape(-1), minlength=len(unique))
    unknown = Counter(
        {
            str(name): int(count)
            for name, count, idx in zip(unique, counts, lookup, strict=True)
            if idx < 0 and name != DONTCARE
        }
    )
    if unknown:
        LOG.warning("%s: dropping rows of unknown classes %s", where, dict(sorted(unknown.items())))
    return lookup[inverse].reshape(-1).astype(np.int64)


def _objects_from_label_columns(
    table: _Table, *, offset: int, frame: IntArray, track_id: IntArray, where: str
) -> KittiObjects:
    """Shared parsing of the KITTI label columns starting at ``type`` (column ``offset``)."""
    n = len(table.line)
    type_name = table.strings(offset)
    numbers = table.floats(range(offset + 1, offset + 15))  # truncated .. rotation_y
    has_score = len(table.tokens) > offset + 15
    score_raw = table.floats([offset + 15])[:, 0] if has_score and n else np.full(n, np.nan)
    _check_positive(table, numbers[:, 7:10], [offset + 8, offset + 9, offset + 10], type_name)
    _check_bound(table, numbers[:, 7:13], list(range(offset + 8, offset + 14)), frame)
    _check_angle(table, numbers[:, 13], offset + 14, frame)
    occluded = numbers[:, 1]
    return KittiObjects(
        frame=frame,
        track_id=track_id,
        type_name=type_name,
        category=_kitti_type_categories(type_name, where),
        truncated=numbers[:, 0],
        occluded=occluded.astype(np.int64),
        xyxy_image=numbers[:, 3:7],
        hwl=numbers[:, 7:10],
        xyz_bottom_rect=numbers[:, 10:13],
        rotation_y=numbers[:, 13],
        score_raw=score_raw,
        **_provenance(table),
    )


def _provenance(table: _Table) -> dict[str, object]:
    return {"paths": tuple(table.paths), "source": table.source, "line": table.line}


def _check_positive(
    table: _Table, values: FloatArray, columns: list[int], type_name: NDArray[np.str_] | None
) -> None:
    """Box dimensions must be > 0 (DontCare rows carry -1 placeholders and are exempt)."""
    bad = values <= 0
    if type_name is not None:
        bad &= (type_name != DONTCARE)[:, None]
    if bad.any():
        row, j = np.argwhere(bad)[0]
        path, line = table.where(int(row))
        raise InputError(
            f"box dimension must be > 0, got {values[row, j]}",
            path=path, line=line, field=table.columns[columns[j]],
        )  # fmt: skip


def _check_bound(table: _Table, values: FloatArray, columns: list[int], frame: IntArray) -> None:
    """Box sizes and locations, and pose translations, must lie within the bound of
    :mod:`tracker.io.bounds`."""
    far = beyond_bound(values)
    if far.any():
        row = int(np.argmax(far))
        j = int(np.argmax(beyond_bound(values[row])))
        path, line = table.where(row)
        raise InputError(
            f"{table.tokens[columns[j]][row].strip()} (frame {frame[row]}) is {BOUND_NOTE}",
            path=path, line=line, field=table.columns[columns[j]],
        )  # fmt: skip


def _check_angle(table: _Table, values: FloatArray, column: int, frame: IntArray) -> None:
    """``rotation_y`` may be unwrapped (tracker results carry it so), but within the heading
    bound of :mod:`tracker.io.bounds`: beyond it a float's spacing nears a turn and the heading
    taken from it is arbitrary (as the BaseVersion reader refuses such a ``global_yaw``)."""
    far = beyond_bound(values, MAX_ANGLE_RAD)
    if far.any():
        row = int(np.argmax(far))
        path, line = table.where(row)
        raise InputError(
            f"{table.tokens[column][row].strip()} (frame {frame[row]}) is {ANGLE_NOTE}",
            path=path, line=line, field=table.columns[column],
        )  # fmt: skip


def read_kitti_labels(path: str | Path) -> KittiObjects:
    """Parse a label_02 file (17 columns, or 18 with a score as in tracker results)."""
    path = Path(path)
    table = _read_table([path], columns=LABEL_COLUMNS, counts=(17, 18))
    return _objects_from_label_columns(
        table, offset=2, frame=_frames(table, 0), track_id=table.ints(1), where=str(path)
    )


def _frames(table: _Table, column: int) -> IntArray:
    frame = table.ints(column)
    if (frame < 0).any():
        row = int(np.argmax(frame < 0))
        path, line = table.where(row)
        raise InputError(f"negative frame index {frame[row]}", path=path, line=line, field="frame")
    return frame


def read_ab3dmot_detections(paths: Sequence[str | Path]) -> KittiObjects:
    """Parse AB3DMOT-layout detection CSVs (15 columns; see :data:`AB3DMOT_COLUMNS`).

    Several files (the kit's per-class folders) are concatenated. Type codes: 1 pedestrian,
    2 car, 3 cyclist; any other code raises :class:`InputError`.
    """
    path_list = [Path(p) for p in paths]
    tracking = "the KITTI tracking format's count: its columns are separated by spaces"
    table = _read_table(
        path_list, columns=AB3DMOT_COLUMNS, sep=",", hints={17: tracking, 18: tracking}
    )
    n = len(table.line)
    frame = _frames(table, 0)
    types = np.char.strip(table.strings(1))
    names = np.flatnonzero(np.isin(types, list(KITTI_TYPES)))
    if len(names):
        path, line = table.where(int(names[0]))
        raise InputError(
            f"a class name ({str(types[names[0]])!r}) where AB3DMOT's type code "
            "goes (1=Pedestrian, 2=Car, 3=Cyclist)",
            path=path, line=line, field="type",
        )  # fmt: skip
    codes = table.ints(1)
    known = np.isin(codes, list(AB3DMOT_TYPE_CODES))
    if not known.all():
        row = int(np.argmax(~known))
        path, line = table.where(row)
        raise InputError(
            f"unknown type code {codes[row]} (expected 1=Pedestrian, 2=Car, 3=Cyclist)",
            path=path, line=line, field="type",
        )  # fmt: skip
    code_to_category = np.full(max(AB3DMOT_TYPE_CODES) + 1, -1, dtype=np.int64)
    for code, name in AB3DMOT_TYPE_CODES.items():
        code_to_category[code] = category_index(name)
    numbers = table.floats([2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13])  # x1 .. rot_y
    _check_positive(table, numbers[:, 5:8], [7, 8, 9], None)
    _check_bound(table, numbers[:, 5:11], list(range(7, 13)), frame)
    _check_angle(table, numbers[:, 11], 13, frame)
    category = code_to_category[codes]
    return KittiObjects(
        frame=frame,
        track_id=np.full(n, -1, dtype=np.int64),
        type_name=np.array(CATEGORIES)[category],
        category=category,
        truncated=np.full(n, -1.0),
        occluded=np.full(n, -1, dtype=np.int64),
        xyxy_image=numbers[:, 0:4],
        hwl=numbers[:, 5:8],
        xyz_bottom_rect=numbers[:, 8:11],
        rotation_y=numbers[:, 11],
        score_raw=numbers[:, 4],
        **_provenance(table),
    )


def _refuse_labels_without_score(table: _Table) -> None:
    """A label_02 file (frame, track id, type, ..., no score) has the 17 columns of a detection
    file too; its class name one column late would read as a bad ``truncated``. Say what it is."""
    if not len(table.line) or table.tokens[1][0] in KITTI_TYPES or table.tokens[1][0] == DONTCARE:
        return
    name = table.tokens[2][0]
    if name in KITTI_TYPES or name == DONTCARE:
        path, line = table.where(0)
        raise InputError(
            f"a class name ({name!r}) in the third column: this is a label file (frame, track "
            "id, type, ...) without the score a detection file ends with",
            path=path, line=line, field="type",
        )  # fmt: skip


def read_kitti_tracking_detections(path: str | Path) -> KittiObjects:
    """Parse detections in the KITTI tracking result format: one file per sequence, lines
    ``frame type truncated occluded alpha x1 y1 x2 y2 h w l x y z rotation_y score`` (17
    columns; 18 with a track id after the frame, as tracker results are written).

    Class names decide the category (unknown ones are counted, logged and dropped by the
    caller's class filter); ``alpha``/``rotation_y`` may be unwrapped (headings are wrapped
    when the boxes move to the world frame; a ``rotation_y`` beyond ±1e4 rad is refused). A
    frame without boxes simply has no line.
    """
    path = Path(path)
    table = _read_table([path], columns=TRACKING_DET_COLUMNS, counts=(17, 18))
    if len(table.tokens) == 18 and table.tokens[1][0] in (*KITTI_TYPES, DONTCARE):
        path, line = table.where(0)
        raise InputError(
            "18 columns with the class second: a detection file has 17 (frame type ... score), "
            "a tracker's result 18 (a track id after the frame); this line has one more",
            path=path, line=line, field="columns",
        )  # fmt: skip
    if len(table.tokens) == 18:
        table = _Table(
            columns=LABEL_COLUMNS, tokens=table.tokens, paths=table.paths,
            source=table.source, line=table.line,
        )  # fmt: skip
        track_id, offset = table.ints(1), 2
    else:
        track_id, offset = np.full(len(table.line), -1, dtype=np.int64), 1
        _refuse_labels_without_score(table)
    objects = _objects_from_label_columns(
        table, offset=offset, frame=_frames(table, 0), track_id=track_id, where=str(path)
    )
    if not np.isfinite(objects.score_raw).all():
        row = int(np.argmax(~np.isfinite(objects.score_raw)))
        bad_path, line = table.where(row)
        raise InputError("score must be finite", path=bad_path, line=line, field="score")
    return objects


def _sniff_single_file(path: Path) -> Literal["ab3dmot", "kitti_tracking"]:
    """A single ``<seq>.txt``: comma-separated AB3DMOT rows, or the whitespace-separated
    KITTI tracking format (decided by the first non-empty line; an empty file is either)."""
    with path.open(encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if line.strip():
                return "ab3dmot" if "," in line else "kitti_tracking"
    return "kitti_tracking"


def read_kitti_object_detections(seq_dir: str | Path) -> tuple[KittiObjects, int]:
    """Parse KITTI-object-layout detections: ``<seq_dir>/<frame:06d>.txt``, 16 columns
    (the label columns from ``type`` on, plus the score). Returns the objects and the number of
    frames implied by the file names (max + 1; a frame file may be empty)."""
    seq_dir = Path(seq_dir)
    files = sorted(seq_dir.glob("*.txt"))
    frame_of_file: list[int] = []
    for f in files:
        if not f.stem.isdigit():
            raise InputError("file name is not a frame number", path=f, field="frame")
        frame_of_file.append(int(f.stem))
    table = _read_table(files, columns=OBJECT_COLUMNS)
    frame = (
        np.array(frame_of_file, dtype=np.int64)[table.source] if files else np.zeros(0, np.int64)
    )
    objects = _objects_from_label_columns(
        table, offset=0, frame=frame, track_id=np.full(len(frame), -1, np.int64), where=str(seq_dir)
    )
    return objects, (max(frame_of_file) + 1 if frame_of_file else 0)


# --------------------------------------------------------------------------------------------
# Rect camera → world


IMAGE_DET_COLUMNS = ("frame", "x1", "y1", "x2", "y2", "score")
#: a 3D detection takes the box of an image detector that overlaps its own 2D box (the
#: projection, for a LiDAR detector) at least this much (IoU); one image box per detection
FUSE_MIN_IOU = 0.5


def read_image_detections(path: str | Path) -> tuple[IntArray, FloatArray]:
    """2D-only detections of one class and sequence, ``frame, x1, y1, x2, y2, score`` comma
    separated (DeepFusionMOT's layout of its RRC boxes): (frame (N,), xyxy (N, 4))."""
    table = _read_table([Path(path)], columns=IMAGE_DET_COLUMNS, sep=",")
    frame = _frames(table, 0)
    xyxy = table.floats([1, 2, 3, 4])
    table.floats([5])  # the score: checked, not used
    for lo, hi in ((1, 3), (2, 4)):  # x1 < x2, y1 < y2
        empty = xyxy[:, hi - 1] <= xyxy[:, lo - 1]
        if empty.any():
            where, line = table.where(int(np.argmax(empty)))
            name = IMAGE_DET_COLUMNS[hi]
            raise InputError(f"empty 2D box ({name} <= {IMAGE_DET_COLUMNS[lo]})", path=where,
                             line=line, field=name)  # fmt: skip
    return frame, xyxy


def fuse_image_boxes(
    frames: Sequence[Frame],
    category: int,
    image_frame: IntArray,
    image_xyxy: FloatArray,
    *,
    min_iou: float = FUSE_MIN_IOU,
) -> tuple[list[Frame], int]:
    """The frames with detections of ``category`` given an image detector's box: pairs of a
    detection's own 2D box and an image box overlapping at least ``min_iou``, one-to-one, with
    the largest total IoU (Hungarian); the others keep theirs. Returns the frames and the number
    of detections that took a box."""
    from scipy.optimize import linear_sum_assignment

    from tracker.cost import iou_xyxy

    order = np.argsort(image_frame, kind="stable")
    image_frame, image_xyxy = image_frame[order], image_xyxy[order]
    out: list[Frame] = []
    fused = 0
    for f in frames:
        lo, hi = np.searchsorted(image_frame, [f.frame_id, f.frame_id + 1])
        own = f.boxes.xyxy_image
        rows = np.flatnonzero((f.boxes.category == category) & np.isfinite(own).all(axis=1))
        if hi == lo or not len(rows):
            out.append(f)
            continue
        iou = iou_xyxy(own[rows][:, None], image_xyxy[None, lo:hi])
        # pairs below the threshold may not steer the assignment
        a, b = linear_sum_assignment(-np.where(iou >= min_iou, iou, 0.0))
        keep = iou[a, b] >= min_iou
        xyxy = own.copy()
        xyxy[rows[a[keep]]] = image_xyxy[lo + b[keep]]
        fused += int(keep.sum())
        out.append(replace(f, boxes=f.boxes.replace(xyxy_image=xyxy)))
    return out, fused


def boxes_rect_to_world(
    objects: KittiObjects, world_from_rect: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """World centre, size and heading of KITTI boxes.

    Parameters
    ----------
    objects : N boxes with ``frame`` indexing ``world_from_rect``.
    world_from_rect : (F, 4, 4) per-frame transforms.

    Returns
    -------
    xyz_world : (N, 3) geometric centre = bottom centre − (0, h/2, 0) in rect (y down), moved.
    lwh : (N, 3) length, width, height.
    yaw_world : (N,) heading of the rotated camera-frame heading (cos ry, 0, −sin ry), in
        (−pi, pi]; equals −ry − pi/2 for ``world_from_rect = W``.
    """
    transform = world_from_rect[objects.frame]  # (N, 4, 4)
    rotation = transform[:, :3, :3]
    centre_rect = objects.xyz_bottom_rect - np.stack(
        [np.zeros(len(objects)), objects.hwl[:, 0] / 2.0, np.zeros(len(objects))], axis=1
    )
    xyz_world = np.einsum("nij,nj->ni", rotation, centre_rect) + transform[:, :3, 3]
    heading_rect = np.stack(
        [np.cos(objects.rotation_y), np.zeros(len(objects)), -np.sin(objects.rotation_y)], axis=1
    )
    heading_world = np.einsum("nij,nj->ni", rotation, heading_rect)
    yaw_world = wrap_angle(np.arctan2(heading_world[:, 1], heading_world[:, 0]))
    lwh = objects.hwl[:, ::-1].copy()
    return xyz_world, lwh, yaw_world


def _sigmoid(x: FloatArray) -> FloatArray:
    return np.exp(-np.logaddexp(0.0, -x))  # 1 / (1 + e^-x) without overflow


def _split_by_frame(frame: IntArray, num_frames: int) -> tuple[IntArray, IntArray]:
    """Row order sorted by frame (stable) and the split points for ``num_frames`` frames."""
    order = np.argsort(frame, kind="stable")
    bounds = np.cumsum(np.bincount(frame, minlength=num_frames))[:-1]
    return order, bounds


def _frames_from_objects(
    scene: str,
    objects: KittiObjects,
    *,
    num_frames: int,
    world_from_rect: FloatArray,
    cameras: Sequence[Camera],
    score: FloatArray,
    ignore: KittiObjects | None = None,
    velocity: FloatArray | None = None,
) -> list[Frame]:
    """One Frame per frame index, boxes grouped with one argsort + np.split per field
    (``velocity``: (N, 2), else 0)."""
    xyz, lwh, yaw = boxes_rect_to_world(objects, world_from_rect)
    order, bounds = _split_by_frame(objects.frame, num_frames)
    values_by_name = {
        "xyz": xyz, "lwh": lwh, "yaw": yaw, "score": score, "score_raw": objects.score_raw,
        "category": objects.category, "xyxy_image": objects.xyxy_image,
        "track_id": objects.track_id,
    }  # fmt: skip
    if velocity is not None:
        values_by_name["velocity"] = velocity
    split = {name: np.split(values[order], bounds) for name, values in values_by_name.items()}
    ignore_xyxy: list[FloatArray] = []
    if ignore is not None:
        ignore_order, ignore_bounds = _split_by_frame(ignore.frame, num_frames)
        ignore_xyxy = np.split(ignore.xyxy_image[ignore_order], ignore_bounds)
    frames: list[Frame] = []
    for i in range(num_frames):
        columns = {name: parts[i] for name, parts in split.items()}
        boxes = Boxes.create(**columns, camera=np.zeros(len(columns["yaw"]), dtype=np.int64))
        extra: dict[str, FloatArray | IntArray] = {}
        if ignore is not None:
            extra = {
                "ignore_xyxy_image": ignore_xyxy[i],
                "ignore_camera": np.zeros(len(ignore_xyxy[i]), dtype=np.int64),
            }
        frames.append(
            Frame(
                scene=scene,
                frame_id=i,
                timestamp_secs=i * FRAME_PERIOD_SECS,
                boxes=boxes,
                cameras=(cameras[i],),
                world_from_ego=world_from_rect[i],
                **extra,
            )
        )
    return frames


# --------------------------------------------------------------------------------------------
# Sequence and dataset conversion


def _normalise_seq(seq: str | int) -> str:
    text = str(seq).strip()
    return text.zfill(4) if text.isdigit() else text


def _detection_sources(
    detections_dir: Path, seq: str, layout: DetectionsLayout, classes: Sequence[str]
) -> tuple[Literal["ab3dmot", "kitti_tracking", "kitti_object"], list[Path] | Path]:
    """Which files hold a sequence's detections, and in which layout."""
    per_frame_dir = detections_dir / seq
    single = detections_dir / f"{seq}.txt"
    per_class = [
        detections_dir / CLASS_FOLDERS[c] / f"{seq}.txt" for c in classes if c in CLASS_FOLDERS
    ]
    per_class = [p for p in per_class if p.is_file()]
    # one entry per layout found, in the order read below: the first is read
    layouts = [f"{p.name}" for p in (per_frame_dir, single) if p.exists()]
    layouts += [" + ".join(f"{p.parent.name}/{p.name}" for p in per_class)] if per_class else []
    if layout == "auto" and len(layouts) > 1:  # the others may be what the user meant
        LOG.warning(
            "%s: detections in more than one layout in %s; reading %s, not %s",
            seq, detections_dir, layouts[0], ", ".join(layouts[1:]),
        )  # fmt: skip
    if layout in ("auto", "kitti_object") and per_frame_dir.is_dir():
        return "kitti_object", per_frame_dir
    if single.is_file() and layout in ("auto", "ab3dmot", "kitti_tracking"):
        found = _sniff_single_file(single) if layout == "auto" else layout
        if found == "kitti_tracking":
            return "kitti_tracking", single
        return "ab3dmot", [single]
    if layout in ("auto", "ab3dmot") and per_class:
        return "ab3dmot", per_class
    if layout in ("auto", "ab3dmot") and any(
        (detections_dir / folder / f"{seq}.txt").is_file() for folder in CLASS_FOLDERS.values()
    ):
        return "ab3dmot", []  # per-class files, none of a class asked for: no detections
    raise FileNotFoundError(
        f"no {'' if layout == 'auto' else layout + ' '}detections for sequence {seq} in "
        f"{detections_dir} "
        f"(looked for {per_frame_dir}/, {single}, and <Class>/{seq}.txt)"
    )


def pose_folder(split_dir: Path, poses: str | Path | None) -> Path | None:
    """The folder of a split's ``<seq>.txt`` pose files: ``"orbslam3"`` the kit's own
    (``<split>/pose_orbslam3``), else the folder given; None without poses."""
    if poses is None:
        return None
    return split_dir / "pose_orbslam3" if str(poses) == "orbslam3" else Path(poses)


def convert_kitti(
    kitti_root: str | Path,
    *,
    split: str = "training",
    seqs: Iterable[str | int] | None = None,
    detector: str = "pointrcnn",
    detections_dir: str | Path | None = None,
    detections_layout: DetectionsLayout = "auto",
    poses: str | Path | None = "orbslam3",
    pose_format: PoseFormat = "camera",
    classes: Sequence[str] = ("car", "pedestrian", "cyclist"),
    with_gt: bool = True,
    num_frames: int | Mapping[str, int] | None = None,
    image_detector: str | None = None,
    skipped: SkippedRows | None = None,
    label_dir: str | Path | None = None,
) -> tuple[dict[str, list[Frame]], dict[str, list[Frame]] | None]:
    """Convert KITTI tracking detections (and labels) to world-frame Frames.

    Parameters
    ----------
    kitti_root : the kit's ``kitti/tracking`` folder (``<split>/calib``, ``<split>/label_02``,
        ``<split>/pose_orbslam3``, ``<split>/image_02``, ``detections/<detector>/<split>``).
    split : ``"training"`` or ``"testing"``.
    seqs : sequence names (``"0001"`` or ``1``); default: every ``<split>/calib/*.txt``.
    detector : detections folder name under ``detections/`` (used when ``detections_dir`` is None).
    detections_dir : folder holding ``<seq>.txt`` (KITTI tracking result format + score, or an
        AB3DMOT CSV), ``<Class>/<seq>.txt`` (AB3DMOT CSV) or ``<seq>/<frame:06d>.txt`` (KITTI
        object layout + score column).
    detections_layout : ``"auto"`` (decided from the files), ``"ab3dmot"``,
        ``"kitti_tracking"`` or ``"kitti_object"``.
    poses : ``"orbslam3"`` (``<split>/pose_orbslam3/<seq>.txt``), a folder of ``<seq>.txt`` pose
        files, or None for no ego motion (world = current camera frame, z up: velocities are then
        relative to the ego vehicle).
    pose_format : ``"camera"`` (camera-2 pose relative to frame 0, as ORB-SLAM3) or ``"lidar"``
        (velodyne → world, the CasTrack/MCTrack ``pose/*.txt`` convention). Ignored for
        ``poses="orbslam3"`` (always camera).
    classes : detection categories to keep. Ground truth keeps every known class (van,
        person_sitting, tram, misc, truck are evaluation distractors); DontCare rows become
        ``Frame.ignore_xyxy_image``.
    with_gt : also convert ``<split>/label_02/<seq>.txt`` (or ``label_dir``'s) where it exists.
    num_frames : sequence length override (one int for all, or per sequence). Default: the
        number of pose lines, else the largest frame index in labels/detections + 1. Rows beyond
        an explicit length are dropped (logged).
    image_detector : folder under ``detections/`` of a 2D image detector's boxes,
        ``<split>/<Class>/<seq>.txt`` (:func:`read_image_detections`): detections take the boxes
        of their class that overlap their own 2D boxes (IoU >= 0.5, one-to-one, Hungarian:
        :func:`fuse_image_boxes`). A class without a file keeps its own boxes (logged).
    skipped : when given, counts the detection rows left out (:class:`SkippedRows`). A sequence
        without a single detection of ``classes`` is logged as a warning (an empty file, or a
        detector without those classes).
    label_dir : the folder of the ``<seq>.txt`` labels (default ``<split>/label_02``): the ground
        truth, and without poses the sequences' lengths.

    Returns
    -------
    detections : ``{seq: [Frame] * num_frames}``, every frame present, boxes with ``score =
        sigmoid(score_raw)``, the detector's 2D box in ``xyxy_image`` (camera 0).
    gt : same layout with ``track_id`` set and ``score = 1``, for the sequences that have labels;
        None when ``with_gt`` is False or no sequence has labels.
    """
    kitti_root = Path(kitti_root)
    split_dir = kitti_root / split
    if pose_format not in ("camera", "lidar"):
        raise ValueError(f"pose_format must be 'camera' or 'lidar', got {pose_format!r}")
    if detections_layout not in ("auto", "ab3dmot", "kitti_tracking", "kitti_object"):
        raise ValueError(f"unknown detections_layout {detections_layout!r}")
    unknown_classes = [c for c in classes if category_index(c) < 0]
    if unknown_classes:
        raise ValueError(f"unknown classes {unknown_classes}; known: {list(CATEGORIES)}")
    class_names = [CATEGORIES[category_index(c)] for c in classes]
    if seqs is None:
        seq_list = sorted(p.stem for p in (split_dir / "calib").glob("*.txt"))
        if not seq_list:
            raise FileNotFoundError(f"no calib files in {split_dir / 'calib'}")
    else:
        seq_list = [_normalise_seq(s) for s in seqs]
    labels_root = Path(label_dir) if label_dir is not None else split_dir / "label_02"
    det_root = Path(detections_dir) if detections_dir is not None else None
    det_root = det_root or kitti_root / "detections" / detector / split
    pose_dir = pose_folder(split_dir, poses)
    if poses is not None and str(poses) == "orbslam3":
        pose_format = "camera"

    detections: dict[str, list[Frame]] = {}
    gt: dict[str, list[Frame]] = {}
    for seq in seq_list:
        explicit = num_frames.get(seq) if isinstance(num_frames, Mapping) else num_frames
        det_frames, gt_frames = _convert_sequence(
            split_dir,
            seq,
            detections_dir=det_root,
            detections_layout=detections_layout,
            pose_path=None if pose_dir is None else pose_dir / f"{seq}.txt",
            pose_format=pose_format,
            classes=class_names,
            with_gt=with_gt,
            num_frames=explicit,
            skipped=skipped,
            label_path=labels_root / f"{seq}.txt",
        )
        if image_detector is not None:
            det_frames = _with_image_boxes(
                det_frames, kitti_root / "detections" / image_detector / split, seq, class_names
            )
        detections[seq] = det_frames
        if gt_frames is not None:
            gt[seq] = gt_frames
        elif with_gt:
            LOG.info("%s: no labels at %s", seq, labels_root / f"{seq}.txt")
    return detections, (gt if with_gt and gt else None)


def _without_duplicates(dets: KittiObjects, seq: str, skipped: SkippedRows | None) -> KittiObjects:
    """The rows with every exact repeat left out (the same frame, class, boxes and score): a
    file listed twice, or every class written into each class's AB3DMOT file. Kept, a repeat
    would be a second track on the same object, as no NMS runs by default."""
    if len(dets) < 2:
        return dets
    key = np.column_stack([
        dets.frame, dets.category, dets.xyxy_image, dets.hwl, dets.xyz_bottom_rect,
        dets.rotation_y, dets.score_raw,
    ])  # fmt: skip
    _, first = np.unique(key, axis=0, return_index=True)
    if len(first) == len(dets):
        return dets
    keep = np.zeros(len(dets), dtype=bool)
    keep[first] = True
    repeats = Counter(CATEGORIES[c] for c in dets.category[~keep].tolist())
    if skipped is not None:
        skipped.duplicates.update(repeats)
    path, line = dets.where(int(np.argmin(keep)))
    LOG.warning(
        "%s: %d detection rows repeat another row exactly (the first at %s:%s); each is read once",
        seq, int((~keep).sum()), path, line,
    )  # fmt: skip
    return dets.select(keep)


def _with_image_boxes(
    frames: list[Frame], image_dir: Path, seq: str, classes: Sequence[str]
) -> list[Frame]:
    """The sequence's detections with the image detector's boxes (:func:`fuse_image_boxes`)."""
    for name in classes:
        path = image_dir / CLASS_FOLDERS.get(name, name) / f"{seq}.txt"
        if not path.is_file():
            LOG.warning("%s: no %s image boxes at %s; its detections keep theirs", seq, name, path)
            continue
        frame, xyxy = read_image_detections(path)
        beyond = int((frame >= len(frames)).sum())
        if beyond:
            LOG.warning(
                "%s: %d image boxes at frames beyond the sequence's %d (%s): another "
                "sequence's file?", seq, beyond, len(frames), path,
            )  # fmt: skip
        total = sum(int((f.boxes.category == category_index(name)).sum()) for f in frames)
        frames, fused = fuse_image_boxes(frames, category_index(name), frame, xyxy)
        LOG.info("%s: %d of %d %s detections took an image box (%s)", seq, fused, total, name, path)
    return frames


def _convert_sequence(
    split_dir: Path,
    seq: str,
    *,
    detections_dir: Path,
    detections_layout: DetectionsLayout,
    pose_path: Path | None,
    pose_format: PoseFormat,
    classes: Sequence[str],
    with_gt: bool,
    num_frames: int | None,
    label_path: Path,
    skipped: SkippedRows | None = None,
) -> tuple[list[Frame], list[Frame] | None]:
    """Detections and (when labelled) ground truth of one sequence."""
    calib = read_kitti_calib(split_dir / "calib" / f"{seq}.txt")
    if pose_path is not None and not pose_path.is_file():
        raise FileNotFoundError(f"pose file {pose_path} not found (--poses none: no poses)")
    poses = None if pose_path is None else read_kitti_poses(pose_path)

    layout, source = _detection_sources(detections_dir, seq, detections_layout, classes)
    if isinstance(source, Path):
        if layout == "kitti_tracking":
            dets, det_frames = read_kitti_tracking_detections(source), 0
        else:
            dets, det_frames = read_kitti_object_detections(source)
        det_where = str(source)
    else:
        dets, det_frames = read_ab3dmot_detections(source), 0
        det_where = (
            ", ".join(map(str, source)) or f"{detections_dir} (no <Class>/{seq}.txt of them)"
        )
    # how far the file's rows reach, every class's: only where one file holds them all (a
    # per-class file of a class seen early would read as a short sequence)
    every_class = isinstance(source, Path) or source == [detections_dir / f"{seq}.txt"]
    read_up_to = max(det_frames, int(dets.frame.max(initial=-1)) + 1) if every_class else 0
    tracked = np.isin(dets.category, [category_index(c) for c in classes])
    if skipped is not None and not tracked.all():
        cats, counts = np.unique(dets.category[~tracked], return_counts=True)
        for cat, count in zip(cats.tolist(), counts.tolist(), strict=True):
            if cat >= 0:
                skipped.not_tracked[CATEGORIES[cat]] += count
        unknown = (dets.category < 0) & (dets.type_name != DONTCARE)
        names, counts = np.unique(dets.type_name[unknown], return_counts=True)
        skipped.unknown.update(dict(zip(map(str, names), counts.tolist(), strict=True)))
    dets = _without_duplicates(dets.select(tracked), seq, skipped)
    if not len(dets):
        LOG.warning("%s: no %s detections in %s", seq, " or ".join(classes), det_where)
    labels = read_kitti_labels(label_path) if with_gt and label_path.is_file() else None
    # without poses, the labels (read for their length alone if need be) say how long a
    # sequence is whose last frames hold no detection: its evaluation needs every frame
    length_labels = labels
    if length_labels is None and pose_path is None and label_path.is_file():
        try:
            length_labels = read_kitti_labels(label_path)
        except InputError as err:  # (not evaluated in this run: the length is a courtesy)
            LOG.warning("%s: length from the detections alone (%s)", seq, err)

    # Length: explicit > pose lines > largest frame index seen + 1.
    seen = max(
        det_frames,
        int(dets.frame.max(initial=-1)) + 1,
        int(length_labels.frame.max(initial=-1)) + 1 if length_labels is not None else 0,
    )
    if num_frames is not None:
        n = int(num_frames)
        if poses is not None and n > len(poses):
            raise InputError(
                f"num_frames={n} but only {len(poses)} poses", path=pose_path, field="frame"
            )
    elif poses is not None:
        n = len(poses)
        # (a detector may miss a sequence's last frames, not half of it)
        if 0 < read_up_to and n - read_up_to > max(10, read_up_to):
            LOG.warning(
                "%s: %s has %d poses, but the last detection is at frame %d: the poses of "
                "another sequence?", seq, pose_path, n, read_up_to - 1,
            )  # fmt: skip
        for objects, where in ((dets, det_where), (labels, str(label_path))):
            if objects is not None and objects.frame.max(initial=-1) >= n:
                row = int(np.argmax(objects.frame))
                path, line = objects.where(row)
                raise InputError(
                    f"frame {objects.frame[row]} is beyond the {n} poses of {pose_path}",
                    path=where if path is None else path,
                    line=line,
                    field="frame",
                )
    else:
        n = seen
    if seen > n:
        LOG.warning("%s: dropping rows at frames >= num_frames=%d", seq, n)
        dets = dets.select(dets.frame < n)
        labels = None if labels is None else labels.select(labels.frame < n)

    world_from_rect = world_from_rect_poses(calib, poses, pose_format=pose_format, num_frames=n)
    camera_from_world = np.linalg.inv(world_from_rect)
    image_from_rect = calib.image_from_rect.copy()
    for shared in (world_from_rect, camera_from_world, image_from_rect):
        shared.flags.writeable = False  # every Frame and Camera holds views of these
    width_px, height_px = image_size_px(calib, split_dir / "image_02" / seq)
    cameras = [
        Camera(CAMERA_NAME, image_from_rect, camera_from_world[i], width_px, height_px)
        for i in range(n)
    ]
    det_frames_out = _frames_from_objects(
        seq,
        dets,
        num_frames=n,
        world_from_rect=world_from_rect,
        cameras=cameras,
        score=_sigmoid(dets.score_raw),
    )
    LOG.debug("%s: %d frames, %d %s detections", seq, n, len(dets), layout)
    if labels is None:
        return det_frames_out, None
    objects = labels.select(labels.category >= 0)
    gt_frames = _frames_from_objects(
        seq,
        objects,
        num_frames=n,
        world_from_rect=world_from_rect,
        cameras=cameras,
        score=np.ones(len(objects)),
        ignore=labels.select(labels.type_name == DONTCARE),
        velocity=np.full((len(objects), 2), np.nan),  # not annotated: unknown, not 0 (standing)
    )
    return det_frames_out, gt_frames
