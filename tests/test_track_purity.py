"""bench/track_purity.py: detections labelled with their ground-truth object, and the object
changes along a tracker's tracks."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from track_purity import label_detections, object_changes

from tracker.boxes import Boxes
from tracker.categories import CATEGORIES
from tracker.events import TrackOutput
from tracker.frame import Frame

PED = CATEGORIES.index("pedestrian")


def _frame(i: int, xy: list[tuple[float, float]], ids: list[int] | None = None) -> Frame:
    n = len(xy)
    boxes = Boxes.create(
        xyz=np.array([[x, y, 0.0] for x, y in xy]).reshape(n, 3),
        lwh=np.tile([0.8, 0.6, 1.7], (n, 1)),
        yaw=np.zeros(n),
        category=np.full(n, PED),
        track_id=None if ids is None else np.array(ids),
    )
    return Frame("s", i, 0.1 * i, boxes)


def _output(i: int, track_ids: list[int], det_rows: list[int]) -> TrackOutput:
    n = len(track_ids)
    boxes = Boxes.create(
        xyz=np.zeros((n, 3)), lwh=np.ones((n, 3)), yaw=np.zeros(n), category=np.full(n, PED),
        track_id=np.array(track_ids),
    )  # fmt: skip
    return TrackOutput(
        "s", i, 0.1 * i, boxes, np.zeros((n, 2)), np.zeros(n, np.int8), np.array(det_rows),
        np.zeros(n, np.int8),
    )  # fmt: skip


def test_detections_take_the_nearest_object_within_a_metre() -> None:
    truth = [_frame(0, [(0.0, 0.0), (0.7, 0.0)], ids=[5, 6])]
    frames = [_frame(0, [(0.6, 0.1), (0.1, 0.0), (3.0, 0.0)])]
    labelled = label_detections(frames, truth, PED)
    assert labelled[0].boxes.track_id.tolist() == [6, 5, -1]


def test_a_track_that_takes_its_neighbours_detection_counts_two_changes() -> None:
    """Objects 5 and 6 walk 0.7 m apart; track 1 holds 5, 5, 6, 5 (two changes), track 2 holds
    6, 6 and misses frame 2, then a false positive (no object) in frame 3."""
    truth = [_frame(i, [(0.1 * i, 0.0), (0.1 * i, 0.7)], ids=[5, 6]) for i in range(4)]
    frames = [_frame(i, [(0.1 * i, 0.0), (0.1 * i, 0.7)], ids=[5, 6]) for i in range(3)] + [
        _frame(3, [(0.3, 0.0), (5.0, 5.0)], ids=[5, -1])
    ]
    outputs = [
        _output(0, [1, 2], [0, 1]),
        _output(1, [1, 2], [0, 1]),
        _output(2, [1, 2], [1, -1]),
        _output(3, [1, 2], [0, 1]),
    ]
    counts = object_changes(outputs, frames, truth)
    assert counts["changes"] == 2
    assert counts["0.5-1.0 m"] == 2
    assert counts["object-track pairs"] == 3 and counts["objects"] == 2
