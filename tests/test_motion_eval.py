"""Motion evaluation (tracker/eval/motion_eval.py): association, GT velocity, estimators,
invariances.

Analytic truths, not snapshots: exact velocities of hand-built tracks, invariance under frame
order and scene splits, and physical sanity on KITTI (parked cars have ~0 GT velocity).
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tracker.boxes import Boxes
from tracker.categories import category_index
from tracker.config import load_config
from tracker.eval.motion_eval import (
    MAX_DISTANCE_M,
    NO_DETECTOR_VELOCITY,
    Estimator,
    collect_motion_samples,
    derive_gt_velocity,
    evaluate_motion,
    greedy_match_bev_distance,
    largest_delay_tracks,
    metrics_from_dict,
    motion_markdown,
)
from tracker.eval.motion_metrics import combine_motion_metrics
from tracker.events import TrackOutput, TrackStatus
from tracker.frame import Frame
from tracker.io.synthetic import synthetic_scene
from tracker.pipeline import run_scene

CAR = category_index("car")
PEDESTRIAN = category_index("pedestrian")
VAN = category_index("van")
CLASSES = ("car", "pedestrian")


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


def tracked(scene: str = "synthetic", seed: int = 0, num_frames: int = 80):
    """(detections, GT, outputs) of a seeded synthetic scene run through the KITTI tracker."""
    dets, gts = synthetic_scene(num_objects=6, num_frames=num_frames, seed=seed, scene=scene)
    # the reference KITTI settings (births at once): independent of the tuned thresholds, which
    # are calibrated to PointRCNN scores, not to the synthetic ones
    config = load_config("kitti_reference", overrides={"categories": list(CLASSES)})
    return dets, gts, run_scene(dets, config).outputs


def output(
    frame_id: int,
    *,
    xy: list[list[float]],
    track_id: list[int],
    category: list[int],
    det_row: list[int] | None = None,
    velocity: list[list[float]] | None = None,
    score: list[float] | None = None,
    scene: str = "s",
) -> TrackOutput:
    n = len(xy)
    boxes = Boxes.create(
        xyz=np.column_stack([np.asarray(xy, dtype=float).reshape(n, 2), np.zeros(n)]),
        lwh=np.tile([4.0, 1.8, 1.5], (n, 1)),
        yaw=np.zeros(n),
        category=category,
        velocity=velocity if velocity is not None else np.zeros((n, 2)),
        score=score,
        track_id=track_id,
    )
    return TrackOutput(
        scene=scene,
        frame_id=frame_id,
        time_secs=0.1 * frame_id,
        boxes=boxes,
        acceleration=np.zeros((n, 2)),
        status=np.full(n, TrackStatus.CONFIRMED, dtype=np.int8),
        det_row=np.asarray(det_row if det_row is not None else range(n), dtype=np.int64),
        stage=np.ones(n, dtype=np.int8),
    )


def frame(
    frame_id: int,
    *,
    xy: list[list[float]],
    category: list[int],
    track_id: list[int] | None = None,
    velocity: list[list[float]] | None = None,
    scene: str = "s",
) -> Frame:
    n = len(xy)
    boxes = Boxes.create(
        xyz=np.column_stack([np.asarray(xy, dtype=float).reshape(n, 2), np.zeros(n)]),
        lwh=np.tile([4.0, 1.8, 1.5], (n, 1)),
        yaw=np.zeros(n),
        category=category,
        velocity=velocity,
        track_id=track_id,
    )
    return Frame(scene=scene, frame_id=frame_id, timestamp_secs=0.1 * frame_id, boxes=boxes)


def metrics_of(result: dict, estimator: str, cls: str):
    return metrics_from_dict(result["metrics"][estimator][cls])


def assert_metrics_close(a, b) -> None:
    for (name, x), y in zip(a.as_dict().items(), b.as_dict().values(), strict=True):
        assert x == pytest.approx(y, rel=1e-9, abs=1e-12, nan_ok=True), name


# --------------------------------------------------------------------------------------------
# Association
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("track_xy", "score", "gt_xy", "max_m", "expected"),
    [
        (np.zeros((0, 2)), np.zeros(0), np.zeros((2, 2)), 2.0, []),
        (np.zeros((2, 2)), np.ones(2), np.zeros((0, 2)), 2.0, []),
        ([[1.0, 0.0]], [0.5], [[0.0, 0.0]], 1.0, [[0, 0]]),  # inclusive threshold
        ([[1.0 + 1e-9, 0.0]], [0.5], [[0.0, 0.0]], 1.0, []),
        # the higher score takes the GT even though the other output is nearer
        ([[0.1, 0.0], [1.5, 0.0]], [0.2, 0.9], [[0.0, 0.0]], 2.0, [[1, 0]]),
        # each output takes its nearest free GT, in score order
        ([[0.0, 0.0], [0.4, 0.0]], [0.9, 0.8], [[0.5, 0.0], [-0.2, 0.0]], 2.0, [[0, 1], [1, 0]]),
        # NaN scores go last
        ([[0.0, 0.0], [0.5, 0.0]], [np.nan, 0.1], [[0.0, 0.0]], 2.0, [[1, 0]]),
    ],
)
def test_greedy_match_table(track_xy, score, gt_xy, max_m, expected) -> None:
    pairs = greedy_match_bev_distance(
        np.asarray(track_xy, dtype=float).reshape(-1, 2),
        np.asarray(score, dtype=float),
        np.asarray(gt_xy, dtype=float).reshape(-1, 2),
        max_distance_m=max_m,
    )
    assert pairs.tolist() == expected
    assert pairs.dtype == np.int64 and pairs.shape[1] == 2


def test_association_threshold_is_per_class_and_other_categories_are_ignored() -> None:
    """A car 1.5 m from its GT matches (2 m), a pedestrian 1.5 m away does not (1 m), a car
    next to a van GT does not match the van."""
    assert MAX_DISTANCE_M["car"] == 2.0 and MAX_DISTANCE_M["pedestrian"] == 1.0
    gt_frames, out_frames, det_frames = [], [], []
    for f in range(12):
        x = 1.0 * f
        gt_frames.append(
            frame(
                f,
                xy=[[x, 0.0], [x, 10.0], [x, 20.0]],
                category=[CAR, PEDESTRIAN, VAN],
                track_id=[1, 2, 3],
            )
        )
        xy = [[x + 1.5, 0.0], [x + 1.5, 10.0], [x, 20.0]]
        out_frames.append(output(f, xy=xy, track_id=[7, 8, 9], category=[CAR, PEDESTRIAN, CAR]))
        det_frames.append(frame(f, xy=xy, category=[CAR, PEDESTRIAN, CAR]))
    samples = collect_motion_samples(
        {"s": det_frames}, {"s": gt_frames}, {"s": out_frames}, classes=CLASSES
    )
    car, ped = samples["car"], samples["pedestrian"]
    assert len(car) == 12 and set(car.track_id) == {7} and set(car.gt_track_id) == {1}
    np.testing.assert_allclose(car.distance_m, 1.5)
    assert len(ped) == 0 and ped.n_gt_boxes == 12 and ped.n_matched == 0
    assert car.n_gt_boxes == 12  # the van is not a car GT box

    loose = collect_motion_samples(
        {"s": det_frames},
        {"s": gt_frames},
        {"s": out_frames},
        classes=CLASSES,
        max_distance_m={"pedestrian": 1.5},
    )
    assert len(loose["pedestrian"]) == 12


# --------------------------------------------------------------------------------------------
# GT velocity and the position baselines
# --------------------------------------------------------------------------------------------


def test_gt_velocity_from_positions_is_exact_and_split_at_gaps() -> None:
    """Constant velocity (exact for the central quadratic fit), a 3-frame hole that starts a new
    segment, a lone sample (NaN) and a box without id (NaN); frames given in shuffled order."""
    v = np.array([3.0, -1.0])
    present = [f for f in range(20) if f not in (8, 9, 10)]
    frames = []
    for f in present:
        xy = [(v * 0.1 * f).tolist()]
        ids = [1]
        if f == 15:
            xy.append([50.0, 50.0])  # track 2: one sample only
            ids.append(2)
        xy.append([0.0, 9.0])  # no id
        ids.append(-1)
        frames.append(frame(f, xy=xy, category=[CAR] * len(xy), track_id=ids))
    order = np.random.default_rng(3).permutation(len(frames))
    shuffled = [frames[i] for i in order]
    velocity = derive_gt_velocity(shuffled)
    for f, vel in zip(shuffled, velocity, strict=True):
        assert vel.shape == (len(f.boxes), 2)
        np.testing.assert_allclose(vel[0], v, atol=1e-9)
        assert np.isnan(vel[-1]).all()
        if f.frame_id == 15:
            assert np.isnan(vel[1]).all()


def test_gt_velocity_gap_is_not_bridged() -> None:
    """Two segments of different constant velocity separated by a gap: each is exact, which a
    fit across the gap would not be."""
    frames = []
    for f in list(range(0, 8)) + list(range(11, 19)):
        x = 2.0 * 0.1 * f if f < 8 else 5.0 - 1.0 * 0.1 * f
        frames.append(frame(f, xy=[[x, 0.0]], category=[CAR], track_id=[1]))
    velocity = np.concatenate(derive_gt_velocity(frames))
    np.testing.assert_allclose(velocity[:8, 0], 2.0, atol=1e-9)
    np.testing.assert_allclose(velocity[8:, 0], -1.0, atol=1e-9)


def test_baselines_use_the_matched_detection_centres() -> None:
    """The output box is displaced (filtered) while the detections move at exactly 4 m/s: the
    difference is 4 m/s from the track's 2nd detection and the curve fit from its 3rd, whatever
    the output positions; a coasting frame is not a sample and the gap is spanned in real
    time."""
    speed = 4.0
    gt_frames, out_frames, det_frames = [], [], []
    for f in range(10):
        x = speed * 0.1 * f
        gt_frames.append(frame(f, xy=[[x, 0.0]], category=[CAR], track_id=[5]))
        # detection row 1 is the track's; row 0 is an unrelated far-away box
        det_frames.append(frame(f, xy=[[100.0, 100.0], [x, 0.0]], category=[CAR, CAR]))
        coasting = f == 4
        out_frames.append(
            output(
                f,
                xy=[[x + 0.3 * (-1) ** f, 0.2]],
                track_id=[1],
                category=[CAR],
                det_row=[-1 if coasting else 1],
                velocity=[[9.0, 0.0]],
            )
        )
    s = collect_motion_samples(
        {"s": det_frames}, {"s": gt_frames}, {"s": out_frames}, classes=["car"]
    )["car"]
    assert s.n_matched == 10 and s.n_matched_coasting == 1 and len(s) == 9
    assert 4 not in s.frame_id.tolist()
    order = np.argsort(s.times_secs)
    diff = s.velocity[Estimator.DIFFERENCE][order]
    curve = s.velocity[Estimator.CURVE_FIT][order]
    np.testing.assert_allclose(diff[0], [0.0, 0.0])  # first detection of the track
    np.testing.assert_allclose(diff[1:], np.tile([speed, 0.0], (8, 1)), atol=1e-9)
    np.testing.assert_allclose(curve[:2], 0.0)
    np.testing.assert_allclose(curve[2:], np.tile([speed, 0.0], (7, 1)), atol=1e-9)
    np.testing.assert_allclose(s.velocity[Estimator.KALMAN], np.tile([9.0, 0.0], (9, 1)))
    np.testing.assert_allclose(s.gt_velocity, np.tile([speed, 0.0], (9, 1)), atol=1e-9)


# --------------------------------------------------------------------------------------------
# Whole evaluation on tracked synthetic scenes
# --------------------------------------------------------------------------------------------


def test_synthetic_kalman_velocity_is_accurate() -> None:
    """10 cm detection noise at 10 Hz, constant speeds: the Kalman speed error is small, and
    smaller than the raw differencing's (√2·0.1/0.1 ≈ 1.4 m/s of noise per axis)."""
    dets, gts, outputs = tracked()
    result = evaluate_motion(
        {"synthetic": dets}, {"synthetic": gts}, {"synthetic": outputs}, classes=CLASSES
    )
    json.dumps(result, allow_nan=False)  # JSON-serialisable, NaN written as None
    kalman = metrics_of(result, "kalman", "all")
    diff = metrics_of(result, "difference", "all")
    assert result["protocol"]["gt_velocity"].startswith("annotated")
    assert kalman.n_samples > 300
    assert kalman.vne_mps < 0.5  # speeds are 1-15 m/s; differencing is ~1.2 m/s off
    assert kalman.vae_deg < 8.0
    assert kalman.vne_mps < diff.vne_mps
    assert kalman.vse_mps < diff.vse_mps
    assert result["counts"]["all"]["samples"] == kalman.n_samples
    for est in ("kalman", "difference", "curve_fit"):  # like for like: the same samples
        assert metrics_of(result, est, "all").n_samples == kalman.n_samples
    box = result["box_errors"]["tracker"]["all"]
    assert box["position_error_m"] < 0.2 and box["n_samples"] == kalman.n_samples


def test_detection_estimator_absent_without_detector_velocity() -> None:
    dets, gts, outputs = tracked()
    result = evaluate_motion(
        {"synthetic": dets}, {"synthetic": gts}, {"synthetic": outputs}, classes=CLASSES
    )
    assert result["absent"] == {"detection": NO_DETECTOR_VELOCITY}
    for cls, row in result["metrics"]["detection"].items():
        assert row["note"] == NO_DETECTOR_VELOCITY, cls
        for key in ("vae_deg", "vne_mps", "vaie_deg", "vir_ratio", "vse_mps", "vde_secs"):
            assert row[key] is None, (cls, key)  # NaN, never 0
        assert row["n_samples"] == 0
    assert NO_DETECTOR_VELOCITY in motion_markdown(result)

    # (the tracker's output carries the difference and curve-fit baselines: they need none)
    no_dets = evaluate_motion(None, {"synthetic": gts}, {"synthetic": outputs}, classes=CLASSES)
    assert set(no_dets["absent"]) == {"detection"}
    for est in ("kalman", "difference", "curve_fit"):
        assert no_dets["metrics"][est]["all"] == result["metrics"][est]["all"]


def test_detection_estimator_present_with_detector_velocity() -> None:
    """Give every detection the velocity of its nearest GT box: the detection estimator is
    then present and exact wherever its GT is the matched one."""
    dets, gts, outputs = tracked()
    with_velocity = []
    for det, gt in zip(dets, gts, strict=True):
        d = np.linalg.norm(det.boxes.xyz[:, None, :2] - gt.boxes.xyz[None, :, :2], axis=2)
        nearest = gt.boxes.velocity[np.argmin(d, axis=1)] if len(det.boxes) else np.zeros((0, 2))
        boxes = det.boxes.replace(velocity=nearest)
        with_velocity.append(
            Frame(det.scene, det.frame_id, det.timestamp_secs, boxes, cameras=det.cameras)
        )
    result = evaluate_motion(
        {"synthetic": with_velocity}, {"synthetic": gts}, {"synthetic": outputs}, classes=CLASSES
    )
    assert "detection" not in result["absent"]
    det = metrics_of(result, "detection", "all")
    assert det.n_samples == metrics_of(result, "kalman", "all").n_samples
    assert det.vne_mps < 1e-9 and det.vae_deg < 1e-6


def test_an_unknown_detection_velocity_is_no_estimate() -> None:
    """NaN detection velocities (BaseVersion null): all unknown is a detector without velocity
    (absent, as all zeros); some unknown leaves those samples out of the detection estimator
    only, counted as dropped."""
    dets, gts, outputs = tracked()

    def with_velocity(unknown: Any) -> list[Frame]:
        frames = []
        for i, (det, gt) in enumerate(zip(dets, gts, strict=True)):
            d = np.linalg.norm(det.boxes.xyz[:, None, :2] - gt.boxes.xyz[None, :, :2], axis=2)
            v = gt.boxes.velocity[np.argmin(d, axis=1)] if len(det.boxes) else np.zeros((0, 2))
            v = np.where(unknown(i), np.nan, v)
            boxes = det.boxes.replace(velocity=v)
            frames.append(
                Frame(det.scene, det.frame_id, det.timestamp_secs, boxes, cameras=det.cameras)
            )
        return frames

    def evaluate(frames: list[Frame]) -> dict[str, Any]:
        scenes = {"synthetic": frames}
        return evaluate_motion(scenes, {"synthetic": gts}, {"synthetic": outputs}, classes=CLASSES)

    none_known = evaluate(with_velocity(lambda i: True))
    assert none_known["absent"] == {"detection": NO_DETECTOR_VELOCITY}
    some = evaluate(with_velocity(lambda i: i % 2 == 1))
    assert "detection" not in some["absent"]
    det, kalman = metrics_of(some, "detection", "all"), metrics_of(some, "kalman", "all")
    assert 0 < det.n_dropped_samples < kalman.n_samples
    assert det.n_samples + det.n_dropped_samples == kalman.n_samples
    assert det.vne_mps < 1e-9  # the known ones are exact; no unknown one was read as 0
    assert metrics_of(some, "difference", "all").n_samples == kalman.n_samples


def test_an_unknown_gt_velocity_is_left_out_of_every_estimator_and_reported(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """NaN GT velocities (BaseVersion null: nuScenes' single-annotation instances) leave their
    samples out of every estimator's metrics, counted per estimator and class and said in the
    report (they were written as 0 and scored as measured standstills). All unknown is a GT
    without velocities (KITTI, Waymo without velos: derived from the positions; it was taken as
    annotated and every sample dropped). All exactly 0 is a file written before unknown was null
    (KITTI's converter wrote 0): still derived from the positions, the same figures, but said
    (a warning, and a note in the protocol), as it is a guess."""
    dets, gts, outputs = tracked()

    def gt_with(unknown: Any) -> list[Frame]:
        return [
            replace(
                g, boxes=g.boxes.replace(velocity=np.where(unknown(i), np.nan, g.boxes.velocity))
            )
            for i, g in enumerate(gts)
        ]

    def evaluate(gt_frames: list[Frame]) -> dict[str, Any]:
        scenes = {"synthetic": gt_frames}
        return evaluate_motion({"synthetic": dets}, scenes, {"synthetic": outputs}, classes=CLASSES)

    known = evaluate(gts)
    some = evaluate(gt_with(lambda i: i % 3 == 0))
    assert some["protocol"]["gt_velocity"] == known["protocol"]["gt_velocity"]
    unknown = some["counts"]["all"]["gt_velocity_unknown"]
    assert 0 < unknown < some["counts"]["all"]["samples"] == known["counts"]["all"]["samples"]
    for estimator in ("kalman", "difference", "curve_fit"):
        m = metrics_of(some, estimator, "all")
        assert m.n_gt_velocity_unknown == unknown and m.n_dropped_samples == 0, estimator
        assert m.n_samples + unknown == metrics_of(known, estimator, "all").n_samples, estimator
    assert (
        f"Samples whose GT velocity is unknown, left out of the velocity metrics: {unknown}."
        in motion_markdown(some)
    )
    assert "GT velocity is unknown" not in motion_markdown(known)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="tracker.eval.motion_eval"):
        none = evaluate(gt_with(lambda i: True))
        assert not caplog.records  # the rule, not a guess: nothing to say
        zeros = evaluate(
            [replace(g, boxes=g.boxes.replace(velocity=0 * g.boxes.velocity)) for g in gts]
        )
    assert [r.getMessage() for r in caplog.records] == [
        "every ground-truth velocity is 0: read as unknown (a file written before unknown "
        "velocities were null), the GT velocity derived from the GT positions"
    ]
    assert none["protocol"]["gt_velocity"] == (
        "GT world positions, central LSQ quadratic over 5 samples"
    )
    assert zeros["protocol"]["gt_velocity"] == (
        "GT world positions, central LSQ quadratic over 5 samples (every GT velocity in the file "
        "is 0: read as unknown (written before unknown was null))"
    )
    for estimator in ("kalman", "difference", "curve_fit"):
        assert_metrics_close(
            metrics_of(none, estimator, "all"), metrics_of(zeros, estimator, "all")
        )
    # one known velocity that is not 0 makes the GT annotated (its zeros: standstills)
    one = [replace(g, boxes=g.boxes.replace(velocity=0 * g.boxes.velocity)) for g in gts]
    first = next(i for i, g in enumerate(one) if len(g.boxes))
    velocity = one[first].boxes.velocity.copy()
    velocity[0] = [0.5, 0.0]
    one[first] = replace(one[first], boxes=one[first].boxes.replace(velocity=velocity))
    assert evaluate(one)["protocol"]["gt_velocity"] == "annotated (GT box velocity)"


def test_frame_order_does_not_matter() -> None:
    dets, gts, outputs = tracked(num_frames=60)
    rng = np.random.default_rng(7)
    shuffled = (
        [dets[i] for i in rng.permutation(len(dets))],
        [gts[i] for i in rng.permutation(len(gts))],
        [outputs[i] for i in rng.permutation(len(outputs))],
    )
    a = evaluate_motion(
        {"synthetic": dets}, {"synthetic": gts}, {"synthetic": outputs}, classes=CLASSES
    )
    b = evaluate_motion(
        {"synthetic": shuffled[0]},
        {"synthetic": shuffled[1]},
        {"synthetic": shuffled[2]},
        classes=CLASSES,
    )
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_scenes_with_the_same_ids_combine_exactly() -> None:
    """Two scenes whose GT and output track ids coincide: evaluated together, every metric
    equals the pooled metrics of each scene alone (ids never merge across scenes)."""
    da, ga, oa = tracked(scene="a", seed=1, num_frames=60)
    db, gb, ob = tracked(scene="b", seed=2, num_frames=60)
    ids_a = {int(t) for o in oa for t in o.boxes.track_id}
    ids_b = {int(t) for o in ob for t in o.boxes.track_id}
    assert ids_a & ids_b  # the ids do collide
    both = evaluate_motion(
        {"a": da, "b": db}, {"a": ga, "b": gb}, {"a": oa, "b": ob}, classes=CLASSES
    )
    alone_a = evaluate_motion({"a": da}, {"a": ga}, {"a": oa}, classes=CLASSES)
    alone_b = evaluate_motion({"b": db}, {"b": gb}, {"b": ob}, classes=CLASSES)
    for est in ("kalman", "difference", "curve_fit"):
        for cls in (*CLASSES, "all"):
            pooled = combine_motion_metrics(
                [metrics_of(alone_a, est, cls), metrics_of(alone_b, est, cls)]
            )
            assert_metrics_close(metrics_of(both, est, cls), pooled)
    assert both["counts"]["all"]["gt_tracks"] == (
        alone_a["counts"]["all"]["gt_tracks"] + alone_b["counts"]["all"]["gt_tracks"]
    )


def test_markdown_and_plot(tmp_path: Path) -> None:
    dets, gts, outputs = tracked()
    png = tmp_path / "curves.png"
    result = evaluate_motion(
        {"synthetic": dets},
        {"synthetic": gts},
        {"synthetic": outputs},
        classes=CLASSES,
        plot_path=png,
    )
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert result["plot"]["path"] == str(png)
    md = motion_markdown(result)
    for heading in ("VAE (°)", "VNE (m/s)", "VAIE (°)", "VIR", "VSE (m/s)", "VDE (s)"):
        assert heading in md
    for line in md.splitlines():
        if line.startswith("| kalman"):
            assert line.count("|") == 9  # estimator + 6 metrics + samples


def test_largest_delay_tracks_finds_the_delayed_one() -> None:
    """Three moving GT tracks with speed peaks; the Kalman estimate of one lags by 0.5 s, the
    others not: it ranks first with that delay."""
    n, dt = 80, 0.1
    i = np.arange(n)
    speed = 5.0 + 3.0 * np.exp(-(((i - 30) / 5.0) ** 2))
    gt_frames, out_frames = [], []
    positions = np.cumsum(speed) * dt
    for f in range(n):
        lag = max(f - 5, 0)
        xs = [positions[f], positions[f], positions[f]]
        gt_frames.append(
            frame(
                f,
                xy=[[xs[0], 0.0], [xs[1], 20.0], [xs[2], 40.0]],
                category=[CAR] * 3,
                track_id=[1, 2, 3],
                velocity=[[speed[f], 0.0]] * 3,
            )
        )
        out_frames.append(
            output(
                f,
                xy=[[xs[0], 0.0], [xs[1], 20.0], [xs[2], 40.0]],
                track_id=[1, 2, 3],
                category=[CAR] * 3,
                velocity=[[speed[f], 0.0], [speed[lag], 0.0], [speed[f], 0.0]],
            )
        )
    samples = collect_motion_samples(None, {"s": gt_frames}, {"s": out_frames}, classes=["car"])
    ranked = largest_delay_tracks(samples, count=1)
    assert len(ranked) == 1
    cls, key, delay = ranked[0]
    s = samples["car"]
    assert cls == "car" and set(s.gt_track_id[s.gt_key == key]) == {2}
    assert delay == pytest.approx(0.5)


def test_velocity_plot_marks_where_the_largest_delay_is(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The plot's title gave the largest delay but not where: the GT speed peak it was
    measured at (frame 30, t = 3.0 s) is marked on the curve and named in the title."""
    import matplotlib.figure

    from tracker.eval.motion_eval import plot_velocity_curves

    n, dt = 80, 0.1
    i = np.arange(n)
    speed = 5.0 + 3.0 * np.exp(-(((i - 30) / 5.0) ** 2))
    positions = np.cumsum(speed) * dt
    gt_frames = [
        frame(f, xy=[[positions[f], 0.0]], category=[CAR], track_id=[1], velocity=[[speed[f], 0]])
        for f in range(n)
    ]
    outs = [
        output(
            f,
            xy=[[positions[f], 0.0]],
            track_id=[1],
            category=[CAR],
            velocity=[[speed[max(f - 5, 0)], 0.0]],
        )
        for f in range(n)
    ]
    samples = collect_motion_samples(None, {"s": gt_frames}, {"s": outs}, classes=["car"])
    figures: list = []
    save = matplotlib.figure.Figure.savefig
    monkeypatch.setattr(
        matplotlib.figure.Figure,
        "savefig",
        lambda fig, *a, **k: (figures.append(fig), save(fig, *a, **k)),
    )
    plotted = plot_velocity_curves(samples, tmp_path / "v.png", count=1)
    assert plotted[0]["kalman_delay_frame"] == 30
    ax = figures[0].axes[0]
    assert "Kalman delay 0.5 s at frame 30 (t = 3.0 s, marked)" in ax.get_title()
    marks = [ln for ln in ax.lines if list(ln.get_xdata()) == [3.0, 3.0]]  # the peak's time
    assert len(marks) == 1
    points = [ln for ln in ax.lines if ln.get_marker() == "o"]
    assert [list(p.get_xydata()[0]) for p in points] == [pytest.approx([3.0, 8.0])]


# --------------------------------------------------------------------------------------------
# Tracks file round trip and the `mctrack eval` command
# --------------------------------------------------------------------------------------------


def test_tracks_file_round_trip_and_eval_command(tmp_path: Path) -> None:
    from app.cli import main
    from tracker.io.baseversion import write_baseversion
    from tracker.io.writers import read_tracks_file, write_tracks_file

    dets, gts, outputs = tracked(num_frames=50)
    write_tracks_file(tmp_path / "tracks.json", {"synthetic": (dets, outputs)})
    _frames, read = read_tracks_file(tmp_path / "tracks.json")
    assert len(read["synthetic"]) == len(outputs)
    for a, b in zip(read["synthetic"], outputs, strict=True):
        np.testing.assert_array_equal(a.det_row, b.det_row)
        np.testing.assert_array_equal(a.status, b.status)
        np.testing.assert_array_equal(a.boxes.track_id, b.boxes.track_id)

    write_baseversion(tmp_path / "dets.json", {"synthetic": dets})
    write_baseversion(tmp_path / "gt.json", {"synthetic": gts})
    out = tmp_path / "eval"
    code = main(
        [
            "eval",
            str(tmp_path / "tracks.json"),
            "--gt",
            str(tmp_path / "gt.json"),
            "--detections",
            str(tmp_path / "dets.json"),
            "--motion",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    saved = json.loads((out / "eval.json").read_text())
    assert saved["static"].startswith("skipped")
    direct = evaluate_motion(
        {"synthetic": dets}, {"synthetic": gts}, {"synthetic": outputs}, classes=CLASSES
    )
    for est in ("kalman", "difference", "curve_fit"):
        assert_metrics_close(
            metrics_of(saved["motion"], est, "all"), metrics_of(direct, est, "all")
        )
    assert "Motion metrics: car" in (out / "eval.md").read_text()
    assert (out / "motion_velocity.png").is_file()


# --------------------------------------------------------------------------------------------
# KITTI (skipped without the kit)
# --------------------------------------------------------------------------------------------


def test_kitti_parked_cars_have_zero_gt_velocity_and_motion_block(
    kitti_root: Path, tmp_path: Path
) -> None:
    """Sequence 0014 (106 frames, the ego drives past parked cars): GT velocity from world
    positions is ~0 for parked cars and several m/s for moving ones; `mctrack kitti --motion`'s
    job produces the motion block with the detection estimator absent."""
    from app.kitti import run_kitti
    from tracker.io.convert.kitti import convert_kitti

    _dets, gt = convert_kitti(kitti_root, seqs=["0014"], classes=["car"], with_gt=True)
    frames = gt["0014"]
    velocity = np.concatenate(derive_gt_velocity(frames))
    ids = np.concatenate([f.boxes.track_id for f in frames])
    cats = np.concatenate([f.boxes.category for f in frames])
    xy = np.concatenate([f.boxes.xyz[:, :2] for f in frames])
    parked = moving = 0
    for tid in np.unique(ids[cats == CAR]):
        rows = (ids == tid) & (cats == CAR)
        if rows.sum() < 20:
            continue
        net = np.linalg.norm(xy[rows] - xy[rows].mean(axis=0), axis=1).max()
        median_speed = float(np.median(np.linalg.norm(velocity[rows], axis=1)))
        if net < 0.5:  # parked: the labels hardly move in the world frame
            parked += 1
            assert median_speed < 0.4, (tid, median_speed)
        elif net > 5.0:
            moving += 1
            assert median_speed > 1.5, (tid, median_speed)
    assert parked >= 3 and moving >= 2

    summary = run_kitti(
        kitti_root=kitti_root,
        seqs=["0014"],
        classes=["car", "pedestrian"],
        evaluate=False,
        motion=True,
        out=tmp_path,
        quiet=True,
    )
    motion = summary["motion"]
    assert motion["absent"] == {"detection": NO_DETECTOR_VELOCITY}
    assert motion["protocol"]["gt_velocity"].startswith("GT world positions")
    car = metrics_of(motion, "kalman", "car")
    assert car.n_samples > 100 and math.isfinite(car.vne_mps) and car.vne_mps < 2.0
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved["motion"]["metrics"]["kalman"]["car"]["n_samples"] == car.n_samples
    assert "Motion metrics: car" in (tmp_path / "motion.md").read_text()
    assert (tmp_path / "motion_velocity.png").is_file()


def test_a_scene_without_tracker_output_is_scored_with_the_others() -> None:
    """A scene whose detector found nothing (no output box) beside a tracked one: the motion
    metrics are those of the tracked scene (was a ValueError from zip in the baselines)."""
    dets, gts, outputs = tracked(scene="a", num_frames=40)
    empty_dets = [replace(f, scene="b", boxes=Boxes.empty()) for f in dets]
    empty_gts = [replace(f, scene="b") for f in gts]
    empty_outputs = run_scene(empty_dets, load_config("kitti_reference")).outputs
    assert not any(len(o.boxes) for o in empty_outputs)
    both = evaluate_motion(
        {"a": dets, "b": empty_dets},
        {"a": gts, "b": empty_gts},
        {"a": outputs, "b": empty_outputs},
        classes=CLASSES,
    )
    alone = evaluate_motion({"a": dets}, {"a": gts}, {"a": outputs}, classes=CLASSES)
    for est in ("kalman", "difference", "curve_fit"):
        for cls in (*CLASSES, "all"):
            assert_metrics_close(metrics_of(both, est, cls), metrics_of(alone, est, cls))
