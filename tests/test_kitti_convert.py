"""tracker.io.convert.kitti on the real KITTI tracking kit (skipped when the kit is absent)."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from tracker.boxes import Boxes
from tracker.camera import project_boxes
from tracker.categories import category_index
from tracker.errors import InputError
from tracker.frame import Frame
from tracker.geometry import wrap_angle
from tracker.io.convert.kitti import (
    WORLD_FROM_CAMERA_AXES,
    KittiObjects,
    boxes_rect_to_world,
    boxes_world_to_rect,
    convert_kitti,
    read_ab3dmot_detections,
    read_kitti_calib,
    read_kitti_labels,
    read_kitti_object_detections,
    read_kitti_tracking_detections,
)

VAL_SEQS = ("0001", "0006", "0008", "0010", "0012", "0013", "0014", "0015", "0016", "0018", "0019")
SEQ_0001_FRAMES = 447


@pytest.fixture(scope="module")
def val_converted(kitti_root: Path) -> tuple[dict[str, list[Frame]], dict[str, list[Frame]]]:
    detections, gt = convert_kitti(kitti_root, seqs=VAL_SEQS)
    assert gt is not None
    return detections, gt


def _label_rows(path: Path) -> list[list[str]]:
    """Independent plain-Python reading of a label_02 file (non-DontCare rows, file order)."""
    rows = [line.split() for line in path.read_text().splitlines() if line.strip()]
    return [r for r in rows if r[2] != "DontCare"]


def _iou_xyxy(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    inter_w = np.clip(np.minimum(a[:, 2], b[:, 2]) - np.maximum(a[:, 0], b[:, 0]), 0, None)
    inter_h = np.clip(np.minimum(a[:, 3], b[:, 3]) - np.maximum(a[:, 1], b[:, 1]), 0, None)
    inter = inter_w * inter_h
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return inter / (area_a + area_b - inter)


def _projection_ious(kitti_root: Path, gt: dict[str, list[Frame]]) -> np.ndarray:
    """IoU of each unoccluded, untruncated GT box's projection with the label's own 2D box."""
    ious = []
    for seq, frames in gt.items():
        rows = _label_rows(kitti_root / "training" / "label_02" / f"{seq}.txt")
        by_frame: dict[int, list[list[str]]] = {}
        for r in rows:
            by_frame.setdefault(int(r[0]), []).append(r)
        for frame in frames:
            frame_rows = by_frame.get(frame.frame_id, [])
            np.testing.assert_array_equal(frame.boxes.track_id, [int(r[1]) for r in frame_rows])
            clean = np.array([float(r[3]) == 0 and int(r[4]) == 0 for r in frame_rows], dtype=bool)
            label_xyxy = np.array([[float(v) for v in r[6:10]] for r in frame_rows]).reshape(-1, 4)
            xyxy, visible = project_boxes(frame.boxes, frame.cameras[0])
            assert visible[clean].all()
            ious.append(_iou_xyxy(xyxy[clean], label_xyxy[clean]))
    return np.concatenate(ious)


# ---------------------------------------------------------------------------------------------
# (a) geometry truth


def test_projected_gt_lands_on_label_2d_boxes(
    kitti_root: Path, val_converted: tuple[dict[str, list[Frame]], dict[str, list[Frame]]]
) -> None:
    ious = _projection_ious(kitti_root, val_converted[1])
    assert len(ious) > 10_000
    assert np.median(ious) > 0.8


def test_projection_without_pose_tilt(kitti_root: Path) -> None:
    """Without poses the world is the camera turned z up, so boxes stay upright in the camera and
    the projection is tighter (the ORB-SLAM3 world tilts them by the ego's pitch/roll, ≤ ~4.6°).
    Pedestrian-heavy 0016/0019 pull the median down: their 2D boxes hug the body."""
    _, gt = convert_kitti(kitti_root, seqs=VAL_SEQS, poses=None)
    assert gt is not None
    assert np.median(_projection_ious(kitti_root, gt)) > 0.9


def test_world_to_rect_round_trip(
    kitti_root: Path, val_converted: tuple[dict[str, list[Frame]], dict[str, list[Frame]]]
) -> None:
    labels = read_kitti_labels(kitti_root / "training" / "label_02" / "0001.txt")
    for frame in val_converted[1]["0001"][::20]:
        ref = labels.select((labels.frame == frame.frame_id) & (labels.category >= 0))
        b = frame.boxes
        xyz, hwl, ry = boxes_world_to_rect(b.xyz, b.lwh, b.yaw, frame.cameras[0].camera_from_world)
        np.testing.assert_allclose(xyz, ref.xyz_bottom_rect, atol=1e-9)
        np.testing.assert_allclose(hwl, ref.hwl)
        # Only the heading loses the world tilt (second order): < 0.2°.
        assert np.abs(wrap_angle(ry - ref.rotation_y)).max(initial=0.0) < np.radians(0.2)


def test_yaw_and_centre_for_the_identity_pose() -> None:
    from tracker.io.convert.kitti import KittiObjects

    ry = np.array([0.0, 0.5, -2.0, np.pi])
    objects = KittiObjects(
        frame=np.zeros(4, dtype=np.int64),
        track_id=np.arange(4),
        type_name=np.array(["Car"] * 4),
        category=np.zeros(4, dtype=np.int64),
        truncated=np.zeros(4),
        occluded=np.zeros(4, dtype=np.int64),
        xyxy_image=np.zeros((4, 4)),
        hwl=np.tile([1.5, 1.6, 4.0], (4, 1)),
        xyz_bottom_rect=np.tile([1.0, 1.7, 10.0], (4, 1)),
        rotation_y=ry,
        score_raw=np.full(4, np.nan),
    )
    xyz, lwh, yaw = boxes_rect_to_world(objects, WORLD_FROM_CAMERA_AXES[None])
    # bottom centre (1, 1.7, 10) in camera -> centre (1, 0.95, 10) -> world (10, -1, -0.95)
    np.testing.assert_allclose(xyz, np.tile([10.0, -1.0, -0.95], (4, 1)))
    np.testing.assert_allclose(lwh, np.tile([4.0, 1.6, 1.5], (4, 1)))
    np.testing.assert_allclose(yaw, wrap_angle(-ry - np.pi / 2), atol=1e-12)
    assert (yaw > -np.pi).all() and (yaw <= np.pi).all()


# ---------------------------------------------------------------------------------------------
# (b) ego motion: parked cars are static in the world


def _median_car_track_std_m(gt: dict[str, list[Frame]], seq: str) -> float:
    positions: dict[int, list[np.ndarray]] = {}
    car = category_index("car")
    for frame in gt[seq]:
        b = frame.boxes
        for track_id, xy in zip(
            b.track_id[b.category == car], b.xyz[b.category == car, :2], strict=True
        ):
            positions.setdefault(int(track_id), []).append(xy)
    stds = [np.linalg.norm(np.std(p, axis=0)) for p in positions.values() if len(p) >= 10]
    assert len(stds) > 20
    return float(np.median(stds))


def test_parked_cars_static_with_poses(
    kitti_root: Path, val_converted: tuple[dict[str, list[Frame]], dict[str, list[Frame]]]
) -> None:
    assert _median_car_track_std_m(val_converted[1], "0001") < 0.5


def test_parked_cars_move_without_poses(kitti_root: Path) -> None:
    _, gt = convert_kitti(kitti_root, seqs=["0001"], poses=None)
    assert gt is not None
    assert _median_car_track_std_m(gt, "0001") > 5.0


def _kit_copy(kitti_root: Path, tmp_path: Path, seq: str = "0001") -> Path:
    """A minimal kit in tmp_path: calib + labels + poses + per-class detections of one seq."""
    root = tmp_path / "kit"
    for sub in ("calib", "label_02", "pose_orbslam3"):
        (root / "training" / sub).mkdir(parents=True)
        shutil.copy(kitti_root / "training" / sub / f"{seq}.txt", root / "training" / sub)
    for cls in ("Car", "Pedestrian", "Cyclist"):
        det_dir = root / "detections" / "pointrcnn" / "training" / cls
        det_dir.mkdir(parents=True)
        shutil.copy(
            kitti_root / "detections" / "pointrcnn" / "training" / cls / f"{seq}.txt", det_dir
        )
    return root


def test_identity_camera_poses_and_lidar_poses_match_no_poses(
    kitti_root: Path, tmp_path: Path
) -> None:
    root = _kit_copy(kitti_root, tmp_path)
    calib = read_kitti_calib(root / "training" / "calib" / "0001.txt")
    camera_dir, lidar_dir = tmp_path / "cam_poses", tmp_path / "lidar_poses"
    camera_dir.mkdir()
    lidar_dir.mkdir()
    identity = " ".join(f"{v:.9f}" for v in np.eye(4)[:3].ravel())
    (camera_dir / "0001.txt").write_text(f"{identity}\n" * SEQ_0001_FRAMES)
    # velodyne -> world chosen so that world_from_rect = W for every frame
    world_from_velo = (WORLD_FROM_CAMERA_AXES @ calib.rect_from_velo)[:3].ravel()
    (lidar_dir / "0001.txt").write_text(
        ((" ".join(f"{v:.17g}" for v in world_from_velo)) + "\n") * SEQ_0001_FRAMES
    )
    _, reference = convert_kitti(root, seqs=["0001"], poses=None)
    _, with_camera = convert_kitti(root, seqs=["0001"], poses=camera_dir, pose_format="camera")
    _, with_lidar = convert_kitti(root, seqs=["0001"], poses=lidar_dir, pose_format="lidar")
    assert reference is not None and with_camera is not None and with_lidar is not None
    for ref, cam, lid in zip(
        reference["0001"], with_camera["0001"], with_lidar["0001"], strict=True
    ):
        np.testing.assert_allclose(cam.boxes.xyz, ref.boxes.xyz, atol=1e-9)
        np.testing.assert_allclose(lid.boxes.xyz, ref.boxes.xyz, atol=1e-9)
        np.testing.assert_allclose(lid.boxes.yaw, ref.boxes.yaw, atol=1e-9)
        np.testing.assert_allclose(
            lid.cameras[0].camera_from_world, ref.cameras[0].camera_from_world, atol=1e-9
        )


# ---------------------------------------------------------------------------------------------
# (c) frames, scores, cameras


def test_every_frame_emitted_with_scores(
    kitti_root: Path, val_converted: tuple[dict[str, list[Frame]], dict[str, list[Frame]]]
) -> None:
    detections, gt = val_converted
    frames = detections["0001"]
    assert len(frames) == SEQ_0001_FRAMES == len(gt["0001"])
    assert [f.frame_id for f in frames] == list(range(SEQ_0001_FRAMES))
    np.testing.assert_allclose([f.timestamp_secs for f in frames], np.arange(SEQ_0001_FRAMES) * 0.1)
    # PointRCNN has no box at frames 177-180 of 0001; the reference would drop these frames.
    assert [len(frames[i].boxes) for i in range(177, 181)] == [0, 0, 0, 0]
    assert all(f.scene == "0001" for f in frames)

    # frame 0: every class file's rows, raw score kept, score = sigmoid(raw)
    raw_expected = []
    for cls in ("Car", "Pedestrian", "Cyclist"):
        text = (kitti_root / "detections" / "pointrcnn" / "training" / cls / "0001.txt").read_text()
        raw_expected += [
            float(r.split(",")[6]) for r in text.splitlines() if r.split(",")[0] == "0"
        ]
    boxes = frames[0].boxes
    np.testing.assert_allclose(np.sort(boxes.score_raw), np.sort(raw_expected))
    np.testing.assert_allclose(boxes.score, 1.0 / (1.0 + np.exp(-boxes.score_raw)))
    assert (boxes.camera == 0).all() and (boxes.track_id == -1).all()
    assert not np.isnan(boxes.xyxy_image).any()


def test_cameras_and_ego(
    val_converted: tuple[dict[str, list[Frame]], dict[str, list[Frame]]],
) -> None:
    detections, gt = val_converted
    sizes = {
        seq: (frames[0].cameras[0].width_px, frames[0].cameras[0].height_px)
        for seq, frames in detections.items()
    }
    assert sizes["0001"] == (1242, 375)  # PNG header
    assert sizes["0016"] == (1224, 370)  # PNG header
    assert sizes["0014"] == (1224, 370)  # recording-day table
    assert sizes["0018"] == (1238, 374)
    frame = gt["0001"][100]
    cam = frame.cameras[0]
    assert cam.name == "CAM_FRONT"
    np.testing.assert_allclose(cam.camera_from_world @ frame.world_from_ego, np.eye(4), atol=1e-9)
    # DontCare rows of frame 0 become ignore regions in camera 0, in file order
    np.testing.assert_allclose(
        gt["0001"][0].ignore_xyxy_image,
        [[356.4, 195.81, 374.1, 216.65], [545.98, 182.27, 574.1, 204.15],
         [573.47, 177.81, 600.64, 199.16], [600.64, 177.81, 614.22, 192.37],
         [621.01, 179.75, 636.54, 193.34]],
    )  # fmt: skip
    np.testing.assert_array_equal(gt["0001"][0].ignore_camera, np.zeros(5))


def test_gt_classes_and_unknown_logged(
    kitti_root: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    root = _kit_copy(kitti_root, tmp_path)
    label = root / "training" / "label_02" / "0001.txt"
    text = label.read_text().replace(" Van ", " Spaceship ", 3)
    label.write_text(text)
    with caplog.at_level(logging.WARNING):
        detections, gt = convert_kitti(root, seqs=["0001"], classes=("car",))
    assert gt is not None
    assert "{'Spaceship': 3}" in caplog.text
    categories = np.concatenate([f.boxes.category for f in gt["0001"]])
    # GT keeps the distractor classes whatever ``classes`` says; DontCare/unknown never appear
    expected = {category_index(c) for c in ("car", "van", "truck", "pedestrian", "misc")}
    assert set(categories.tolist()) == expected
    det_categories = np.concatenate([f.boxes.category for f in detections["0001"]])
    assert set(det_categories.tolist()) == {category_index("car")}


def test_sequence_length_rules(kitti_root: Path, tmp_path: Path) -> None:
    root = _kit_copy(kitti_root, tmp_path)
    # without poses: max frame index + 1 over labels and detections
    detections, _ = convert_kitti(root, seqs=["0001"], poses=None)
    assert len(detections["0001"]) == SEQ_0001_FRAMES
    # an explicit length wins (rows beyond it are dropped)
    detections, gt = convert_kitti(root, seqs=["1"], num_frames=50)
    assert gt is not None and len(detections["0001"]) == 50 == len(gt["0001"])
    # fewer pose lines than frames is an error naming the file, the line and the field
    pose = root / "training" / "pose_orbslam3" / "0001.txt"
    pose.write_text("\n".join(pose.read_text().splitlines()[:100]) + "\n")
    with pytest.raises(InputError, match="frame") as excinfo:
        convert_kitti(root, seqs=["0001"])
    error = excinfo.value
    assert error.path is not None and error.line is not None and error.field == "frame"
    assert f"{error.path}:{error.line}: field 'frame'" in str(error)
    row = Path(error.path).read_text().splitlines()[error.line - 1]
    frame = int(row.replace(",", " ").split()[0])
    assert frame >= 100 and f"frame {frame} is beyond the 100 poses" in str(error)


def test_a_pose_that_is_not_rigid_is_refused_naming_its_line(
    kitti_root: Path, tmp_path: Path
) -> None:
    root = _kit_copy(kitti_root, tmp_path)
    pose = root / "training" / "pose_orbslam3" / "0001.txt"
    lines = pose.read_text().splitlines()
    values = [float(v) for v in lines[9].split()]
    values[0] *= 2.0  # R[0, 0] scaled: not a rotation
    pose.write_text("\n".join([*lines[:9], " ".join(map(str, values)), *lines[10:]]) + "\n")
    with pytest.raises(InputError) as excinfo:
        convert_kitti(root, seqs=["0001"])
    assert str(excinfo.value).startswith(f"{pose}:10: field 'pose': not a rigid motion")


@pytest.mark.parametrize(("column", "value"), [(3, "1e300"), (11, "-2e8")])
def test_a_pose_beyond_the_bound_is_refused_naming_its_line_frame_and_field(
    kitti_root: Path, tmp_path: Path, column: int, value: str
) -> None:
    """A pose translation beyond the bound of tracker.io.bounds (finite, but no place on Earth):
    one line naming the file, the line, the field and the frame (was converted: every box of
    that frame at 1e300 in the world frame)."""
    root = _kit_copy(kitti_root, tmp_path)
    pose = root / "training" / "pose_orbslam3" / "0001.txt"
    lines = pose.read_text().splitlines()
    values = lines[9].split()
    values[column] = value
    pose.write_text("\n".join([*lines[:9], " ".join(values), *lines[10:]]) + "\n")
    with pytest.raises(InputError) as excinfo:
        convert_kitti(root, seqs=["0001"])
    assert str(excinfo.value) == (
        f"{pose}:10: field 'pose[{column // 4},3]': {value} (frame 9) is beyond ±1e+08 m "
        "(farther or larger than anything on Earth)"
    )


@pytest.mark.parametrize(
    ("key", "column", "value", "said"),
    [
        ("Tr_velo_to_cam", 3, "1e300", "translation [1e+300, "),
        ("P2", 3, "1e300", "the camera's translation K⁻¹ P2[:, 3] [1.38"),
        ("P2", 0, "0", "its left 3x3 (the intrinsics) is singular: not a camera"),
    ],
)
def test_a_calib_translation_beyond_the_bound_or_a_singular_camera_is_refused(
    kitti_root: Path, tmp_path: Path, key: str, column: int, value: str, said: str
) -> None:
    """The calib translations applied to every box (the velodyne's in the camera, camera 2's
    from P2) beyond the bound of tracker.io.bounds, or a P2 whose intrinsics are singular: one
    line naming the calib file, the line and the key (the translation was applied: every box at
    1e300; the singular P2 ended in a LinAlgError traceback)."""
    root = _kit_copy(kitti_root, tmp_path)
    calib = root / "training" / "calib" / "0001.txt"
    lines = calib.read_text().splitlines()
    line = next(i for i, text in enumerate(lines) if text.split()[0].rstrip(":") == key)
    values = lines[line].split()
    values[1 + column] = value
    lines[line] = " ".join(values)
    if key == "P2" and column == 0:
        values[1 + 5] = "0"  # fy too: the first two rows of K are zero
        lines[line] = " ".join(values)
    calib.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as excinfo:
        convert_kitti(root, seqs=["0001"])
    message = str(excinfo.value)
    assert message.startswith(f"{calib}:{line + 1}: field '{key}': {said}")
    assert "singular" in said or message.endswith(
        "is beyond ±1e+08 m (farther or larger than anything on Earth)"
    )


def _edit_calib_line(calib: Path, key: str, text: str) -> int:
    """Replace the values of ``key``'s line in ``calib`` by ``text``; its 1-based line number."""
    lines = calib.read_text().splitlines()
    line = next(i for i, row in enumerate(lines) if row.split()[0].rstrip(":") == key)
    lines[line] = f"{lines[line].split()[0]} {text}".rstrip()
    calib.write_text("\n".join(lines) + "\n")
    return line + 1


_ZEROS_12 = " ".join(["0"] * 12)
_UNUSED_CALIB_CASES = [
    ("P0", "1 2 3", "expected 12 values, got 3"),
    ("P0", "", "expected 12 values, got 0"),
    ("P1", " ".join(["x"] * 12), "not a number (could not convert string to float: 'x')"),
    ("P3", " ".join(["nan"] * 12), "non-finite value"),
    ("P3", _ZEROS_12, "its left 3x3 (the intrinsics) is singular: not a camera"),
    ("P1", "1 0 0 1e300 0 1 0 0 0 0 1 0", "the camera's translation K⁻¹ P1[:, 3] [1e+300, "),
    ("Tr_imu_to_velo", "1 0 0 0 0 1 0 0 0 0", "expected 12 values, got 10"),
    ("Tr_imu_to_velo", "1 0 0 0 0 1 0 0 0 0 1 -3e8", "translation [0.0, 0.0, -300000000.0] is"),
]


@pytest.mark.parametrize(
    ("key", "text", "said"),
    _UNUSED_CALIB_CASES,
    ids=[f"{k}:{s[:20]}" for k, _, s in _UNUSED_CALIB_CASES],
)
def test_a_malformed_calib_matrix_the_conversion_does_not_use_is_a_logged_skip(
    kitti_root: Path,
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
    key: str,
    text: str,
    said: str,
) -> None:
    """P0, P1, P3 and Tr_imu_to_velo are read for the record and used by nothing: a malformed
    one refused the whole sequence (or, all zeros, was kept as a projection that is no camera).
    Now it is left out with a warning naming the file, line and key, and the conversion is the
    same as with the file intact."""
    root = _kit_copy(kitti_root, tmp_path)
    calib = root / "training" / "calib" / "0001.txt"
    intact = read_kitti_calib(calib)
    reference, _ = convert_kitti(root, seqs=["0001"], poses=None, with_gt=False)
    line = _edit_calib_line(calib, key, text)
    with caplog.at_level(logging.WARNING, logger="tracker.io.convert.kitti"):
        read = read_kitti_calib(calib)
        converted, _ = convert_kitti(root, seqs=["0001"], poses=None, with_gt=False)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert f"{calib}:{line}: field '{key}': {said}" in warnings[0]
    assert warnings[0].endswith("(not used by the conversion: left out)")
    if key.startswith("P"):
        assert set(read.projections) == set(intact.projections) - {key}
    else:
        assert read.velo_from_imu is None and intact.velo_from_imu is not None
    np.testing.assert_array_equal(read.image_from_rect, intact.image_from_rect)
    np.testing.assert_array_equal(read.rect_from_velo, intact.rect_from_velo)
    for a, b in zip(reference["0001"], converted["0001"], strict=True):
        assert a.boxes.equals(b.boxes)


_USED_CALIB_CASES = [
    ("P2", "1 2 3", "expected 12 values, got 3"),
    ("R0_rect", " ".join(["x"] * 9), "not a number (could not convert string to float: 'x')"),
    ("R0_rect", _ZEROS_12, "expected 9 values, got 12"),
    ("Tr_velo_to_cam", " ".join(["inf"] * 12), "non-finite value"),
]


@pytest.mark.parametrize(
    ("key", "text", "said"),
    _USED_CALIB_CASES,
    ids=[f"{k}:{s[:20]}" for k, _, s in _USED_CALIB_CASES],
)
def test_a_malformed_calib_matrix_the_conversion_uses_is_refused(
    kitti_root: Path, tmp_path: Path, key: str, text: str, said: str
) -> None:
    """P2, R0_rect and Tr_velo_to_cam place every box: a malformed one is one line naming the
    calib file, the line and the key (the CLI's exit status 2), never a traceback."""
    root = _kit_copy(kitti_root, tmp_path)
    calib = root / "training" / "calib" / "0001.txt"
    line = _edit_calib_line(calib, key, text)
    with pytest.raises(InputError) as excinfo:
        convert_kitti(root, seqs=["0001"], poses=None, with_gt=False)
    assert str(excinfo.value) == f"{calib}:{line}: field '{key}': {said}"


@pytest.mark.parametrize(
    ("key", "spelling"),
    [("P2", "P2:"), ("R0_rect", "R_rect"), ("Tr_velo_to_cam", "Tr_velo_cam")],
)
def test_a_repeated_calib_key_the_conversion_uses_is_refused(
    kitti_root: Path, tmp_path: Path, key: str, spelling: str
) -> None:
    """A second P2, R0_rect or Tr_velo_to_cam line (in either spelling) silently replaced the
    first, so the boxes were placed by whichever came last. Now it is one line naming the calib
    file, the repeated line and the key; the CLI exits 2 without a traceback."""
    root = _kit_copy(kitti_root, tmp_path)
    calib = root / "training" / "calib" / "0001.txt"
    rows = calib.read_text().splitlines()
    first = next(i for i, row in enumerate(rows) if row.split()[0].rstrip(":") == key) + 1
    values = rows[first - 1].split()[1:]
    calib.write_text("\n".join([*rows, " ".join([spelling, *values])]) + "\n")
    said = f"{calib}:{len(rows) + 1}: field '{key}': repeated key (first on line {first})"
    with pytest.raises(InputError) as excinfo:
        read_kitti_calib(calib)
    assert str(excinfo.value) == said
    argv = ["kitti", "--kitti-root", str(root), "--detector", "pointrcnn", "--seqs", "0001"]
    assert main([*argv, "--no-eval", "--out", str(tmp_path / "out")]) == 2


def test_a_repeated_calib_key_the_conversion_does_not_use_keeps_its_first_line(
    kitti_root: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A repeated P0 (read for the record, used by nothing) keeps its first line with a logged
    warning naming the file, line and key; the sequence is not refused."""
    root = _kit_copy(kitti_root, tmp_path)
    calib = root / "training" / "calib" / "0001.txt"
    intact = read_kitti_calib(calib)
    rows = calib.read_text().splitlines()
    calib.write_text("\n".join([*rows, "P0: " + " ".join(["7"] * 12)]) + "\n")
    with caplog.at_level(logging.WARNING, logger="tracker.io.convert.kitti"):
        read = read_kitti_calib(calib)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == [
        f"{calib}:{len(rows) + 1}: field 'P0': repeated key (first on line 1) "
        "(not used by the conversion: this line ignored)"
    ]
    np.testing.assert_array_equal(read.projections["P0"], intact.projections["P0"])
    np.testing.assert_array_equal(read.image_from_rect, intact.image_from_rect)


def test_poses_of_a_longer_sequence_are_a_warning(
    kitti_root: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    root = _kit_copy(kitti_root, tmp_path)
    single = root / "detections" / "vc" / "training"  # one file holding every class's rows
    single.mkdir(parents=True)
    shutil.copy(kitti_root / "detections" / "virconv" / "training" / "0001.txt", single)
    pose = root / "training" / "pose_orbslam3" / "0001.txt"
    lines = pose.read_text().splitlines()
    pose.write_text("\n".join(lines + lines[-1:] * 1000) + "\n")  # 1447 poses for 447 frames
    with caplog.at_level(logging.WARNING):
        convert_kitti(root, seqs=["0001"], with_gt=False, detector="vc", classes=("car",))
    assert "has 1447 poses, but the last detection is at frame 427" in caplog.text
    caplog.clear()
    # per-class files: the class asked for may end early (none at all here), the others are
    # not read; no warning
    with caplog.at_level(logging.WARNING):
        convert_kitti(root, seqs=["0001"], with_gt=False, classes=("cyclist",))
    assert "another sequence" not in caplog.text


def test_kitti_object_layout(kitti_root: Path, tmp_path: Path) -> None:
    """Per-frame files: frames without a file or with an empty file are still emitted."""
    root = _kit_copy(kitti_root, tmp_path)
    det_dir = tmp_path / "object_layout" / "0001"
    det_dir.mkdir(parents=True)
    rows = "Car -1 -1 -1.8 10 20 110 80 1.5 1.6 3.9 2.9 1.6 6.4 -1.58 2.5\n"
    (det_dir / "000000.txt").write_text(rows + rows.replace("Car", "Pedestrian"))
    (det_dir / "000002.txt").write_text("")
    (det_dir / "000004.txt").write_text(rows.replace(" 2.5\n", " -1.0\n"))
    detections, _ = convert_kitti(
        root, seqs=["0001"], detections_dir=tmp_path / "object_layout", poses=None
    )
    frames = detections["0001"]
    assert len(frames) == SEQ_0001_FRAMES  # labels reach frame 446
    assert [len(f.boxes) for f in frames[:5]] == [2, 0, 0, 0, 1]
    np.testing.assert_allclose(frames[4].boxes.score_raw, [-1.0])
    np.testing.assert_allclose(frames[0].boxes.xyxy_image[0], [10, 20, 110, 80])
    np.testing.assert_allclose(frames[0].boxes.lwh[0], [3.9, 1.6, 1.5])
    assert frames[0].boxes.category.tolist() == [
        category_index("car"),
        category_index("pedestrian"),
    ]


def test_boxes_are_plain_boxes(
    val_converted: tuple[dict[str, list[Frame]], dict[str, list[Frame]]],
) -> None:
    boxes = Boxes.concat([f.boxes for f in val_converted[0]["0012"]])
    assert len(boxes) > 0
    assert np.isfinite(boxes.xyz).all() and (boxes.lwh > 0).all()
    assert (boxes.yaw > -np.pi).all() and (boxes.yaw <= np.pi).all()


# ---------------------------------------------------------------------------------------------
# (d) calib spellings


def test_both_calib_spellings(kitti_root: Path, tmp_path: Path) -> None:
    object_style = kitti_root / "training" / "calib" / "0001.txt"
    text = object_style.read_text()
    for old, new in (
        ("R0_rect:", "R_rect"),
        ("Tr_velo_to_cam:", "Tr_velo_cam"),
        ("Tr_imu_to_velo:", "Tr_imu_velo"),
    ):
        assert old in text
        text = text.replace(old, new)
    tracking_style = tmp_path / "0001.txt"
    tracking_style.write_text(text)
    a, b = read_kitti_calib(object_style), read_kitti_calib(tracking_style)
    for name in (
        "image_from_rect",
        "rect_from_cam0",
        "cam0_from_velo",
        "velo_from_imu",
        "rect_from_velo",
    ):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.rect_from_cam0 is not None and not np.allclose(a.rect_from_cam0, np.eye(4))


def test_calib_missing_key_names_file_and_key(kitti_root: Path, tmp_path: Path) -> None:
    src = (kitti_root / "training" / "calib" / "0001.txt").read_text().splitlines()
    path = tmp_path / "0001.txt"
    path.write_text("\n".join(line for line in src if not line.startswith("Tr_velo_to_cam")))
    calib = read_kitti_calib(path)
    with pytest.raises(InputError) as excinfo:
        _ = calib.rect_from_velo
    assert str(path) in str(excinfo.value) and "Tr_velo_to_cam" in str(excinfo.value)
    path.write_text("\n".join(line for line in src if not line.startswith("P2")))
    with pytest.raises(InputError, match="P2"):
        read_kitti_calib(path)


# ---------------------------------------------------------------------------------------------
# (e) bad input: one case per failure class, the message names the file and the field

_GOOD_DET = "0,2,786.7,180.1,1241.0,374.0,12.2,1.52,1.68,4.45,2.93,1.60,6.42,-1.58,-2.01"
_GOOD_LABEL = "0 3 Car 0 0 -1.79 296.7 161.7 455.2 292.3 2.0 1.8 4.4 -4.5 2.0 11.0 -2.1"


def _replace_column(row: str, sep: str, index: int, value: str) -> str:
    cols = row.split(sep)
    cols[index] = value
    return sep.join(cols)


@pytest.mark.parametrize(
    ("kind", "bad_row", "field"),
    [
        ("detections", _replace_column(_GOOD_DET, ",", 9, "4.4x5"), "'l'"),  # malformed number
        ("detections", _GOOD_DET + ",0.5", "'columns'"),  # wrong column count
        ("detections", _replace_column(_GOOD_DET, ",", 12, "nan"), "'z'"),  # NaN
        ("detections", _replace_column(_GOOD_DET, ",", 1, "7"), "'type'"),  # unknown type code
        ("detections", _replace_column(_GOOD_DET, ",", 0, "1.5"), "'frame'"),  # non-integral frame
        ("detections", _replace_column(_GOOD_DET, ",", 8, "0"), "'w'"),  # degenerate box
        ("labels", _replace_column(_GOOD_LABEL, " ", 13, "-4,5"), "'x'"),  # malformed number
        ("labels", _GOOD_LABEL.rsplit(" ", 2)[0], "'columns'"),  # wrong column count
        ("labels", _replace_column(_GOOD_LABEL, " ", 16, "NaN"), "'rotation_y'"),  # NaN
        ("poses", "1 0 0 0 0 1 0 0 0 0 1", "'columns'"),  # wrong column count
        ("poses", "1 0 0 0 0 1 0 0 0 0 1 inf", "'pose[2,3]'"),  # non-finite
    ],
)
def test_bad_input_names_file_line_and_field(
    kitti_root: Path, tmp_path: Path, kind: str, bad_row: str, field: str
) -> None:
    root = _kit_copy(kitti_root, tmp_path)
    if kind == "detections":
        path = root / "detections" / "pointrcnn" / "training" / "Car" / "0001.txt"
    elif kind == "labels":
        path = root / "training" / "label_02" / "0001.txt"
    else:
        path = root / "training" / "pose_orbslam3" / "0001.txt"
    lines = path.read_text().splitlines()
    lines.insert(5, bad_row)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as excinfo:
        convert_kitti(root, seqs=["0001"])
    message = str(excinfo.value)
    assert f"{path}:6:" in message  # file and 1-based line
    assert f"field {field}" in message


# A car and a DontCare row of label_02 (the DontCare as in the kit's files: sizes -1000), from
# the ``type`` column on; each layout below wraps them in its own columns.
_CAR = "Car 0 0 -1.79 296.7 161.7 455.2 292.3 2.0 1.8 4.4 -4.5 2.0 11.0 -2.1"
_DONTCARE = (
    "DontCare -1 -1 -10.000000 356.400000 195.810000 374.100000 216.650000 -1000.000000 "
    "-1000.000000 -1000.000000 -10.000000 -1.000000 -1.000000 -1.000000"
)
_HWL = {"h": 8, "w": 9, "l": 10}  # their columns from ``type`` on


def _write_layout(layout: str, objects: list[str], tmp_path: Path) -> Path:
    """Write ``objects`` (rows from ``type`` on) as frame 0 of a sequence in ``layout``."""
    if layout == "label_02":
        lines = [f"0 {-1 if o.startswith('DontCare') else i} {o}" for i, o in enumerate(objects)]
        path = tmp_path / "label_02" / "0001.txt"
    elif layout == "tracking":  # KITTI tracking result format: label_02 without track id + score
        lines, path = [f"0 {o} 0.9" for o in objects], tmp_path / "dets" / "0001.txt"
    elif layout == "tracking_with_ids":  # as tracker results are written: 18 columns
        lines = [f"0 {i} {o} 0.9" for i, o in enumerate(objects)]
        path = tmp_path / "dets" / "0001.txt"
    else:  # per-frame KITTI object layout: <seq>/<frame:06d>.txt
        lines, path = [f"{o} 0.9" for o in objects], tmp_path / "0001" / "000000.txt"
    path.parent.mkdir(parents=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def _read_layout(layout: str, path: Path) -> KittiObjects:
    if layout == "label_02":
        return read_kitti_labels(path)
    if layout == "object":
        return read_kitti_object_detections(path.parent)[0]
    return read_kitti_tracking_detections(path)


_LAYOUTS = ("label_02", "tracking", "tracking_with_ids", "object")


@pytest.mark.parametrize("value", ["0", "-1.5"])
@pytest.mark.parametrize("field", list(_HWL))
@pytest.mark.parametrize("layout", _LAYOUTS)
def test_a_box_size_not_above_zero_names_file_line_and_field(
    tmp_path: Path, layout: str, field: str, value: str
) -> None:
    """h, w or l <= 0 in any of the readers sharing the label columns: one line naming the file,
    the line and the field (a DontCare row before it, sizes -1000, is not the one named)."""
    bad = _replace_column(_CAR, " ", _HWL[field], value)
    path = _write_layout(layout, [_DONTCARE, _CAR, bad], tmp_path)
    with pytest.raises(InputError) as excinfo:
        _read_layout(layout, path)
    assert str(excinfo.value) == (
        f"{path}:3: field '{field}': box dimension must be > 0, got {float(value)}"
    )


@pytest.mark.parametrize(("field", "value"), [("x", "1e300"), ("z", "-2e8"), ("l", "1e300")])
@pytest.mark.parametrize("layout", [*_LAYOUTS, "ab3dmot"])
def test_a_box_beyond_the_bound_names_file_line_frame_and_field(
    tmp_path: Path, layout: str, field: str, value: str
) -> None:
    """A location or size beyond the bound of every box reader (tracker.io.bounds; finite, but
    farther than anything on Earth), in the labels (ground truth) as in every detection layout:
    one line naming the file, the line, the field and the frame (was converted, and overflowed
    the motion metrics)."""
    column = {**_HWL, "x": 11, "y": 12, "z": 13}[field]
    path, message, line, frame = _refusal(
        layout, _replace_column(_CAR, " ", column, value), tmp_path
    )
    assert message == (
        f"{path}:{line}: field '{field}': {value} (frame {frame}) is beyond ±1e+08 m (farther or "
        "larger than anything on Earth)"
    )


def _refusal(layout: str, bad: str, tmp_path: Path) -> tuple[Path, str, int, int]:
    """The label row ``bad`` after a good one, written in ``layout`` and read: the file, the
    refusal's message, and the line and frame it should name."""
    if layout == "ab3dmot":  # (frame, type code, 2D box, score, h, w, l, x, y, z, ry, alpha)
        row = bad.split()
        path = tmp_path / "Car" / "0001.txt"
        path.parent.mkdir()
        path.write_text(f"{_GOOD_DET}\n4," + ",".join(["2", *row[4:8], "0.9", *row[8:15], "0"]))
        with pytest.raises(InputError) as excinfo:
            read_ab3dmot_detections([path])
        return path, str(excinfo.value), 2, 4
    path = _write_layout(layout, [_DONTCARE, _CAR, bad], tmp_path)
    with pytest.raises(InputError) as excinfo:
        _read_layout(layout, path)
    return path, str(excinfo.value), 3, 0


@pytest.mark.parametrize("value", ["2e4", "-1e300"])
@pytest.mark.parametrize("layout", [*_LAYOUTS, "ab3dmot"])
def test_a_rotation_y_beyond_the_heading_bound_names_file_line_frame_and_field(
    tmp_path: Path, layout: str, value: str
) -> None:
    """rotation_y may be unwrapped, but not beyond the bound the BaseVersion reader puts on a
    heading (tracker.io.bounds): at 1e300 a float's spacing is more than a turn, and the heading
    converted from it was an arbitrary angle, written without a word."""
    path, message, line, frame = _refusal(layout, _replace_column(_CAR, " ", 14, value), tmp_path)
    field = "rot_y" if layout == "ab3dmot" else "rotation_y"
    assert message == (
        f"{path}:{line}: field '{field}': {value} (frame {frame}) is beyond ±10000 rad (a "
        "heading is within a few turns of zero)"
    )


def test_a_converted_file_with_unwrapped_rotation_y_reads_back(
    kitti_root: Path, tmp_path: Path
) -> None:
    """Detections and labels whose rotation_y is unwrapped by a thousand turns (as tracker
    results carry it, here far beyond a few turns): the converted headings are wrapped into
    (-pi, pi], so `mctrack convert kitti` writes files its own reader accepts, with the
    headings of the wrapped input."""
    from tracker.io.baseversion import read_baseversion

    root = _kit_copy(kitti_root, tmp_path)
    argv = ["convert", "kitti", "--kitti-root", str(root), "--seqs", "0001", "--detector"]
    assert main([*argv, "pointrcnn", "--out", str(tmp_path / "wrapped")]) == 0
    turns = 2 * np.pi * 1000
    for path, sep, column in (
        *((root / "detections" / "pointrcnn" / "training" / c / "0001.txt", ",", 13)
          for c in ("Car", "Pedestrian", "Cyclist")),
        (root / "training" / "label_02" / "0001.txt", " ", 16),
    ):  # fmt: skip
        rows = [line.split(sep) for line in path.read_text().splitlines() if line.strip()]
        for row in rows:
            row[column] = f"{float(row[column]) + turns:.17g}"
        path.write_text("\n".join(sep.join(row) for row in rows) + "\n")
    assert main([*argv, "pointrcnn", "--out", str(tmp_path / "unwrapped")]) == 0
    for name in ("detections.json", "gt.json"):
        raw = json.loads((tmp_path / "unwrapped" / name).read_text())
        yaws = np.array([b["global_yaw"] for f in raw["0001"] for b in f["bboxes"]])
        assert len(yaws) > 100 and (np.abs(yaws) <= np.pi).all()
        expected = read_baseversion(tmp_path / "wrapped" / name)["0001"]
        got = read_baseversion(tmp_path / "unwrapped" / name)["0001"]
        for a, b in zip(expected, got, strict=True):
            assert np.abs(wrap_angle(a.boxes.yaw - b.boxes.yaw)).max(initial=0.0) < 1e-9


@pytest.mark.parametrize("layout", _LAYOUTS)
def test_a_dontcare_row_with_the_kits_sizes_still_reads(tmp_path: Path, layout: str) -> None:
    objects = _read_layout(layout, _write_layout(layout, [_DONTCARE, _CAR], tmp_path))
    assert objects.type_name.tolist() == ["DontCare", "Car"]
    assert objects.category.tolist() == [-1, category_index("car")]
    np.testing.assert_array_equal(objects.hwl, [[-1000.0] * 3, [2.0, 1.8, 4.4]])


# ---------------------------------------------------------------------------------------------
# CLI


def test_cli_convert_kitti(
    kitti_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from tracker.io.baseversion import read_baseversion

    out = tmp_path / "out"
    argv = ["convert", "kitti", "--kitti-root", str(kitti_root), "--seqs", "0012,14"]
    assert main([*argv, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "detections: 2 sequences, 184 frames" in printed and "converted in" in printed
    detections = read_baseversion(out / "detections.json")
    gt = read_baseversion(out / "gt.json")
    assert sorted(detections) == ["0012", "0014"] == sorted(gt)
    direct, direct_gt = convert_kitti(kitti_root, seqs=["0014"])
    for a, b in zip(direct["0014"], detections["0014"], strict=True):
        assert a.boxes.equals(b.boxes)
        np.testing.assert_allclose(a.cameras[0].camera_from_world, b.cameras[0].camera_from_world)
    # KITTI annotates no velocity: unknown in the ground truth (null, read back as NaN), not 0,
    # which is a measured standstill; the detections' stays 0 (no detector velocity)
    assert direct_gt is not None
    raw = json.loads((out / "gt.json").read_text())
    assert {repr(b["global_velocity"]) for f in raw["0014"] for b in f["bboxes"]} == {"None"}
    for a, b in zip(direct_gt["0014"], gt["0014"], strict=True):
        assert a.boxes.equals(b.boxes) and np.isnan(b.boxes.velocity).all()
    assert all((f.boxes.velocity == 0).all() for f in detections["0014"])

    assert main([*argv, "--poses", "none", "--no-gt", "--out", str(tmp_path / "no_poses")]) == 0
    assert not (tmp_path / "no_poses" / "gt.json").exists()
    frame = read_baseversion(tmp_path / "no_poses" / "detections.json")["0012"][0]
    np.testing.assert_allclose(frame.world_from_ego, WORLD_FROM_CAMERA_AXES)


def test_cli_missing_input_exit_code(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "training" / "calib").mkdir(parents=True)
    (tmp_path / "training" / "calib" / "0000.txt").write_text("P2: " + " ".join(["1"] * 11) + "\n")
    (tmp_path / "detections" / "pointrcnn" / "training").mkdir(parents=True)
    argv = ["convert", "kitti", "--kitti-root", str(tmp_path), "--poses", "none"]
    assert main([*argv, "--out", str(tmp_path / "o")]) == 2
    assert "P2" in capsys.readouterr().err
