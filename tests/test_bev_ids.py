"""bench/bev_ids.py: rows relabelled by the ground-truth object they are on in BEV, and the HOTA
that recovers on a scene where the run swapped two pedestrians."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("trackeval")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from bev_ids import UNMATCHED_ID0, bev_ids, relabel, robustness_rows, score


def _row(frame: int, tid: int, x: float, z: float, kind: str = "Pedestrian") -> str:
    # the image box follows x so that two objects' boxes never overlap in this scene
    u = 600.0 + 60.0 * x
    box = f"{u - 20:.1f} 150.0 {u + 20:.1f} 250.0"
    return f"{frame} {tid} {kind} 0 0 0.0 {box} 1.7 0.6 0.8 {x:.2f} 1.5 {z:.2f} 0.0 0.9\n"


def _scene(tmp_path: Path) -> tuple[Path, Path]:
    """Pedestrians 4 (x = -1) and 9 (x = +1) walk away from the camera for 10 frames; the run
    follows them as 1 and 2 but exchanges the ids from frame 5 on, and writes a false row 3 m
    from both in frame 0."""
    labels, run = tmp_path / "labels", tmp_path / "run"
    labels.mkdir()
    run.mkdir()
    gt = [_row(t, k, x, 10.0 + 0.1 * t) for t in range(10) for k, x in ((4, -1.0), (9, 1.0))]
    rows = [
        _row(t, (1, 2)[(k == 9) ^ (t >= 5)], x + 0.1, 10.0 + 0.1 * t)
        for t in range(10)
        for k, x in ((4, -1.0), (9, 1.0))
    ]
    (labels / "0000.txt").write_text("".join(gt))
    (run / "0000.txt").write_text("".join(rows) + _row(0, 3, 4.0, 10.0))
    return labels, run


def test_rows_take_the_id_of_the_object_they_are_on(tmp_path: Path) -> None:
    labels, run = _scene(tmp_path)
    text, label = (run / "0000.txt").read_text(), (labels / "0000.txt").read_text()
    ids = bev_ids(text, label, "pedestrian")
    assert ids[0, 1] == 4 and ids[0, 2] == 9 and ids[5, 1] == 9 and ids[5, 2] == 4
    assert (0, 3) not in ids  # 3 m from both objects
    rows = [line.split() for line in relabel(text, label, "pedestrian").splitlines()]
    assert {r[1] for r in rows if r[0] == "7"} == {"4", "9"}
    assert [r[1] for r in rows if r[0] == "0"][-1] == str(UNMATCHED_ID0 + 3)
    # other classes' rows are left as written
    car = _row(0, 8, 0.0, 30.0, kind="Car")
    assert relabel(car, label, "pedestrian") == car


def test_bev_ids_recover_the_swap(tmp_path: Path) -> None:
    labels, run = _scene(tmp_path)
    written, perfect = score(run, labels, "pedestrian")
    assert written["IDSW"] == 2 and perfect["IDSW"] == 0
    assert perfect["AssA"] > written["AssA"] + 10
    assert perfect["DetA"] == pytest.approx(written["DetA"])  # the same rows and boxes


def test_robustness_rows_average_the_seeds_clean_first(tmp_path: Path) -> None:
    labels, run = _scene(tmp_path)
    out = tmp_path / "rob"
    text = (run / "0000.txt").read_text()
    for level, seed in (("noise", "seed0"), ("noise", "seed1"), ("clean", "clean")):
        (out / "runs" / level / seed).mkdir(parents=True)
        (out / "runs" / level / seed / "0000.txt").write_text(text)
    rows = robustness_rows(out, labels, "pedestrian")
    assert [(name, n) for name, n, *_ in rows] == [("clean", 1), ("noise", 2)]
    assert rows[0][2:] == pytest.approx(rows[1][2:])
    assert rows[0][3] > rows[0][2]
