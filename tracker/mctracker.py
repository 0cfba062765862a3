"""MCTracker: one ``step(frame)`` per frame, in the order of the paper's pipeline (Fig. 2).

    preprocess -> predict -> stage 1 (BEV, Ro_GDIoU, Hungarian)
               -> stage 2 (image plane, SDIoU, greedy) -> update -> lifecycle -> output

Where we differ from the reference code (docs/differences.md): real dt from timestamps, every
filter advances on misses, wrapped angles, per-track (not ``trajs[0]``) cost settings, tracks
projected into the image for stage 2, gated-out detections start tracks, optional tentative
state, and the filtered acceleration in the output.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from tracker import kalman
from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.camera import project_boxes
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
from tracker.cost import back_predict, iou_bev, ro_gdiou_bev, sdiou_image
from tracker.errors import InputError
from tracker.events import (
    CostComputed,
    DetectionsFiltered,
    DropReason,
    FrameFinished,
    FrameStarted,
    LifecycleChanged,
    Matched,
    Observer,
    Predicted,
    Stage,
    TrackOutput,
    TrackStatus,
)
from tracker.frame import Frame
from tracker.geometry import wrap_angle
from tracker.matching import Matches, greedy, hungarian
from tracker.track import POSE_DIM, TrackTable

_EMPTY_INT = np.zeros(0, dtype=np.int64)
HEADING_FLIP_VOTES = 3  # consecutive detections disagreeing by > 90° that flip a static track


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
        self.rv_cost_max = arr(lambda c: c.rv.cost_max)
        self.rv_yaw_gate = np.deg2rad(arr(lambda c: c.rv.yaw_gate_deg))
        self.rv_distance_gate = arr(lambda c: c.rv.distance_gate_m)
        self.min_hits = arr(lambda c: c.lifecycle.min_hits)
        self.confirm_score = arr(lambda c: c.lifecycle.confirm_score)
        self.max_misses_tentative = arr(lambda c: c.lifecycle.max_misses_tentative)
        self.max_misses_output = arr(lambda c: c.lifecycle.max_misses_output)
        self.max_misses = arr(lambda c: c.lifecycle.max_misses)
        self.measure_velocity = np.array([c.pose.measure_velocity for c in cfgs])
        self.is_ca = np.array([c.pose.motion is MotionModel.CA for c in cfgs])
        self.pose_p0, self.pose_q, self.pose_r = self._pose_noise(cfgs)
        self.size_p0 = np.array([c.size.p for c in cfgs], dtype=np.float64)
        self.size_q = np.array([c.size.q for c in cfgs], dtype=np.float64)
        self.size_r = np.array([c.size.r for c in cfgs], dtype=np.float64)
        self.head_p0 = np.array([c.heading.noise.p for c in cfgs], dtype=np.float64)
        self.head_q = np.array([c.heading.noise.q for c in cfgs], dtype=np.float64)
        self.head_r = np.array([c.heading.noise.r for c in cfgs], dtype=np.float64)
        self.head_min_speed = arr(lambda c: c.heading.min_speed_mps)

    @staticmethod
    def _pose_noise(cfgs: list[CategoryConfig]) -> tuple[FloatArray, FloatArray, FloatArray]:
        """6-state P0/Q for every category; CV = CA with zero acceleration variance (exact)."""
        p0 = np.zeros((len(cfgs), POSE_DIM))
        q = np.zeros((len(cfgs), POSE_DIM))
        r = np.ones((len(cfgs), 4))
        for i, c in enumerate(cfgs):
            noise = c.pose.ca if c.pose.motion is MotionModel.CA else c.pose.cv
            k = len(noise.p)
            p0[i, :k], q[i, :k] = noise.p, noise.q
            r[i, : len(noise.r)] = noise.r
        return p0, q, r


class MCTracker:
    """The MCTrack tracker for one scene (create one per scene, or call :meth:`reset`).

    Parameters
    ----------
    config : the resolved configuration (:func:`tracker.config.load_config`).
    observer : called with one event per stage (:mod:`tracker.events`); None costs nothing.
    """

    def __init__(self, config: TrackerConfig, *, observer: Observer | None = None) -> None:
        self.config = config
        self.observer = observer
        self._cat = _PerCategory(config)
        self.reset()

    def reset(self) -> None:
        self._tracks = TrackTable.empty()
        self._next_id = 0
        self._last_time: float | None = None
        self._last_frame_id: int | None = None
        self._scene: str | None = None

    # -----------------------------------------------------------------------------------------
    def step(self, frame: Frame) -> TrackOutput:
        """Track one frame; returns the confirmed tracks (rows sorted by id)."""
        obs = self.observer
        time_secs, dt = self._advance_clock(frame)
        if obs:
            obs(FrameStarted(frame, time_secs))

        dets, kept_rows = self._preprocess(frame)
        prev_boxes = self._tracks.boxes() if self._needs_back_prediction() else None
        self._predict(dt)
        tracks = self._tracks
        pred_boxes = tracks.boxes() if len(tracks) else Boxes.empty()
        if obs:
            obs(Predicted(tracks.track_id, pred_boxes, tracks.status))

        det_for_track = np.full(len(tracks), -1, dtype=np.int64)
        stage_of_track = np.zeros(len(tracks), dtype=np.int8)

        # stage 1: BEV plane, Ro_GDIoU cost, Hungarian
        if len(tracks) and len(dets):
            cost = self._bev_cost(pred_boxes, prev_boxes, dets, dt)
            max_cost = self._cat.bev_cost_max[tracks.category]
            m1 = hungarian(cost, max_cost_per_row=max_cost)
            if obs:
                obs(CostComputed(Stage.BEV, cost, tracks.track_id, kept_rows, max_cost))
        else:
            m1 = Matches.empty(len(tracks), len(dets))
        det_for_track[m1.pairs[:, 0]] = m1.pairs[:, 1]
        stage_of_track[m1.pairs[:, 0]] = 1
        if obs:
            obs(_matched(Stage.BEV, m1, tracks.track_id, kept_rows))
        unmatched_dets = m1.unmatched_cols

        # stage 2: image plane, SDIoU, greedy
        if self.config.rv_matching and len(m1.unmatched_rows) and len(unmatched_dets):
            rows, cols = m1.unmatched_rows, unmatched_dets
            m2, consumed = self._rv_stage(frame, pred_boxes, dets, rows, cols, kept_rows)
            det_for_track[rows[m2.pairs[:, 0]]] = cols[m2.pairs[:, 1]]
            stage_of_track[rows[m2.pairs[:, 0]]] = 2
            unmatched_dets = np.setdiff1d(cols, cols[consumed])

        matched = np.flatnonzero(det_for_track >= 0)
        self._update(matched, dets[det_for_track[matched]])
        tracks.matched_det = np.full(len(tracks), -1, dtype=np.int64)
        tracks.matched_det[matched] = kept_rows[det_for_track[matched]]
        tracks.matched_stage = stage_of_track
        born = self._birth(dets[unmatched_dets], kept_rows[unmatched_dets])
        changes = self._lifecycle(matched, born)
        if obs:
            obs(changes)
        output = self._output(frame, time_secs)
        if obs:
            obs(FrameFinished(output))
        return output

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
        reason = np.full(len(boxes), DropReason.KEPT, dtype=np.int8)
        tracked = cat.tracked[boxes.category] if len(boxes) else np.zeros(0, dtype=bool)
        reason[~tracked] = DropReason.CATEGORY
        low = tracked & ~(boxes.score > cat.score_min[np.where(tracked, boxes.category, 0)])
        reason[low] = DropReason.SCORE
        kept = np.flatnonzero(reason == DropReason.KEPT)
        if self.config.nms and len(kept) > 1:
            suppressed = _nms_suppressed(boxes[kept], cat.nms_iou_max)
            reason[kept[suppressed]] = DropReason.NMS
            kept = kept[~suppressed]
        if self.observer:
            self.observer(DetectionsFiltered(frame, reason, kept))
        return boxes[kept], kept

    def _needs_back_prediction(self) -> bool:
        return bool(len(self._tracks)) and bool(np.any(self._cat.alpha[self._tracks.category] < 1))

    def _predict(self, dt: float) -> None:
        """Advance every track's three filters by the real elapsed time (misses included)."""
        tr = self._tracks
        if not len(tr):
            return
        cat, dts, nominal = self._cat, np.full(len(tr), dt), self.config.nominal_dt_secs
        tr.pose_x, tr.pose_P = kalman.pose_predict(
            tr.pose_x,
            tr.pose_P,
            dt_secs=dts,
            q_diag=cat.pose_q[tr.category],
            dt_nominal_secs=nominal,
        )
        tr.size_x, tr.size_P = kalman.size_predict(
            tr.size_x,
            tr.size_P,
            dt_secs=dts,
            q_diag=cat.size_q[tr.category],
            dt_nominal_secs=nominal,
        )
        tr.head_x, tr.head_P = kalman.heading_predict(
            tr.head_x,
            tr.head_P,
            dt_secs=dts,
            q_diag=cat.head_q[tr.category],
            dt_nominal_secs=nominal,
        )
        tr.age += 1

    def _bev_cost(self, pred: Boxes, prev: Boxes | None, dets: Boxes, dt: float) -> FloatArray:
        """(T, D) cost = 1 - similarity; +inf across categories and beyond the distance gate."""
        tr, cat = self._tracks, self._cat
        same = tr.category[:, None] == dets.category[None, :]
        delta = pred.xyz[:, None, :2] - dets.xyz[None, :, :2]
        near = np.einsum("tdk,tdk->td", delta, delta) < cat.gate_m[tr.category][:, None] ** 2
        mask = same & near
        w1, w2 = cat.w1[tr.category], cat.w2[tr.category]
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
            sim = np.where(a >= 1, sim, np.where(a <= 0, back, a * sim + (1 - a) * back))
        with np.errstate(invalid="ignore"):
            return np.where(mask, 1.0 - sim, np.inf)

    def _rv_stage(
        self,
        frame: Frame,
        pred: Boxes,
        dets: Boxes,
        rows: IntArray,
        cols: IntArray,
        kept_rows: IntArray,
    ) -> tuple[Matches, IntArray]:
        """Stage 2 on the leftovers of stage 1: SDIoU of 2D boxes, greedy, yaw/distance gate.

        Returns the accepted matches (indices into ``rows``/``cols``) and the indices into
        ``cols`` of detections consumed by the stage (accepted, plus gated ones in reference
        mode, which drops them as the original code does).
        """
        tr, cat, reference = self._tracks, self._cat, self.config.rv_reference
        sub_dets = dets[cols]
        track_xyxy = np.full((len(rows), 4), np.nan)
        track_cam = np.full(len(rows), -1, dtype=np.int64)
        cost = np.full((len(rows), len(cols)), np.inf)
        same = tr.category[rows][:, None] == sub_dets.category[None, :]
        if reference:
            # the reference compares the detector's 2D box of the track's last detection
            track_xyxy, track_cam = tr.last_xyxy[rows], tr.last_camera[rows]
            for c in np.unique(sub_dets.camera[sub_dets.camera >= 0]):
                r, d = track_cam == c, sub_dets.camera == c
                cost[np.ix_(r, d)] = 1.0 - sdiou_image(track_xyxy[r], sub_dets.xyxy_image[d])
        else:
            # the paper: project the track's predicted 3D box into the detection's camera
            for c in np.unique(sub_dets.camera[sub_dets.camera >= 0]):
                xyxy, visible = project_boxes(pred[rows], frame.cameras[c])
                d = sub_dets.camera == c
                take = visible & (track_cam < 0)
                track_xyxy[take], track_cam[take] = xyxy[take], c
                block = 1.0 - sdiou_image(xyxy[visible], sub_dets.xyxy_image[d])
                cost[np.ix_(visible, d)] = block
        cost = np.where(same, cost, np.inf)
        max_cost = cat.rv_cost_max[tr.category[rows]]
        m = greedy(cost, max_cost_per_row=max_cost, order=self.config.greedy_order.value)

        # gate: heading within yaw_gate and centres within distance_gate of the track
        t_rows, d_cols = rows[m.pairs[:, 0]], m.pairs[:, 1]
        if reference:
            track_yaw, track_xyz = tr.last_det_yaw[t_rows], tr.last_det_xyz[t_rows]
        else:
            track_yaw, track_xyz = pred.yaw[t_rows], pred.xyz[t_rows]
        yaw_gap = np.abs(wrap_angle(track_yaw - sub_dets.yaw[d_cols]))
        dist = np.linalg.norm(track_xyz - sub_dets.xyz[d_cols], axis=1)
        ok = (yaw_gap <= cat.rv_yaw_gate[tr.category[t_rows]]) & (
            dist <= cat.rv_distance_gate[tr.category[t_rows]]
        )
        accepted = Matches(
            pairs=m.pairs[ok],
            costs=m.costs[ok],
            unmatched_rows=np.setdiff1d(np.arange(len(rows)), m.pairs[ok, 0]),
            unmatched_cols=np.setdiff1d(np.arange(len(cols)), m.pairs[ok, 1]),
        )
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
                    kept_rows[cols[d_cols[ok]]],
                    m.costs[ok],
                    tr.track_id[t_rows[~ok]],
                    kept_rows[cols[d_cols[~ok]]],
                )
            )
        return accepted, consumed

    def _update(self, idx: IntArray, dets: Boxes) -> None:
        """Kalman updates of the matched tracks (position, size, heading from both sources)."""
        if not len(idx):
            return
        tr, cat = self._tracks, self._cat
        c = tr.category[idx]
        vel = np.where(cat.measure_velocity[c][:, None], dets.velocity, np.nan)
        pose_x, pose_P = kalman.pose_update(
            tr.pose_x[idx],
            tr.pose_P[idx],
            xy=dets.xyz[:, :2],
            r_diag=cat.pose_r[c],
            velocity_xy=vel,
        )
        size_x, size_P = kalman.size_update(
            tr.size_x[idx], tr.size_P[idx], lw=dets.lwh[:, :2], r_diag=cat.size_r[c]
        )
        # heading from perception and from velocity (paper §3.3). Detections carry a 180°
        # ambiguity, so the sign of the heading is decided first: by the direction of travel
        # when the object clearly moves (speed above its threshold and 3 sigma of its
        # estimate), else by the detector's majority (a run of disagreeing detections flips
        # the state). The detection's yaw is then aligned to that heading and both update θ.
        head_x = tr.head_x[idx].copy()
        yaw_vel = np.arctan2(pose_x[:, 3], pose_x[:, 2])
        speed = np.hypot(pose_x[:, 2], pose_x[:, 3])
        speed_sigma = np.sqrt(pose_P[:, 2, 2] + pose_P[:, 3, 3])
        moving = (speed > cat.head_min_speed[c]) & (speed > 3.0 * speed_sigma)
        disagree = np.abs(wrap_angle(dets.yaw - head_x[:, 0])) > np.pi / 2
        votes = np.where(disagree, tr.heading_votes[idx] + 1, 0)
        flip_by_votes = ~moving & (votes >= HEADING_FLIP_VOTES)
        head_x[:, 0] = np.where(moving, kalman.align_heading(head_x[:, 0], yaw_vel), head_x[:, 0])
        head_x[:, 0] = np.where(flip_by_votes, wrap_angle(head_x[:, 0] + np.pi), head_x[:, 0])
        tr.heading_votes[idx] = np.where(flip_by_votes | moving, 0, votes)
        yaw_det = kalman.align_heading(dets.yaw, head_x[:, 0])
        head_x, head_P = kalman.heading_update(
            head_x,
            tr.head_P[idx],
            yaw_det_rad=yaw_det,
            yaw_vel_rad=yaw_vel,
            r_diag=cat.head_r[c],
            yaw_vel_valid=moving,
        )
        tr.pose_x[idx], tr.pose_P[idx] = pose_x, pose_P
        tr.size_x[idx], tr.size_P[idx] = size_x, size_P
        tr.head_x[idx], tr.head_P[idx] = head_x, head_P
        tr.z[idx], tr.height[idx] = dets.xyz[:, 2], dets.lwh[:, 2]
        tr.score[idx] = dets.score
        tr.logit_sum[idx] += _logit(dets.score)
        tr.last_xyxy[idx], tr.last_camera[idx] = dets.xyxy_image, dets.camera
        tr.last_det_xyz[idx], tr.last_det_lwh[idx] = dets.xyz, dets.lwh
        tr.last_det_yaw[idx] = dets.yaw
        tr.hits[idx] += 1

    def _birth(self, dets: Boxes, det_rows: IntArray) -> IntArray:
        """New tracks from unmatched detections scoring above the birth threshold."""
        cat = self._cat
        strong = dets.score > cat.birth_score_min[dets.category]
        dets, det_rows = dets[strong], det_rows[strong]
        n = len(dets)
        if not n:
            return _EMPTY_INT
        c = dets.category
        new = TrackTable.empty()
        new.track_id = np.arange(self._next_id, self._next_id + n, dtype=np.int64)
        self._next_id += n
        new.category = c.copy()
        new.status = np.full(n, TrackStatus.TENTATIVE, dtype=np.int8)
        new.hits = np.ones(n, dtype=np.int64)
        new.misses = np.zeros(n, dtype=np.int64)
        new.age = np.zeros(n, dtype=np.int64)
        vel = np.where(cat.measure_velocity[c][:, None], dets.velocity, 0.0)
        new.pose_x, _ = kalman.pose_init(
            dets.xyz[:, :2], p0_diag=cat.pose_p0[0], velocity_xy=vel, n_state=POSE_DIM
        )
        new.pose_P = _diag(cat.pose_p0[c])
        new.size_x, _ = kalman.size_init(dets.lwh[:, :2], p0_diag=cat.size_p0[0])
        new.size_P = _diag(cat.size_p0[c])
        new.head_x, _ = kalman.heading_init(dets.yaw, p0_diag=cat.head_p0[0])
        new.head_P = _diag(cat.head_p0[c])
        new.z, new.height = dets.xyz[:, 2].copy(), dets.lwh[:, 2].copy()
        new.score = dets.score.copy()
        new.logit_sum = _logit(dets.score)
        new.last_xyxy, new.last_camera = dets.xyxy_image.copy(), dets.camera.copy()
        new.last_det_xyz, new.last_det_lwh = dets.xyz.copy(), dets.lwh.copy()
        new.last_det_yaw = dets.yaw.copy()
        new.heading_votes = np.zeros(n, dtype=np.int64)
        new.matched_det = det_rows.copy()
        new.matched_stage = np.zeros(n, dtype=np.int8)
        self._tracks = self._tracks.append(new)
        return new.track_id

    def _lifecycle(self, matched: IntArray, born: IntArray) -> LifecycleChanged:
        """Per-category birth/confirm/coast/lose/delete rules (paper §3.4)."""
        tr, cat = self._tracks, self._cat
        n_old = len(tr) - len(born)
        hit = np.zeros(len(tr), dtype=bool)
        hit[matched] = True
        hit[n_old:] = True  # a birth is its own first hit
        tr.misses[hit] = 0
        tr.misses[~hit] += 1
        c = tr.category
        old_status = tr.status.copy()
        tentative = old_status == TrackStatus.TENTATIVE
        confirm = (
            hit & tentative & ((tr.hits >= cat.min_hits[c]) | (tr.score >= cat.confirm_score[c]))
        )
        reacquire = hit & ((old_status == TrackStatus.COASTING) | (old_status == TrackStatus.LOST))
        status = tr.status
        status[confirm | reacquire] = TrackStatus.CONFIRMED
        live = ~tentative & ~hit
        status[live & (tr.misses >= 1)] = TrackStatus.COASTING
        status[live & (tr.misses > cat.max_misses_output[c])] = TrackStatus.LOST
        dead = (live & (tr.misses > cat.max_misses[c])) | (
            tentative & ~hit & (tr.misses > cat.max_misses_tentative[c])
        )
        lost = (status == TrackStatus.LOST) & (old_status != TrackStatus.LOST) & ~dead
        change = LifecycleChanged(
            born=born,
            confirmed=tr.track_id[confirm],
            lost=tr.track_id[lost],
            reacquired=tr.track_id[reacquire & (old_status == TrackStatus.LOST)],
            deleted=tr.track_id[dead],
        )
        if dead.any():
            self._tracks = tr.select(~dead)
        return change

    def _output(self, frame: Frame, time_secs: float) -> TrackOutput:
        tr = self._tracks
        out = (tr.status == TrackStatus.CONFIRMED) | (tr.status == TrackStatus.COASTING)
        if self.config.mode is TrackingMode.OFFLINE:
            # offline post-processing decides per whole track (it knows the future), so it also
            # gets the detections of tracks not confirmed yet
            out |= (tr.status == TrackStatus.TENTATIVE) & (tr.matched_det >= 0)
        boxes = tr.boxes()[out]
        if self.config.output_geometry is OutputGeometry.DETECTION:
            hit = tr.matched_det[out] >= 0
            boxes = boxes.replace(
                xyz=np.where(hit[:, None], tr.last_det_xyz[out], boxes.xyz),
                lwh=np.where(hit[:, None], tr.last_det_lwh[out], boxes.lwh),
                yaw=np.where(hit, kalman.align_heading(tr.last_det_yaw[out], boxes.yaw), boxes.yaw),
            )
        return TrackOutput(
            scene=frame.scene,
            frame_id=frame.frame_id,
            time_secs=time_secs,
            boxes=boxes,
            acceleration=tr.pose_x[out, 4:6].copy(),
            status=tr.status[out].copy(),
            det_row=tr.matched_det[out].copy(),
            stage=tr.matched_stage[out].copy(),
        )


def _matched(stage: Stage, m: Matches, track_ids: IntArray, kept_rows: IntArray) -> Matched:
    return Matched(
        stage,
        track_ids[m.pairs[:, 0]],
        kept_rows[m.pairs[:, 1]],
        m.costs,
        _EMPTY_INT,
        _EMPTY_INT,
    )


def _diag(diags: FloatArray) -> FloatArray:
    """(B, n) diagonals -> (B, n, n) diagonal matrices."""
    out = np.zeros((*diags.shape, diags.shape[-1]))
    idx = np.arange(diags.shape[-1])
    out[:, idx, idx] = diags
    return out


def _logit(p: FloatArray) -> FloatArray:
    p = np.clip(p, 1e-6, 1 - 1e-6)
    return np.log(p / (1 - p))


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
