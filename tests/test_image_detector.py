"""2D boxes of an image detector fused into the 3D detections (`mctrack kitti --image-detector`)."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

from tracker.categories import category_index
from tracker.cost import iou_xyxy
from tracker.errors import InputError
from tracker.io.baseversion import read_baseversion
from tracker.io.convert.kitti import fuse_image_boxes, read_image_detections

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"
CAR, PED = category_index("car"), category_index("pedestrian")


def _shift(xyxy: np.ndarray, fraction: float) -> np.ndarray:
    w = xyxy[:, 2] - xyxy[:, 0]
    return xyxy + np.column_stack([fraction * w, 0 * w, fraction * w, 0 * w])


def _image_boxes(frames: list, fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """Every car detection's own 2D box moved right by ``fraction`` of its width."""
    frame, xyxy = [], []
    for f in frames:
        rows = np.flatnonzero((f.boxes.category == CAR) & np.isfinite(f.boxes.xyxy_image).all(1))
        frame += [f.frame_id] * len(rows)
        xyxy.append(_shift(f.boxes.xyxy_image[rows], fraction))
    return np.array(frame, dtype=np.int64), np.concatenate(xyxy)


def test_read_image_detections(tmp_path: Path) -> None:
    good = tmp_path / "good.txt"
    good.write_text("0,10,20,30,40,0.9\n\n3,1.5,2,3,4,0.2\n")
    frame, xyxy = read_image_detections(good)
    assert frame.tolist() == [0, 3] and xyxy[1].tolist() == [1.5, 2, 3, 4]
    cases = {
        "0,10,20,30,40\n": "expected 6 columns",
        "0,10,20,abc,40,0.9\n": "x2",
        "0,10,20,30,40,0.9\n1,30,20,10,40,0.9\n": "empty 2D box",
        "-1,10,20,30,40,0.9\n": "negative frame",
    }
    for text, message in cases.items():
        bad = tmp_path / "bad.txt"
        bad.write_text(text)
        with pytest.raises(InputError, match=message) as err:
            read_image_detections(bad)
        assert "bad.txt" in str(err.value)


def test_each_detection_takes_the_image_box_over_it() -> None:
    """Car boxes overlapping a detection (IoU >= 0.5) replace its 2D box one to one (nearly
    all their own: a near-duplicate detection may take its neighbour's); boxes overlapping
    less are ignored; other classes keep theirs."""
    frames = read_baseversion(SAMPLE / "detections.json.gz")["0001"][:60]
    frame, xyxy = _image_boxes(frames, 0.1)  # IoU ~0.82
    decoy_frame, decoy = _image_boxes(frames, 0.6)  # IoU 0.25: another object's box
    fused, count = fuse_image_boxes(
        frames, CAR, np.concatenate([decoy_frame, frame]), np.concatenate([decoy, xyxy])
    )
    assert count == len(frame) > 100
    own = total = 0
    for before, after in zip(frames, fused, strict=True):
        car = (before.boxes.category == CAR) & np.isfinite(before.boxes.xyxy_image).all(1)
        mine = _shift(before.boxes.xyxy_image[car], 0.1)
        took = after.boxes.xyxy_image[car]
        own += int((np.abs(took - mine).max(axis=1) < 1e-9).sum())
        total += int(car.sum())
        np.testing.assert_array_equal(after.boxes.xyxy_image[~car], before.boxes.xyxy_image[~car])
        np.testing.assert_array_equal(after.boxes.xyz, before.boxes.xyz)
    assert own > 0.95 * total
    # with only boxes that overlap their own detection by 0.25, a detection takes one only
    # where it overlaps that detection's neighbour at least 0.5
    decoyed, some = fuse_image_boxes(frames, CAR, decoy_frame, decoy)
    assert some < count / 4
    for before, after in zip(frames, decoyed, strict=True):
        moved = np.flatnonzero((after.boxes.xyxy_image != before.boxes.xyxy_image).any(axis=1))
        assert (
            iou_xyxy(after.boxes.xyxy_image[moved], before.boxes.xyxy_image[moved]) >= 0.5
        ).all()
    _, peds = fuse_image_boxes(frames, PED, frame, xyxy)  # car boxes on pedestrians: none fit
    assert peds < count / 10


def test_kitti_run_with_an_image_detector_writes_its_boxes(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """`mctrack kitti --image-detector`: the bundled sequence with image boxes for cars only;
    matched car tracks write them (image_boxes auto), the missing pedestrian file is logged."""
    from app.kitti import run_kitti
    from tracker.io.convert.kitti import convert_kitti

    root = tmp_path / "kit"
    shutil.copytree(SAMPLE / "raw", root)
    dets, _ = convert_kitti(root, seqs=["0001"], classes=["car"], with_gt=False)
    frame, xyxy = _image_boxes(dets["0001"], 0.1)
    folder = root / "detections" / "img" / "training" / "Car"
    folder.mkdir(parents=True)
    rows = [
        f"{f},{a:.2f},{b:.2f},{c:.2f},{d:.2f},0.9"
        for f, (a, b, c, d) in zip(frame, xyxy, strict=True)
    ]
    # (and one row past the sequence's end: a warning, as a file of another sequence has them)
    (folder / "0001.txt").write_text("\n".join([*rows, "5000,10,20,110,80,0.9"]) + "\n")
    image_boxes = {(int(f), tuple(np.round(x, 2))) for f, x in zip(frame, xyxy, strict=True)}

    def written(out: Path) -> float:
        lines = [ln.split() for ln in (out / "data" / "0001.txt").read_text().splitlines()]
        boxes = [(int(c[0]), tuple(np.round(np.array(c[6:10], float), 2))) for c in lines]
        return sum(b in image_boxes for b in boxes) / len(boxes)

    common = {"kitti_root": root, "seqs": ["0001"], "classes": ["car", "pedestrian"],
              "quiet": True, "evaluate": False}  # fmt: skip
    with caplog.at_level(logging.INFO):
        fused = run_kitti(out=tmp_path / "fused", image_detector="img", **common)
    assert fused["image_boxes"] == "auto" and fused["image_detector"] == "img"
    assert "no pedestrian image boxes" in caplog.text and "took an image box" in caplog.text
    assert "0001: 1 image boxes at frames beyond the sequence's 447" in caplog.text
    plain = run_kitti(out=tmp_path / "plain", **common)
    assert plain["image_boxes"] == "auto"  # (the default: the projections of LiDAR boxes)
    assert written(tmp_path / "fused") > 0.5 and written(tmp_path / "plain") == 0.0


def test_iou_xyxy_pairs_and_matrix() -> None:
    a = np.array([[0.0, 0.0, 2.0, 2.0], [10.0, 10.0, 11.0, 12.0]])
    b = np.array([[1.0, 1.0, 3.0, 3.0], [10.0, 10.0, 11.0, 12.0]])
    np.testing.assert_allclose(iou_xyxy(a, b), [1 / 7, 1.0])
    np.testing.assert_allclose(iou_xyxy(a[:, None], b[None]), [[1 / 7, 0.0], [0.0, 1.0]])


@pytest.mark.parametrize("command", ["kitti", "convert"])
def test_a_missing_image_detector_is_one_line(
    command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from app.cli import main

    argv = ["kitti", "--kitti-root", str(SAMPLE / "raw"), "--seqs", "0001"]
    argv = (["convert", *argv] if command == "convert" else argv) + ["--image-detector", "nope"]
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "detections/nope/training: image detections not found" in err


@pytest.mark.parametrize("command", ["kitti", "convert"])
@pytest.mark.parametrize(
    ("layout", "fragments"),
    [
        (  # a 3D detector's one file per sequence (was a warning per sequence, and a run)
            "per_sequence",
            ("detections/threed/training: no Car/ folder of 2D boxes", "a 3D detector's"),
        ),
        (  # per-class files of a 3D detector (was an error per sequence, after the work)
            "per_class",
            ("threed/training/Car/0001.txt:1: field 'columns': expected 6", "got 15"),
        ),
    ],
)
def test_a_3d_detectors_folder_as_image_detector_is_refused_once(
    command: str,
    layout: str,
    fragments: tuple[str, ...],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from app.cli import main

    root = tmp_path / "kit"
    shutil.copytree(SAMPLE / "raw", root)
    lidar = root / "detections" / "pointrcnn" / "training" / "Car" / "0001.txt"
    folder = root / "detections" / "threed" / "training"
    folder.mkdir(parents=True)
    if layout == "per_sequence":
        shutil.copy(lidar, folder / "0001.txt")
    else:
        (folder / "Car").mkdir()
        shutil.copy(lidar, folder / "Car" / "0001.txt")
    argv = ["kitti", "--kitti-root", str(root), "--seqs", "0001", "--classes", "car"]
    argv = (["convert", *argv] if command == "convert" else argv) + ["--image-detector", "threed"]
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and all(f in err for f in fragments), err
    assert "--image-detector names a folder of <Class>/<seq>.txt" in err
    assert not (tmp_path / "out").exists()  # (refused before the work)
