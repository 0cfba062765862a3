"""bench/motion_table.py: the docs' motion page and its control estimators, scored on the run's
own samples (real KITTI run; skipped without the kit)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from motion_table import control_metrics, main

from tracker.eval.motion_eval import metrics_from_dict


def test_controls_use_the_runs_own_samples(kitti_root: Path, tmp_path: Path) -> None:
    """A fresh `mctrack kitti --motion` run (shipped score profile): the controls' samples are
    the run's, so its Kalman metrics are reproduced and the difference baseline equals the
    summary's (it re-ran the tracker without the profile, and said the metrics differed)."""
    from app.kitti import run_kitti

    run = tmp_path / "run"
    run_kitti(
        kitti_root=kitti_root, seqs=["0014"], classes=["car"], evaluate=False, motion=True,
        out=run, quiet=True,
    )  # fmt: skip
    summary = json.loads((run / "summary.json").read_text())
    assert summary["poses"] == "orbslam3" and summary["kitti_root"] == str(kitti_root)
    controls = control_metrics(
        summary, kitti_root, classes=["car"], poses="orbslam3", tracks=run / "tracks.json"
    )
    assert controls["reproduced"]
    difference = controls["rows"]["car"]["difference"].as_dict()
    expected = metrics_from_dict(summary["motion"]["metrics"]["difference"]["car"]).as_dict()
    for key, value in expected.items():
        assert np.isclose(difference[key], value, equal_nan=True), key
    page = tmp_path / "motion.md"
    code = main(
        [str(run / "summary.json"), "--out", str(page), "--classes", "car"]
    )  # (the kit and the poses: the run's)
    assert code == 0
    text = page.read_text()
    assert "## Controls: what VDE responds to" in text and "differ from the summary" not in text
