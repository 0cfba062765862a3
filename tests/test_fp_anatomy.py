"""bench/fp_anatomy.py: false-positive rows classed by where they sit in their track (TrackEval's
own preprocessing), and the label-free trimming rule it is compared with."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("trackeval")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import numpy as np
from fp_anatomy import (
    KINDS,
    anatomy,
    classify,
    hidden_counts,
    hidden_fraction,
    results_dir,
    trim_hidden_leading,
    trim_leading,
)

BOX = (100.0, 100.0, 200.0, 180.0)  # a car's 2D box (80 px tall, above KITTI's 25 px)
ELSEWHERE = (600.0, 100.0, 700.0, 180.0)
TAIL = "1.5 1.6 3.9 0.0 1.6 10.0 0.0"


def _row(frame: int, tid: int, box: tuple[float, ...], score: float | None = None) -> str:
    line = f"{frame} {tid} Car 0 0 0.0 " + " ".join(f"{v:.1f}" for v in box) + f" {TAIL}"
    return line + (f" {score}" if score is not None else "") + "\n"


@pytest.fixture()
def scene(tmp_path: Path) -> tuple[Path, Path]:
    """Ground truth: one car, frames 2-5. Track 1 is on it in frames 0-6 (rows 0, 1 before the
    label starts, row 6 after it ends); track 2 sits elsewhere in frames 0-3, on nothing."""
    labels, results = tmp_path / "labels", tmp_path / "results"
    labels.mkdir(), results.mkdir()
    (labels / "0000.txt").write_text("".join(_row(f, 7, BOX) for f in range(2, 6)))
    scores = {0: 0.3, 1: 0.9, 2: 0.95, 3: 0.95, 4: 0.95, 5: 0.95, 6: 0.95}
    rows = [_row(f, 1, BOX, scores[f]) for f in range(7)]
    rows += [_row(f, 2, ELSEWHERE, 0.5) for f in range(4)]
    (results / "0000.txt").write_text("".join(sorted(rows, key=lambda r: int(r.split()[0]))))
    return labels, results


def test_false_positives_are_classed_by_their_place_in_the_track(scene) -> None:
    labels, results = scene
    kinds = classify(results / "0000.txt", labels / "0000.txt", 7, "car")
    assert kinds == {
        (0, 1): KINDS[1], (1, 1): KINDS[1], (6, 1): KINDS[2],
        **{(f, 2): KINDS[0] for f in range(4)},
    }  # fmt: skip


def test_deleting_a_kind_of_false_positive_raises_hota(scene) -> None:
    labels, results = scene
    a = anatomy(results, labels, "car")
    assert a["metrics"]["FP"] == 7
    assert a["counts"] == {KINDS[0]: 4, KINDS[1]: 2, KINDS[2]: 1}
    assert all(hota > a["metrics"]["HOTA"] for hota in a["oracle_hota"].values())


def test_trimming_deletes_rows_before_the_first_confident_one(scene, tmp_path: Path) -> None:
    _, results = scene
    trim_leading(results, tmp_path / "trimmed", 0.8)
    kept = [line.split()[:2] for line in open(tmp_path / "trimmed" / "0000.txt")]
    # track 1 from its frame 1 (score 0.9) on; track 2 never reaches 0.8 and goes whole
    assert kept == [[str(f), "1"] for f in range(1, 7)]


def test_hidden_fraction_is_the_union_of_nearer_boxes_exactly() -> None:
    """Against a pixel raster: boxes on integer corners, so every pixel is in or out."""
    rng = np.random.default_rng(0)
    corners = np.sort(rng.integers(0, 40, size=(12, 2, 2)), axis=1)  # (box, min/max, x/y)
    xyxy = np.column_stack([corners[:, 0, 0], corners[:, 0, 1], corners[:, 1, 0] + 1,
                            corners[:, 1, 1] + 1]).astype(float)  # fmt: skip
    depth = rng.uniform(5, 40, size=12)
    got = hidden_fraction(xyxy, depth)
    for i, (x0, y0, x1, y1) in enumerate(xyxy.astype(int)):
        raster = np.zeros((41, 41), bool)
        for j, (a0, b0, a1, b1) in enumerate(xyxy.astype(int)):
            if depth[j] < depth[i] - 1.0:
                raster[b0:b1, a0:a1] = True
        assert got[i] == pytest.approx(raster[y0:y1, x0:x1].mean())
    assert got.max() > 0.5 and (got == 0).any()  # the draw has hidden and free boxes


def test_hidden_trimming_deletes_rows_until_the_track_is_first_seen(tmp_path: Path) -> None:
    """Track 2 sits behind track 1 (5 m further) in frames 0-1, then beside it; only track 1's
    object is labelled."""
    results, labels = tmp_path / "results", tmp_path / "labels"
    results.mkdir(), labels.mkdir()
    (labels / "0000.txt").write_text("".join(_row(f, 7, BOX) for f in range(4)))
    near = "1.5 1.6 3.9 0.0 1.6 10.0 0.0 0.9"
    far = "1.5 1.6 3.9 0.0 1.6 15.0 0.0 0.9"
    rows = []
    for f in range(4):
        rows.append(f"{f} 1 Car 0 0 0.0 100.0 100.0 200.0 180.0 {near}\n")
        x0 = 120.0 if f < 2 else 400.0
        rows.append(f"{f} 2 Car 0 0 0.0 {x0} 110.0 {x0 + 60} 170.0 {far}\n")
    (results / "0000.txt").write_text("".join(rows))
    trim_hidden_leading(results, tmp_path / "trimmed", 0.7)
    kept = [line.split()[:2] for line in open(tmp_path / "trimmed" / "0000.txt")]
    assert kept == [["0", "1"], ["1", "1"], ["2", "1"], ["2", "2"], ["3", "1"], ["3", "2"]]
    # track 2's two hidden rows are false positives of a track never matched
    assert hidden_counts(results, labels, "car", 0.7) == {KINDS[0]: 2}


def test_a_run_folder_is_read_for_its_data_and_an_empty_one_is_named(tmp_path: Path) -> None:
    (tmp_path / "run" / "data").mkdir(parents=True)
    (tmp_path / "run" / "data" / "0000.txt").write_text(_row(0, 1, BOX, 0.9))
    assert results_dir(tmp_path / "run") == tmp_path / "run" / "data"
    assert results_dir(tmp_path / "run" / "data") == tmp_path / "run" / "data"
    with pytest.raises(SystemExit, match="empty: no KITTI result files"):
        results_dir(tmp_path / "empty")
