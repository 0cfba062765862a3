"""Stage 2 deferred (the recording's path): the same matrices and gated pairs as the tracker's
own stage 2, computed later for many frames at once, and the same tracking."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from tracker.config import load_config
from tracker.eval.fates import FateCounter, Tee
from tracker.events import (
    CostComputed,
    FrameStarted,
    ImageStageDeferred,
    ListObserver,
    Matched,
    Predicted,
    Stage,
)
from tracker.image_stage import deferred_image_stage
from tracker.io.baseversion import read_baseversion
from tracker.pipeline import run_scene

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"


class _Deferred(ListObserver):
    rv_costs_deferred = True


def _per_frame(events: list) -> dict[int, dict]:
    out: dict[int, dict] = {}
    cur: dict = {}
    for e in events:
        if isinstance(e, FrameStarted):
            cur = out.setdefault(e.frame.frame_id, {"frame": e.frame})
        elif isinstance(e, Predicted):
            cur["pred"] = e
        elif isinstance(e, CostComputed) and e.stage is Stage.RV:
            cur["cost"] = e
        elif isinstance(e, Matched) and e.stage is Stage.RV:
            cur["matched"] = e
        elif isinstance(e, ImageStageDeferred):
            cur["deferred"] = e
    return out


@pytest.fixture(scope="module")
def runs():
    if not SAMPLE.is_dir():
        pytest.skip("sample_data/kitti-0001 missing")
    frames = read_baseversion(SAMPLE / "detections.json.gz")["0001"]
    config = load_config("kitti")
    eager, lazy = ListObserver(), _Deferred()
    eager_out = run_scene(frames, config, observer=eager).outputs
    lazy_out = run_scene(frames, config, observer=lazy).outputs
    return _per_frame(eager.events), _per_frame(lazy.events), eager_out, lazy_out


def _items(lazy: dict[int, dict]) -> list:
    return [
        (v["frame"], v["pred"].track_ids, v["pred"].boxes, v["deferred"])
        for _, v in sorted(lazy.items())
        if "deferred" in v
    ]


def test_deferred_stage2_equals_the_trackers(runs) -> None:
    eager, lazy, eager_out, lazy_out = runs
    for a, b in zip(eager_out, lazy_out, strict=True):  # tracking unchanged
        assert a.boxes.equals(b.boxes)
        np.testing.assert_array_equal(a.stage, b.stage)
    items = _items(lazy)
    # most frames' stage 2 cannot match (0001: ~300 of ~430) and is left to the observer
    assert len(items) > 200
    assert not any("deferred" in v and "cost" in v for v in lazy.values())
    rejected = 0
    for (frame, *_), (cost, matched) in zip(items, deferred_image_stage(items), strict=True):
        ref_cost, ref_matched = eager[frame.frame_id]["cost"], eager[frame.frame_id]["matched"]
        np.testing.assert_array_equal(cost.track_ids, ref_cost.track_ids)
        np.testing.assert_array_equal(cost.det_rows, ref_cost.det_rows)
        np.testing.assert_array_equal(cost.max_cost_per_row, ref_cost.max_cost_per_row)
        # the same cells, values up to the rounding of the projection
        np.testing.assert_array_equal(np.isinf(cost.cost), np.isinf(ref_cost.cost))
        np.testing.assert_allclose(cost.cost, ref_cost.cost, rtol=0, atol=1e-9)
        assert len(matched.track_ids) == len(ref_matched.track_ids) == 0
        np.testing.assert_array_equal(matched.rejected_track_ids, ref_matched.rejected_track_ids)
        np.testing.assert_array_equal(matched.rejected_det_rows, ref_matched.rejected_det_rows)
        rejected += len(matched.rejected_track_ids)
        # the 2D box of every track with a comparable cell
        rows = np.isfinite(cost.cost).any(axis=1)
        np.testing.assert_array_equal(cost.camera[rows], ref_cost.camera[rows])
        np.testing.assert_allclose(cost.track_xyxy[rows], ref_cost.track_xyxy[rows], atol=1e-6)
    assert rejected > 0  # gated pairs are shown on the skipped frames too


def test_a_pair_passing_the_gate_is_an_error(runs) -> None:
    _, lazy, _, _ = runs
    items = _items(lazy)
    computed = deferred_image_stage(items)
    k = next(i for i, (_, m) in enumerate(computed) if len(m.rejected_track_ids))
    frame, ids, boxes, event = items[k]
    wide = dataclasses.replace(
        event,
        yaw_gate_rad=np.full(len(event.track_rows), 4.0),
        distance_gate_m=np.full(len(event.track_rows), 1e6),
    )
    with pytest.raises(RuntimeError, match=f"frame {frame.frame_id}"):
        deferred_image_stage([(frame, ids, boxes, wide)])


def test_tee_defers_only_when_every_asking_observer_does() -> None:
    assert Tee(FateCounter(), _Deferred()).rv_costs_deferred
    assert not Tee(FateCounter(), _Deferred(), ListObserver()).rv_costs_deferred
    assert not Tee(FateCounter()).wants_rv_costs


def test_recording_shows_stage2_as_when_computed_per_frame(tmp_path: Path, monkeypatch) -> None:
    """The recording with stage 2 deferred holds the same stage-2 matrices, labels, accepted
    outlines and image-plane match lines as with the tracker computing it on every frame."""
    from tests.test_viz import entity_table
    from viz import paths
    from viz.observer import RerunObserver
    from viz.record import record_scene

    if not SAMPLE.is_dir():
        pytest.skip("sample_data/kitti-0001 missing")
    frames = read_baseversion(SAMPLE / "detections.json.gz")["0001"][:150]
    config = load_config("kitti")
    kw = {"images": {"CAM_FRONT": SAMPLE / "image_02"}, "motion_metrics": False}
    record_scene(frames, config, path=tmp_path / "deferred.rrd", **kw)
    monkeypatch.setattr(RerunObserver, "rv_costs_deferred", False)
    record_scene(frames, config, path=tmp_path / "eager.rrd", **kw)
    entities = {
        paths.COST_RV: ["Image:format", "Image:buffer"],
        f"{paths.COST_RV}/{paths.COST_LABELS}": ["Points2D:labels", "Points2D:positions"],
        f"{paths.COST_RV}/{paths.COST_MATCHED}": ["Boxes2D:centers"],
        paths.camera_matches_rv("CAM_FRONT"): ["LineStrips2D:labels", "LineStrips2D:strips"],
    }
    shown = 0
    for entity, columns in entities.items():
        a = entity_table(tmp_path / "deferred.rrd", entity)
        b = entity_table(tmp_path / "eager.rrd", entity)
        assert a[paths.FRAME].to_pylist() == b[paths.FRAME].to_pylist(), entity
        for column in columns:
            if column in b.column_names:
                assert a[column].to_pylist() == b[column].to_pylist(), (entity, column)
        shown += len(a)
    assert shown > 100
