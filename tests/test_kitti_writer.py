"""The KITTI result writer's 2D boxes: projected 3D boxes, optionally narrowed per class."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tracker.calibration import calibrate_frames, find_profile
from tracker.categories import CATEGORIES, category_index
from tracker.config import load_config
from tracker.io.baseversion import read_baseversion
from tracker.io.writers import kitti_lines
from tracker.pipeline import run_scene

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"


def _boxes(lines: list[str]) -> dict[tuple[int, str], np.ndarray]:
    return {(int(f[1]), f[2]): np.array(f[6:10], float) for f in (ln.split() for ln in lines)}


def test_width_scale_narrows_only_its_class_about_the_centre() -> None:
    frames = read_baseversion(SAMPLE / "detections.json.gz")["0001"]
    frames = calibrate_frames(frames, find_profile("pointrcnn"))
    outputs = run_scene(frames, load_config("kitti")).outputs
    scale = np.ones(len(CATEGORIES))
    scale[category_index("pedestrian")] = 0.5
    pairs = 0
    for out, frame in zip(outputs, frames, strict=True):
        cam = frame.cameras[frame.camera_index("CAM_FRONT")]
        plain = _boxes(kitti_lines(out, cam))
        narrow = _boxes(kitti_lines(out, cam, width_scale=scale))
        assert set(narrow) <= set(plain)
        for key, b in narrow.items():
            a = plain[key]
            if key[1] != "Pedestrian":
                np.testing.assert_allclose(b, a)
                continue
            assert b[[1, 3]] == pytest.approx(a[[1, 3]])  # height unchanged
            if 0 < a[0] and a[2] < cam.width_px - 1:  # not clipped by the image edge
                assert b[2] - b[0] == pytest.approx((a[2] - a[0]) / 2, abs=1e-3)
                assert b[0] + b[2] == pytest.approx(a[0] + a[2], abs=1e-3)
                pairs += 1
    assert pairs > 20


def test_eval_writes_boxes_with_the_given_configs_width(tmp_path: Path) -> None:
    """`mctrack eval --config` shapes the static metrics' 2D boxes like the tracking run did:
    the shipped pedestrian width gives another pedestrian HOTA than no narrowing."""
    import json

    from app.cli import main
    from tracker.io.writers import write_tracks_file

    cfg = load_config("kitti")
    frames = read_baseversion(SAMPLE / "detections.json.gz")["0001"]
    frames = calibrate_frames(frames, find_profile("pointrcnn"))
    outputs = run_scene(frames, cfg).outputs
    write_tracks_file(tmp_path / "tracks.json", {"0001": (frames, outputs)})
    hota = {}
    for name in ("kitti", "kitti_reference"):  # pedestrian width 0.8155 / 1
        out = tmp_path / name
        args = ["eval", str(tmp_path / "tracks.json"), "--gt", str(SAMPLE / "gt.json.gz")]
        args += ["--labels", str(SAMPLE / "raw" / "training" / "label_02"), "--out", str(out)]
        assert main([*args, "--config", name]) == 0
        hota[name] = json.loads((out / "eval.json").read_text())["static"]["pedestrian"]["HOTA"]
    assert hota["kitti"] > hota["kitti_reference"] + 1.0
