"""bench/cut_detections.py: the score-cut detection sets of docs/results.md, made by a user."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from app.cli import main

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from cut_detections import cut_kit


def test_the_cut_kit_keeps_the_scores_at_or_above_the_cut_and_runs(
    kitti_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    kit = tmp_path / "cut_kit"
    assert cut_kit(kitti_root, "virconv", kit, seqs=["0001"]) == "virconv_cut"
    source = (kitti_root / "detections" / "virconv" / "training" / "0001.txt").read_text()
    kept = (kit / "detections" / "virconv_cut" / "training" / "0001.txt").read_text()
    want = [ln for ln in source.splitlines() if float(ln.split()[-1]) >= 0.0]
    assert kept.splitlines() == want and 0 < len(want) < len(source.splitlines())
    # the command docs/results.md gives, with the shipped profile of the detector cut
    out = tmp_path / "out"
    argv = ["kitti", "--kitti-root", str(kit), "--detector", "virconv_cut", "--seqs", "0001"]
    assert main([*argv, "--classes", "car", "--profile", "virconv", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["detector"] == "virconv_cut" and "car" in summary["metrics"]
    assert summary["score_calibration"] == "profile virconv"
