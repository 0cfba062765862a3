"""The live tracks, stored as one structure of arrays (rows = tracks).

Keeping every track's three filters stacked lets one numpy call predict or update all of them;
per-track objects would cost a Python loop per stage and cap the tracker far below 1500 frames/s.
Rows are kept sorted by ``track_id`` (births get increasing ids and are appended).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from tracker.boxes import Boxes, FloatArray, IntArray

POSE_DIM = 6  # [x, y, vx, vy, ax, ay]; constant velocity = zero acceleration variance


@dataclass(slots=True)
class TrackTable:
    track_id: IntArray  # (T,)
    category: IntArray  # (T,)
    status: np.ndarray  # (T,) int8 TrackStatus
    hits: IntArray  # (T,) matched detections so far
    misses: IntArray  # (T,) consecutive misses
    age: IntArray  # (T,) frames since birth
    pose_x: FloatArray  # (T, 6)
    pose_P: FloatArray  # (T, 6, 6)
    size_x: FloatArray  # (T, 4) [l, w, vl, vw]
    size_P: FloatArray  # (T, 4, 4)
    head_x: FloatArray  # (T, 2) [theta, omega]
    head_P: FloatArray  # (T, 2, 2)
    z: FloatArray  # (T,) centre height of the last detection
    height: FloatArray  # (T,) box height of the last detection
    score: FloatArray  # (T,) last detection score
    logit_sum: FloatArray  # (T,) sum of detection logits (offline track score)
    last_xyxy: FloatArray  # (T, 4) last detection's 2D box (reference RV stage)
    last_camera: IntArray  # (T,)
    last_det_xyz: FloatArray  # (T, 3) last detection's centre (reference RV gate)
    last_det_lwh: FloatArray  # (T, 3)
    last_det_yaw: FloatArray  # (T,)
    heading_votes: IntArray  # (T,) consecutive detections whose yaw disagrees by > 90°
    matched_det: IntArray  # (T,) this frame's matched detection row (-1: none)
    matched_stage: np.ndarray  # (T,) int8: 1 BEV, 2 RV, 0 none (births: 0)

    @classmethod
    def empty(cls) -> TrackTable:
        shapes: dict[str, tuple[tuple[int, ...], Any]] = {
            "track_id": ((0,), np.int64),
            "category": ((0,), np.int64),
            "status": ((0,), np.int8),
            "hits": ((0,), np.int64),
            "misses": ((0,), np.int64),
            "age": ((0,), np.int64),
            "pose_x": ((0, POSE_DIM), np.float64),
            "pose_P": ((0, POSE_DIM, POSE_DIM), np.float64),
            "size_x": ((0, 4), np.float64),
            "size_P": ((0, 4, 4), np.float64),
            "head_x": ((0, 2), np.float64),
            "head_P": ((0, 2, 2), np.float64),
            "z": ((0,), np.float64),
            "height": ((0,), np.float64),
            "score": ((0,), np.float64),
            "logit_sum": ((0,), np.float64),
            "last_xyxy": ((0, 4), np.float64),
            "last_camera": ((0,), np.int64),
            "last_det_xyz": ((0, 3), np.float64),
            "last_det_lwh": ((0, 3), np.float64),
            "last_det_yaw": ((0,), np.float64),
            "heading_votes": ((0,), np.int64),
            "matched_det": ((0,), np.int64),
            "matched_stage": ((0,), np.int8),
        }
        return cls(**{k: np.zeros(shape, dtype=dt) for k, (shape, dt) in shapes.items()})

    def __len__(self) -> int:
        return len(self.track_id)

    def select(self, index: Any) -> TrackTable:
        return TrackTable(**{f.name: getattr(self, f.name)[index] for f in fields(self)})

    def append(self, other: TrackTable) -> TrackTable:
        if len(other) == 0:
            return self
        return TrackTable(
            **{
                f.name: np.concatenate([getattr(self, f.name), getattr(other, f.name)])
                for f in fields(self)
            }
        )

    def boxes(self) -> Boxes:
        """The tracks' current (filtered or predicted) boxes, with ids and velocities."""
        return Boxes._trusted(
            {
                "xyz": np.column_stack([self.pose_x[:, 0], self.pose_x[:, 1], self.z]),
                "lwh": np.column_stack([self.size_x[:, 0], self.size_x[:, 1], self.height]),
                "yaw": self.head_x[:, 0].copy(),
                "velocity": self.pose_x[:, 2:4].copy(),
                "score": self.score.copy(),
                "category": self.category.copy(),
                "xyxy_image": self.last_xyxy.copy(),
                "camera": self.last_camera.copy(),
                "track_id": self.track_id.copy(),
                "score_raw": np.full(len(self), np.nan),
            }
        )


_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(TrackTable))
