"""The paper's velocity baselines kept by the tracker (tracker/velocity_baselines.py): equal to
the whole-track reference maths, over every detection a track took (tentative ones included),
carried through the tracks file and used by the motion evaluation."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from tracker.categories import CATEGORIES
from tracker.config import load_config
from tracker.errors import InputError
from tracker.eval.motion_eval import Estimator, collect_motion_samples
from tracker.eval.motion_metrics import velocity_curve_fit, velocity_differencing
from tracker.events import FrameStarted, LifecycleChanged, ListObserver, Matched, TrackOutput
from tracker.fusion import fuse_scene
from tracker.io.synthetic import synthetic_scene
from tracker.io.writers import read_tracks_file, write_tracks_file
from tracker.pipeline import run_scene
from tracker.velocity_baselines import WINDOW, latest_velocities

CLASSES = ["car", "pedestrian"]


def test_latest_velocities_equal_the_whole_track_reference() -> None:
    """At every prefix of a track (irregular times), the latest window gives the last value of
    the reference functions over the whole prefix: 0 before 2 (3) detections."""
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.05, 0.35, 9))
    xy = rng.normal(0.0, 5.0, (9, 2))
    for n in range(1, len(t) + 1):
        window_t = np.full((1, WINDOW), np.nan)
        window_xy = np.full((1, WINDOW, 2), np.nan)
        k = min(n, WINDOW)
        window_t[0, -k:], window_xy[0, -k:] = t[n - k : n], xy[n - k : n]
        diff, curve = latest_velocities(window_t, window_xy)
        np.testing.assert_allclose(diff[0], velocity_differencing(t[:n], xy[:n])[-1], atol=1e-12)
        np.testing.assert_allclose(
            curve[0], velocity_curve_fit(t[:n], xy[:n], window=WINDOW)[-1], atol=1e-12
        )


def _history(dets: list, config) -> tuple[list[TrackOutput], dict]:
    """The scene tracked, and each track's detections (time, frame row) from the tracker's own
    events, tentative ones too."""
    observer = ListObserver()
    outputs = run_scene(dets, config, observer=observer).outputs
    history: dict[int, list[tuple[float, int]]] = defaultdict(list)
    times = iter(f.timestamp_secs for f in dets)
    now = 0.0
    for event in observer.events:
        if isinstance(event, FrameStarted):
            now = next(times)
        elif isinstance(event, Matched):
            for tid, row in zip(event.track_ids, event.det_rows, strict=True):
                history[int(tid)].append((now, int(row)))
        elif isinstance(event, LifecycleChanged):
            for tid, row in zip(event.born, event.born_det_rows, strict=True):
                history[int(tid)].append((now, int(row)))
    return outputs, history


def _tracked_with_history() -> tuple[list, list, list[TrackOutput], dict]:
    """A synthetic scene tracked online with tracks confirmed only at their 3rd hit."""
    dets, gts = synthetic_scene(num_objects=6, num_frames=60, seed=4, scene="s")
    config = load_config(
        "kitti_reference",
        overrides={"categories": CLASSES, "defaults": {"lifecycle": {"min_hits": 3}}},
    )
    return dets, gts, *_history(dets, config)


def _check_against_reference(dets: list, outputs: list[TrackOutput], history: dict) -> int:
    """Every detection-backed row's baselines equal the reference maths over the detector's own
    centres of every detection its track took so far; returns the number of tracks whose first
    output row has a non-zero baseline from detections before it (tentative ones)."""
    frame_at = {f.timestamp_secs: f for f in dets}
    first_output: set[int] = set()
    checked = from_tentative = 0
    for out in outputs:
        assert out.baselines is not None and out.baselines.shape == (len(out), 2, 2)
        has_det = out.det_row >= 0
        assert np.isnan(out.baselines[~has_det]).all()
        for k in np.flatnonzero(has_det):
            tid = int(out.boxes.track_id[k])
            past = sorted(h for h in history[tid] if h[0] <= out.time_secs)
            assert past[-1] == (out.time_secs, int(out.det_row[k]))
            t = np.array([h[0] for h in past])
            xy = np.array([frame_at[h[0]].boxes.xyz[h[1], :2] for h in past])
            np.testing.assert_allclose(out.baselines[k, 0], velocity_differencing(t, xy)[-1])
            np.testing.assert_allclose(
                out.baselines[k, 1], velocity_curve_fit(t, xy, window=WINDOW)[-1]
            )
            checked += 1
            if tid not in first_output:
                first_output.add(tid)
                from_tentative += len(past) >= 2 and bool(np.any(out.baselines[k] != 0))
    assert checked > 200
    return from_tentative


def test_tracker_baselines_see_the_detections_before_confirmation() -> None:
    dets, _gts, outputs, history = _tracked_with_history()
    # (over its output rows alone, each of these tracks' first row would be 0)
    assert _check_against_reference(dets, outputs, history) >= 4


def test_baselines_follow_the_detectors_centres_under_bearing_fusion(kitti_root: Path) -> None:
    """With an image detector the tracker sees centres turned toward their 2D boxes' bearing;
    the baselines still follow the detector's own centres, as the reference's do and as the
    motion evaluation reads a detection (offline, and in older files)."""
    from tracker.io.convert.kitti import convert_kitti

    dets, _ = convert_kitti(
        kitti_root, seqs=["0014"], classes=["car"], image_detector="rrc_2d", with_gt=False
    )
    frames = dets["0014"]
    config = load_config("kitti", overrides={"categories": ["car"]})
    assert config.image_bearing
    fused = fuse_scene(frames, len(CATEGORIES))
    assert any(a is not b for a, b in zip(fused, frames, strict=True))  # (centres moved)
    outputs, history = _history(frames, config)
    _check_against_reference(frames, outputs, history)


def test_the_motion_evaluation_reads_the_tracker_baselines() -> None:
    """With the tracker's baselines the first output row of a track is scored with a real
    estimate; without them (a file from before), the evaluation falls back to the output's
    detection rows, where it is 0."""
    dets, gts, outputs, _ = _tracked_with_history()
    with_ = collect_motion_samples({"s": dets}, {"s": gts}, {"s": outputs}, classes=["car"])
    bare = [TrackOutput(**{**_fields(o), "baselines": None}) for o in outputs]
    without = collect_motion_samples({"s": dets}, {"s": gts}, {"s": bare}, classes=["car"])
    a, b = with_["car"], without["car"]
    assert len(a) == len(b) > 100
    np.testing.assert_array_equal(a.velocity[Estimator.KALMAN], b.velocity[Estimator.KALMAN])
    by_row = {
        (o.time_secs, int(o.boxes.track_id[k])): o.baselines[k]
        for o in outputs
        for k in range(len(o))
    }
    expected = np.array(
        [by_row[(t, int(k))][0] for t, k in zip(a.times_secs, a.track_id, strict=True)]
    )
    np.testing.assert_allclose(a.velocity[Estimator.DIFFERENCE], expected)
    zero_a = (a.velocity[Estimator.DIFFERENCE] == 0).all(axis=1).sum()
    zero_b = (b.velocity[Estimator.DIFFERENCE] == 0).all(axis=1).sum()
    assert zero_b > zero_a  # the first output rows, 0 without the tentative detections


def test_the_tracker_baselines_need_no_detections() -> None:
    """An online run's output carries its baselines: scored without the detections (only the
    detection estimator is then absent); an output without them has none to score."""
    dets, gts, outputs, _ = _tracked_with_history()
    with_dets = collect_motion_samples({"s": dets}, {"s": gts}, {"s": outputs}, classes=["car"])
    alone = collect_motion_samples(None, {"s": gts}, {"s": outputs}, classes=["car"])["car"]
    assert set(alone.absent) == {Estimator.DETECTION}
    for e in (Estimator.KALMAN, Estimator.DIFFERENCE, Estimator.CURVE_FIT):
        np.testing.assert_array_equal(alone.velocity[e], with_dets["car"].velocity[e])
    bare = [TrackOutput(**{**_fields(o), "baselines": None}) for o in outputs]
    none = collect_motion_samples(None, {"s": gts}, {"s": bare}, classes=["car"])["car"]
    assert set(none.absent) == {Estimator.DETECTION, Estimator.DIFFERENCE, Estimator.CURVE_FIT}


def _fields(out: TrackOutput) -> dict:
    return {name: getattr(out, name) for name in TrackOutput.__dataclass_fields__}


def test_select_keeps_the_baselines_row_for_row() -> None:
    _dets, _gts, outputs, _ = _tracked_with_history()
    out = next(o for o in outputs if len(o) >= 3)
    keep = np.array([True, False] + [True] * (len(out) - 2))
    part = out.select(keep)
    np.testing.assert_array_equal(part.boxes.track_id, out.boxes.track_id[keep])
    np.testing.assert_array_equal(part.baselines, out.baselines[keep])
    np.testing.assert_array_equal(part.det_row, out.det_row[keep])


def test_tracks_file_round_trips_the_baselines(tmp_path: Path) -> None:
    dets, _gts, outputs, _ = _tracked_with_history()
    path = tmp_path / "tracks.json"
    write_tracks_file(path, {"s": (dets, outputs)})
    raw = json.loads(path.read_text())
    boxes = [b for record in raw["s"] for b in record["bboxes"]]
    assert any("global_velocity_curve" in b for b in boxes)
    assert all(("global_velocity_diff" in b) == (b["det_row"] >= 0) for b in boxes)
    _frames, read = read_tracks_file(path)
    for a, b in zip(read["s"], outputs, strict=True):
        np.testing.assert_array_equal(a.baselines, b.baselines)  # (NaN where no detection)
    for record in raw["s"]:  # a file from before the tracker kept them
        for box in record["bboxes"]:
            box.pop("global_velocity_diff", None)
            box.pop("global_velocity_curve", None)
    path.write_text(json.dumps(raw))
    assert all(o.baselines is None for o in read_tracks_file(path)[1]["s"])


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("global_velocity_diff", "fast", "'global_velocity_diff' must be a list of 2"),
        ("global_velocity_curve", [1.0, "x"], "'global_velocity_curve' must be a list of 2"),
        ("global_acceleration", [1.0], "'global_acceleration' must be a list of 2"),
        ("det_row", "3", "'det_row' must be an integer >= -1"),
        ("det_row", -7, "'det_row' must be an integer >= -1"),
    ],
)
def test_tracks_file_tracker_fields_are_checked(
    tmp_path: Path, field: str, value: object, message: str
) -> None:
    dets, _gts, outputs, _ = _tracked_with_history()
    path = tmp_path / "tracks.json"
    write_tracks_file(path, {"s": (dets, outputs)})
    raw = json.loads(path.read_text())
    frame_id, record = next((r["frame_id"], r) for r in raw["s"] if r["bboxes"])
    record["bboxes"][0][field] = value
    path.write_text(json.dumps(raw))
    with pytest.raises(InputError) as err:
        read_tracks_file(path)
    text = str(err.value)
    assert str(path) in text and f"frame {frame_id}" in text and message in text
