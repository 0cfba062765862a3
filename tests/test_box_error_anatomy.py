"""bench/box_error_anatomy.py: which part of a written 3D box costs its 2D overlap (real labels)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from box_error_anatomy import anatomy


def _shifted_labels(kitti_root: Path, out: Path, dy: float) -> None:
    """Sequence 0001's labels as a result file, each 3D box moved down by dy (2D boxes kept)."""
    out.mkdir()
    lines = []
    for line in (kitti_root / "training" / "label_02" / "0001.txt").read_text().splitlines():
        parts = line.split()
        parts[14] = f"{float(parts[14]) + dy:.6f}"  # (the bottom centre's camera y)
        lines.append(" ".join(parts))
    (out / "0001.txt").write_text("\n".join(lines) + "\n")


def test_the_ground_truth_itself_loses_nothing(kitti_root: Path, tmp_path: Path) -> None:
    _shifted_labels(kitti_root, tmp_path / "gt", 0.0)
    ious, err = anatomy(tmp_path / "gt", kitti_root, ["0001"])
    perfect = ious["ground truth's 3D box"]
    assert len(perfect) > 1000 and np.mean(perfect >= 0.95) > 0.99  # (the labels' projections)
    for name, values in ious.items():
        if name != "written 2D box":
            np.testing.assert_allclose(values, perfect, err_msg=name)
    for name, values in err["errors"].items():
        np.testing.assert_allclose(values, 0.0, atol=1e-9, err_msg=name)


def test_a_height_error_shows_in_its_own_rows_alone(kitti_root: Path, tmp_path: Path) -> None:
    _shifted_labels(kitti_root, tmp_path / "run", 0.1)
    ious, err = anatomy(tmp_path / "run", kitti_root, ["0001"])
    perfect = ious["ground truth's 3D box"]
    assert ious["ground truth, run's centre y (height)"].mean() < perfect.mean() - 0.02
    np.testing.assert_allclose(ious["run, ground truth's centre y (height)"], perfect)
    for part in ("centre x", "centre z (depth)", "size", "heading"):
        np.testing.assert_allclose(ious[f"ground truth, run's {part}"], perfect, err_msg=part)
    np.testing.assert_allclose(err["errors"]["centre y (height)"], 0.1, atol=1e-4)
    np.testing.assert_allclose(err["errors"]["centre x"], 0.0, atol=1e-9)
