"""Stage events: how the tracker is observed without depending on a viewer.

``MCTracker(config, observer=...)`` calls ``observer(event)`` once per stage with one of the
small frozen dataclasses below. They hold arrays the tracker computed anyway (no copies). With
the default ``observer=None`` no event is even built, so observing costs nothing when unused.
"""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.frame import Frame


class Stage(enum.Enum):
    BEV = "bev"  # stage 1: bird's-eye-view plane, Ro_GDIoU, Hungarian
    RV = "rv"  # stage 2: image plane, SDIoU, greedy


class DropReason(enum.IntEnum):
    KEPT = 0
    CATEGORY = 1  # not a tracked category
    SCORE = 2  # score <= the category's score_min
    NMS = 3  # suppressed by class-aware BEV NMS


class TrackStatus(enum.IntEnum):
    TENTATIVE = 0  # born, not yet confirmed (fewer than min_hits)
    CONFIRMED = 1  # matched recently: output
    COASTING = 2  # missed, still output for up to max_misses_output frames
    LOST = 3  # missed longer: kept for re-acquisition, not output
    DELETED = 4


@dataclass(frozen=True, slots=True)
class FrameStarted:
    frame: Frame
    time_secs: float


@dataclass(frozen=True, slots=True)
class DetectionsFiltered:
    """``reason[i]`` tells why detection row i was dropped (``KEPT`` for kept rows)."""

    frame: Frame
    reason: NDArray[np.int8]
    kept_rows: IntArray


@dataclass(frozen=True, slots=True)
class Predicted:
    """Every live track predicted to the frame's time (rows aligned with ``track_ids``)."""

    track_ids: IntArray
    boxes: Boxes
    status: NDArray[np.int8]


@dataclass(frozen=True, slots=True)
class CostComputed:
    """One stage's cost matrix (rows: tracks, columns: detection rows of the frame).

    ``cost`` is 1 - similarity (+inf where not comparable: other category, gated out, no
    camera); a pair is accepted only if ``cost <= max_cost_per_row``. For the RV stage
    ``track_xyxy`` holds the tracks' 2D boxes used (projected, or the reference's stale ones)
    and ``camera`` the camera index per row (-1 when the track is not in view).
    """

    stage: Stage
    cost: FloatArray
    track_ids: IntArray
    det_rows: IntArray
    max_cost_per_row: FloatArray
    track_xyxy: FloatArray | None = None
    camera: IntArray | None = None


@dataclass(frozen=True, slots=True)
class ImageStageDeferred:
    """Stage 2 (RV) left uncomputed on a frame where it can match nothing: no leftover pair of
    one category is within its yaw and distance gate (exact, the shortcut of a plain run).

    Emitted instead of its ``CostComputed`` and ``Matched`` only to an observer whose
    ``rv_costs_deferred`` is True: it computes the same matrix later, for many frames at once,
    with :func:`tracker.image_stage.deferred_image_stage`. The inputs: ``track_rows`` index
    this frame's ``Predicted`` arrays (the leftover tracks), ``det_rows`` the frame's
    detections; per track row the cost threshold and the gates; the greedy order.
    """

    track_rows: IntArray
    det_rows: IntArray
    max_cost_per_row: FloatArray
    yaw_gate_rad: FloatArray
    distance_gate_m: FloatArray
    greedy_order: str


@dataclass(frozen=True, slots=True)
class Matched:
    """Accepted pairs of a stage: ``track_ids[k]`` took detection row ``det_rows[k]``.

    ``rejected_*`` are RV pairs that passed the cost threshold but failed the yaw/distance gate.
    """

    stage: Stage
    track_ids: IntArray
    det_rows: IntArray
    costs: FloatArray
    rejected_track_ids: IntArray
    rejected_det_rows: IntArray


@dataclass(frozen=True, slots=True)
class LifecycleChanged:
    """Track ids whose status changed this frame (each array sorted).

    ``born_det_rows[k]`` is the detection row (of the frame) that started track ``born[k]``.
    """

    born: IntArray
    confirmed: IntArray
    lost: IntArray
    reacquired: IntArray
    deleted: IntArray
    born_det_rows: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


@dataclass(frozen=True, slots=True)
class TrackOutput:
    """The tracker's output for one frame, rows sorted by track id.

    ``boxes`` holds filtered position (``xyz``), size, heading (``yaw``), velocity, score,
    category and ``track_id``; ``acceleration`` (K, 2) m/s² (NaN for a category tracked with
    the constant-velocity model, which has none); ``status`` (K,) TrackStatus;
    ``det_row`` (K,) the detection row matched this frame (-1 when coasting or interpolated);
    ``stage`` (K,) 1 = BEV, 2 = RV, 0 = none; ``baselines`` (K, 2, 2) the paper's difference
    ``[:, 0]`` and curve-fit ``[:, 1]`` velocities (m/s, world) over the track's latest
    detections, tentative ones included (:mod:`tracker.velocity_baselines`), NaN where the row
    has no detection, or None: not computed (the motion evaluation then takes them from the
    output's own detection rows).
    """

    scene: str
    frame_id: int
    time_secs: float
    boxes: Boxes
    acceleration: FloatArray
    status: NDArray[np.int8]
    det_row: IntArray
    stage: NDArray[np.int8]
    baselines: FloatArray | None = None

    def __len__(self) -> int:
        return len(self.boxes)

    def select(self, keep: NDArray[np.bool_] | IntArray) -> TrackOutput:
        """The rows ``keep`` (a mask or indices) of every per-row field."""
        return dataclasses.replace(
            self,
            boxes=self.boxes[keep],
            acceleration=self.acceleration[keep],
            status=self.status[keep],
            det_row=self.det_row[keep],
            stage=self.stage[keep],
            baselines=None if self.baselines is None else self.baselines[keep],
        )


@dataclass(frozen=True, slots=True)
class NoiseEstimated:
    """Per global category id: the detections' centre variance estimated so far
    (:mod:`tracker.noise`; NaN until it exists) and the x and y measurement variance the
    position filter uses, m², only for categories with ``pose.r_scale`` (NaN elsewhere); and the
    radius of the BEV distance gate in effect, m, only for categories with ``bev.gate_motion_m``
    (NaN elsewhere)."""

    variance: FloatArray
    r: FloatArray
    gate_m: FloatArray


@dataclass(frozen=True, slots=True)
class FrameFinished:
    output: TrackOutput


Event = (
    FrameStarted
    | DetectionsFiltered
    | Predicted
    | CostComputed
    | ImageStageDeferred
    | Matched
    | LifecycleChanged
    | NoiseEstimated
    | FrameFinished
)


class Observer(Protocol):
    def __call__(self, event: Event) -> None: ...


class ListObserver:
    """Keeps every event (tests, offline analysis)."""

    def __init__(self) -> None:
        self.events: list[Event] = []

    def __call__(self, event: Event) -> None:
        self.events.append(event)

    def of_type(self, kind: type) -> list[Event]:
        return [e for e in self.events if isinstance(e, kind)]
