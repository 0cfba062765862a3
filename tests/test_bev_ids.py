"""bench/bev_ids.py: rows relabelled by the ground-truth object they are on in BEV, and the HOTA
that recovers on a scene where the run swapped two pedestrians."""

from __future__ import annotations

import json
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
    follows them as 1 and 2 but exchanges the ids from frame 5 on, and writes a false row 3 m or
    more from either in frame 0."""
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
    result, label = run / "0000.txt", labels / "0000.txt"
    ids = bev_ids(result, label, "pedestrian")
    assert ids[0, 1] == 4 and ids[0, 2] == 9 and ids[5, 1] == 9 and ids[5, 2] == 4
    assert (0, 3) not in ids  # 3 m or more from either object
    rows = [line.split() for line in relabel(result, label, "pedestrian").splitlines()]
    assert {r[1] for r in rows if r[0] == "7"} == {"4", "9"}
    assert [r[1] for r in rows if r[0] == "0"][-1] == str(UNMATCHED_ID0 + 3)
    # other classes' rows are left as written
    car = _row(0, 8, 0.0, 30.0, kind="Car")
    (tmp_path / "car.txt").write_text(car)
    assert relabel(tmp_path / "car.txt", label, "pedestrian") == car


def test_bev_ids_recover_the_swap(tmp_path: Path) -> None:
    labels, run = _scene(tmp_path)
    written, perfect = score(run, labels, "pedestrian")
    assert written["IDSW"] == 2 and perfect["IDSW"] == 0
    assert perfect["AssA"] > written["AssA"] + 10
    assert perfect["DetA"] == pytest.approx(written["DetA"])  # the same rows and boxes


def test_robustness_rows_average_the_seeds_in_the_reports_order(tmp_path: Path) -> None:
    labels, run = _scene(tmp_path)
    swapped = (run / "0000.txt").read_text()
    kept = relabel(run / "0000.txt", labels / "0000.txt", "pedestrian")  # no swap
    out = tmp_path / "rob"
    for level, seed, text in (
        ("noise", "seed0", swapped), ("noise", "seed1", kept), ("clean", "clean", kept),
        ("blur", "seed0", swapped),
    ):  # fmt: skip
        (out / "runs" / level / seed).mkdir(parents=True)
        (out / "runs" / level / seed / "0000.txt").write_text(text)
    (out / "runs" / "README").write_text("not a level")
    (out / "robustness.json").write_text(json.dumps({"levels": ["clean", "noise"]}))
    rows = robustness_rows(out, labels, "pedestrian")
    # the report's levels first, in its order; a level it does not list after them
    assert [(name, n) for name, n, *_ in rows] == [("clean", 1), ("noise", 2), ("blur", 1)]
    clean, noise, blur = (row[2] for row in rows)
    assert noise == pytest.approx((clean + blur) / 2)  # the mean of a kept and a swapped run
    assert blur < clean
    assert rows[2][3] == pytest.approx(rows[0][3])  # BEV ids undo the swap


def test_bad_input_is_one_line_naming_the_file(tmp_path: Path) -> None:
    labels, run = _scene(tmp_path)
    with pytest.raises(SystemExit, match=r"no <seq>\.txt"):
        score(tmp_path / "labels" / "none", labels, "pedestrian")
    (run / "0001.txt").write_text(_row(0, 1, 0.0, 10.0))
    with pytest.raises(SystemExit, match=r"labels/0001\.txt: missing"):
        score(run, labels, "pedestrian")
    (run / "0001.txt").unlink()
    (run / "0000.txt").write_text(_row(0, 1, 0.0, 10.0) + "0 2 Pedestrian 0 0\n")
    with pytest.raises(SystemExit, match=r"run/0000\.txt:2: field 'columns'"):
        score(run, labels, "pedestrian")
    with pytest.raises(SystemExit, match="no runs/"):
        robustness_rows(tmp_path / "nothing", labels, "pedestrian")
