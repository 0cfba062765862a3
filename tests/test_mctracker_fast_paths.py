"""The tracker's fast paths change nothing: stage-2 shortcut, compiled geometry and stages,
Kalman variant.

Each fast path has a slow twin that is still used elsewhere: an observer disables the stage-2
shortcut, ``_geometry_kernel`` returning None selects the numpy geometry.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tracker import geometry, mctracker
from tracker.calibration import calibrate_frames, find_profile
from tracker.config import ScoreSource, load_config
from tracker.events import CostComputed, ListObserver, Stage, TrackOutput
from tracker.io.baseversion import read_baseversion
from tracker.io.synthetic import synthetic_scene
from tracker.pipeline import run_scene

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"


@pytest.fixture(scope="module")
def sample_frames():
    if not SAMPLE.is_dir():
        pytest.skip("sample_data/kitti-0001 missing")
    return read_baseversion(SAMPLE / "detections.json.gz")["0001"]


def assert_same_tracking(a: list[TrackOutput], b: list[TrackOutput], *, exact: bool) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.boxes.track_id, y.boxes.track_id)
        np.testing.assert_array_equal(x.status, y.status)
        np.testing.assert_array_equal(x.det_row, y.det_row)
        np.testing.assert_array_equal(x.stage, y.stage)
        assert (x.baselines is None) == (y.baselines is None)
        if x.baselines is not None:  # (NaN on the same rows: those without a detection)
            np.testing.assert_allclose(x.baselines, y.baselines, rtol=1e-12, atol=1e-12)
        if exact:
            assert x.boxes.equals(y.boxes)
            np.testing.assert_array_equal(x.acceleration, y.acceleration)
        else:
            for field in ("xyz", "lwh", "yaw", "velocity", "score"):
                np.testing.assert_allclose(
                    getattr(x.boxes, field), getattr(y.boxes, field), rtol=1e-9, atol=1e-9
                )


@pytest.mark.parametrize("config_name", ["kitti", "kitti_reference"])
def test_stage2_shortcut_equals_the_full_stage(sample_frames, config_name: str) -> None:
    """Without an observer, stage 2 is skipped when its gate can accept no pair."""
    cfg = load_config(config_name)
    if cfg.scores is ScoreSource.PROFILE:  # the sample is PointRCNN's
        sample_frames = calibrate_frames(sample_frames, find_profile("pointrcnn"))
    plain = run_scene(sample_frames, cfg).outputs
    observer = ListObserver()
    observed = run_scene(sample_frames, cfg, observer=observer).outputs
    assert_same_tracking(plain, observed, exact=True)
    scored = [e for e in observer.events if isinstance(e, CostComputed) and e.stage is Stage.RV]
    assert sum(e.cost.size for e in scored) > 100  # the full stage 2 scored pairs
    if config_name == "kitti_reference":  # (with the tuned kitti gates stage 1 takes them all)
        assert sum(int((o.stage == 2).sum()) for o in plain) > 0  # and matched some


def test_compiled_geometry_equals_numpy_in_the_tracker(sample_frames, monkeypatch) -> None:
    cfg = load_config("kitti")
    compiled = run_scene(sample_frames, cfg).outputs
    monkeypatch.setattr(geometry, "_geometry_kernel", lambda: None)
    fallback = run_scene(sample_frames, cfg).outputs
    assert_same_tracking(compiled, fallback, exact=False)


@pytest.mark.parametrize("motion", ["cv", "ca"])
def test_dense_synthetic_scene_both_pose_models(motion: str, monkeypatch) -> None:
    """50 objects per frame, CV and CA tables (k = 2 and 3): the fast paths change nothing."""
    dets, _ = synthetic_scene(num_objects=50, num_frames=30, seed=5)
    per_category = {"score_min": 0.5, "birth_score_min": 0.6, "pose": {"motion": motion}}
    cfg = load_config(
        "kitti",
        overrides={
            "categories": ["car", "pedestrian"],
            "category": {"car": per_category, "pedestrian": per_category},
        },
    )
    plain = run_scene(dets, cfg).outputs
    assert len(plain[-1]) >= 40  # the scene is tracked
    observed = run_scene(dets, cfg, observer=ListObserver()).outputs
    assert_same_tracking(plain, observed, exact=True)
    monkeypatch.setattr(mctracker, "load_kernels", lambda: None)  # numpy stages
    assert_same_tracking(plain, run_scene(dets, cfg).outputs, exact=False)
    monkeypatch.setattr(geometry, "_geometry_kernel", lambda: None)  # and numpy geometry
    assert_same_tracking(plain, run_scene(dets, cfg).outputs, exact=False)
