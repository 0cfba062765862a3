"""The live tracks, stored as one structure of arrays (rows = tracks).

Keeping every track's filters stacked lets one numpy call predict or update all of them;
per-track objects would cost a Python loop per stage and cap the tracker far below 1500 frames/s.
Rows are kept sorted by ``track_id`` (births get increasing ids and are appended).

The pose, size and heading filters are stored per axis (:mod:`tracker.kalman` fast path):
``motion_x (T, 5, k)``, ``motion_P (T, 5, k, k)`` for the axes x, y, l, w, θ, with k = 2
([value, rate], constant velocity) or 3 (with acceleration, when a category uses CA).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.kalman import N_AXES, Axis
from tracker.velocity_baselines import WINDOW, latest_velocities


@dataclass(slots=True)
class TrackTable:
    track_id: IntArray  # (T,)
    category: IntArray  # (T,)
    status: np.ndarray  # (T,) int8 TrackStatus
    hits: IntArray  # (T,) matched detections so far
    misses: IntArray  # (T,) consecutive misses
    age: IntArray  # (T,) frames since birth
    motion_x: FloatArray  # (T, 5, k) axes x, y, l, w, θ: [value, rate(, acceleration)]
    motion_P: FloatArray  # (T, 5, k, k)
    score: FloatArray  # (T,) last detection score
    last_xyxy: FloatArray  # (T, 4) last detection's 2D box (reference RV stage)
    last_camera: IntArray  # (T,)
    last_det_xyz: FloatArray  # (T, 3) last detection's centre
    last_det_lwh: FloatArray  # (T, 3)
    zh: FloatArray  # (T, 2) the track's z and height (smoothed detection values)
    last_det_yaw: FloatArray  # (T,)
    heading_votes: IntArray  # (T,) consecutive detections whose yaw disagrees by > 90°
    evidence: FloatArray  # (T,) sum over hits of -log(1 - score): 1 - exp(-e) = noisy-OR
    log_odds: FloatArray  # (T,) sum over hits of log(score / (1 - score)); / hits = the mean
    matched_det: IntArray  # (T,) this frame's matched detection row (-1: none)
    matched_stage: np.ndarray  # (T,) int8: 1 BEV, 2 RV, 0 none (births: 0)
    det_t: FloatArray  # (T, W) the last W detections' times, oldest first (NaN: fewer yet)
    det_xy: FloatArray  # (T, W, 2) and their centres (the velocity baselines' input)
    baseline: FloatArray  # (T, 2, 2) difference and curve-fit velocity at the last detection

    @classmethod
    def empty(cls, *, order: int = 2) -> TrackTable:
        """No track; ``order`` k is the number of states per filter axis (2 CV, 3 CA)."""
        shapes: dict[str, tuple[tuple[int, ...], Any]] = {
            "track_id": ((0,), np.int64),
            "category": ((0,), np.int64),
            "status": ((0,), np.int8),
            "hits": ((0,), np.int64),
            "misses": ((0,), np.int64),
            "age": ((0,), np.int64),
            "motion_x": ((0, N_AXES, order), np.float64),
            "motion_P": ((0, N_AXES, order, order), np.float64),
            "score": ((0,), np.float64),
            "last_xyxy": ((0, 4), np.float64),
            "last_camera": ((0,), np.int64),
            "last_det_xyz": ((0, 3), np.float64),
            "last_det_lwh": ((0, 3), np.float64),
            "zh": ((0, 2), np.float64),
            "last_det_yaw": ((0,), np.float64),
            "heading_votes": ((0,), np.int64),
            "evidence": ((0,), np.float64),
            "log_odds": ((0,), np.float64),
            "matched_det": ((0,), np.int64),
            "matched_stage": ((0,), np.int8),
            "det_t": ((0, WINDOW), np.float64),
            "det_xy": ((0, WINDOW, 2), np.float64),
            "baseline": ((0, 2, 2), np.float64),
        }
        return cls(**{k: np.zeros(shape, dtype=dt) for k, (shape, dt) in shapes.items()})

    def __len__(self) -> int:
        return len(self.track_id)

    def select(self, index: Any) -> TrackTable:
        return TrackTable(*[getattr(self, name)[index] for name in _FIELDS])

    def append(self, other: TrackTable) -> TrackTable:
        if len(other) == 0:
            return self
        return TrackTable(
            *[np.concatenate([getattr(self, name), getattr(other, name)]) for name in _FIELDS]
        )

    def record_matches(self, rows: IntArray, det_rows: IntArray, stage: np.ndarray) -> None:
        """This frame's match of each track: detection row (-1 none) and stage (0 none)."""
        self.matched_det = np.full(len(self), -1, dtype=np.int64)
        self.matched_det[rows] = det_rows
        self.matched_stage = np.zeros(len(self), dtype=np.int8)
        self.matched_stage[rows] = stage

    def record_detections(self, rows: IntArray, time_secs: float, xy: FloatArray) -> None:
        """Tracks ``rows`` took detections centred at ``xy`` (R, 2) at ``time_secs``: their
        detection windows move on and their velocity baselines are recomputed."""
        self.det_t[rows] = np.column_stack([self.det_t[rows, 1:], np.full(len(rows), time_secs)])
        self.det_xy[rows] = np.concatenate([self.det_xy[rows, 1:], xy[:, None, :]], axis=1)
        self.baseline[rows] = np.stack(latest_velocities(self.det_t[rows], self.det_xy[rows]), 1)

    def xyz(self, rows: IntArray) -> FloatArray:
        """(R, 3) current box centres of the tracks ``rows`` (filtered x, y; smoothed z)."""
        xyz = np.empty((len(rows), 3))
        xyz[:, :2] = self.motion_x[rows, Axis.X : Axis.Y + 1, 0]
        xyz[:, 2] = self.zh[rows, 0]
        return xyz

    def boxes(self, rows: IntArray | None = None) -> Boxes:
        """The tracks' current (filtered or predicted) boxes, with ids and velocities.

        ``rows`` selects tracks (default: all), as ``boxes()[rows]`` would, without the copy.
        """
        x = self.motion_x if rows is None else self.motion_x[rows]
        n = len(x)
        xyz, lwh = np.empty((n, 3)), np.empty((n, 3))
        xyz[:, :2] = x[:, Axis.X : Axis.Y + 1, 0]
        lwh[:, :2] = x[:, Axis.LENGTH : Axis.WIDTH + 1, 0]
        if rows is None:
            xyz[:, 2], lwh[:, 2] = self.zh[:, 0], self.zh[:, 1]
            score, category = self.score.copy(), self.category.copy()
            xyxy, camera = self.last_xyxy.copy(), self.last_camera.copy()
            track_id = self.track_id.copy()
        else:
            zh = self.zh[rows]
            xyz[:, 2], lwh[:, 2] = zh[:, 0], zh[:, 1]
            score, category = self.score[rows], self.category[rows]
            xyxy, camera = self.last_xyxy[rows], self.last_camera[rows]
            track_id = self.track_id[rows]
        return Boxes._trusted(
            {
                "xyz": xyz,
                "lwh": lwh,
                "yaw": x[:, Axis.YAW, 0].copy(),
                "velocity": x[:, Axis.X : Axis.Y + 1, 1].copy(),
                "score": score,
                "category": category,
                "xyxy_image": xyxy,
                "camera": camera,
                "track_id": track_id,
                "score_raw": np.full(n, np.nan),
            }
        )


_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(TrackTable))
