"""bench/fn_anatomy.py: missed ground truth classed by whether a detection covered it and where it
sits in its object's history; false positives at a track's ends whose object is not labelled
then."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("trackeval")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from fn_anatomy import classify_misses, unlabelled_end_rows

TAIL = "1.5 1.6 3.9 0.0 1.6 10.0 0.0"
# four cars' 2D boxes (80 px tall, above KITTI's 25 px), apart from each other
A, B, C, D = ((x, 100.0, x + 100.0, 180.0) for x in (100.0, 300.0, 500.0, 700.0))
D_SHIFTED = (760.0, 100.0, 860.0, 180.0)  # IoU 0.25 with D


def _row(frame: int, tid: int, box: tuple[float, ...], score: float | None = None) -> str:
    line = f"{frame} {tid} Car 0 0 0.0 " + " ".join(f"{v:.1f}" for v in box) + f" {TAIL}"
    return line + (f" {score}" if score is not None else "") + "\n"


def _write(path: Path, rows: list[str]) -> Path:
    path.write_text("".join(sorted(rows, key=lambda r: int(r.split()[0]))))
    return path


def test_misses_are_classed_by_detection_and_place(tmp_path: Path) -> None:
    # car 7 on A in frames 0-5, tracked in 2, 3, 5 (missed at 4), detected from frame 1 on;
    # car 8 on B in frames 0-1, never tracked, detected in frame 0 only
    labels = _write(
        tmp_path / "labels.txt",
        [_row(f, 7, A) for f in range(6)] + [_row(f, 8, B) for f in range(2)],
    )
    results = _write(tmp_path / "results.txt", [_row(f, 1, A, 0.9) for f in (2, 3, 5)])
    dets = _write(
        tmp_path / "dets.txt",
        [_row(f, 10 + f, A, 0.5) for f in range(1, 6)] + [_row(0, 20, B, 0.5)],
    )
    counts = classify_misses(labels, results, dets, "car")
    assert counts == {
        ("before", False): 1,  # car 7, frame 0: no detection
        ("before", True): 1,  # car 7, frame 1: detected, not tracked yet
        ("inside", True): 1,  # car 7, frame 4: detected, the track missed it
        ("never matched", True): 1,  # car 8, frame 0
        ("never matched", False): 1,  # car 8, frame 1
    }


@pytest.mark.parametrize("end", ["before first TP", "after last TP"])
def test_false_positives_at_a_tracks_ends_whose_object_is_unlabelled(
    tmp_path: Path, end: str
) -> None:
    # car 9 on C is labelled from frame 2, tracked from frame 0: two leading rows, unlabelled;
    # car 10 on D is labelled from frame 0, but the track's frame-0 box misses it: labelled.
    # "after last TP": the same scene backwards in time (labelled up to frame 1, tracked to 3)
    t = (lambda f: f) if end == "before first TP" else (lambda f: 3 - f)
    labels = _write(
        tmp_path / "labels.txt",
        [_row(t(f), 9, C) for f in (2, 3)] + [_row(t(f), 10, D) for f in range(4)],
    )
    results = _write(
        tmp_path / "results.txt",
        [_row(t(f), 2, C, 0.9) for f in range(4)]
        + [_row(t(0), 3, D_SHIFTED, 0.9)]
        + [_row(t(f), 3, D, 0.9) for f in (1, 2, 3)],
    )
    other = "after last TP" if end == "before first TP" else "before first TP"
    assert unlabelled_end_rows(labels, results, "car") == {end: (3, 2), other: (0, 0)}


def test_misses_after_the_last_match_with_no_detections_at_all(tmp_path: Path) -> None:
    # car 11 on A in frames 0-3, tracked in 0-1; the detector has no box in any frame
    labels = _write(tmp_path / "labels.txt", [_row(f, 11, A) for f in range(4)])
    results = _write(tmp_path / "results.txt", [_row(f, 1, A, 0.9) for f in (0, 1)])
    dets = _write(tmp_path / "dets.txt", [])
    assert classify_misses(labels, results, dets, "car") == {("after", False): 2}
