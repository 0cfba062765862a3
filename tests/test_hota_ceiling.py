"""bench/hota_ceiling.py: a run with perfect ids, and the detector's oracle with and without
interpolation, on a scene whose every figure is known."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("trackeval")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from hota_ceiling import UNMATCHED_ID0, ceiling_rows, interpolate, relabel

TAIL = "1.5 1.6 3.9 0.0 1.6 10.0 0.0"
A, B = (100.0, 100.0, 200.0, 180.0), (500.0, 100.0, 600.0, 180.0)  # apart, 80 px tall


def _row(frame: int, tid: int, box: tuple[float, ...], score: float | None = None) -> str:
    line = f"{frame} {tid} Car 0 0 0.0 " + " ".join(f"{v:.1f}" for v in box) + f" {TAIL}"
    return line + (f" {score}" if score is not None else "") + "\n"


def _write(path: Path, rows: list[str]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(sorted(rows, key=lambda r: int(r.split()[0]))))
    return path


def test_interpolate_fills_gaps_up_to_the_longest(tmp_path: Path) -> None:
    moved = (110.0, 100.0, 210.0, 180.0)
    text = _row(0, 3, A, 0.9) + _row(2, 3, moved, 0.9) + _row(9, 3, A, 0.9)
    rows = [line.split() for line in interpolate(text, max_gap=5).splitlines()]
    assert [r[0] for r in rows] == ["0", "1", "2", "9"]  # the 6-frame gap is left
    assert [float(v) for v in rows[1][6:10]] == [105.0, 100.0, 205.0, 180.0]
    assert rows[1][10:] == rows[0][10:]  # the other columns are the earlier row's
    assert len(interpolate(text, max_gap=6).splitlines()) == 10


def test_relabel_puts_true_positives_under_their_objects_id(tmp_path: Path) -> None:
    f = _write(tmp_path / "r.txt", [_row(0, 1, A, 0.9), _row(0, 2, B, 0.9), _row(1, 1, A, 0.9)])
    tp = {(0, 1): 7, (1, 1): 7}
    kept = [r.split()[:2] for r in relabel(f, tp, keep_others=True).splitlines()]
    assert kept == [["0", "7"], ["0", str(UNMATCHED_ID0 + 2)], ["1", "7"]]
    assert [r.split()[:2] for r in relabel(f, tp, keep_others=False).splitlines()] == [
        ["0", "7"], ["1", "7"],
    ]  # fmt: skip


def test_ceiling_rows_on_a_known_scene(tmp_path: Path) -> None:
    # car 7 on A in frames 0-5. The detector boxes it exactly except in frame 2 and adds a
    # false box on B in frame 0; the run follows it as id 1 then id 2 (a switch after the gap)
    # and writes the false box as id 1 as well in frame 0.
    labels = _write(tmp_path / "labels" / "0000.txt", [_row(t, 7, A) for t in range(6)])
    dets = [_row(t, 10 + t, A, 0.5) for t in (0, 1, 3, 4, 5)] + [_row(0, 30, B, 0.5)]
    _write(tmp_path / "dets" / "0000.txt", dets)
    run = [_row(t, 1, A, 0.9) for t in (0, 1)] + [_row(t, 2, A, 0.9) for t in (3, 4, 5)]
    _write(tmp_path / "run" / "0000.txt", [*run, _row(0, 3, B, 0.9)])
    rows = dict(
        ceiling_rows([tmp_path / "run"], tmp_path / "dets", labels.parent, "car", max_gap=1)
    )
    name = str(tmp_path / "run")
    assert list(rows) == [name, f"{name} perfect ids", "oracle", "oracle interpolated"]
    assert rows[name]["IDSW"] == 1 and rows[name]["FP"] == 1 and rows[name]["FN"] == 1
    assert rows[f"{name} perfect ids"]["IDSW"] == 0
    assert rows[f"{name} perfect ids"]["AssA"] > rows[name]["AssA"]
    assert rows[f"{name} perfect ids"]["DetA"] == pytest.approx(rows[name]["DetA"])
    assert (rows["oracle"]["FP"], rows["oracle"]["FN"], rows["oracle"]["IDSW"]) == (0, 1, 0)
    assert rows["oracle interpolated"]["HOTA"] == pytest.approx(100.0)
