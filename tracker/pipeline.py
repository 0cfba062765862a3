"""Running the tracker over scenes: online, or offline (global) with track-level post-processing.

Offline mode (reference §2.9, improved): run online with the offline config, then
  0. (``offline.exchange_seconds`` > 0) give two neighbouring tracks that traded objects their
     tails back (:func:`tracker.exchange.exchange_tails`),
and per track
  1. score = mean logit of its real detections; drop the whole track if score <= threshold
     (``offline.track_score_min``, or its class's ``lifecycle.offline_track_score_min`` where
     higher) or it has fewer than ``min_hits`` detections (tentative rows are kept for
     confirmed tracks: offline, a track's first detections need not wait for its confirmation),
  2. fill interior gaps (up to ``interpolate_max_gap`` frames) by linear interpolation of
     position, size, heading (on the circle) and velocity — replacing coasting predictions,
  3. drop trailing coasting rows after the last real detection (offline knows the track ended),
  4. (``offline.smooth_seconds`` > 0) smooth each track's positions by a centred local quadratic
     fit before interpolating (:func:`smooth_positions`); with ``offline.rts``, x and y of its
     detected rows come from the RTS smoother over its detections instead
     (:func:`tracker.smoothing.rts_smooth`: the online filter without its lag; velocity and
     acceleration too), and with ``offline.rts_heading`` their heading from the heading filter's
     smoother over its detected yaws (:func:`tracker.smoothing.rts_smooth_heading`),
  5. (``offline.constant_size``) give each track one size, the mean of its detected rows'
     (:func:`mean_size_per_track`): a rigid object's size does not change,
  6. (``offline.stitch_max_gap`` > 0) between 1 and 2, join fragments: a kept track that starts soon
     after another of its class ended, where that one's constant-velocity extrapolation puts it,
     continues it under its id (:func:`stitch_tracks`), so its gap is filled like any other
     (up to ``interpolate_max_gap`` frames).
"""

from __future__ import annotations

import itertools
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from tracker.boxes import Boxes
from tracker.calibration import score_log_odds
from tracker.categories import CATEGORIES
from tracker.config import TrackerConfig, TrackingMode
from tracker.events import Observer, TrackOutput, TrackStatus
from tracker.exchange import exchange_tails
from tracker.frame import Frame
from tracker.fusion import fuse_scene
from tracker.geometry import wrap_angle
from tracker.matching import hungarian
from tracker.mctracker import MCTracker, motion_noise_tables
from tracker.smoothing import rts_smooth, rts_smooth_heading

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class RemovedTrack:
    """A whole track offline post-processing removed, and why."""

    track_id: int
    category: str
    detections: int  # its real (matched or born) detections
    score: float  # mean logit of its detections
    reason: str  # "track_score" (score <= the offline track score threshold) or "min_hits"


@dataclass(frozen=True, slots=True)
class SceneResult:
    scene: str
    outputs: list[TrackOutput]
    tracker_seconds: float  # time inside the tracker (and offline post-processing) only
    removed_offline: list[RemovedTrack] = field(default_factory=list)


def run_scene(
    frames: Sequence[Frame], config: TrackerConfig, *, observer: Observer | None = None
) -> SceneResult:
    """Track one scene's frames (in time order) with a fresh tracker."""
    tracker = MCTracker(config, observer=observer)
    outputs: list[TrackOutput] = []
    removed: list[RemovedTrack] = []
    start = time.perf_counter()
    unfused = frames
    if config.image_bearing:  # the tracker (and the offline smoothers) see the fused centres
        frames = fuse_scene(frames, len(CATEGORIES))
    for frame, own in zip(frames, unfused, strict=True):
        outputs.append(tracker.step(frame, None if own is frame else own))
    if config.mode is TrackingMode.OFFLINE:
        outputs = offline_postprocess(
            outputs, config, removed=removed, frames=frames, motion_r=tracker.motion_r,
            noise_variance=tracker.noise_variance,
        )  # fmt: skip
    elapsed = time.perf_counter() - start
    scene = frames[0].scene if frames else ""
    if removed:
        log.info(
            "scene %s: offline post-processing removed %d tracks (%d detections): %s",
            scene,
            len(removed),
            sum(r.detections for r in removed),
            ", ".join(f"{r.track_id} {r.category} {r.reason}" for r in removed[:20])
            + (" ..." if len(removed) > 20 else ""),
        )
    return SceneResult(scene, outputs, elapsed, removed)


def offline_postprocess(
    outputs: list[TrackOutput],
    config: TrackerConfig,
    *,
    removed: list[RemovedTrack] | None = None,
    frames: Sequence[Frame] | None = None,
    motion_r: np.ndarray | None = None,
    noise_variance: np.ndarray | None = None,
) -> list[TrackOutput]:
    """Track-score filter and gap interpolation over a whole scene (see module docstring).

    Whole tracks removed by the filter are appended to ``removed`` (when given). ``frames``, the
    scene's input frames, are needed by ``offline.rts``, ``offline.rts_heading`` and
    ``offline.exchange_seconds`` (without them they are off). ``motion_r``: the R table the
    position smoother uses instead of the config's, the tracker's at the scene's end (with
    ``pose.r_scale``, r from the noise of the whole scene's detections). ``noise_variance``
    (C,): the detections' estimated centre variance per class, the tracker's at the scene's end
    (``offline.exchange_seconds`` needs it).
    """
    if not outputs:
        return outputs
    # flatten: one row per (frame, track)
    frame_index = np.concatenate([np.full(len(o), i) for i, o in enumerate(outputs)])
    boxes = Boxes.concat([o.boxes for o in outputs])
    acc = np.concatenate([o.acceleration for o in outputs])
    status = np.concatenate([o.status for o in outputs])
    det_row = np.concatenate([o.det_row for o in outputs])
    stage = np.concatenate([o.stage for o in outputs])
    real = det_row >= 0
    times = np.array([o.time_secs for o in outputs])
    if config.offline.exchange_seconds > 0 and frames is not None and noise_variance is not None:
        # neighbours that traded objects get their tails back, before the tracks are judged
        xy = np.full((len(boxes), 2), np.nan)
        xy[real] = _detection_xy(frames, frame_index[real], det_row[real])
        track_id = exchange_tails(
            boxes.track_id, frame_index, times, xy,
            boxes.category, np.flatnonzero(real), noise_variance, config.offline.exchange_seconds,
        )  # fmt: skip
        boxes = boxes.replace(track_id=track_id)
    keep = real.copy()
    new_src: list[tuple[int, int, int, float]] = []  # (frame index, row before, row after, w)
    logit = score_log_odds(boxes.score)
    for tid in np.unique(boxes.track_id):
        rows = np.flatnonzero((boxes.track_id == tid) & real)
        if not len(rows):
            continue
        score = float(logit[rows].mean())
        name = CATEGORIES[int(boxes.category[rows[0]])]
        lifecycle = config.per_category[name].lifecycle
        score_min = max(config.offline.track_score_min, lifecycle.offline_track_score_min)
        if score <= score_min or len(rows) < lifecycle.min_hits:
            keep[rows] = False
            if removed is not None:
                reason = "track_score" if score <= score_min else "min_hits"
                removed.append(RemovedTrack(int(tid), name, len(rows), score, reason))
    if config.offline.stitch_max_gap > 0:
        track_id = stitch_tracks(
            boxes, frame_index, times, keep,
            max_gap=config.offline.stitch_max_gap, distance_m=config.offline.stitch_distance_m,
        )  # fmt: skip
        boxes = boxes.replace(track_id=track_id)
    tracks_score: dict[int, float] = {}
    for tid in np.unique(boxes.track_id[keep]):
        rows = np.flatnonzero((boxes.track_id == tid) & keep)
        tracks_score[int(tid)] = float(logit[rows].mean())
        for a, b in itertools.pairwise(rows):
            gap = frame_index[b] - frame_index[a] - 1
            if 0 < gap <= config.offline.interpolate_max_gap:
                for k in range(1, gap + 1):
                    new_src.append((int(frame_index[a]) + k, int(a), int(b), k / (gap + 1)))
    window = config.offline_smooth_frames
    if window >= 3:
        xyz = smooth_positions(boxes.xyz, boxes.track_id, frame_index, keep, window)
        boxes = boxes.replace(xyz=xyz)
    if frames is not None and (config.offline.rts or config.offline.rts_heading):
        # the detected rows, smoothed over the track's detections by the online filters rerun
        # forwards and then backwards (tracker.smoothing)
        measured = np.flatnonzero(keep & (det_row >= 0))
        det_at = _detection_index(frames, frame_index[measured], det_row[measured])
        at = (frame_index[measured], boxes.track_id[measured])
        category = boxes.category[measured]
        if config.offline.rts:
            if motion_r is None and any(c.pose.r_scale > 0 for c in config.per_category.values()):
                log.warning(
                    "offline smoother: no motion_r given, so the config's r is used where"
                    " pose.r_scale would set it from the detections (pass the tracker's)"
                )
            # position, velocity and acceleration (x, y); z keeps the fit above
            det_xy = _detection_xy(frames, frame_index[measured], det_row[measured])
            r_table = motion_noise_tables(config)[2] if motion_r is None else motion_r
            r_table = r_table * config.offline.rts_r_multiple
            state = rts_smooth(times, *at, det_xy, category, config, motion_r=r_table)
            xyz, velocity = boxes.xyz.copy(), boxes.velocity.copy()
            xyz[measured, :2], velocity[measured] = state[..., 0], state[..., 1]
            boxes = boxes.replace(xyz=xyz, velocity=velocity)
            acc = acc.copy()
            has_acc = np.isfinite(acc[measured]).all(axis=1)  # (NaN: a CV category has none)
            acc[measured[has_acc]] = state[has_acc, :, 2]
        if config.offline.rts_heading:
            det_yaw = np.concatenate([f.boxes.yaw for f in frames])[det_at]
            ok = np.isfinite(det_yaw)  # (a box without a yaw keeps the online heading)
            yaw = boxes.yaw.copy()
            yaw[measured[ok]] = rts_smooth_heading(
                times, at[0][ok], at[1][ok], det_yaw[ok], boxes.yaw[measured[ok]], category[ok],
                config,
            )  # fmt: skip
            boxes = boxes.replace(yaw=yaw)
    if config.offline.constant_size:
        boxes = boxes.replace(lwh=mean_size_per_track(boxes.lwh, boxes.track_id, keep))
    parts: list[list[Boxes]] = [[] for _ in outputs]
    extra_acc: list[list[np.ndarray]] = [[] for _ in outputs]
    if new_src:
        f_idx = np.array([s[0] for s in new_src])
        a = np.array([s[1] for s in new_src])
        b = np.array([s[2] for s in new_src])
        w = np.array([s[3] for s in new_src])[:, None]
        yaw = wrap_angle(boxes.yaw[a] + w[:, 0] * wrap_angle(boxes.yaw[b] - boxes.yaw[a]))
        interp = Boxes(
            xyz=(1 - w) * boxes.xyz[a] + w * boxes.xyz[b],
            lwh=(1 - w) * boxes.lwh[a] + w * boxes.lwh[b],
            yaw=yaw,
            velocity=(1 - w) * boxes.velocity[a] + w * boxes.velocity[b],
            score=np.full(len(a), np.nan),  # set below to the track score (as a probability)
            category=boxes.category[a],
            xyxy_image=np.full((len(a), 4), np.nan),
            camera=boxes.camera[a],
            track_id=boxes.track_id[a],
            score_raw=np.full(len(a), np.nan),
        )
        track_p = np.array([1 / (1 + np.exp(-tracks_score[int(t)])) for t in interp.track_id])
        interp = interp.replace(score=track_p)
        interp_acc = (1 - w) * acc[a] + w * acc[b]
        for i in range(len(outputs)):
            sel = f_idx == i
            if sel.any():
                parts[i].append(interp[sel])
                extra_acc[i].append(interp_acc[sel])
    result: list[TrackOutput] = []
    for i, out in enumerate(outputs):
        rows = np.flatnonzero((frame_index == i) & keep)
        n_new = sum(len(p) for p in parts[i])
        merged = Boxes.concat([boxes[rows], *parts[i]])
        order = np.argsort(merged.track_id, kind="stable")
        result.append(
            TrackOutput(
                scene=out.scene,
                frame_id=out.frame_id,
                time_secs=out.time_secs,
                boxes=merged[order],
                acceleration=np.concatenate([acc[rows], *extra_acc[i]])[order]
                if n_new
                else acc[rows],
                status=np.concatenate(
                    [status[rows], np.full(n_new, TrackStatus.COASTING, dtype=np.int8)]
                )[order],
                det_row=np.concatenate([det_row[rows], np.full(n_new, -1)])[order],
                stage=np.concatenate([stage[rows], np.zeros(n_new, dtype=np.int8)])[order],
            )
        )
    return result


def _detection_index(
    frames: Sequence[Frame], frame_index: np.ndarray, det_row: np.ndarray
) -> np.ndarray:
    """Rows' detections as indices into the scene's detections, concatenated frame by frame."""
    start = np.cumsum([0] + [len(f.boxes) for f in frames])  # each frame's first detection
    return start[frame_index] + det_row


def _detection_xy(
    frames: Sequence[Frame], frame_index: np.ndarray, det_row: np.ndarray
) -> np.ndarray:
    """(K, 2) the BEV centres of the rows' own detections."""
    xy = np.concatenate([f.boxes.xyz[:, :2] for f in frames])
    return xy[_detection_index(frames, frame_index, det_row)]


def stitch_tracks(
    boxes: Boxes,
    frame_index: np.ndarray,
    times: np.ndarray,
    keep: np.ndarray,
    *,
    max_gap: int,
    distance_m: float,
) -> np.ndarray:
    """(N,) track ids with fragments joined: a kept track B that starts 1..``max_gap`` frames
    after a kept track A of its class ends continues A (takes A's id) when A's last position,
    carried forward at A's last velocity to B's first frame, is within ``distance_m`` of B's first
    position. Each track continues at most one and is continued by at most one (Hungarian on that
    distance; dense over the scene's kept tracks); chains join. Rows outside ``keep`` keep their
    ids."""
    track_id = boxes.track_id.copy()
    kept = np.flatnonzero(keep)  # in frame order (rows are flattened frame by frame)
    ids, of = np.unique(track_id[kept], return_inverse=True)
    if len(ids) < 2:
        return track_id
    first = kept[np.unique(of, return_index=True)[1]]
    last = kept[len(kept) - 1 - np.unique(of[::-1], return_index=True)[1]]
    f0, f1 = frame_index[first], frame_index[last]
    gap = f0[None, :] - f1[:, None]  # (A, B) frames from A's end to B's start
    ok = (gap >= 1) & (gap <= max_gap) & (boxes.category[last][:, None] == boxes.category[first])
    dt = times[f0][None, :] - times[f1][:, None]
    ahead = boxes.xyz[last, None, :2] + boxes.velocity[last, None, :] * dt[..., None]
    dist = np.linalg.norm(ahead - boxes.xyz[first][None, :, :2], axis=-1)
    m = hungarian(np.where(ok, dist, np.inf), max_cost_per_row=np.full(len(ids), distance_m))
    parent = np.arange(len(ids))
    parent[m.pairs[:, 1]] = m.pairs[:, 0]
    root = parent.copy()
    for b in np.argsort(f0, kind="stable"):  # A starts before B: its root is already final
        root[b] = root[parent[b]]
    log.debug(
        "stitching: %d of %d tracks continue another", (root != np.arange(len(ids))).sum(), len(ids)
    )
    track_id[kept] = ids[root[of]]
    return track_id


def mean_size_per_track(lwh: np.ndarray, track_id: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """(N, 3) sizes with every kept row of a track set to the mean over the track's kept rows;
    rows outside ``keep`` are unchanged."""
    out = lwh.copy()
    rows = np.flatnonzero(keep)
    if not len(rows):
        return out
    _, inverse, count = np.unique(track_id[rows], return_inverse=True, return_counts=True)
    total = np.zeros((len(count), 3))
    np.add.at(total, inverse, lwh[rows])
    out[rows] = (total / count[:, None])[inverse]
    return out


def smooth_positions(
    xyz: np.ndarray, track_id: np.ndarray, frame_index: np.ndarray, keep: np.ndarray, window: int
) -> np.ndarray:
    """(N, 3) positions with each track's kept rows smoothed over time.

    A centred local quadratic fit (Savitzky-Golay, ``window`` frames, odd; shorter at the ends
    of short runs) over every run of consecutive frames of a track: constant-acceleration motion
    passes unchanged, box noise averages out, and, looking ahead as offline can, there is none of
    the causal filter's lag. Runs shorter than 3 frames and rows outside ``keep`` are unchanged.
    """
    from scipy.signal import savgol_filter

    out = xyz.copy()
    rows = np.flatnonzero(keep)
    order = rows[np.lexsort((frame_index[rows], track_id[rows]))]
    tid, f = track_id[order], frame_index[order]
    breaks = np.flatnonzero((np.diff(tid) != 0) | (np.diff(f) != 1)) + 1
    for run in np.split(order, breaks):
        n = len(run)
        if n < 3:
            continue
        w = min(window, n if n % 2 else n - 1)
        out[run] = savgol_filter(xyz[run], w, min(2, w - 1), axis=0, mode="interp")
    return out
