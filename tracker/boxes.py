"""Boxes: a batch of oriented 3D boxes stored as a structure of arrays.

Detections, ground truth and stacked track predictions all use this one type, so every pairwise
cost is ``f(tracks: Boxes, dets: Boxes) -> (M, N)`` and every visualisation call logs one batch.

Conventions (see docs/baseversion.md): world frame, z up, metres, seconds, radians.
``xyz`` is the geometric box centre; ``lwh`` is (length along the heading, width, height);
``yaw`` is the heading about +z, counter-clockwise from +x, wrapped to (-pi, pi].
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True, slots=True, eq=False)
class Boxes:
    """N oriented 3D boxes in the world frame.

    Missing values are NaN (floats) or -1 (ints); no field is ever ``None``.

    Attributes
    ----------
    xyz : (N, 3) geometric centre, metres.
    lwh : (N, 3) length, width, height, metres.
    yaw : (N,) heading about +z, radians in (-pi, pi].
    velocity : (N, 2) world-frame vx, vy in m/s (0 when the source has none; NaN rows: the
        detector gave no estimate, which the tracker does not measure).
    score : (N,) calibrated confidence in [0, 1].
    category : (N,) index into :data:`tracker.categories.CATEGORIES`.
    xyxy_image : (N, 4) 2D box in pixels of ``camera`` (NaN when absent).
    camera : (N,) index into the frame's camera list, -1 when the box is in no camera.
    track_id : (N,) identity for ground truth and tracker output, -1 for detections.
    score_raw : (N,) the detector's own score before calibration (NaN when unknown).
    """

    xyz: FloatArray
    lwh: FloatArray
    yaw: FloatArray
    velocity: FloatArray
    score: FloatArray
    category: IntArray
    xyxy_image: FloatArray
    camera: IntArray
    track_id: IntArray
    score_raw: FloatArray

    def __post_init__(self) -> None:
        n = len(self.yaw)
        shapes = {
            "xyz": (n, 3),
            "lwh": (n, 3),
            "yaw": (n,),
            "velocity": (n, 2),
            "score": (n,),
            "category": (n,),
            "xyxy_image": (n, 4),
            "camera": (n,),
            "track_id": (n,),
            "score_raw": (n,),
        }
        for name, shape in shapes.items():
            arr = getattr(self, name)
            if not isinstance(arr, np.ndarray) or arr.shape != shape:
                got = getattr(arr, "shape", type(arr).__name__)
                raise ValueError(f"Boxes.{name}: expected shape {shape}, got {got}")
            if arr.flags.writeable:
                arr = arr.view()
                arr.flags.writeable = False
                object.__setattr__(self, name, arr)

    @classmethod
    def create(
        cls,
        *,
        xyz: Any,
        lwh: Any,
        yaw: Any,
        category: Any,
        score: Any = None,
        velocity: Any = None,
        xyxy_image: Any = None,
        camera: Any = None,
        track_id: Any = None,
        score_raw: Any = None,
    ) -> Boxes:
        """Build from array-likes, filling absent optional fields with their 'missing' value."""
        xyz_arr = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        n = len(xyz_arr)

        def floats(value: Any, shape: tuple[int, ...], fill: float) -> FloatArray:
            if value is None:
                return np.full(shape, fill, dtype=np.float64)
            return np.asarray(value, dtype=np.float64).reshape(shape)

        def ints(value: Any, fill: int) -> IntArray:
            if value is None:
                return np.full(n, fill, dtype=np.int64)
            return np.asarray(value, dtype=np.int64).reshape(n)

        return cls(
            xyz=xyz_arr,
            lwh=floats(lwh, (n, 3), np.nan),
            yaw=floats(yaw, (n,), np.nan),
            velocity=floats(velocity, (n, 2), 0.0),
            score=floats(score, (n,), 1.0),
            category=ints(category, -1),
            xyxy_image=floats(xyxy_image, (n, 4), np.nan),
            camera=ints(camera, -1),
            track_id=ints(track_id, -1),
            score_raw=floats(score_raw, (n,), np.nan),
        )

    @classmethod
    def _trusted(cls, values: dict[str, Any]) -> Boxes:
        """Internal fast path for arrays derived from valid Boxes (hot loops): no shape checks,
        but still read-only. Validation happens where data enters (``__init__``/``create``)."""
        out = object.__new__(cls)
        for name, arr in values.items():
            arr.setflags(write=False)
            object.__setattr__(out, name, arr)
        return out

    @classmethod
    def empty(cls) -> Boxes:
        return cls.create(xyz=np.zeros((0, 3)), lwh=np.zeros((0, 3)), yaw=[], category=[])

    @classmethod
    def concat(cls, parts: list[Boxes]) -> Boxes:
        if not parts:
            return cls.empty()
        return cls(
            **{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)}
        )

    def __len__(self) -> int:
        return len(self.yaw)

    def __getitem__(self, index: Any) -> Boxes:
        """Rows selected by a boolean mask, an index array or a slice (a new batch, never a
        view of this one; rows keep order)."""
        if isinstance(index, slice):  # (np.asarray(slice) is an object array numpy refuses)
            index = np.arange(len(self))[index]
        if not isinstance(index, np.ndarray) or index.ndim == 0:
            index = np.asarray(index).reshape(-1) if np.ndim(index) == 0 else np.asarray(index)
        return Boxes._trusted({name: getattr(self, name)[index] for name in _FIELDS})

    def replace(self, **changes: Any) -> Boxes:
        values = {name: getattr(self, name) for name in _FIELDS}
        values.update({k: np.asarray(v) for k, v in changes.items()})
        return Boxes(**values)

    def equals(self, other: Boxes) -> bool:
        """Exact equality of every array (NaN equals NaN)."""
        return all(
            np.array_equal(getattr(self, f.name), getattr(other, f.name), equal_nan=True)
            if getattr(self, f.name).dtype.kind == "f"
            else np.array_equal(getattr(self, f.name), getattr(other, f.name))
            for f in fields(self)
        )


_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(Boxes))
