"""MCTracker: one ``step(frame)`` per frame, in the order of the paper's pipeline (Fig. 2).

    preprocess -> predict -> stage 1 (BEV, Ro_GDIoU, Hungarian)
               -> stage 2 (image plane, SDIoU, greedy) -> update -> lifecycle -> output

Where we differ from the reference code (docs/differences.md): real dt from timestamps, every
filter advances on misses, wrapped angles, per-track (not ``trajs[0]``) cost settings, tracks
projected into the image for stage 2, gated-out detections start tracks, optional tentative
state, and the filtered acceleration in the output.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from types import SimpleNamespace

import numpy as np

from tracker import kalman
from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.calibration import score_log_odds
from tracker.camera import NEAR_PLANE_M, in_image_fraction, project_boxes
from tracker.categories import CATEGORIES
from tracker.config import (
    CategoryConfig,
    CostKind,
    CostState,
    MotionModel,
    OutputGeometry,
    TrackerConfig,
    TrackingMode,
)
from tracker.cost import (
    back_predict,
    bev_array,
    iou_bev,
    ro_gdiou_bev,
    ro_gdiou_bev_arrays,
    sdiou_image,
)
from tracker.errors import InputError
from tracker.events import (
    CostComputed,
    DetectionsFiltered,
    DropReason,
    Event,
    FrameFinished,
    FrameStarted,
    ImageStageDeferred,
    LifecycleChanged,
    Matched,
    NoiseEstimated,
    Observer,
    Predicted,
    Stage,
    TrackOutput,
    TrackStatus,
)
from tracker.frame import Camera, Frame
from tracker.geometry import prepare_kernels, wrap_angle
from tracker.kalman import Axis
from tracker.kernels import load as load_kernels
from tracker.matching import Matches, greedy, hungarian
from tracker.noise import PositionNoise
from tracker.track import TrackTable
from tracker.velocity_baselines import WINDOW

_EMPTY_INT = np.zeros(0, dtype=np.int64)
HEADING_FLIP_VOTES = 3  # consecutive detections disagreeing by > 90° that flip a static track
# bev.gate_motion_m's allowance for a detection's own error, in standard deviations of the
# scene's estimated centre noise (per axis): a normal error's 2D distance exceeds 4σ with
# probability e^(-4²/2) = 0.03 %
GATE_NOISE_SIGMAS = 4.0
# TrackStatus values as plain ints: comparing an int8 array with an IntEnum member is slower
_TENTATIVE, _CONFIRMED = int(TrackStatus.TENTATIVE), int(TrackStatus.CONFIRMED)
_COASTING, _LOST = int(TrackStatus.COASTING), int(TrackStatus.LOST)
# lookups by status: output (confirmed, coasting), re-acquired on a hit (coasting, lost)
_IS_OUTPUT = np.isin(np.arange(len(TrackStatus)), [_CONFIRMED, _COASTING])
_IS_REACQUIRED = np.isin(np.arange(len(TrackStatus)), [_COASTING, _LOST])


class _PerCategory:
    """Config values as arrays indexed by global category id (vectorised lookups)."""

    def __init__(self, config: TrackerConfig) -> None:
        n = len(CATEGORIES)
        self.tracked = np.zeros(n, dtype=bool)
        self.tracked[list(config.category_ids)] = True
        default = CategoryConfig()
        cfgs = [config.per_category.get(name, default) for name in CATEGORIES]

        def arr(get: Callable[[CategoryConfig], float]) -> FloatArray:
            return np.array([get(c) for c in cfgs], dtype=np.float64)

        self.score_min = arr(lambda c: c.score_min)
        self.score_min_tracked = np.where(self.tracked, self.score_min, np.inf)
        self.birth_score_min = arr(lambda c: max(c.score_min, c.birth_score_min))
        self.nms_iou_max = arr(lambda c: c.nms_iou_max)
        weights = {
            CostKind.IOU: lambda c: (0.0, 0.0),
            CostKind.GIOU: lambda c: (1.0, 0.0),
            CostKind.DIOU: lambda c: (0.0, 1.0),
            CostKind.RO_GDIOU: lambda c: (c.bev.w1, c.bev.w2),
        }
        self.w1 = arr(lambda c: weights[c.bev.cost](c)[0])
        self.w2 = arr(lambda c: weights[c.bev.cost](c)[1])
        # forward-prediction weight of the cost: Predict 1, BackPredict 0, Fusion alpha
        self.alpha = arr(
            lambda c: {
                CostState.PREDICT: 1.0,
                CostState.BACK_PREDICT: 0.0,
                CostState.FUSION: c.bev.alpha,
            }[c.bev.cost_state]
        )
        self.bev_cost_max = arr(lambda c: c.bev.cost_max)
        self.gate_m = arr(lambda c: c.bev.gate_distance_m)
        self.gate_sq = self.gate_m**2
        # the distance gate that follows the detections' noise (bev.gate_motion_m)
        self.gate_motion_sq = (
            np.where(self.tracked, arr(lambda c: c.bev.gate_motion_m), np.inf) ** 2
        )
        self.any_motion_gate = bool(np.any(np.isfinite(self.gate_motion_sq)))
        # the cost's factors of a BEV box [x, y, l, w, yaw]: l and w grown by 1 + 2 buffer
        scale = 1.0 + 2.0 * arr(lambda c: c.bev.buffer)
        self.buffer_lw = np.ones((n, 5))
        self.buffer_lw[:, 2:4] = scale[:, None]
        self.any_buffer = bool(np.any(scale[self.tracked] != 1.0))
        self.rv_cost_max = arr(lambda c: c.rv.cost_max)
        self.rv_yaw_gate = np.deg2rad(arr(lambda c: c.rv.yaw_gate_deg))
        self.rv_distance_gate = arr(lambda c: c.rv.distance_gate_m)
        # the stage-2 shortcut's yaw gate, wider by 1 nrad than the real gate's
        self.rv_yaw_gate_loose = self.rv_yaw_gate + 1e-9
        self.rv_gate_within_bev_gate = self.rv_within(self.rv_distance_gate, self.gate_sq)
        self.min_hits = arr(lambda c: c.lifecycle.min_hits)
        self.confirm_score = arr(lambda c: c.lifecycle.confirm_score)
        self.max_misses_tentative = arr(lambda c: c.lifecycle.max_misses_tentative)
        self.max_misses_output = arr(lambda c: c.lifecycle.max_misses_output)
        self.coast_min_hits = arr(lambda c: c.lifecycle.coast_min_hits)
        self.max_misses = arr(lambda c: c.lifecycle.max_misses)
        self.vertical_gain = arr(lambda c: c.vertical_gain)
        self.any_vertical_smoothing = bool(np.any(self.vertical_gain[self.tracked] < 1.0))
        with np.errstate(divide="ignore"):  # confirm_prob 1: an infinite threshold (never)
            self.confirm_evidence = -np.log1p(-arr(lambda c: c.lifecycle.confirm_prob))
        # the lifecycle thresholds per category, gathered once per frame
        self.lifecycle = np.column_stack(
            [
                self.min_hits,
                self.confirm_score,
                self.max_misses_output,
                self.max_misses,
                self.max_misses_tentative,
                self.confirm_evidence,
                self.coast_min_hits,
            ]
        )
        # the online output gate on a track's mean log-odds (-inf: off)
        self.track_score_min = arr(lambda c: c.lifecycle.track_score_min)
        self.any_track_score_gate = bool(np.any(np.isfinite(self.track_score_min[self.tracked])))
        self.measure_velocity = np.array([c.pose.measure_velocity for c in cfgs])
        self.head_min_speed = arr(lambda c: c.heading.min_speed_mps)
        # Whole-config switches, so the per-frame path skips work no tracked category needs.
        tracked = self.tracked
        self.any_measure_velocity = bool(np.any(self.measure_velocity[tracked]))
        self.any_back_prediction = bool(np.any(self.alpha[tracked] < 1))
        self.all_forward = bool(np.all(self.alpha[tracked] >= 1))
        # CA (k = 3) for every track as soon as one tracked category uses it: CV is CA with a
        # zero acceleration variance (exact), so one table holds both.
        # acceleration is estimated (CA) or absent (CV: reported as NaN, not as a fake 0)
        self.has_acceleration = np.array([c.pose.motion is MotionModel.CA for c in cfgs])
        self.any_cv = not bool(np.all(self.has_acceleration[tracked]))
        any_ca = bool(np.any(self.has_acceleration[tracked]))
        self.motion_model = kalman.MotionModel.CA if any_ca else kalman.MotionModel.CV
        noise = kalman.DiagonalNoise.stack([self._motion_noise(c) for c in cfgs])
        self.motion_p0, self.motion_q, self.motion_r = noise.p0_diag, noise.q_diag, noise.r_diag
        # r of x and y from the detections' estimated noise (tracker.noise) where > 0
        self.r_scale = np.where(self.tracked, arr(lambda c: c.pose.r_scale), 0.0)
        self.any_r_scale = bool(np.any(self.r_scale > 0))
        self.follows_noise = self.any_r_scale or self.any_motion_gate

    def rv_within(self, rv_gate: FloatArray, gate_sq: FloatArray) -> bool:
        """Whether stage 2's distance gate ``rv_gate`` (m) lies inside the BEV gate ``gate_sq``
        (squared), per category, for every tracked category (stage 2's shortcut relies on it)."""
        t = self.tracked
        return bool(np.all(rv_gate[t] < np.sqrt(gate_sq[t]) * (1 - 1e-9)))

    def _motion_noise(self, c: CategoryConfig) -> kalman.DiagonalNoise:
        """Per-axis P0/Q/R (5, k) of one category for the tracker's motion model."""
        k = self.motion_model.order
        pose = c.pose.ca if c.pose.motion is MotionModel.CA else c.pose.cv
        p0, q = np.zeros(2 * k), np.zeros(2 * k)  # a CV pose in a CA table: no acceleration
        p0[: len(pose.p)], q[: len(pose.q)] = pose.p, pose.q
        return kalman.motion_noise(
            pose=kalman.DiagonalNoise(p0_diag=p0, q_diag=q, r_diag=pose.r),
            size=kalman.DiagonalNoise(p0_diag=c.size.p, q_diag=c.size.q, r_diag=c.size.r),
            heading=kalman.DiagonalNoise(
                p0_diag=c.heading.noise.p, q_diag=c.heading.noise.q, r_diag=c.heading.noise.r
            ),
            model=self.motion_model,
        )


def motion_noise_tables(config: TrackerConfig) -> tuple[FloatArray, FloatArray, FloatArray]:
    """P0 and Q (C, 5, k) and R (C, 5, 2) of the tracker's per-axis motion filter, indexed by
    global category id: the tables :class:`MCTracker` filters with (``tracker.kalman``)."""
    cat = _PerCategory(config)
    return cat.motion_p0, cat.motion_q, cat.motion_r


class MCTracker:
    """The MCTrack tracker for one scene (create one per scene, or call :meth:`reset`).

    Parameters
    ----------
    config : the resolved configuration (:func:`tracker.config.load_config`).
    observer : called with one event per stage (:mod:`tracker.events`); None costs nothing.
    compiled : run the stages that have one through their compiled kernel
        (:mod:`tracker.kernels`) when numba is available; False: numpy only (the
        reference the kernels are tested against).
    """

    def __init__(
        self, config: TrackerConfig, *, observer: Observer | None = None, compiled: bool = True
    ) -> None:
        self.config = config
        self.observer = observer
        self._cat = _PerCategory(config)
        # one-time JIT loads here, never inside a frame
        self._kernels = load_kernels() if compiled else None
        prepare_kernels()
        self.reset()

    def reset(self) -> None:
        self._tracks = TrackTable.empty(order=self._cat.motion_model.order)
        # the R table in effect: the config's, with x and y following the noise estimate
        self.motion_r = self._cat.motion_r.copy()
        # the BEV distance gate in effect (squared, per category): the config's, narrowed by
        # bev.gate_motion_m once the noise is estimated
        self.gate_sq = self._cat.gate_sq.copy()
        # stage 2's distance gate in effect (m, per category): the config's, capped inside the
        # motion gate so that stage 2 cannot take a box that stage 1's gate refused
        self.rv_gate = self._cat.rv_distance_gate.copy()
        self._rv_within_bev_gate = self._cat.rv_gate_within_bev_gate
        self._noise = (
            PositionNoise(len(CATEGORIES), self._kernels) if self._cat.follows_noise else None
        )
        self._next_id = 0
        self._last_time: float | None = None
        self._last_frame_id: int | None = None
        self._scene: str | None = None

    @property
    def noise_variance(self) -> FloatArray:
        """(C,) the detections' centre variance per class and axis (m²) as estimated so far
        (``tracker.noise``); NaN where not yet estimated, or everywhere when the config follows
        no noise (no ``pose.r_scale`` and no ``bev.gate_motion_m``)."""
        if self._noise is None:
            return np.full(len(CATEGORIES), np.nan)
        return self._noise.variance()

    # -----------------------------------------------------------------------------------------
    def step(self, frame: Frame, unfused: Frame | None = None) -> TrackOutput:
        """Track one frame; returns the confirmed tracks (rows sorted by id).

        ``unfused``: the frame before bearing fusion (:func:`tracker.fusion.fuse_scene`) moved
        its centres, when it did. The velocity baselines follow the detector's own centres, as
        in the reference (and as the motion evaluation reads a detection).
        """
        time_secs, dt = self._advance_clock(frame)
        self._emit(FrameStarted(frame, time_secs))
        dets, kept_rows = self._preprocess(frame)  # category, score, NMS
        if self._noise is not None:
            self._follow_noise(dets, time_secs)
        prev_boxes = self._tracks.boxes() if self._needs_back_prediction() else None
        self._predict(dt)  # three decoupled Kalman filters
        m1, bev_mask = self._bev_stage(prev_boxes, dets, kept_rows, dt)  # Ro_GDIoU, Hungarian
        assoc = self._image_stage(frame, dets, kept_rows, m1, bev_mask)  # SDIoU, greedy
        self._update(assoc.rows, dets, assoc.dets)
        self._tracks.record_matches(assoc.rows, kept_rows[assoc.dets], assoc.stage)
        centres = (frame if unfused is None else unfused).boxes.xyz[:, :2]  # (frame rows)
        self._record_detections(assoc.rows, time_secs, centres[kept_rows[assoc.dets]])
        born = self._birth(dets, assoc.unmatched_dets, kept_rows, time_secs, centres)
        born_rows = self._tracks.matched_det[len(self._tracks) - len(born) :]  # appended last
        changes = self._lifecycle(assoc.rows, born)
        self._emit(changes and dataclasses.replace(changes, born_det_rows=born_rows))
        output = self._output(frame, time_secs)
        self._emit(FrameFinished(output))
        return output

    def _follow_noise(self, dets: Boxes, time_secs: float) -> None:
        """Update the detections' noise estimate with this frame's boxes, then r of x and y
        (``pose.r_scale`` × the estimate) and the distance gate (``bev.gate_motion_m``) where
        it exists."""
        assert self._noise is not None
        self._noise.update(time_secs, dets.xyz[:, :2], dets.lwh[:, 0], dets.category)
        scale = self._cat.r_scale
        variance = self._noise.variance()
        if self._cat.any_motion_gate:
            # a detection's distance from its track's prediction: its own error (per axis σ,
            # GATE_NOISE_SIGMAS of it) plus the object's motion the filter did not predict;
            # no radius (inf) until σ is estimated, or where the class has no motion gate
            with np.errstate(invalid="ignore"):  # (inf + NaN where both are missing)
                radius_sq = self._cat.gate_motion_sq + GATE_NOISE_SIGMAS**2 * variance
            radius_sq = np.where(np.isfinite(radius_sq), radius_sq, np.inf)
            self.gate_sq = np.minimum(self._cat.gate_sq, radius_sq)
            if not self.config.rv_reference:  # (the reference's stage 2 keeps its own gate)
                # just inside (1 µm a metre): stage 2 measures in 3D, never less than in BEV
                cap = np.sqrt(radius_sq) * (1 - 1e-6)
                self.rv_gate = np.minimum(self._cat.rv_distance_gate, cap)
            self._rv_within_bev_gate = self._cat.rv_within(self.rv_gate, self.gate_sq)
        r = scale * variance
        ready = (scale > 0) & np.isfinite(r) & (r > 0)
        if ready.any():
            self.motion_r[ready, Axis.X, 0] = r[ready]
            self.motion_r[ready, Axis.Y, 0] = r[ready]
        if self.observer:
            on = scale > 0
            self.observer(
                NoiseEstimated(
                    np.where(on, variance, np.nan),
                    np.where(on, self.motion_r[:, Axis.X, 0], np.nan),
                    np.where(np.isfinite(self._cat.gate_motion_sq), np.sqrt(self.gate_sq), np.nan),
                )
            )

    def _emit(self, event: Event | None) -> None:
        if self.observer and event is not None:
            self.observer(event)

    def _bev_stage(
        self, prev_boxes: Boxes | None, dets: Boxes, kept_rows: IntArray, dt: float
    ) -> tuple[Matches, np.ndarray | None]:
        """Stage 1 in the BEV plane: the gated Ro_GDIoU cost and the Hungarian assignment.
        Also returns the mask of the pairs scored (None when there was nothing to score)."""
        tracks, obs = self._tracks, self.observer
        if obs:
            obs(
                Predicted(
                    tracks.track_id, tracks.boxes() if len(tracks) else Boxes.empty(), tracks.status
                )
            )
        bev_mask = None
        if len(tracks) and len(dets):
            cost, bev_mask = self._bev_cost(prev_boxes, dets, dt)
            max_cost = self._cat.bev_cost_max[tracks.category]
            m1 = self._assign(cost, max_cost)
            if obs:
                obs(CostComputed(Stage.BEV, cost, tracks.track_id, kept_rows, max_cost))
        else:
            m1 = Matches.empty(len(tracks), len(dets))
        if obs:
            obs(_matched(Stage.BEV, m1, tracks.track_id, kept_rows))
        return m1, bev_mask

    def _image_stage(
        self,
        frame: Frame,
        dets: Boxes,
        kept_rows: IntArray,
        m1: Matches,
        bev_mask: np.ndarray | None,
    ) -> _Association:
        """Stage 2 on stage 1's unmatched tracks and detections (when enabled and both
        exist), merged with stage 1's matches."""
        rows, cols = m1.unmatched_rows, m1.unmatched_cols
        if not (self.config.rv_matching and len(rows) and len(cols)):
            return _merge_stages(m1, None, rows, cols, _EMPTY_INT)
        m2, consumed = self._rv_stage(frame, dets, rows, cols, kept_rows, bev_mask)
        return _merge_stages(m1, m2, rows, cols, consumed)

    # -----------------------------------------------------------------------------------------
    def _advance_clock(self, frame: Frame) -> tuple[float, float]:
        """Frame time (seconds) and the elapsed time since the previous frame."""
        if self._scene is not None and frame.scene != self._scene:
            self.reset()
        self._scene = frame.scene
        t = frame.timestamp_secs
        if not math.isfinite(t):
            t = frame.frame_id * self.config.nominal_dt_secs
        if self._last_time is None:
            dt = self.config.nominal_dt_secs
        else:
            dt = t - self._last_time
            if dt <= 0 or (
                self._last_frame_id is not None and frame.frame_id <= self._last_frame_id
            ):
                raise InputError(
                    f"scene {frame.scene!r}, frame_id {frame.frame_id}: time {t:.6f} s is not "
                    f"after the previous frame ({self._last_time:.6f} s); frames must be in "
                    "time order"
                )
        self._last_time, self._last_frame_id = t, frame.frame_id
        return t, dt

    def _preprocess(self, frame: Frame) -> tuple[Boxes, IntArray]:
        """Category filter, score threshold (strict >), optional class-aware BEV NMS."""
        boxes = frame.boxes
        cat = self._cat
        # strict >: NaN scores are dropped, and untracked categories (threshold +inf) too
        candidates = kept = np.nonzero(boxes.score > cat.score_min_tracked[boxes.category])[0]
        suppressed = None
        if self.config.nms and len(candidates) > 1:
            suppressed = _nms_suppressed(boxes[candidates], cat.nms_iou_max)
            kept = candidates[~suppressed]
        if self.observer:
            tracked = cat.tracked[boxes.category]
            above = boxes.score > cat.score_min[boxes.category]
            reason = np.full(len(boxes), DropReason.KEPT, dtype=np.int8)
            reason[~tracked] = DropReason.CATEGORY
            reason[tracked & ~above] = DropReason.SCORE
            if suppressed is not None:
                reason[candidates[suppressed]] = DropReason.NMS
            self.observer(DetectionsFiltered(frame, reason, kept))
        # all kept (common with few detections): the frame's own read-only batch, no copy
        return (boxes if len(kept) == len(boxes) else boxes[kept]), kept

    def _needs_back_prediction(self) -> bool:
        return self._cat.any_back_prediction and bool(
            len(self._tracks) and np.any(self._cat.alpha[self._tracks.category] < 1)
        )

    def _predict(self, dt: float) -> None:
        """Advance every track's filters by the real elapsed time (misses included)."""
        tr = self._tracks
        if not len(tr):
            return
        if self._kernels is not None:
            tau = dt / self.config.nominal_dt_secs
            tr.motion_x, tr.motion_P = self._kernels.motion_predict_kernel(
                tr.motion_x, tr.motion_P, tr.category, self._cat.motion_q, dt, tau
            )
            tr.age += 1
            return
        tr.motion_x, tr.motion_P = kalman.motion_predict(
            tr.motion_x,
            tr.motion_P,
            dt_secs=dt,
            q_diag=self._cat.motion_q[tr.category],
            dt_nominal_secs=self.config.nominal_dt_secs,
        )
        tr.age += 1

    def _bev_cost(
        self, prev: Boxes | None, dets: Boxes, dt: float
    ) -> tuple[FloatArray, np.ndarray]:
        """(T, D) cost = 1 - similarity of the predicted tracks; +inf across categories and
        beyond the distance gate. Also returns the (T, D) mask of the pairs scored."""
        tr, cat = self._tracks, self._cat
        bev = tr.motion_x[:, :, 0]  # (T, 5) predicted x, y, l, w, yaw: the BEV boxes
        det_bev = bev_array(dets)
        if cat.any_buffer:  # buffered boxes: l, w grown by their category's factor
            bev = bev * cat.buffer_lw[tr.category]
            det_bev *= cat.buffer_lw[dets.category]
        if cat.all_forward and self._kernels is not None:
            cost, mask = self._kernels.bev_cost_kernel(
                bev, tr.category, det_bev, dets.category, self.gate_sq, cat.w1, cat.w2
            )
            return cost, mask
        same = tr.category[:, None] == dets.category[None, :]
        delta = bev[:, None, :2] - dets.xyz[None, :, :2]
        near = np.einsum("tdk,tdk->td", delta, delta) < self.gate_sq[tr.category][:, None]
        mask = same & near
        w1, w2 = cat.w1[tr.category], cat.w2[tr.category]
        if cat.all_forward:
            # Predict cost state for every category: the similarity is -inf outside mask
            sim = ro_gdiou_bev_arrays(bev, det_bev, w1=w1, w2=w2, mask=mask)
            return 1.0 - sim, mask
        pred = tr.boxes()
        if cat.any_buffer:
            pred, dets = _buffered(pred, cat.buffer_lw), _buffered(dets, cat.buffer_lw)
            prev = None if prev is None else _buffered(prev, cat.buffer_lw)
        alpha = cat.alpha[tr.category]
        sim = np.full(mask.shape, -np.inf)
        if np.any(alpha > 0):
            fwd = ro_gdiou_bev(pred, dets, w1=w1, w2=w2, mask=mask & (alpha > 0)[:, None])
            sim = np.where((alpha > 0)[:, None], fwd, sim)
        if np.any(alpha < 1) and prev is not None:
            # backward prediction: the detection moved back by its own velocity to the
            # previous frame's time, compared with the track's previous filtered box (§3.2.2)
            back = ro_gdiou_bev(
                prev, back_predict(dets, dt), w1=w1, w2=w2, mask=mask & (alpha < 1)[:, None]
            )
            a = alpha[:, None]
            with np.errstate(invalid="ignore"):  # 0 · -inf where a = 0: not selected
                sim = np.where(a >= 1, sim, np.where(a <= 0, back, a * sim + (1 - a) * back))
        with np.errstate(invalid="ignore"):
            return np.where(mask, 1.0 - sim, np.inf), mask

    def _assign(self, cost: FloatArray, max_cost: FloatArray) -> Matches:
        """Stage 1's Hungarian assignment (a compiled shortcut when no pair is contested)."""
        if self._kernels is not None:
            pairs, costs, rows, cols, solved = self._kernels.isolated_pairs_kernel(cost, max_cost)
            if solved:
                return Matches._trusted(pairs, costs, rows, cols)
        return hungarian(cost, max_cost_per_row=max_cost)

    def _rv_stage(
        self,
        frame: Frame,
        dets: Boxes,
        rows: IntArray,
        cols: IntArray,
        kept_rows: IntArray,
        bev_mask: np.ndarray | None = None,
    ) -> tuple[Matches, IntArray]:
        """Stage 2 on the leftovers of stage 1: SDIoU of 2D boxes, greedy, yaw/distance gate.

        Returns the accepted matches (indices into ``rows``/``cols``) and the indices into
        ``cols`` of detections consumed by the stage (accepted, plus gated ones in reference
        mode, which drops them as the original code does). ``bev_mask`` is stage 1's mask of
        the pairs it scored.
        """
        tr, cat, reference = self._tracks, self._cat, self.config.rv_reference
        # an observer that only counts (tracker.eval.fates) does not need the costs of empty
        # stages; the recording takes them deferred (computed later, many frames at once)
        obs = self.observer
        wants = obs is not None and getattr(obs, "wants_rv_costs", True)
        deferred = wants and getattr(obs, "rv_costs_deferred", False)
        shortcut = not reference and (not wants or deferred)
        # Shortcut (exact): when the gate below can accept no pair, whatever the costs, nothing
        # is matched or consumed. Most frames' leftovers are far apart or of other classes: a
        # pair outside stage 1's mask is of another class or farther (in BEV, so in 3D) than
        # the BEV gate, which is wider than this stage's.
        if shortcut and (
            (
                self._rv_within_bev_gate
                and bev_mask is not None
                and not bev_mask[rows][:, cols].any()
            )
            or not self._rv_gate_passable(rows, dets, cols)
        ):
            if deferred:
                category = tr.category[rows]
                self._emit(
                    ImageStageDeferred(
                        rows,
                        kept_rows[cols],
                        cat.rv_cost_max[category],
                        cat.rv_yaw_gate[category],
                        self.rv_gate[category],
                        self.config.greedy_order.value,
                    )
                )
            return Matches.empty(len(rows), len(cols)), _EMPTY_INT
        pred = tr.boxes(rows)  # the predicted boxes of the tracks in ``rows``
        track_category = pred.category
        det_camera, det_xyxy = dets.camera[cols], dets.xyxy_image[cols]
        track_xyxy = np.full((len(rows), 4), np.nan)
        track_cam = np.full(len(rows), -1, dtype=np.int64)
        cost = np.full((len(rows), len(cols)), np.inf)
        same = track_category[:, None] == dets.category[cols][None, :]
        if reference:
            # the reference compares the detector's 2D box of the track's last detection
            track_xyxy, track_cam = tr.last_xyxy[rows], tr.last_camera[rows]
            for c in _cameras_of(det_camera):
                r, d = track_cam == c, det_camera == c
                cost[np.ix_(r, d)] = 1.0 - sdiou_image(track_xyxy[r], det_xyxy[d])
        else:
            # the paper: project the track's predicted 3D box into the detection's camera
            for c in _cameras_of(det_camera):
                xyxy, visible = project_boxes(pred, frame.cameras[c])
                d = det_camera == c
                take = visible & (track_cam < 0)
                track_xyxy[take], track_cam[take] = xyxy[take], c
                block = 1.0 - sdiou_image(xyxy[visible], det_xyxy[d])
                cost[np.ix_(visible, d)] = block
        cost = np.where(same, cost, np.inf)
        max_cost = cat.rv_cost_max[track_category]
        m = greedy(cost, max_cost_per_row=max_cost, order=self.config.greedy_order)

        # gate: heading within yaw_gate and centres within distance_gate of the track
        t_rows, d_cols = rows[m.pairs[:, 0]], cols[m.pairs[:, 1]]
        if reference:
            track_yaw, track_xyz = tr.last_det_yaw[t_rows], tr.last_det_xyz[t_rows]
        else:
            track_yaw, track_xyz = pred.yaw[m.pairs[:, 0]], pred.xyz[m.pairs[:, 0]]
        yaw_gap = np.abs(wrap_angle(track_yaw - dets.yaw[d_cols]))
        dist = np.linalg.norm(track_xyz - dets.xyz[d_cols], axis=1)
        t_category = tr.category[t_rows]
        ok = (yaw_gap <= cat.rv_yaw_gate[t_category]) & (dist <= self.rv_gate[t_category])
        accepted = m.subset(ok)
        consumed = m.pairs[:, 1] if reference else accepted.pairs[:, 1]
        if self.observer:
            self.observer(
                CostComputed(
                    Stage.RV,
                    cost,
                    tr.track_id[rows],
                    kept_rows[cols],
                    max_cost,
                    track_xyxy=track_xyxy,
                    camera=track_cam,
                )
            )
            self.observer(
                Matched(
                    Stage.RV,
                    tr.track_id[t_rows[ok]],
                    kept_rows[d_cols[ok]],
                    m.costs[ok],
                    tr.track_id[t_rows[~ok]],
                    kept_rows[d_cols[~ok]],
                )
            )
        return accepted, consumed

    def _rv_gate_passable(self, rows: IntArray, dets: Boxes, cols: IntArray) -> bool:
        """Whether any (track ``rows``, detection ``cols``) pair of one category passes the
        stage-2 yaw and distance gate (on the predicted boxes).

        Conservative by a hair (1 µm, 1 nrad) so that rounding can never skip a real match.
        """
        tr, cat = self._tracks, self._cat
        category = tr.category[rows]
        same = category[:, None] == dets.category[cols][None, :]
        if not same.any():
            return False
        delta = tr.xyz(rows)[:, None, :] - dets.xyz[cols][None, :, :]
        gate_sq = (self.rv_gate[category][:, None] + 1e-6) ** 2  # 1 µm wider than the gate
        near = np.einsum("tdk,tdk->td", delta, delta) <= gate_sq
        near &= same
        if not near.any():
            return False
        yaw = tr.motion_x[rows, Axis.YAW, 0]
        yaw_gap = np.abs(wrap_angle(yaw[:, None] - dets.yaw[cols][None, :]))
        near &= yaw_gap <= cat.rv_yaw_gate_loose[category][:, None]
        return bool(near.any())

    def _update(self, idx: IntArray, dets: Boxes, det_rows: IntArray) -> None:
        """Kalman updates of tracks ``idx`` with detections ``det_rows`` (position, size, and
        heading from both sources)."""
        if not len(idx):
            return
        tr, cat = self._tracks, self._cat
        c = tr.category[idx]
        xyz, lwh, det_yaw = dets.xyz[det_rows], dets.lwh[det_rows], dets.yaw[det_rows]
        if self._kernels is not None and not cat.any_measure_velocity:
            # the code below, compiled (value measurements only)
            self._kernels.motion_update_kernel(
                tr.motion_x, tr.motion_P, tr.heading_votes, idx, c, xyz[:, :2], lwh[:, :2],
                det_yaw, self.motion_r, cat.head_min_speed, HEADING_FLIP_VOTES,
            )  # fmt: skip
            self._record_hits(idx, dets, det_rows, xyz, lwh)
            return
        r_diag = self.motion_r[c]
        vel = None
        if cat.any_measure_velocity:
            vel = np.where(cat.measure_velocity[c][:, None], dets.velocity[det_rows], np.nan)
        # Heading from perception and from velocity (paper §3.3). Detections carry a 180°
        # ambiguity, so the sign of the heading is decided first: by the direction of travel
        # when the object clearly moves (speed above its threshold and 3 sigma of its
        # *updated* estimate), else by the detector's majority (a run of disagreeing detections
        # flips the state). The detection's yaw is then aligned to that heading and both update
        # θ. The axes are independent, so all are updated at once with the heading kept as
        # predicted, the usual outcome (no row moving or flipping); otherwise the heading axis
        # is redone from its prediction.
        x_pred, P_pred = tr.motion_x[idx], tr.motion_P[idx]
        heading = x_pred[:, Axis.YAW, 0].copy()  # predicted θ
        disagree = np.abs(wrap_angle(det_yaw - heading)) > np.pi / 2
        # = kalman.align_heading(det_yaw, heading), whose test is ``disagree``
        yaw_det = wrap_angle(np.where(disagree, det_yaw + np.pi, det_yaw))
        x, P = kalman.motion_update(
            x_pred,
            P_pred,
            xy=xyz[:, :2],
            lw=lwh[:, :2],
            yaw_det_rad=yaw_det,
            r_diag=r_diag,
            velocity_xy=vel,
        )
        vx, vy = x[:, Axis.X, 1], x[:, Axis.Y, 1]
        speed = np.hypot(vx, vy)
        speed_sigma = np.sqrt(P[:, Axis.X, 1, 1] + P[:, Axis.Y, 1, 1])
        # speed above its threshold and above 3 sigma (one comparison with the larger)
        moving = speed > np.maximum(cat.head_min_speed[c], 3.0 * speed_sigma)
        votes = (tr.heading_votes[idx] + 1) * disagree  # consecutive disagreements (else 0)
        flip_by_votes = ~moving & (votes >= HEADING_FLIP_VOTES)
        if (moving | flip_by_votes).any():
            any_moving, any_flip = moving.any(), flip_by_votes.any()
            yaw_vel = np.arctan2(vy, vx)
            if any_moving:
                heading[moving] = kalman.align_heading(heading[moving], yaw_vel[moving])
            if any_flip:
                heading[flip_by_votes] = wrap_angle(heading[flip_by_votes] + np.pi)
            votes[flip_by_votes | moving] = 0
            x[:, Axis.YAW], P[:, Axis.YAW] = x_pred[:, Axis.YAW], P_pred[:, Axis.YAW]
            x[:, Axis.YAW, 0] = heading
            x, P = kalman.motion_update(
                x,
                P,
                yaw_det_rad=kalman.align_heading(det_yaw, heading),
                yaw_vel_rad=yaw_vel if any_moving else None,  # (None: masked on every row)
                yaw_vel_valid=moving,
                r_diag=r_diag,
            )
        tr.heading_votes[idx] = votes
        tr.motion_x[idx], tr.motion_P[idx] = x, P
        self._record_hits(idx, dets, det_rows, xyz, lwh)

    def _record_hits(
        self, idx: IntArray, dets: Boxes, det_rows: IntArray, xyz: FloatArray, lwh: FloatArray
    ) -> None:
        """The matched detections' own fields kept on their tracks, and the hit counts."""
        tr = self._tracks
        if self._kernels is not None:
            self._kernels.record_hits_kernel(
                idx, det_rows, dets.score, dets.xyxy_image, dets.camera, dets.xyz, dets.lwh,
                dets.yaw, tr.category, self._cat.vertical_gain, self._cat.any_vertical_smoothing,
                tr.score, tr.last_xyxy, tr.last_camera, tr.last_det_xyz, tr.last_det_lwh, tr.zh,
                tr.last_det_yaw, tr.hits, tr.evidence, tr.log_odds,
            )  # fmt: skip
            return
        tr.score[idx] = dets.score[det_rows]
        tr.last_xyxy[idx], tr.last_camera[idx] = dets.xyxy_image[det_rows], dets.camera[det_rows]
        tr.last_det_xyz[idx], tr.last_det_lwh[idx] = xyz, lwh
        zh = np.column_stack([xyz[:, 2], lwh[:, 2]])
        if self._cat.any_vertical_smoothing:  # zh += gain (detection - zh)
            gain = self._cat.vertical_gain[tr.category[idx]][:, None]
            zh = tr.zh[idx] + gain * (zh - tr.zh[idx])
        tr.zh[idx] = zh
        tr.last_det_yaw[idx] = dets.yaw[det_rows]
        tr.hits[idx] += 1
        tr.evidence[idx] += _evidence(dets.score[det_rows])
        tr.log_odds[idx] += _log_odds(dets.score[det_rows])

    def _record_detections(self, idx: IntArray, time_secs: float, xy: FloatArray) -> None:
        """Tracks ``idx`` took detections at ``xy`` (their velocity baselines follow)."""
        tr = self._tracks
        if self._kernels is not None:
            self._kernels.record_detections_kernel(
                idx, time_secs, xy, tr.det_t, tr.det_xy, tr.baseline
            )
        else:
            tr.record_detections(idx, time_secs, xy)

    def _birth(
        self,
        dets: Boxes,
        det_index: IntArray,
        kept_rows: IntArray,
        time_secs: float,
        centres: FloatArray,
    ) -> IntArray:
        """New tracks from unmatched detections ``det_index`` scoring above the birth threshold
        (``centres``: the frame's detector centres, the velocity baselines' first)."""
        cat = self._cat
        det_index = det_index[dets.score[det_index] > cat.birth_score_min[dets.category[det_index]]]
        n = len(det_index)
        if not n:
            return _EMPTY_INT
        c = dets.category[det_index]
        xyz, lwh, yaw = dets.xyz[det_index], dets.lwh[det_index], dets.yaw[det_index]
        score = dets.score[det_index]
        vel = None  # (no measured velocity: the filters start at rest)
        if cat.any_measure_velocity:
            vel = np.where(cat.measure_velocity[c][:, None], dets.velocity[det_index], 0.0)
        motion_x, motion_P = kalman.motion_init(
            xy=xyz[:, :2], lw=lwh[:, :2], yaw_rad=yaw, p0_diag=cat.motion_p0[c], velocity_xy=vel
        )
        track_id = np.arange(self._next_id, self._next_id + n, dtype=np.int64)
        self._next_id += n
        zeros = np.zeros(n, dtype=np.int64)
        det_t = np.full((n, WINDOW), np.nan)
        det_xy = np.full((n, WINDOW, 2), np.nan)
        det_t[:, -1], det_xy[:, -1] = time_secs, centres[kept_rows[det_index]]
        new = TrackTable(
            track_id=track_id,
            category=c,
            status=np.full(n, TrackStatus.TENTATIVE, dtype=np.int8),
            hits=np.ones(n, dtype=np.int64),
            misses=zeros,
            age=zeros,
            motion_x=motion_x,
            motion_P=motion_P,
            score=score,
            last_xyxy=dets.xyxy_image[det_index],
            last_camera=dets.camera[det_index],
            last_det_xyz=xyz,
            last_det_lwh=lwh,
            zh=np.column_stack([xyz[:, 2], lwh[:, 2]]),
            last_det_yaw=yaw,
            heading_votes=zeros,
            evidence=_evidence(score),
            log_odds=_log_odds(score),
            matched_det=kept_rows[det_index],
            matched_stage=np.zeros(n, dtype=np.int8),
            det_t=det_t,
            det_xy=det_xy,
            baseline=np.zeros((n, 2, 2)),  # (0 at a track's first detection, as the reference)
        )  # every array is fresh or only read: append() copies them into the table
        self._tracks = self._tracks.append(new)
        return track_id

    def _lifecycle(self, matched: IntArray, born: IntArray) -> LifecycleChanged | None:
        """Per-category birth/confirm/coast/lose/delete rules (paper §3.4).

        Returns the changes as an event when there is an observer (else None: not built).
        """
        tr, cat = self._tracks, self._cat
        n_old = len(tr) - len(born)
        hit = np.zeros(len(tr), dtype=bool)
        hit[matched] = True
        hit[n_old:] = True  # a birth is its own first hit
        if self._kernels is not None:
            return self._lifecycle_compiled(hit, born)
        misses = np.where(hit, 0, tr.misses + 1)
        tr.misses = misses
        (min_hits, confirm_score, max_output, max_live, max_tentative, confirm_evidence,
         coast_hits) = cat.lifecycle[tr.category].T  # fmt: skip
        old_status = tr.status
        status = old_status.copy()
        tentative = old_status == _TENTATIVE
        confirm = (
            hit
            & tentative
            & (
                (tr.hits >= min_hits)
                | (tr.score >= confirm_score)
                | (tr.evidence >= confirm_evidence)
            )
        )
        reacquire = hit & _IS_REACQUIRED[old_status]
        status[confirm | reacquire] = _CONFIRMED
        missed = ~hit
        live = ~tentative & missed  # missed this frame: misses >= 1
        status[live] = _COASTING
        status[live & ((misses > max_output) | (tr.hits < coast_hits))] = _LOST
        dead = (live & (misses > max_live)) | (tentative & missed & (misses > max_tentative))
        tr.status = status
        change = None
        if self.observer:
            lost = (status == _LOST) & (old_status != _LOST) & ~dead
            change = LifecycleChanged(
                born=born,
                confirmed=tr.track_id[confirm],
                lost=tr.track_id[lost],
                reacquired=tr.track_id[reacquire & (old_status == _LOST)],
                deleted=tr.track_id[dead],
            )
        if dead.any():
            self._tracks = tr.select(~dead)
        return change

    def _lifecycle_compiled(self, hit: np.ndarray, born: IntArray) -> LifecycleChanged | None:
        """:meth:`_lifecycle` after its hit mask, by the compiled kernel (same rules)."""
        tr, k = self._tracks, self._kernels
        assert k is not None
        tr.status, tr.misses, flags = k.lifecycle_kernel(
            tr.status,
            tr.hits,
            tr.misses,
            tr.score,
            tr.evidence,
            tr.category,
            hit,
            self._cat.lifecycle,
        )
        dead = (flags & k.DEAD) != 0
        change = None
        if self.observer:
            change = LifecycleChanged(
                born=born,
                confirmed=tr.track_id[(flags & k.CONFIRMED_NOW) != 0],
                lost=tr.track_id[(flags & k.LOST_NOW) != 0],
                reacquired=tr.track_id[(flags & k.REACQUIRED_FROM_LOST) != 0],
                deleted=tr.track_id[dead],
            )
        if dead.any():
            self._tracks = tr.select(~dead)
        return change

    def _output(self, frame: Frame, time_secs: float) -> TrackOutput:
        tr = self._tracks
        out = _IS_OUTPUT[tr.status]  # confirmed or coasting
        if self.config.mode is TrackingMode.OFFLINE:
            # offline post-processing decides per whole track (it knows the future), so it also
            # gets the detections of tracks not confirmed yet
            out |= (tr.status == _TENTATIVE) & (tr.matched_det >= 0)
        elif self._cat.any_track_score_gate:
            # mean log-odds of the track's hits; hits >= 1 for every live track
            out &= tr.log_odds >= self._cat.track_score_min[tr.category] * tr.hits
        rows = np.flatnonzero(out)
        det_row = tr.matched_det[rows]
        if self.config.coast_min_in_view > 0 and frame.cameras and (det_row < 0).any():
            coasting = rows[det_row < 0]  # (their boxes are the predictions)
            lwh = np.column_stack(
                [tr.motion_x[coasting, Axis.LENGTH : Axis.WIDTH + 1, 0], tr.zh[coasting, 1]]
            )
            fraction = _in_image_fraction(
                tr.xyz(coasting),
                lwh,
                tr.motion_x[coasting, Axis.YAW, 0],
                frame.cameras,
                self._kernels,
            )
            if (fraction < self.config.coast_min_in_view).any():
                keep = np.ones(len(rows), dtype=bool)
                keep[det_row < 0] = fraction >= self.config.coast_min_in_view
                rows, det_row = rows[keep], det_row[keep]
        boxes = tr.boxes(rows)
        if self.config.output_geometry is OutputGeometry.DETECTION:
            hit = det_row >= 0
            boxes = boxes.replace(
                xyz=np.where(hit[:, None], tr.last_det_xyz[rows], boxes.xyz),
                lwh=np.where(hit[:, None], tr.last_det_lwh[rows], boxes.lwh),
                yaw=np.where(
                    hit, kalman.align_heading(tr.last_det_yaw[rows], boxes.yaw), boxes.yaw
                ),
            )
        acceleration = kalman.motion_acceleration_xy(tr.motion_x[rows])
        if self._cat.any_cv:
            cv = ~self._cat.has_acceleration[boxes.category]
            acceleration = np.where(cv[:, None], np.nan, acceleration)
        baselines = tr.baseline[rows]
        baselines[det_row < 0] = np.nan  # (a coasting row has no detection of its own)
        return TrackOutput(
            scene=frame.scene,
            frame_id=frame.frame_id,
            time_secs=time_secs,
            boxes=boxes,
            acceleration=acceleration,
            status=tr.status[rows],
            det_row=det_row,
            stage=tr.matched_stage[rows],
            baselines=baselines,
        )


@dataclasses.dataclass(frozen=True, slots=True)
class _Association:
    """Both stages' matches of one frame: track rows (sorted), their detection rows (into the
    kept detections), the stage of each (1 BEV, 2 image plane), and the unused detections."""

    rows: IntArray
    dets: IntArray
    stage: np.ndarray
    unmatched_dets: IntArray


def _merge_stages(
    m1: Matches, m2: Matches | None, rv_rows: IntArray, rv_cols: IntArray, consumed: IntArray
) -> _Association:
    """Stage 1's matches plus stage 2's (mapped back from the leftovers), sorted by track row."""
    stage1 = np.ones(len(m1), dtype=np.int8)
    unmatched = _without(rv_cols, consumed) if len(consumed) else m1.unmatched_cols
    if m2 is None or not len(m2):
        return _Association(m1.rows, m1.cols, stage1, unmatched)
    rows = np.concatenate([m1.rows, rv_rows[m2.rows]])
    order = np.argsort(rows, kind="stable")
    dets = np.concatenate([m1.cols, rv_cols[m2.cols]])[order]
    stage = np.concatenate([stage1, np.full(len(m2), 2, dtype=np.int8)])[order]
    return _Association(rows[order], dets, stage, unmatched)


def _buffered(boxes: Boxes, buffer_lw: FloatArray) -> Boxes:
    """The boxes with length and width grown by their category's factor (``buffer_lw`` rows
    per category, columns x, y, l, w, yaw)."""
    factor = buffer_lw[boxes.category, 2:4]
    return boxes.replace(lwh=np.column_stack([boxes.lwh[:, :2] * factor, boxes.lwh[:, 2]]))


def _in_image_fraction(
    xyz: FloatArray,
    lwh: FloatArray,
    yaw: FloatArray,
    cameras: Sequence[Camera],
    kernels: SimpleNamespace | None,
) -> FloatArray:
    """(K,) the largest fraction of each box's projected width inside a camera's image
    (:func:`tracker.camera.in_image_fraction`; the compiled kernel where every corner is in
    front of the camera, the numpy reference for the rest)."""
    fraction = np.zeros(len(xyz))
    for cam in cameras:
        if kernels is None:
            frac = in_image_fraction(xyz, lwh, yaw, cam)
        else:
            frac = kernels.in_image_fraction_kernel(
                xyz,
                lwh,
                yaw,
                cam.image_from_world,
                cam.width_px - 1.0,
                cam.height_px - 1.0,
                NEAR_PLANE_M,
            )
            clipped = np.isnan(frac)  # a corner behind the near plane: edges need clipping
            if clipped.any():
                frac[clipped] = in_image_fraction(xyz[clipped], lwh[clipped], yaw[clipped], cam)
        fraction = np.maximum(fraction, frac)
    return fraction


def _evidence(score: FloatArray) -> FloatArray:
    """A hit's contribution -log(1 - p) to its track's evidence (p capped below 1, NaN: 0)."""
    # fmax/fmin drop a NaN operand: a NaN score becomes p = 0 (ufuncs: nan_to_num and clip
    # cost more than the rest of a hit's bookkeeping)
    return -np.log1p(-np.fmin(np.fmax(score, 0.0), 1.0 - 1e-9))


def _log_odds(score: FloatArray) -> FloatArray:
    """A hit's contribution to its track's log-odds sum (NaN: 0)."""
    return np.where(np.isnan(score), 0.0, score_log_odds(score))


def _without(index: IntArray, positions: IntArray) -> IntArray:
    """``index`` without the entries at ``positions`` (order kept; setdiff1d for sorted unique
    ``index``, without its sort)."""
    keep = np.ones(len(index), dtype=bool)
    keep[positions] = False
    return index[keep]


def _cameras_of(camera: IntArray) -> list[int]:
    """Sorted distinct camera indices >= 0 (``np.unique`` with a shortcut for one camera)."""
    present = camera[camera >= 0]
    if not len(present):
        return []
    first = int(present[0])
    if (present == first).all():
        return [first]
    return np.unique(present).tolist()


def _matched(stage: Stage, m: Matches, track_ids: IntArray, kept_rows: IntArray) -> Matched:
    return Matched(
        stage,
        track_ids[m.pairs[:, 0]],
        kept_rows[m.pairs[:, 1]],
        m.costs,
        _EMPTY_INT,
        _EMPTY_INT,
    )


def _nms_suppressed(boxes: Boxes, iou_max_per_category: FloatArray) -> np.ndarray:
    """Class-aware greedy BEV NMS: True for boxes suppressed by a higher-scoring one."""
    order = np.argsort(-boxes.score, kind="stable")
    iou = iou_bev(boxes, boxes)
    same = boxes.category[:, None] == boxes.category[None, :]
    over = same & (iou > iou_max_per_category[boxes.category][:, None])
    suppressed = np.zeros(len(boxes), dtype=bool)
    for i in order:
        if not suppressed[i]:
            later = over[i].copy()
            later[i] = False
            later &= boxes.score <= boxes.score[i]
            suppressed |= later & ~suppressed
            suppressed[i] = False
    return suppressed
