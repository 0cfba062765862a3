"""nuScenes: converter, camera assignment, submission writer and the official evaluation, on a
synthetic dataset written in the devkit's own table schema (tests/test_nuscenes_fixture.py)."""

from __future__ import annotations

import json
import math
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.test_nuscenes_fixture import (
    CAMERA_DELAY_MICROS,
    CAMERAS,
    EGO_SPEED_MPS,
    SCENES,
    SyntheticNuScenes,
    make_detections,
    rot_z,
    write_synthetic_nuscenes,
)
from tracker.boxes import Boxes
from tracker.camera import project_points
from tracker.categories import CATEGORIES, category_index
from tracker.config import load_config
from tracker.errors import InputError
from tracker.events import TrackOutput, TrackStatus
from tracker.frame import Camera, Frame
from tracker.geometry import corners_3d
from tracker.io.baseversion import read_baseversion, write_baseversion
from tracker.io.convert.nuscenes import (
    CATEGORY_TO_TRACKING_NAME,
    NUSCENES_CAMERAS,
    assign_cameras,
    convert_nuscenes,
    load_nuscenes,
    table_problem,
    yaw_from_quaternions,
)
from tracker.io.nuscenes_writer import nuscenes_results, write_nuscenes_results
from tracker.pipeline import run_scene

VAL_SCENES = ("scene-0103", "scene-0916")
NOISY = {
    "position_sigma_m": 0.4,
    "velocity_sigma_mps": 0.6,
    "yaw_sigma_rad": 0.1,
    "dropout": 0.25,
    "false_positives_per_sample": 2.0,
}


def _devkit_missing() -> str | None:
    try:
        import motmetrics  # noqa: F401
        import nuscenes.eval.tracking.evaluate  # noqa: F401
    except ImportError as exc:
        return (
            f"nuScenes devkit not importable ({exc}); install: pip install -e '.[nuscenes]' && "
            "pip install --no-deps nuscenes-devkit==1.2.0"
        )
    return None


needs_devkit = pytest.mark.skipif(_devkit_missing() is not None, reason=str(_devkit_missing()))


# ---------------------------------------------------------------------------------------------
# devkit-free units


def _front_camera() -> Camera:
    """A 1600x900 camera at the world origin looking along world +x (camera axes: x right,
    y down, z forward)."""
    camera_from_world = np.array(
        [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    )
    k = np.array([[1266.0, 0.0, 800.0, 0.0], [0.0, 1266.0, 450.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    return Camera("CAM_FRONT", k, camera_from_world, 1600, 900)


def _back_camera() -> Camera:
    front = _front_camera()
    turn = np.eye(4)
    turn[:3, :3] = rot_z(math.pi)
    return Camera("CAM_BACK", front.image_from_camera, front.camera_from_world @ turn, 1600, 900)


def _naive_reference_visible(xyz: np.ndarray, lwh: np.ndarray, yaw: np.ndarray, cam: Camera):
    """The reference's test: divide every corner by its depth (no in-front check), clip to the
    canvas and call the box visible when the result has an area."""
    corners = corners_3d(xyz, lwh, yaw)[0]
    uv, _ = project_points(corners, cam)
    x1, y1 = np.clip(uv.min(axis=0), 0, [cam.width_px, cam.height_px])
    x2, y2 = np.clip(uv.max(axis=0), 0, [cam.width_px, cam.height_px])
    return x2 > x1 and y2 > y1


def test_box_behind_a_camera_is_never_assigned_to_it() -> None:
    front, back = _front_camera(), _back_camera()
    behind = (np.array([[-8.0, 0.3, 0.8]]), np.array([[4.5, 1.9, 1.6]]), np.array([0.2]))
    ahead = (np.array([[12.0, -1.0, 0.8]]), np.array([[4.5, 1.9, 1.6]]), np.array([0.0]))
    # the reference's sign-flip bug: the box behind "projects" into the front image
    assert _naive_reference_visible(*behind, front)
    camera, xyxy = assign_cameras(*behind, [front])
    assert camera.tolist() == [-1] and np.isnan(xyxy).all()
    camera, xyxy = assign_cameras(*behind, [front, back])
    assert camera.tolist() == [1] and np.isfinite(xyxy).all()
    camera, _ = assign_cameras(*ahead, [front, back])
    assert camera.tolist() == [0]


def test_box_straddling_the_camera_plane_keeps_its_visible_part() -> None:
    front = _front_camera()
    # a bus beside the camera: its front half is ahead and visible on the left of the image
    xyz, lwh, yaw = np.array([[1.0, 3.0, 1.5]]), np.array([[12.0, 2.9, 3.4]]), np.array([0.0])
    camera, xyxy = assign_cameras(xyz, lwh, yaw, [front])
    assert camera.tolist() == [0]
    assert xyxy[0, 0] == 0.0 and xyxy[0, 2] < 800  # to the left of the principal point


def test_yaw_from_quaternions_round_trip() -> None:
    yaws = np.array([-3.0, -1.2, 0.0, 0.7, 3.1])
    quats = np.stack([np.cos(yaws / 2), 0 * yaws, 0 * yaws, np.sin(yaws / 2)], axis=1)
    np.testing.assert_allclose(yaw_from_quaternions(quats), yaws, atol=1e-12)
    np.testing.assert_allclose(yaw_from_quaternions(-quats), yaws, atol=1e-12)  # q ≡ -q


def test_yaw_of_a_quaternion_that_is_not_unit() -> None:
    """A detector's quaternion of norm 2 or 0.5 has the heading of its unit quaternion (the
    devkit normalises it too); it gave 127° or 18° for 90°."""
    yaws = np.array([-2.0, 0.5, np.pi / 2])
    quats = np.stack([np.cos(yaws / 2), 0 * yaws, 0 * yaws, np.sin(yaws / 2)], axis=1)
    for scale in (2.0, 0.5, 1.01):
        np.testing.assert_allclose(yaw_from_quaternions(scale * quats), yaws, atol=1e-12)


def _output(scene: str, frame_id: int, n: int, rng: np.random.Generator) -> TrackOutput:
    boxes = Boxes.create(
        xyz=rng.normal(0, 30, (n, 3)),
        lwh=np.tile([4.5, 1.9, 1.6], (n, 1)),
        yaw=rng.uniform(-3, 3, n),
        velocity=rng.normal(0, 3, (n, 2)),
        score=rng.uniform(0, 1, n),
        category=np.full(n, category_index("car")),
        track_id=np.arange(n),
    )
    status = np.full(n, TrackStatus.CONFIRMED, dtype=np.int8)
    status[:3] = TrackStatus.COASTING
    det_row = np.arange(n)
    det_row[:3] = -1
    return TrackOutput(
        scene=scene,
        frame_id=frame_id,
        time_secs=0.0,
        boxes=boxes,
        acceleration=np.zeros((n, 2)),
        status=status,
        det_row=det_row,
        stage=np.ones(n, dtype=np.int8),
    )


def test_writer_fields_top_500_and_coasting_score() -> None:
    rng = np.random.default_rng(0)
    out = _output("scene-x", 0, 600, rng)
    frame = Frame("scene-x", 0, 0.0, Boxes.empty(), sample_token="tok0")
    per_sample = nuscenes_results({"scene-x": ([frame], [out])})
    boxes = per_sample["tok0"]
    assert len(boxes) == 500
    scores = [b["tracking_score"] for b in boxes]
    assert scores == sorted(scores, reverse=True)
    kept = np.sort(np.r_[np.zeros(3), out.boxes.score[3:]])[::-1][:500]
    np.testing.assert_allclose(scores, kept)
    b = boxes[0]
    assert b["size"] == [1.9, 4.5, 1.6]  # nuScenes w, l, h
    assert b["tracking_name"] == "car" and b["tracking_id"].startswith("scene-x_")
    i = int(b["tracking_id"].split("_")[1])
    yaw = out.boxes.yaw[i]
    np.testing.assert_allclose(b["rotation"], [math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)])
    np.testing.assert_allclose(b["velocity"], out.boxes.velocity[i])
    # coasting boxes get score 0 (the reference), or keep theirs with coasting_score=None
    small = nuscenes_results({"scene-x": ([frame], [_output("scene-x", 0, 5, rng)])})
    assert sorted(b["tracking_score"] for b in small["tok0"])[:3] == [0.0, 0.0, 0.0]
    keep = nuscenes_results(
        {"scene-x": ([frame], [_output("scene-x", 0, 5, rng)])}, coasting_score=None
    )
    assert min(b["tracking_score"] for b in keep["tok0"]) > 0.0


def test_writer_needs_sample_tokens() -> None:
    out = _output("s", 0, 2, np.random.default_rng(1))
    with pytest.raises(InputError, match="no nuScenes sample token"):
        nuscenes_results({"s": ([Frame("s", 0, 0.0, Boxes.empty())], [out])})


# ---------------------------------------------------------------------------------------------
# with the devkit: the synthetic dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> SyntheticNuScenes:
    if _devkit_missing():
        pytest.skip(str(_devkit_missing()))
    return write_synthetic_nuscenes(tmp_path_factory.mktemp("nuscenes"))


@pytest.fixture(scope="module")
def nusc(dataset: SyntheticNuScenes) -> Any:
    return load_nuscenes(dataset.dataroot, dataset.version)


def _write_detections(data: SyntheticNuScenes, name: str, seed: int, **noise: Any) -> Path:
    path = data.dataroot / f"{name}.json"
    path.write_text(json.dumps(make_detections(data, seed=seed, **noise)))
    return path


@pytest.fixture(scope="module")
def clean_path(dataset: SyntheticNuScenes) -> Path:
    return _write_detections(dataset, "clean", seed=1)


@needs_devkit
def test_category_mapping_matches_devkit() -> None:
    from nuscenes.eval.tracking.utils import category_to_tracking_name

    for name, tracking in CATEGORY_TO_TRACKING_NAME.items():
        assert category_to_tracking_name(name) == tracking
    assert category_to_tracking_name("movable_object.barrier") is None
    assert all(category_index(t) >= 0 for t in CATEGORY_TO_TRACKING_NAME.values())


@needs_devkit
def test_convert_frames_cameras_and_gt(
    dataset: SyntheticNuScenes, nusc: Any, clean_path: Path, tmp_path: Path
) -> None:
    conv = convert_nuscenes(
        dataset.dataroot,
        version=dataset.version,
        detections=clean_path,
        split="mini_val",
        with_gt=True,
        nusc=nusc,
    )
    assert list(conv.detections) == list(VAL_SCENES)
    assert conv.skipped_detections == {"barrier": 32}
    assert conv.meta["use_lidar"] is True
    for scene, frames in conv.detections.items():
        n_samples, heading, start = SCENES[scene]
        assert [f.sample_token for f in frames] == dataset.samples[scene]
        assert [f.frame_id for f in frames] == list(range(n_samples))
        np.testing.assert_allclose(np.diff([f.timestamp_secs for f in frames]), 0.5)
        for f in frames:
            assert tuple(c.name for c in f.cameras) == NUSCENES_CAMERAS
            assert len(f.boxes) == 10  # every tracking object, the barrier dropped
            gt = dataset.gt[f.sample_token]
            cars = f.boxes.category == category_index("car")
            np.testing.assert_allclose(f.boxes.lwh[cars][0], [4.5, 1.9, 1.6])
            expected_xyz = np.array([g["translation"] for g in gt if g["class"] != "barrier"])
            np.testing.assert_allclose(f.boxes.xyz, expected_xyz, atol=1e-9)
            # the ego pose (LIDAR_TOP) and each camera's own pose at its timestamp
            t0 = frames[0].timestamp_secs
            forward = np.array([math.cos(heading), math.sin(heading)])
            ego_xy = np.array(start) + EGO_SPEED_MPS * (f.timestamp_secs - t0) * forward
            np.testing.assert_allclose(f.world_from_ego[:2, 3], ego_xy, atol=1e-6)
            for cam, (name, _yaw, x, y, z, *_k) in zip(f.cameras, CAMERAS, strict=True):
                assert cam.name == name
                delay = CAMERA_DELAY_MICROS[name] / 1e6  # the ego moved on since LIDAR_TOP
                cam_ego_xy = ego_xy + EGO_SPEED_MPS * delay * forward
                origin = np.linalg.inv(cam.camera_from_world)[:3, 3]
                expected = np.r_[cam_ego_xy, 0.0] + rot_z(heading) @ np.array([x, y, z])
                np.testing.assert_allclose(origin, expected, atol=1e-6)
    # GT: ids per instance, devkit box_velocity = the known velocity
    assert conv.gt is not None
    first = conv.gt["scene-0103"][3]
    truth = [g for g in dataset.gt[first.sample_token] if g["class"] != "barrier"]
    np.testing.assert_allclose(first.boxes.velocity, [g["velocity"] for g in truth], atol=1e-6)
    ids = {int(t) for f in conv.gt["scene-0103"] for t in f.boxes.track_id}
    assert len(ids) == 10 and min(ids) >= 0
    assert conv.gt_velocity_unknown == 0
    # the BaseVersion round trip keeps boxes, cameras and camera assignment
    path = tmp_path / "dets.json"
    write_baseversion(path, conv.detections)
    back = read_baseversion(path)
    f0, b0 = conv.detections["scene-0916"][5], back["scene-0916"][5]
    np.testing.assert_allclose(b0.boxes.xyz, f0.boxes.xyz)
    names0 = [f0.cameras[c].name if c >= 0 else None for c in f0.boxes.camera]
    names1 = [b0.cameras[c].name if c >= 0 else None for c in b0.boxes.camera]
    assert names0 == names1 and any(n is not None for n in names0)
    for cam in f0.cameras:
        twin = b0.cameras[b0.camera_index(cam.name)]
        np.testing.assert_allclose(twin.camera_from_world, cam.camera_from_world, atol=1e-9)


@needs_devkit
def test_projection_matches_devkit_and_no_box_behind_its_camera(
    dataset: SyntheticNuScenes, nusc: Any, clean_path: Path
) -> None:
    from nuscenes.utils.geometry_utils import view_points

    conv = convert_nuscenes(
        dataset.dataroot,
        version=dataset.version,
        detections=clean_path,
        split="mini_val",
        nusc=nusc,
    )
    checked = 0
    for frames in conv.detections.values():
        for f in frames:
            sample = nusc.get("sample", f.sample_token)
            for c, cam in enumerate(f.cameras):
                # the devkit's own chain: global -> ego (camera time) -> camera, then view_points
                _, boxes, intrinsic = nusc.get_sample_data(sample["data"][cam.name])
                for box in boxes:
                    if box.center[2] < 1.0:
                        continue
                    devkit_uv = view_points(box.center[:, None], intrinsic, normalize=True)[:2, 0]
                    ann = nusc.get("sample_annotation", box.token)
                    uv, depth = project_points(np.array([ann["translation"]]), cam)
                    np.testing.assert_allclose(uv[0], devkit_uv, atol=1e-6)
                    np.testing.assert_allclose(depth[0], box.center[2], atol=1e-6)
                    checked += 1
                mine = f.boxes.camera == c
                if mine.any():
                    corners = corners_3d(f.boxes.xyz[mine], f.boxes.lwh[mine], f.boxes.yaw[mine])
                    _, depth = project_points(corners.reshape(-1, 3), cam)
                    assert (depth.reshape(-1, 8).max(axis=1) > 0.1).all()
    assert checked > 100


@needs_devkit
def test_bad_inputs_name_the_table_or_token(
    dataset: SyntheticNuScenes, nusc: Any, clean_path: Path, tmp_path: Path
) -> None:
    # a missing table
    broken = tmp_path / "broken"
    shutil.copytree(dataset.dataroot / dataset.version, broken / dataset.version)
    (broken / dataset.version / "sample_data.json").unlink()
    (broken / dataset.version / "ego_pose.json").unlink()
    with pytest.raises(InputError, match=r"missing nuScenes tables: ego_pose\.json, sample_data"):
        load_nuscenes(broken, dataset.version)
    with pytest.raises(InputError, match=r"no table folder for version 'v1\.0-trainval'"):
        load_nuscenes(dataset.dataroot, "v1.0-trainval")
    # the split belongs to other tables
    with pytest.raises(InputError, match=r"split 'val' belongs to the v1\.0-trainval tables"):
        convert_nuscenes(
            dataset.dataroot, version=dataset.version, detections=clean_path, split="val", nusc=nusc
        )
    results = json.loads(clean_path.read_text())
    # an unknown sample token
    bad = dict(results, results={**results["results"], "feedbeef" * 4: []})
    path = tmp_path / "unknown.json"
    path.write_text(json.dumps(bad))
    with pytest.raises(InputError, match="sample token 'feedbeeffeedbeeffeedbeeffeedbeef'"):
        convert_nuscenes(
            dataset.dataroot, version=dataset.version, detections=path, split="mini_val", nusc=nusc
        )
    # detections for a sample of another split (scene-0061 is mini_train)
    outside = dataset.samples["scene-0061"][2]
    bad = dict(results, results={**results["results"], outside: []})
    path.write_text(json.dumps(bad))
    with pytest.raises(InputError, match=f"'{outside}' belongs to scene 'scene-0061'.*mini_val"):
        convert_nuscenes(
            dataset.dataroot, version=dataset.version, detections=path, split="mini_val", nusc=nusc
        )
    # a malformed box names its sample and index
    token = dataset.samples["scene-0103"][1]
    boxes = [dict(b) for b in results["results"][token]]
    boxes[2]["size"] = [1.0, "x", 2.0]
    bad = dict(results, results={**results["results"], token: boxes})
    path.write_text(json.dumps(bad))
    with pytest.raises(InputError, match=rf"results\['{token}'\]\[2\]: field 'size'"):
        convert_nuscenes(
            dataset.dataroot, version=dataset.version, detections=path, split="mini_val", nusc=nusc
        )
    # a box without a length, width or height (BaseVersion's rule: a flat box is allowed)
    for size, said in (([1.8, 0.0, 1.5], "[1.8, 0.0, 1.5]: width and length must be > 0"),
                       ([1.8, 4.0, -1.0], "[1.8, 4.0, -1.0]: width and length must be > 0, "
                                          "height >= 0")):  # fmt: skip
        boxes = [dict(b) for b in results["results"][token]]
        boxes[3]["size"] = size
        path.write_text(json.dumps(dict(results, results={**results["results"], token: boxes})))
        with pytest.raises(InputError, match=re.escape(f"[3]: field 'size' = {said}")):
            convert_nuscenes(
                dataset.dataroot,
                version=dataset.version,
                detections=path,
                split="mini_val",
                nusc=nusc,
            )
    # a zero quaternion has no heading
    boxes = [dict(b) for b in results["results"][token]]
    boxes[1]["rotation"] = [0.0, 0.0, 0.0, 0.0]
    path.write_text(json.dumps(dict(results, results={**results["results"], token: boxes})))
    with pytest.raises(InputError, match=r"\[1\]: field 'rotation' is the zero quaternion"):
        convert_nuscenes(
            dataset.dataroot, version=dataset.version, detections=path, split="mini_val", nusc=nusc
        )


def _track_and_evaluate(
    data: SyntheticNuScenes, nusc: Any, detections: Path, out: Path
) -> dict[str, Any]:
    from tracker.eval.nuscenes import evaluate_nuscenes, load_results_with_devkit

    conv = convert_nuscenes(
        data.dataroot, version=data.version, detections=detections, split="mini_val", nusc=nusc
    )
    config = load_config("nuscenes")
    results = {s: (f, run_scene(f, config).outputs) for s, f in conv.detections.items()}
    path = out / "results.json"
    written = write_nuscenes_results(path, results, meta=conv.meta)
    # the devkit's own loader accepts the file, with every sample of the split
    loaded, meta = load_results_with_devkit(path)
    assert set(loaded.sample_tokens) == set(data.split_samples(VAL_SCENES))
    assert sum(len(loaded[t]) for t in loaded.sample_tokens) == written
    assert meta["use_lidar"] is True
    return evaluate_nuscenes(
        path, dataroot=data.dataroot, version=data.version, split="mini_val", out_dir=out
    )


@needs_devkit
def test_official_evaluation_clean_vs_noisy(
    dataset: SyntheticNuScenes, nusc: Any, clean_path: Path, tmp_path: Path
) -> None:
    clean = _track_and_evaluate(dataset, nusc, clean_path, tmp_path / "clean")
    noisy_path = _write_detections(dataset, "noisy", seed=7, **NOISY)
    noisy = _track_and_evaluate(dataset, nusc, noisy_path, tmp_path / "noisy")
    print("AMOTA clean", clean["overall"]["amota"], "noisy", noisy["overall"]["amota"])
    assert clean["overall"]["amota"] >= 0.98
    assert clean["overall"]["recall"] == pytest.approx(1.0)
    assert clean["overall"]["ids"] == 0
    assert set(clean["per_class"]) == {
        c for c in CATEGORIES if c in CATEGORY_TO_TRACKING_NAME.values()
    }
    assert 0.5 <= noisy["overall"]["amota"] <= clean["overall"]["amota"] - 0.02
    assert noisy["overall"]["recall"] < 1.0
    assert (tmp_path / "clean" / "metrics_summary.json").is_file()


def _edited_dataset(
    dataset: SyntheticNuScenes, root: Path, edit: Callable[[dict[str, list[Any]]], None]
) -> Path:
    """A copy of the synthetic dataset (tables and maps) with ``edit`` applied to its tables."""
    shutil.copytree(dataset.dataroot / "maps", root / "maps")
    tables = {
        p.stem: json.loads(p.read_text())
        for p in (dataset.dataroot / dataset.version).glob("*.json")
    }
    edit(tables)
    (root / dataset.version).mkdir()
    for name, rows in tables.items():
        (root / dataset.version / f"{name}.json").write_text(json.dumps(rows))
    return root


def _conversion_error(
    dataset: SyntheticNuScenes,
    root: Path,
    edit: Callable[[dict[str, list[Any]]], None],
    detections: Path,
    match: str | None = None,
) -> tuple[Path, str]:
    """The edited dataset (:func:`_edited_dataset`) and the InputError converting it raises."""
    root = _edited_dataset(dataset, root, edit)
    with pytest.raises(InputError, match=match) as err:
        convert_nuscenes(root, version=dataset.version, detections=detections, split="mini_val")
    return root, str(err.value)


def _set_sample(tables: dict[str, list[Any]], token: str, **fields: Any) -> None:
    next(s for s in tables["sample"] if s["token"] == token).update(fields)


@needs_devkit
def test_a_sample_chain_that_loops_or_leaves_its_scene_is_named(
    dataset: SyntheticNuScenes, clean_path: Path, tmp_path: Path
) -> None:
    """Following 'next' from a scene's first sample: a loop (was an endless loop) or a step into
    another scene (its samples were tracked as this scene's) is an error naming the sample."""
    val, other = dataset.samples["scene-0103"], dataset.samples["scene-0061"]
    cases = {  # the loop last: without the check it never ends
        "leaves": (
            lambda t: _set_sample(t, val[-1], next=other[0]),
            "of another scene",
            other[0],
        ),
        "loop": (lambda t: _set_sample(t, val[5], next=val[2]), "reached again", val[2]),
    }
    for name, (edit, match, named) in cases.items():
        _, error = _conversion_error(dataset, tmp_path / name, edit, clean_path, match)
        assert f"sample.json: sample '{named}'" in error


@needs_devkit
def test_sample_timestamps_out_of_order_are_named_at_conversion(
    dataset: SyntheticNuScenes, clean_path: Path, tmp_path: Path
) -> None:
    """A scene's sample timestamp repeated or going back: one error naming the sample (was
    converted; then the tracker refused the scene, or `mctrack track` the converted file)."""
    val = dataset.samples["scene-0103"]
    table = json.loads((dataset.dataroot / dataset.version / "sample.json").read_text())
    t4 = next(s["timestamp"] for s in table if s["token"] == val[4])
    for name, timestamp in (("repeated", t4), ("backwards", t4 - 1)):
        root = _edited_dataset(
            dataset, tmp_path / name, lambda t, ts=timestamp: _set_sample(t, val[5], timestamp=ts)
        )
        with pytest.raises(InputError, match=rf"'{val[5]}': field 'timestamp' = {timestamp} "):
            convert_nuscenes(root, version=dataset.version, detections=clean_path, split="mini_val")


@needs_devkit
def test_a_pose_without_a_rotation_or_beyond_the_bound_is_named(
    dataset: SyntheticNuScenes, clean_path: Path, tmp_path: Path
) -> None:
    """A zero or short quaternion, or a translation beyond the bound of tracker.io.bounds, in
    ego_pose / calibrated_sensor: one error naming the table, the record and the field (a zero
    quaternion made NaN matrices: 'unexpected error' at writing; a translation of 1e300 was
    converted: the cameras and the ego there, every box in no camera)."""
    records: dict[str, dict[str, Any]] = {}

    def edit_record(table: str, index: int, key: str, value: list[float]) -> Any:
        def edit(tables: dict[str, list[Any]]) -> None:
            records[table] = dict(tables[table][index])
            tables[table][index][key] = value

        return edit

    for table, index, key, value, said in (
        ("ego_pose", 0, "rotation", [0.0] * 4, "'rotation' is the zero quaternion"),
        ("calibrated_sensor", -1, "rotation", [1.0, 0.0, 0.0], "'rotation' must be 4 finite"),
        ("ego_pose", 0, "translation", [1e300, 0.0, 0.0],
         f"'translation' = [1e+300, 0.0, 0.0]: {_FAR}"),
        ("calibrated_sensor", -1, "translation", [0.5, -2e8, 1.8],
         f"'translation' = [0.5, -200000000.0, 1.8]: {_FAR}"),
    ):  # fmt: skip
        edit = edit_record(table, index, key, value)
        _, error = _conversion_error(dataset, tmp_path / f"{table}_{key}", edit, clean_path)
        assert f"{table}.json: {table} '{records[table]['token']}': field {said}" in error


@needs_devkit
def test_a_ground_truth_size_is_checked_as_a_detection_size(
    dataset: SyntheticNuScenes, nusc: Any, clean_path: Path, tmp_path: Path
) -> None:
    """A tracked sample_annotation whose size is zero, negative, NaN or short: one error naming
    the table, the annotation and the field, as for a detection (was converted: a zero-width
    GT box went into --gt-out)."""
    ann = next(
        a
        for a in nusc.sample_annotation
        if a["sample_token"] in set(dataset.split_samples(VAL_SCENES))
        and a["num_lidar_pts"] > 0
        and a["category_name"] in CATEGORY_TO_TRACKING_NAME
    )
    for name, size, said in (
        ("zero", [0.0, 4.5, 1.6], "= [0.0, 4.5, 1.6]: width and length must be > 0, height >= 0"),
        ("negative", [1.9, 4.5, -1.0], "= [1.9, 4.5, -1.0]: width and length must be > 0, "
                                       "height >= 0"),
        ("nan", [1.9, math.nan, 1.6], "must be 3 finite numbers"),
        ("short", [1.9, 4.5], "must be 3 finite numbers"),
    ):  # fmt: skip

        def edit(tables: dict[str, list[Any]], size: list[float] = size) -> None:
            record = next(a for a in tables["sample_annotation"] if a["token"] == ann["token"])
            record["size"] = size

        root = _edited_dataset(dataset, tmp_path / name, edit)
        with pytest.raises(InputError) as err:
            convert_nuscenes(
                root, version=dataset.version, detections=clean_path, split="mini_val", with_gt=True
            )
        table = root / dataset.version / "sample_annotation.json"
        assert str(err.value) == (
            f"{table}: sample_annotation '{ann['token']}' of sample '{ann['sample_token']}': "
            f"field 'size' {said}"
        )


def _tracked_annotation(dataset: SyntheticNuScenes, nusc: Any) -> dict[str, Any]:
    """A val annotation of a tracking class with points and a previous and next annotation."""
    return next(
        a
        for a in nusc.sample_annotation
        if a["sample_token"] in set(dataset.split_samples(VAL_SCENES))
        and a["num_lidar_pts"] > 0
        and a["category_name"] in CATEGORY_TO_TRACKING_NAME
        and a["prev"]
        and a["next"]
    )


def _set_annotation(tables: dict[str, list[Any]], token: str, **fields: Any) -> None:
    next(a for a in tables["sample_annotation"] if a["token"] == token).update(fields)


_EMPTY = {"num_lidar_pts": 0, "num_radar_pts": 0}
_MUST = "must be {} finite numbers"
_FAR = "beyond ±1e+08 m (farther or larger than anything on Earth)"
_FAST = "beyond ±10000 m/s (faster than anything on or near Earth)"


@needs_devkit
@pytest.mark.parametrize(
    ("fields", "said"),
    [
        ({"translation": [1.0, math.nan, 0.8]}, f"'translation' {_MUST.format(3)}"),
        ({"translation": [math.inf, 2.0, 0.8]}, f"'translation' {_MUST.format(3)}"),
        ({"translation": [1.0, 2.0]}, f"'translation' {_MUST.format(3)}"),
        ({"translation": [1.0, "2", 0.8]}, f"'translation' {_MUST.format(3)}"),
        ({"translation": [1.0, 2.0], **_EMPTY}, f"'translation' {_MUST.format(3)}"),
        ({"rotation": [1.0, 0.0, 0.0, math.nan]}, f"'rotation' {_MUST.format(4)}"),
        ({"rotation": [1.0, 0.0, 0.0]}, f"'rotation' {_MUST.format(4)}"),
        ({"rotation": [0.0] * 4}, "'rotation' is the zero quaternion (no heading)"),
        ({"rotation": [1e-170] * 4}, "'rotation' is the zero quaternion (no heading)"),
        # finite, as a detection's: beyond the bound of every box reader (tracker.io.bounds)
        ({"translation": [1e300, 2.0, 0.8]}, f"'translation' = [1e+300, 2.0, 0.8]: {_FAR}"),
        ({"translation": [1.0, -1e9, 0.8], **_EMPTY}, f"'translation' = [1.0, -1000000000.0, "
                                                      f"0.8]: {_FAR}"),
        ({"size": [1.9, 1e300, 1.6]}, f"'size' = [1.9, 1e+300, 1.6]: {_FAR}"),
    ],
    ids=["t_nan", "t_inf", "t_short", "t_text", "t_short_no_points", "r_nan", "r_short",
         "r_zero", "r_tiny", "t_far", "t_far_no_points", "s_far"],
)  # fmt: skip
def test_a_ground_truth_translation_or_rotation_is_checked_as_a_detection_one(
    dataset: SyntheticNuScenes,
    nusc: Any,
    clean_path: Path,
    tmp_path: Path,
    fields: dict[str, Any],
    said: str,
) -> None:
    """A tracked sample_annotation whose translation is not 3 finite numbers, or whose rotation
    is not 4 or is the zero quaternion: one error naming the table, the annotation and the
    field (a NaN translation or a zero quaternion failed the GT writing after the detections
    were written, a short translation or rotation was an 'unexpected error'). One without points
    too: its translation is read for its neighbours' velocity (a short one was a crash). A
    translation or size beyond the bound a detection's has (1e300: finite) is refused as a
    detection's (was converted, and overflowed the motion metrics)."""
    ann = _tracked_annotation(dataset, nusc)
    root = _edited_dataset(dataset, tmp_path, lambda t: _set_annotation(t, ann["token"], **fields))
    table = root / dataset.version / "sample_annotation.json"
    # with_gt converts the annotations; check_gt checks them for the official evaluation
    for flags in ({"with_gt": True}, {"check_gt": True}):
        with pytest.raises(InputError) as err:
            convert_nuscenes(
                root, version=dataset.version, detections=clean_path, split="mini_val", **flags
            )
        assert str(err.value) == (
            f"{table}: sample_annotation '{ann['token']}' of sample '{ann['sample_token']}': "
            f"field {said}"
        )


@needs_devkit
def test_a_ground_truth_velocity_beyond_the_bound_is_named(
    dataset: SyntheticNuScenes, nusc: Any, clean_path: Path, tmp_path: Path
) -> None:
    """An annotation moved 9e7 m away (within the box bound) gives its previous one a devkit
    velocity of ~1e8 m/s, beyond the velocity bound of tracker.io.bounds: one error naming the
    table, the annotation whose velocity it is, its sample and what that velocity comes from
    (was written into --gt-out, and overflowed the motion metrics)."""
    ann = _tracked_annotation(dataset, nusc)
    prev = nusc.get("sample_annotation", ann["prev"])
    far = [9e7, *ann["translation"][1:]]
    root = _edited_dataset(
        dataset, tmp_path, lambda t: _set_annotation(t, ann["token"], translation=far)
    )
    table = root / dataset.version / "sample_annotation.json"
    with pytest.raises(InputError) as err:
        convert_nuscenes(
            root, version=dataset.version, detections=clean_path, split="mini_val", with_gt=True
        )
    message = str(err.value)
    assert message.startswith(
        f"{table}: sample_annotation '{prev['token']}' of sample '{prev['sample_token']}': its "
        "velocity (the devkit's box_velocity, from the translations and times of the instance's "
        "neighbouring annotations) = ["
    )
    assert message.endswith(f"]: {_FAST}")


@needs_devkit
def test_a_ground_truth_quaternion_is_normalised_as_the_devkit_does(
    dataset: SyntheticNuScenes, nusc: Any, clean_path: Path, tmp_path: Path
) -> None:
    """A non-unit GT quaternion is a rotation: its heading is its unit quaternion's."""
    ann = _tracked_annotation(dataset, nusc)
    scaled = [3.0 * q for q in ann["rotation"]]
    root = _edited_dataset(
        dataset, tmp_path / "scaled", lambda t: _set_annotation(t, ann["token"], rotation=scaled)
    )

    def gt_yaw(root: Path) -> dict[str, list[np.ndarray]]:
        conv = convert_nuscenes(
            root, version=dataset.version, detections=clean_path, split="mini_val", with_gt=True
        )
        assert conv.gt is not None
        return {s: [f.boxes.yaw for f in frames] for s, frames in conv.gt.items()}

    clean, edited = gt_yaw(dataset.dataroot), gt_yaw(root)
    assert clean.keys() == edited.keys()
    for scene in clean:
        for a, b in zip(clean[scene], edited[scene], strict=True):
            np.testing.assert_allclose(b, a, atol=1e-12)
    # not moot: the heading formula on the scaled quaternion itself is another heading
    w, x, y, z = scaled
    unnormalised = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    assert abs(unnormalised - float(yaw_from_quaternions(np.array([ann["rotation"]]))[0])) > 0.1


@needs_devkit
def test_a_sample_without_lidar_top_names_the_sample_data_table(
    dataset: SyntheticNuScenes, clean_path: Path, tmp_path: Path
) -> None:
    """The ego pose comes from the sample's key-frame LIDAR_TOP record in sample_data.json: the
    error names that table (it named the sample only)."""
    sample = dataset.samples["scene-0103"][3]

    def drop_lidar(tables: dict[str, list[Any]]) -> None:
        for record in tables["sample_data"]:
            if record["sample_token"] == sample and "/LIDAR_TOP/" in record["filename"]:
                record["is_key_frame"] = False

    root, error = _conversion_error(dataset, tmp_path / "no_lidar", drop_lidar, clean_path)
    table = root / dataset.version / "sample_data.json"
    assert error.startswith(f"{table}: no key-frame LIDAR_TOP record of sample '{sample}'")


@needs_devkit
def test_detection_meta_flags_are_booleans(
    dataset: SyntheticNuScenes,
    nusc: Any,
    clean_path: Path,
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The modality flags go into the submission: a string "false" was copied as true, a meta
    that is not an object became the defaults silently; a missing meta says which defaults."""
    results = json.loads(clean_path.read_text())
    path = tmp_path / "meta.json"

    def convert(meta: Any) -> Any:
        data = {"results": results["results"]} if meta is None else {**results, "meta": meta}
        path.write_text(json.dumps(data))
        return convert_nuscenes(
            dataset.dataroot, version=dataset.version, detections=path, split="mini_val", nusc=nusc
        )

    for meta, said in (
        ({**results["meta"], "use_camera": "false"}, "field 'meta.use_camera' must be true or "
         "false, got 'false'"),
        ({**results["meta"], "use_lidar": 1}, "field 'meta.use_lidar' must be true or false"),
        ([True], "field 'meta' must be an object of flags"),
    ):  # fmt: skip
        with pytest.raises(InputError) as err:
            convert(meta)
        assert str(err.value).startswith(f"{path}: {said}")
    with caplog.at_level("INFO"):
        conv = convert(None)
    assert f"{path}: no 'meta': the submission gets the defaults" in caplog.text
    written = tmp_path / "results.json"
    write_nuscenes_results(written, {}, meta=conv.meta)
    assert json.loads(written.read_text())["meta"] == {
        "use_camera": False, "use_lidar": True, "use_radar": False, "use_map": False,
        "use_external": False,
    }  # fmt: skip
    caplog.clear()
    with caplog.at_level("INFO"):
        assert convert({"use_camera": True}).meta == {"use_camera": True}
    assert "'meta' has no use_lidar, use_radar, use_map, use_external" in caplog.text


@needs_devkit
def test_detection_fields_are_read_strictly(
    dataset: SyntheticNuScenes,
    nusc: Any,
    clean_path: Path,
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A boolean score (was 1.0), a detection_name that is not a string (was counted as a
    skipped class), a velocity of three values (the first two were used; the format and the
    devkit say two) or an infinite one (was 0, unsaid): one error naming the box and field. A
    NaN, null or absent velocity (the devkit's "no estimate") is kept unknown (NaN, was 0:
    measured as standing still), counted and logged (null was not), and a half-NaN one wholly
    (its other half was kept)."""
    results = json.loads(clean_path.read_text())
    token = dataset.samples["scene-0916"][2]
    path = tmp_path / "fields.json"

    def convert(**fields: Any) -> Any:
        boxes = [dict(b) for b in results["results"][token]]
        boxes[1].update(fields)
        path.write_text(json.dumps(dict(results, results={**results["results"], token: boxes})))
        return convert_nuscenes(
            dataset.dataroot, version=dataset.version, detections=path, split="mini_val", nusc=nusc
        )

    def convert_absent() -> Any:
        boxes = [dict(b) for b in results["results"][token]]
        del boxes[1]["velocity"]
        path.write_text(json.dumps(dict(results, results={**results["results"], token: boxes})))
        return convert_nuscenes(
            dataset.dataroot, version=dataset.version, detections=path, split="mini_val", nusc=nusc
        )

    at = f"{path}: results['{token}'][1]: field"
    for fields, said in (
        ({"detection_score": True}, "'detection_score' must be a number, got True"),
        ({"detection_name": 7}, "'detection_name' must be a string, got 7"),
        ({"detection_name": None}, "'detection_name' must be a string, got None"),
        ({"velocity": [1.0, 2.0, 0.5]}, "'velocity' must be [vx, vy], got [1.0, 2.0, 0.5]"),
        ({"velocity": [math.inf, 0.0]}, "'velocity' = [inf, 0.0] is infinite"),
        ({"translation": [1e300, 0.0, 1.0]}, f"'translation' = [1e+300, 0.0, 1.0]: {_FAR}"),
        ({"size": [1e9, 4.5, 1.6]}, f"'size' = [1000000000.0, 4.5, 1.6]: {_FAR}"),
        # finite, but faster than anything on Earth (tracker.io.bounds): it overflowed downstream
        ({"velocity": [1e300, 0.0]}, f"'velocity' = [1e+300, 0.0]: {_FAST}"),
        ({"velocity": [2.0, -2e4]}, f"'velocity' = [2.0, -20000.0]: {_FAST}"),
    ):
        with pytest.raises(InputError) as err:
            convert(**fields)
        assert str(err.value) == f"{at} {said}", fields
    for velocity in ([math.nan, 1.5], None, "absent"):  # (None: "velocity": null)
        caplog.clear()
        with caplog.at_level("WARNING"):
            conv = convert(velocity=velocity) if velocity != "absent" else convert_absent()
        assert conv.velocity_unknown == 1, velocity
        assert f"{path}: 1 detections without a velocity estimate" in caplog.text
        frame = next(f for f in conv.detections["scene-0916"] if f.sample_token == token)
        unknown = ~np.isfinite(frame.boxes.velocity).all(axis=1)
        assert np.isnan(frame.boxes.velocity[unknown]).all(), "not 0, not half kept"
        assert unknown.sum() == 1 and not np.any(frame.boxes.velocity == 1.5), velocity
        write_baseversion(tmp_path / "bv.json", conv.detections)  # `mctrack convert nuscenes`
        back = read_baseversion(tmp_path / "bv.json")["scene-0916"][frame.frame_id]
        np.testing.assert_array_equal(back.boxes.velocity, frame.boxes.velocity)  # null: NaN
    assert convert_nuscenes(
        dataset.dataroot, version=dataset.version, detections=clean_path, split="mini_val",
        nusc=nusc,
    ).velocity_unknown == 0  # fmt: skip


@needs_devkit
def test_coordinates_that_overflow_the_transforms_are_named(
    dataset: SyntheticNuScenes, nusc: Any, clean_path: Path, tmp_path: Path
) -> None:
    """A detection beyond the bound of every box reader (1e308: tracker.io.bounds), or an ego
    pose so far away (1.7e308) that the camera or pose transforms overflow: one error naming
    the file and the record (was converted with numpy overflow warnings: the box in no camera,
    NaN matrices in the transforms)."""
    import warnings

    results = json.loads(clean_path.read_text())
    token = dataset.samples["scene-0103"][4]
    boxes = [dict(b) for b in results["results"][token]]
    boxes[2]["translation"] = [1e308, 1e308, 0.0]
    path = tmp_path / "far.json"
    path.write_text(json.dumps(dict(results, results={**results["results"], token: boxes})))
    pose: dict[str, Any] = {}

    def far_pose(tables: dict[str, list[Any]]) -> None:
        lidar = next(
            d
            for d in tables["sample_data"]
            if d["sample_token"] == token and "/LIDAR_TOP/" in d["filename"]
        )
        record = next(p for p in tables["ego_pose"] if p["token"] == lidar["ego_pose_token"])
        record["translation"] = [1.7e308, 1.7e308, 0.0]
        pose.update(record)

    root = _edited_dataset(dataset, tmp_path / "far_pose", far_pose)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # said once, as an error: no numpy warnings first
        with pytest.raises(InputError) as err:
            convert_nuscenes(
                dataset.dataroot, version=dataset.version, detections=path, split="mini_val",
                nusc=nusc,
            )  # fmt: skip
        assert str(err.value) == (
            f"{path}: results['{token}'][2]: field 'translation' = [1e+308, 1e+308, 0.0]: "
            "beyond ±1e+08 m (farther or larger than anything on Earth)"
        )
        with pytest.raises(InputError) as err:
            convert_nuscenes(root, version=dataset.version, detections=clean_path, split="mini_val")
        table = root / dataset.version / "ego_pose.json"
        assert str(err.value) == (
            f"{table}: ego_pose '{pose['token']}': field 'translation' = [1.7e+308, 1.7e+308, "
            f"0.0]: {_FAR}"
        )


def _table_case(
    table: str, key: str, value: Any, pick: Callable[[dict[str, list[Any]]], dict[str, Any]]
) -> Callable[[dict[str, list[Any]]], str]:
    """An edit setting ``key`` of the record ``pick`` chooses; it returns the record's token."""

    def edit(tables: dict[str, list[Any]]) -> str:
        record = pick(tables)
        record[key] = value
        return str(record["token"])

    return edit


def _val_sample(tables: dict[str, list[Any]]) -> dict[str, Any]:
    return tables["sample"][1]  # (the fixture's tables start with scene-0103, a val scene)


def _front_camera_data(tables: dict[str, list[Any]]) -> dict[str, Any]:
    first = tables["sample"][0]["token"]
    return next(
        r
        for r in tables["sample_data"]
        if r["sample_token"] == first and "/CAM_FRONT/" in r["filename"]
    )


def _front_camera_sensor(tables: dict[str, list[Any]]) -> dict[str, Any]:
    token = _front_camera_data(tables)["calibrated_sensor_token"]
    return next(r for r in tables["calibrated_sensor"] if r["token"] == token)


def _car_annotation(tables: dict[str, list[Any]]) -> dict[str, Any]:
    return tables["sample_annotation"][0]  # (the fixture's first object is a car)


_NOT_TOKEN = "is not the token of a"
_TABLE_FIELDS = {
    "timestamp_text": (
        "sample", _table_case("sample", "timestamp", "1533151603500000", _val_sample),
        "field 'timestamp' must be an integer >= 0, got '1533151603500000'",
    ),
    "timestamp_float": (
        "sample", _table_case("sample", "timestamp", 1.5e15, _val_sample),
        "field 'timestamp' must be an integer >= 0",
    ),
    "next_int": (
        "sample", _table_case("sample", "next", 7, _val_sample),
        f"field 'next' = 7 {_NOT_TOKEN} sample record",
    ),
    "first_sample_unknown": (
        "scene", _table_case("scene", "first_sample_token", "nope", lambda t: t["scene"][0]),
        f"field 'first_sample_token' = 'nope' {_NOT_TOKEN} sample record",
    ),
    "scene_name_list": (
        "scene", _table_case("scene", "name", ["scene-0103"], lambda t: t["scene"][0]),
        "field 'name' must be a string",
    ),
    "ego_pose_token": (
        "sample_data", _table_case("sample_data", "ego_pose_token", None, _front_camera_data),
        f"field 'ego_pose_token' = None {_NOT_TOKEN} ego_pose record",
    ),
    "width_text": (
        "sample_data", _table_case("sample_data", "width", "1600", _front_camera_data),
        "field 'width' must be an integer >= 0, got '1600'",
    ),
    "filename_number": (
        "sample_data", _table_case("sample_data", "filename", 3, _front_camera_data),
        "field 'filename' must be a path (a string), got 3",
    ),
    "intrinsic_text": (
        "calibrated_sensor",
        _table_case("calibrated_sensor", "camera_intrinsic", [["1"] * 3] * 3, _front_camera_sensor),
        "(CAM_FRONT): field 'camera_intrinsic' must be 3x3 finite numbers",
    ),
    "intrinsic_nan": (
        "calibrated_sensor",
        _table_case(
            "calibrated_sensor", "camera_intrinsic", [[math.nan] * 3] * 3, _front_camera_sensor
        ),
        "(CAM_FRONT): field 'camera_intrinsic' must be 3x3 finite numbers",
    ),
    "lidar_points_text": (
        "sample_annotation",
        _table_case("sample_annotation", "num_lidar_pts", "40", _car_annotation),
        "field 'num_lidar_pts' must be an integer >= 0, got '40'",
    ),
    "radar_points_negative": (
        "sample_annotation",
        _table_case("sample_annotation", "num_radar_pts", -1, _car_annotation),
        "field 'num_radar_pts' must be an integer >= 0, got -1",
    ),
    "annotation_next_list": (
        "sample_annotation",
        _table_case("sample_annotation", "next", ["x"], _car_annotation),
        f"field 'next' = ['x'] {_NOT_TOKEN} sample_annotation record",
    ),
}  # fmt: skip


@needs_devkit
@pytest.mark.parametrize("case", sorted(_TABLE_FIELDS))
def test_every_table_field_read_is_type_checked(
    dataset: SyntheticNuScenes, clean_path: Path, tmp_path: Path, case: str
) -> None:
    """A table field of the wrong type (a string timestamp or point count, a token that is no
    token): one error naming the table file, the record and the field (was 'unexpected error:
    TypeError' or KeyError, or a string of digits silently read as a number)."""
    table, edit, said = _TABLE_FIELDS[case]
    tokens: list[str] = []
    root = _edited_dataset(dataset, tmp_path / case, lambda t: tokens.append(edit(t)))
    with pytest.raises(InputError) as err:
        convert_nuscenes(
            root,
            version=dataset.version,
            detections=clean_path,
            split="mini_val",
            with_gt=True,
        )
    where = f"{root / dataset.version / f'{table}.json'}: {table} '{tokens[0]}'"
    assert str(err.value).startswith(where), str(err.value)
    assert said in str(err.value)


def _break_json(root: Path, version: str) -> None:
    (root / version / "instance.json").write_text('[{"token": ')


_LOAD_PROBLEMS: dict[str, tuple[Callable[[dict[str, list[Any]]], None], str, str]] = {
    "not_a_list": (
        lambda t: t.__setitem__("sensor", {"token": "x"}),
        "sensor.json", ": not a nuScenes table (a JSON list of records)",
    ),
    "token_not_a_string": (
        lambda t: t["visibility"][0].__setitem__("token", ["x"]),
        "visibility.json", ": record 0: field 'token' must be a string, got ['x']",
    ),
    "dangling_instance": (
        lambda t: t["sample_annotation"][2].__setitem__("instance_token", "gone"),
        "sample_annotation.json",
        "field 'instance_token' = 'gone' is not the token of a instance record",
    ),
    "sensor_without_channel": (
        lambda t: t["sensor"][0].pop("channel"),
        "sensor.json", "field 'channel' must be a str, got None",
    ),
    "log_of_no_map": (
        lambda t: t["map"][0].__setitem__("log_tokens", []),
        "log.json", "in the field 'log_tokens' of no map record (map.json)",
    ),
    # (the log was said to be in no map: the map's token, the likelier typo, was not named)
    "map_names_no_log": (
        lambda t: t["map"][0].__setitem__("log_tokens", ["gone"]),
        "log.json", "of no map record (map.json; it names 1 of no log, first 'gone': a typo?)",
    ),
    # (was '<dataroot>/v1.0-mini: malformed nuScenes tables (TypeError("unhashable type..."))')
    "map_log_token_a_list": (
        lambda t: t["map"][0]["log_tokens"].append(["x"]),
        "map.json", "field 'log_tokens' holds ['x'], not a log token",
    ),
}  # fmt: skip


@needs_devkit
@pytest.mark.parametrize("case", ["malformed_json", *sorted(_LOAD_PROBLEMS)])
def test_tables_the_devkit_cannot_load_are_named(
    dataset: SyntheticNuScenes, tmp_path: Path, case: str
) -> None:
    """A table the devkit fails to load or index: the error names its file (and the record and
    field); it was '<dataroot>/v1.0-mini: malformed nuScenes tables (JSONDecodeError(...))' or
    (KeyError('gone')), naming no table."""
    if case == "malformed_json":
        root = _edited_dataset(dataset, tmp_path / case, lambda t: None)
        _break_json(root, dataset.version)
        table, said = "instance.json", ": malformed JSON (Expecting value: line 1 column 12"
    else:
        edit, table, said = _LOAD_PROBLEMS[case]
        root = _edited_dataset(dataset, tmp_path / case, edit)
    with pytest.raises(InputError) as err:
        load_nuscenes(root, dataset.version)
    assert str(err.value).startswith(f"{root / dataset.version / table}"), str(err.value)
    assert said in str(err.value)


@needs_devkit
def test_a_map_naming_logs_it_lacks_is_no_table_problem(
    dataset: SyntheticNuScenes, tmp_path: Path
) -> None:
    """The official v1.0-mini map lists logs of the full dataset, which mini lacks: the devkit
    loads such tables, and table_problem (run once the devkit failed, for whatever reason) must
    not blame the map for it (it did, hiding the real problem)."""
    assert table_problem(dataset.dataroot / dataset.version) is None

    def edit(tables: dict[str, list[Any]]) -> None:
        tables["map"][0]["log_tokens"].append("a-log-of-the-full-dataset")

    root = _edited_dataset(dataset, tmp_path / "map", edit)
    load_nuscenes(root, dataset.version)  # (the devkit loads them)
    assert table_problem(root / dataset.version) is None
