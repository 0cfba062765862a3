"""MCTracker behaviour: lifecycle state machine, matching rules, time handling, determinism,
and an end-to-end regression on the bundled sample sequence."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from tracker.boxes import Boxes
from tracker.calibration import calibrate_frames, find_profile
from tracker.categories import category_index
from tracker.config import load_config
from tracker.errors import InputError
from tracker.eval.fates import FateCounter
from tracker.events import LifecycleChanged, ListObserver, TrackStatus
from tracker.frame import Camera, Frame
from tracker.io.baseversion import read_baseversion
from tracker.mctracker import MCTracker
from tracker.pipeline import run_scene

CAR = category_index("car")
PED = category_index("pedestrian")
SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"
GOLDEN = Path(__file__).resolve().parent / "golden" / "sample_metrics.json"


def config(**lifecycle: int | float):
    """KITTI config with explicit, test-owned lifecycle and filter numbers (not the tuned ones)."""
    life = {
        "min_hits": 2,
        "confirm_score": 2.0,
        "max_misses_output": 1,
        "max_misses": 3,
        "max_misses_tentative": 0,
        "coast_min_hits": 1,
        **lifecycle,
    }
    return load_config(
        "kitti",
        overrides={
            "categories": ["car", "pedestrian"],
            "rv_matching": False,
            "defaults": {"score_min": 0.1, "birth_score_min": 0.5, "lifecycle": life},
            "category": {
                name: {
                    "score_min": 0.1,
                    "birth_score_min": 0.5,
                    "lifecycle": life,
                    "pose": {"motion": "ca", "ca": {"r": [0.1, 0.1]}},  # trusts each box
                }
                for name in ("car", "pedestrian", "cyclist")
            },
        },
    )


def frame(
    i: int,
    xs: list[float],
    *,
    cats: list[int] | None = None,
    scores: list[float] | None = None,
    t: float | None = None,
) -> Frame:
    n = len(xs)
    boxes = Boxes.create(
        xyz=[[x, 0.0, 0.8] for x in xs],
        lwh=[[4.0, 1.8, 1.6]] * n,
        yaw=[0.0] * n,
        category=cats if cats is not None else [CAR] * n,
        score=scores if scores is not None else [0.9] * n,
    )
    return Frame(scene="s", frame_id=i, timestamp_secs=0.1 * i if t is None else t, boxes=boxes)


def test_tentative_confirm_coast_lose_delete() -> None:
    obs = ListObserver()
    tracker = MCTracker(config(), observer=obs)
    out0 = tracker.step(frame(0, [10.0]))
    assert len(out0) == 0  # tentative: not output at birth (min_hits 2)
    out1 = tracker.step(frame(1, [11.0]))
    assert out1.boxes.track_id.tolist() == [0]
    assert out1.status.tolist() == [TrackStatus.CONFIRMED]
    out2 = tracker.step(frame(2, []))  # first miss: coasting, still output (max_misses_output 1)
    assert out2.status.tolist() == [TrackStatus.COASTING]
    assert out2.det_row.tolist() == [-1]
    assert out2.boxes.xyz[0, 0] > 11.0  # predicted forward, beyond the last detection
    assert len(tracker.step(frame(3, []))) == 0  # second miss: lost, not output
    tracker.step(frame(4, []))
    tracker.step(frame(5, []))  # fourth miss > max_misses 3: deleted
    changes = [e for e in obs.events if isinstance(e, LifecycleChanged)]
    assert changes[0].born.tolist() == [0]
    assert changes[1].confirmed.tolist() == [0]
    assert changes[3].lost.tolist() == [0]
    assert changes[5].deleted.tolist() == [0]
    assert len(tracker.step(frame(6, [16.0]))) == 0  # a new, tentative track
    assert tracker.step(frame(7, [17.0])).boxes.track_id.tolist() == [1]


def _front_camera() -> Camera:
    """A 90-degree pinhole camera at the origin looking along world +x (z up), 100 px wide."""
    camera_from_world = np.array(
        [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    )
    image_from_camera = np.array([[50.0, 0.0, 50.0, 0.0], [0.0, 50.0, 40.0, 0.0], [0, 0, 1.0, 0]])
    return Camera("CAM_FRONT", image_from_camera, camera_from_world, 100, 80)


@pytest.mark.parametrize("min_in_view", [0.0, 0.5])
def test_coasting_track_leaving_the_image_is_not_output(min_in_view: float) -> None:
    """A car 20 m ahead drives right, out of the image; its detections stop at the edge. The
    first coasting box (predicted y -18 m) is 3/4 inside the image, the second (y -20 m) under
    2/5: with coast_min_in_view 0.5 only the first is output, with 0 both; a miss in the middle
    of the image is output either way, and the track lives on out of view."""
    cfg = config(max_misses_output=2, max_misses=5)
    cfg = dataclasses.replace(cfg, coast_min_in_view=min_in_view)
    cam = (_front_camera(),)

    def lateral(i: int, ys: list[float]) -> Frame:
        boxes = Boxes.create(
            xyz=[[20.0, y, 0.8] for y in ys],
            lwh=[[4.0, 1.8, 1.6]] * len(ys),
            yaw=[-np.pi / 2] * len(ys),  # heading right (-y), the way it drives
            category=[CAR] * len(ys),
            score=[0.9] * len(ys),
        )
        return Frame(scene="s", frame_id=i, timestamp_secs=0.1 * i, boxes=boxes, cameras=cam)

    tracker = MCTracker(cfg)
    outs = [tracker.step(lateral(i, [-2.0 - 2.0 * i])) for i in range(8)]  # to y = -16 m
    assert outs[-1].boxes.track_id.tolist() == [0]
    coast1, coast2 = tracker.step(lateral(8, [])), tracker.step(lateral(9, []))
    assert coast1.det_row.tolist() == [-1] and coast1.boxes.xyz[0, 1] == pytest.approx(-18, abs=0.5)
    assert len(coast2) == (1 if min_in_view == 0 else 0)
    back = tracker.step(lateral(10, [-22.0]))  # not deleted: the same track takes it
    assert back.boxes.track_id.tolist() == [0] and back.det_row.tolist() == [0]

    centre = MCTracker(cfg)
    for i in range(4):
        centre.step(lateral(i, [0.0]))
    assert centre.step(lateral(4, [])).det_row.tolist() == [-1]  # in view: coasting, output


def test_coast_min_in_view_is_a_fraction() -> None:
    with pytest.raises(InputError, match="coast_min_in_view must be in"):
        load_config("kitti", overrides={"coast_min_in_view": 1.5})


@pytest.mark.parametrize("gain", [1.0, 0.5])
def test_vertical_gain_smooths_z_and_height(gain: float) -> None:
    """z and height alternate 0.8/1.2 and 1.6/2.0 between detections: with gain 1 the track
    reports each detection's own; with 0.5 each hit moves halfway (z_k = z_{k-1} + g (d_k -
    z_{k-1})), and a coasting frame keeps the last value."""
    cfg = config(max_misses_output=2, max_misses=5)
    cfg = dataclasses.replace(
        cfg,
        per_category={
            n: dataclasses.replace(c, vertical_gain=gain) for n, c in cfg.per_category.items()
        },
    )
    tracker = MCTracker(cfg)
    z, h = [0.8, 1.2, 0.8, 1.2], [1.6, 2.0, 1.6, 2.0]
    want_z, want_h = [z[0]], [h[0]]
    for k in range(1, 4):
        want_z.append(want_z[-1] + gain * (z[k] - want_z[-1]))
        want_h.append(want_h[-1] + gain * (h[k] - want_h[-1]))
    got = []
    for i in range(4):
        boxes = Boxes.create(
            xyz=[[10.0 + i, 0.0, z[i]]],
            lwh=[[4.0, 1.8, h[i]]],
            yaw=[0.0],
            category=[CAR],
            score=[0.9],
        )
        out = tracker.step(Frame(scene="s", frame_id=i, timestamp_secs=0.1 * i, boxes=boxes))
        got.append((out.boxes.xyz[:, 2].tolist(), out.boxes.lwh[:, 2].tolist()))
    assert got[0] == ([], [])  # tentative (min_hits 2)
    for i in range(1, 4):
        assert got[i][0] == pytest.approx([want_z[i]]) and got[i][1] == pytest.approx([want_h[i]])
    coast = tracker.step(Frame(scene="s", frame_id=4, timestamp_secs=0.4, boxes=Boxes.empty()))
    assert coast.boxes.xyz[:, 2] == pytest.approx([want_z[3]])
    # by hand: 0.8 -> 1.0 -> 0.9 -> 1.05 with gain 0.5; the last detection's 1.2 with gain 1
    assert coast.boxes.xyz[:, 2] == pytest.approx([1.05 if gain == 0.5 else 1.2])
    with pytest.raises(InputError, match="vertical_gain must be in"):
        load_config("kitti", overrides={"category": {"car": {"vertical_gain": 0.0}}})


@pytest.mark.parametrize("cost_state", ["predict", "fusion"])
def test_buffered_boxes_keep_a_jittering_small_object(cost_state: str) -> None:
    """A standing pedestrian (0.5 x 0.5 m) whose detections alternate 0.9 m apart: the boxes
    never overlap and their plain cost is beyond the gate, so each detection starts a new
    track; grown by the buffer (0.5: 1.0 m boxes) they overlap and the track keeps its id."""

    def run(buffer: float) -> tuple[set[int], int]:
        bev = {"buffer": buffer, "cost_max": 1.2, "cost_state": cost_state}
        pose = {"r_scale": 0.0, "ca": {"r": [1.0, 1.0]}}  # trusting one box little
        cfg = load_config(
            "kitti",
            overrides={
                "categories": ["pedestrian"],
                "coast_min_in_view": 0.0,
                "category": {"pedestrian": {"bev": bev, "pose": pose}},
            },
        )
        observer = ListObserver()
        tracker, output_ids = MCTracker(cfg, observer=observer), set()
        for i in range(6):
            boxes = Boxes.create(
                xyz=[[10.0, 0.9 * (i % 2), 0.9]], lwh=[[0.5, 0.5, 1.7]], yaw=[0.0],
                category=[PED], score=[0.95],
            )  # fmt: skip
            out = tracker.step(Frame(scene="s", frame_id=i, timestamp_secs=0.1 * i, boxes=boxes))
            output_ids |= set(out.boxes.track_id.tolist())
        births = sum(len(e.born) for e in observer.events if isinstance(e, LifecycleChanged))
        return output_ids, births

    assert run(0.5) == ({0}, 1)  # one track, output once confirmed
    assert run(0.0) == (set(), 6)  # a new track per frame, none ever confirmed
    with pytest.raises(InputError, match=r"bev\.buffer must be in"):
        load_config("kitti", overrides={"category": {"car": {"bev": {"buffer": -0.1}}}})


def test_reacquire_keeps_identity() -> None:
    tracker = MCTracker(config())
    for i in range(3):
        tracker.step(frame(i, [10.0 + i]))
    tracker.step(frame(3, []))
    tracker.step(frame(4, []))
    out = tracker.step(frame(5, [15.0]))  # re-acquired within max_misses
    assert out.boxes.track_id.tolist() == [0]
    assert out.status.tolist() == [TrackStatus.CONFIRMED]


def test_tentative_track_dies_on_first_miss_and_confirm_score() -> None:
    tracker = MCTracker(config(confirm_score=0.95))
    assert len(tracker.step(frame(0, [10.0], scores=[0.9]))) == 0
    assert len(tracker.step(frame(1, []))) == 0  # tentative + miss -> deleted
    out = tracker.step(frame(2, [30.0], scores=[0.99]))  # confident: confirmed at birth
    assert out.boxes.track_id.tolist() == [1]


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("coast_min_hits", [1, 2])
def test_a_track_coasts_only_after_coast_min_hits(compiled: bool, coast_min_hits: int) -> None:
    """Two tracks confirmed at birth by a confident box (confirm_score 0.95), coasting output up
    to 2 misses: the one seen once (a one-frame false positive's pattern) is written for its
    misses only with coast_min_hits 1; the one seen twice coasts either way. A lost track seen
    once still lives: its box back within max_misses keeps its id."""
    cfg = config(confirm_score=0.95, max_misses_output=2, max_misses=5,
                 coast_min_hits=coast_min_hits)  # fmt: skip
    tracker = MCTracker(cfg, compiled=compiled)
    seen = [tracker.step(frame(0, [10.0], scores=[0.99])).boxes.track_id.tolist()]
    seen.append(tracker.step(frame(1, [40.0], scores=[0.99])).boxes.track_id.tolist())
    seen.append(tracker.step(frame(2, [41.0], scores=[0.99])).boxes.track_id.tolist())
    for i in (3, 4):
        out = tracker.step(frame(i, []))
        seen.append(out.boxes.track_id.tolist())
        assert (out.status == TrackStatus.COASTING).all()
    # track 0: one hit at frame 0, missed from frame 1; track 1: hits at 1 and 2, missed from 3
    if coast_min_hits == 1:
        assert seen == [[0], [0, 1], [0, 1], [1], [1]]
    else:
        assert seen == [[0], [1], [1], [1], [1]]
    out = tracker.step(frame(5, [10.0], scores=[0.99]))
    assert out.boxes.track_id.tolist() == [0]  # track 0 reacquired (5 misses <= max_misses)


@pytest.mark.parametrize("compiled", [True, False])
def test_confirmation_from_accumulated_evidence(compiled: bool) -> None:
    """confirm_prob 0.99: one 0.995 box confirms at birth; 0.9 boxes need two hits (1 - 0.1²
    = 0.99); 0.6 boxes need six (1 - 0.4⁶ = 0.996 but 1 - 0.4⁵ < 0.99), before min_hits (10)."""
    tracker = MCTracker(config(min_hits=10, confirm_prob=0.99), compiled=compiled)
    out = tracker.step(frame(0, [10.0, 30.0, 50.0], scores=[0.995, 0.9, 0.6]))
    assert out.boxes.xyz[:, 0].tolist() == [10.0]
    out = tracker.step(frame(1, [11.0, 31.0, 51.0], scores=[0.995, 0.9, 0.6]))
    assert out.boxes.xyz[:, 0].round().tolist() == [11.0, 31.0]  # 1 - 0.1 * 0.1 >= 0.99
    confirmed_at = None
    for i in range(2, 8):
        out = tracker.step(frame(i, [10.0 + i, 30.0 + i, 50.0 + i], scores=[0.995, 0.9, 0.6]))
        if confirmed_at is None and len(out) == 3:
            confirmed_at = i
    assert confirmed_at == 5  # the sixth hit


@pytest.mark.parametrize("compiled", [True, False])
def test_track_score_gate_withholds_a_persistent_weak_track(compiled: bool) -> None:
    """A wall detected every frame at p 0.3 after one 0.6 birth: noisy-OR evidence confirms it
    (1 - 0.4 * 0.7^4 >= 0.9), but its mean log-odds is below 0, so the gate withholds it; the
    car beside it (p 0.95) is output. Without the gate (-inf) both are output. The withheld track
    still lives: when its hits turn confident its mean rises above 0 and it is output again."""
    wall, car = [0.6] + [0.3] * 5, [0.95] * 6

    def run(gate: float) -> tuple[list[list[int]], int]:
        cfg = config(min_hits=10, confirm_prob=0.9, track_score_min=gate)
        fates = FateCounter()
        tracker = MCTracker(cfg, observer=fates, compiled=compiled)
        out = [tracker.step(frame(i, [10.0, 40.0], scores=[wall[i], car[i]])) for i in range(6)]
        return [o.boxes.track_id.tolist() for o in out], fates.summary()["fed_not_output"]

    ungated, not_output = run(-np.inf)
    assert ungated[-1] == [0, 1]
    # tentative until confirmed: the wall's first 4 hits (evidence -log(0.4 * 0.7^4) = 2.35 >=
    # -log(0.1) at the 5th); the car is confirmed at birth (-log(0.05) = 3.0)
    assert not_output == 4
    gated, not_output = run(0.0)
    assert gated[-1] == [1]  # mean log-odds (0.41 + 5 * -0.85) / 6 < 0
    assert all(0 not in ids for ids in gated)
    assert not_output == 6  # the wall's every hit
    tracker = MCTracker(config(min_hits=10, confirm_prob=0.9, track_score_min=0.0))
    for i, p in enumerate([0.6, 0.3, 0.3, 0.3, 0.99, 0.99, 0.99]):
        out = tracker.step(frame(i, [10.0], scores=[p]))
    assert out.boxes.track_id.tolist() == [0]  # 0.41 - 3 * 0.85 + 3 * 4.6 > 0


def test_birth_threshold_and_score_filter() -> None:
    tracker = MCTracker(config(min_hits=1))
    out = tracker.step(frame(0, [10.0, 30.0, 50.0], scores=[0.05, 0.3, 0.9]))
    # 0.05 is below score_min (dropped), 0.3 can match but not start a track, 0.9 starts one
    assert len(out) == 1 and out.boxes.xyz[0, 0] == pytest.approx(50.0)


def test_never_matches_across_categories() -> None:
    tracker = MCTracker(config(min_hits=1))
    tracker.step(frame(0, [10.0], cats=[CAR]))
    out = tracker.step(frame(1, [10.1], cats=[PED]))
    assert sorted(out.boxes.track_id.tolist()) == [0, 1]
    assert out.boxes.category[out.boxes.track_id == 1].tolist() == [PED]


def test_real_time_step_and_order() -> None:
    tracker = MCTracker(config(min_hits=1))
    for i in range(10):  # 10 m/s along x (enough frames for the velocity to converge)
        tracker.step(frame(i, [10.0 + 1.0 * i]))
    # a frame 0.3 s later (two frames missing): the prediction covers the real elapsed time
    out = tracker.step(frame(10, [], t=1.2))
    assert out.boxes.xyz[0, 0] == pytest.approx(19.0 + 3.0, abs=0.3)
    with pytest.raises(InputError, match="time order"):
        tracker.step(frame(11, [30.0], t=1.0))


def test_empty_frames_and_determinism() -> None:
    frames = [frame(i, [10.0 + i, 40.0 - i] if i % 4 else []) for i in range(20)]
    a = run_scene(frames, config(min_hits=1)).outputs
    b = run_scene(frames, config(min_hits=1)).outputs
    for x, y in zip(a, b, strict=True):
        assert x.boxes.equals(y.boxes)
        assert np.all(np.diff(x.boxes.track_id) > 0)  # sorted, unique ids


def test_observer_does_not_change_results() -> None:
    frames = [frame(i, [10.0 + i, 40.0 - 0.5 * i]) for i in range(15)]
    plain = run_scene(frames, config()).outputs
    observed = run_scene(frames, config(), observer=ListObserver()).outputs
    for x, y in zip(plain, observed, strict=True):
        assert x.boxes.equals(y.boxes)


@pytest.mark.skipif(not SAMPLE.is_dir(), reason="sample_data/kitti-0001 missing")
def test_output_acceleration_ca_estimated_cv_absent() -> None:
    """Car (CA, the KITTI config) accelerating at 2 m/s² along x: its filtered acceleration
    converges to it; a pedestrian tracked with CV has no acceleration state: NaN, not 0."""
    cv_ped = {"pedestrian": {"pose": {"motion": "cv"}}}
    cfg = load_config("kitti", overrides={"categories": ["car", "pedestrian"], "category": cv_ped})
    assert cfg.per_category["car"].pose.motion.value == "ca"
    tracker = MCTracker(cfg)
    for i in range(40):
        t = 0.1 * i
        xs = [5.0 * t + t * t, 50.0 + t]
        out = tracker.step(frame(i, xs, cats=[CAR, PED], scores=[0.99, 0.99]))
    assert list(out.boxes.category) == [CAR, PED]
    np.testing.assert_allclose(out.acceleration[0], [2.0, 0.0], atol=0.3)
    np.testing.assert_allclose(out.boxes.velocity[0], [5.0 + 2 * 3.9, 0.0], atol=0.3)
    assert np.isnan(out.acceleration[1]).all()


def test_sample_sequence_regression() -> None:
    """Track count and ID switches on the bundled sequence, against committed numbers."""
    from tracker.eval.kitti import evaluate_kitti
    from tracker.io.writers import write_kitti_sequence

    cfg = load_config("kitti")
    frames = read_baseversion(SAMPLE / "detections.json.gz")["0001"]
    frames = calibrate_frames(frames, find_profile("pointrcnn"))  # the sample is PointRCNN's
    outputs = run_scene(frames, cfg).outputs
    ids = {int(t) for o in outputs for t in o.boxes.track_id}
    result = Path(pytest.importorskip("tempfile").mkdtemp())
    write_kitti_sequence(result / "0001.txt", outputs, frames, width_scale=cfg.image_width_scales())
    metrics = evaluate_kitti(
        label_dir=SAMPLE / "raw" / "training" / "label_02",
        result_dir=result,
        seq_lengths={"0001": len(frames)},
        classes=["car", "pedestrian"],
    )
    golden = json.loads(GOLDEN.read_text())
    assert len(ids) == golden["tracks"]
    assert metrics["car"]["IDSW"] == golden["car"]["IDSW"]
    assert metrics["pedestrian"]["IDSW"] == golden["pedestrian"]["IDSW"]
    assert metrics["car"]["HOTA"] == pytest.approx(golden["car"]["HOTA"], abs=0.05)


@pytest.mark.parametrize("category", ["car", "motorcycle"])  # motorcycle: backward prediction
def test_an_unknown_detector_velocity_is_not_measured(tmp_path: Path, category: str) -> None:
    """nuScenes config (measures the detector velocity): an object moving at 4 m/s whose
    detections say ``global_velocity: null`` (no estimate) gets its velocity from the positions,
    not a "measured" 0; the same boxes with [0, 0] are held back by that measurement."""
    cfg = load_config("nuscenes")
    assert cfg.per_category[category].pose.measure_velocity

    def box(i: int, velocity: list[float] | None) -> dict[str, object]:
        return {
            "category": category,
            "detection_score": 0.9,
            "global_xyz": [10.0 + 2.0 * i, 5.0, 1.0],  # 4 m/s along x at 2 Hz
            "lwh": [4.6, 1.9, 1.6] if category == "car" else [2.2, 0.9, 1.5],
            "global_yaw": 0.0,
            "global_velocity": velocity,
        }

    def speed(velocity: list[float] | None) -> float:
        scene = [
            {"frame_id": i, "timestamp": 500_000 * i, "bboxes": [box(i, velocity)]}
            for i in range(12)
        ]
        path = tmp_path / "dets.json"
        path.write_text(json.dumps({"s": scene}))
        outputs = run_scene(read_baseversion(path)["s"], cfg).outputs
        assert {int(o.boxes.track_id[0]) for o in outputs} == {outputs[0].boxes.track_id[0]}
        vx, vy = outputs[-1].boxes.velocity[0]
        assert abs(vy) < 0.1
        return float(vx)

    assert speed(None) == pytest.approx(4.0, abs=0.2)
    assert speed([0.0, 0.0]) < 3.0  # a measured 0 does hold it back (the test can tell)
