"""Waymo: a synthetic segment in the ImmortalTracker / MCTrack file layout → BaseVersion (world
frame, five cameras), the tracker, and the per-segment result npz writer."""

from __future__ import annotations

import json
import math
import shutil
import sys
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.cli import main
from tracker.camera import project_points
from tracker.categories import category_index
from tracker.config import load_config
from tracker.errors import InputError
from tracker.io.baseversion import read_baseversion, write_baseversion
from tracker.io.convert.waymo import WAYMO_CAMERAS, convert_waymo
from tracker.io.fileio import load_npz
from tracker.io.waymo_writer import FLAT_MEMBERS, read_waymo_results, write_waymo_results
from tracker.pipeline import run_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from waymo_flatten_npz import main as flatten_main

SEGMENT = "segment-1234_5678_with_camera_labels"
N_FRAMES = 20
N_DET_FRAMES = 17  # ImmortalTracker's files stop at the last frame with a box
T0_MICROS = 1_550_083_467_346_370
F_PX, CX_PX, CY_PX = 2055.0, 960.0, 640.0
CAMERA_YAWS_DEG = {"FRONT": 0, "FRONT_LEFT": 45, "FRONT_RIGHT": -45, "SIDE_LEFT": 90,
                   "SIDE_RIGHT": -90}  # fmt: skip
CAMERA_XYZ = (1.5, 0.0, 2.1)
EGO_HEADING = 0.7
EGO_SPEED_MPS = 8.0

#: id, Waymo type, start in the world relative to the ego start (m), velocity (m/s), lwh
OBJECTS = (
    ("veh-a", 1, (20.0, 0.0), (8.0, 0.0), (4.6, 2.0, 1.7)),  # straight ahead, pacing the ego
    ("veh-b", 1, (-15.0, 0.0), (8.0, 0.0), (4.6, 2.0, 1.7)),  # straight behind: no camera
    ("ped-a", 2, (2.0, 15.0), (0.0, -1.0), (0.8, 0.7, 1.8)),  # on the left
    ("cyc-a", 4, (25.0, -8.0), (5.0, 0.0), (1.9, 0.7, 1.6)),  # ahead right
    ("sign-a", 3, (30.0, 10.0), (0.0, 0.0), (0.3, 0.3, 2.0)),  # not tracked
)


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def world_from_ego(i: int) -> np.ndarray:
    """Ego pose at frame i: heading EGO_HEADING, driving forward, with a slight roll."""
    m = np.eye(4)
    roll = np.array([[1.0, 0, 0], [0, math.cos(0.02), -math.sin(0.02)], [0, math.sin(0.02), 0]])
    roll[2, 2] = math.cos(0.02)
    m[:3, :3] = rot_z(EGO_HEADING) @ roll
    forward = rot_z(EGO_HEADING)[:, 0]
    m[:3, 3] = np.array([1000.0, -500.0, 30.0]) + EGO_SPEED_MPS * 0.1 * i * forward
    return m


def object_world(i: int, start: tuple[float, float], vel: tuple[float, float]) -> np.ndarray:
    """World centre of an object at frame i; start/velocity are in the ego's initial axes."""
    r0 = rot_z(EGO_HEADING)
    origin = world_from_ego(0)[:3, 3]
    rel = np.array([start[0] + vel[0] * 0.1 * i, start[1] + vel[1] * 0.1 * i, 0.0])
    centre = origin + r0 @ rel
    centre[2] = origin[2] + 2.1  # at the camera height, so "straight ahead" is the image centre
    return centre


def object_yaw_world(vel: tuple[float, float]) -> float:
    return EGO_HEADING + (math.atan2(vel[1], vel[0]) if any(vel) else 0.3)


def write_segment(
    root: Path, *, mctrack_layout: bool = True, with_gt: bool = True, pickled: bool = False
) -> Path:
    """ts_info, ego_info and detections (and GT) of one segment: written as the preprocessing
    writes them (pickled per-frame object arrays, kept under ``root/pickled/``) and turned into
    the pickle-free layout by ``bench/waymo_flatten_npz.py``, as a user would; with ``pickled``
    the preprocessing's files themselves are where the converter looks."""
    final = root
    if not pickled:
        root = root / "pickled"
    for sub in ("ts_info", "ego_info", "dets", "gt"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    (final / "ts_info").mkdir(parents=True, exist_ok=True)
    (final / "ts_info" / f"{SEGMENT}.json").write_text(
        json.dumps([T0_MICROS + 100_000 * i for i in range(N_FRAMES)])
    )
    if mctrack_layout:
        infos = np.empty((N_FRAMES, 1, 16), dtype=object)
        for i in range(N_FRAMES):
            infos[i, 0, 0] = world_from_ego(i)
            for k, name in enumerate(("FRONT", "FRONT_LEFT", "FRONT_RIGHT", "SIDE_LEFT",
                                      "SIDE_RIGHT")):  # fmt: skip
                extrinsic = np.eye(4)  # camera -> vehicle, Waymo camera axes
                extrinsic[:3, :3] = rot_z(math.radians(CAMERA_YAWS_DEG[name]))
                extrinsic[:3, 3] = CAMERA_XYZ
                infos[i, 0, 1 + k] = extrinsic
                infos[i, 0, 6 + k] = np.array([F_PX, F_PX, CX_PX, CY_PX, 0, 0, 0, 0, 0])
            for k in range(5):
                infos[i, 0, 11 + k] = np.eye(4)
        np.savez_compressed(root / "ego_info" / f"{SEGMENT}.npz", ego_infos=infos)
    else:
        np.savez_compressed(
            root / "ego_info" / f"{SEGMENT}.npz",
            **{str(i): world_from_ego(i) for i in range(N_FRAMES)},
        )
    bboxes, types, ids, velos = [], [], [], []
    for i in range(N_DET_FRAMES):
        ego_from_world = np.linalg.inv(world_from_ego(i))
        rows, frame_types, frame_ids, frame_velos = [], [], [], []
        for obj_id, code, start, vel, lwh in OBJECTS:
            centre = ego_from_world[:3, :3] @ object_world(i, start, vel) + ego_from_world[:3, 3]
            heading = object_yaw_world(vel) - EGO_HEADING  # the roll is tiny; exact enough
            rows.append([*centre, heading, *lwh, 0.9])
            frame_types.append(code)
            frame_ids.append(obj_id)
            world_v = rot_z(EGO_HEADING)[:2, :2] @ np.array(vel)
            frame_velos.append(rot_z(-EGO_HEADING)[:2, :2] @ world_v)
        bboxes.append(np.array(rows))
        types.append(np.array(frame_types))
        ids.append(frame_ids)
        velos.append(np.array(frame_velos))

    def ragged(items: list[Any]) -> np.ndarray:
        out = np.empty(len(items), dtype=object)
        for k, item in enumerate(items):
            out[k] = item
        return out

    np.savez_compressed(
        root / "dets" / f"{SEGMENT}.npz", bboxes=ragged(bboxes), types=ragged(types)
    )
    if with_gt:
        np.savez_compressed(
            root / "gt" / f"{SEGMENT}.npz",
            bboxes=ragged([b[:, :7] for b in bboxes]),
            types=ragged(types),
            ids=ragged(ids),
            velos=ragged(velos),
        )
    if not pickled:
        for sub in ("ego_info", "dets", "gt"):
            if any((root / sub).iterdir()):
                assert flatten_main([str(root / sub), str(final / sub)]) == 0
    return final


@pytest.fixture
def segment(tmp_path: Path) -> Path:
    return write_segment(tmp_path / "waymo")


def test_segment_to_world_frames_and_cameras(segment: Path, tmp_path: Path) -> None:
    conv = convert_waymo(segment, segment / "dets", gt=segment / "gt")
    frames = conv.detections[SEGMENT]
    assert len(frames) == N_FRAMES  # frames after the last detection are kept, empty
    assert [len(f.boxes) for f in frames] == [4] * N_DET_FRAMES + [0] * (N_FRAMES - N_DET_FRAMES)
    assert conv.skipped_types == {3: N_DET_FRAMES}
    assert frames[1].timestamp_secs - frames[0].timestamp_secs == pytest.approx(0.1, abs=1e-6)
    f = frames[6]
    tracked = [o for o in OBJECTS if o[1] != 3]
    np.testing.assert_allclose(f.boxes.xyz, [object_world(6, o[2], o[3]) for o in tracked])
    np.testing.assert_allclose(f.boxes.yaw, [object_yaw_world(o[3]) for o in tracked], atol=1e-3)
    assert [f.boxes.category[k] for k in range(4)] == [
        category_index(c) for c in ("car", "car", "pedestrian", "cyclist")
    ]
    np.testing.assert_allclose(f.world_from_ego, world_from_ego(6))
    assert [c.name for c in f.cameras] == [c[0] for c in WAYMO_CAMERAS]
    assert [c.height_px for c in f.cameras] == [1280, 1280, 1280, 886, 886]
    # camera axes: an object straight ahead at the camera height is at the front image centre
    front = f.cameras[0]
    uv, depth = project_points(f.boxes.xyz[:1], front)
    np.testing.assert_allclose(uv[0], [CX_PX, CY_PX], atol=6.0)  # the ego's 0.02 rad roll
    # exactly: Waymo camera axes x forward, y left, z up; u grows to the right, v downwards
    x, y, z = (np.linalg.inv(world_from_ego(6)) @ np.r_[f.boxes.xyz[0], 1.0])[:3] - CAMERA_XYZ
    np.testing.assert_allclose(uv[0], [CX_PX - F_PX * y / x, CY_PX - F_PX * z / x], atol=1e-6)
    assert depth[0] == pytest.approx(x)
    # camera assignment: ahead -> CAM_FRONT, behind -> none (Waymo has no rear camera), the
    # pedestrian on the left -> CAM_SIDE_LEFT (or FRONT_LEFT), the cyclist -> a front camera
    names = [f.cameras[c].name if c >= 0 else None for c in f.boxes.camera]
    assert names[0] == "CAM_FRONT" and names[1] is None
    assert names[2] in ("CAM_FRONT_LEFT", "CAM_SIDE_LEFT")
    assert names[3] in ("CAM_FRONT", "CAM_FRONT_RIGHT")
    u_ped = project_points(f.boxes.xyz[2:3], f.cameras[f.boxes.camera[2]])[0][0, 0]
    assert 0 <= u_ped <= 1920
    # GT: one id per object, velocity rotated into the world
    assert conv.gt is not None
    gt = conv.gt[SEGMENT]
    assert {int(t) for g in gt for t in g.boxes.track_id} == {0, 1, 2, 3}
    np.testing.assert_allclose(
        gt[3].boxes.velocity[0], rot_z(EGO_HEADING)[:2, :2] @ [8.0, 0.0], atol=0.2
    )
    # round trip through the BaseVersion file
    path = tmp_path / "waymo.json"
    write_baseversion(path, conv.detections)
    back = read_baseversion(path)[SEGMENT][6]
    np.testing.assert_allclose(back.boxes.xyz, f.boxes.xyz)
    for cam in f.cameras:
        twin = back.cameras[back.camera_index(cam.name)]
        np.testing.assert_allclose(twin.camera_from_world, cam.camera_from_world, atol=1e-9)
        np.testing.assert_allclose(twin.image_from_camera, cam.image_from_camera)
    assert [back.cameras[c].name if c >= 0 else None for c in back.boxes.camera] == names


def test_immortaltracker_ego_layout_has_no_cameras(tmp_path: Path) -> None:
    root = write_segment(tmp_path / "w", mctrack_layout=False, with_gt=False)
    frames = convert_waymo(root, root / "dets").detections[SEGMENT]
    assert frames[3].cameras == () and (frames[3].boxes.camera == -1).all()
    np.testing.assert_allclose(
        frames[3].boxes.xyz[0], object_world(3, OBJECTS[0][2], OBJECTS[0][3])
    )


def test_tracking_and_result_writer(segment: Path, tmp_path: Path) -> None:
    conv = convert_waymo(segment, segment / "dets")
    frames = conv.detections[SEGMENT]
    outputs = run_scene(frames, load_config("waymo")).outputs
    written = write_waymo_results(tmp_path / "results", {SEGMENT: (frames, outputs)})
    assert written["vehicle"] == 2 * N_DET_FRAMES and written["pedestrian"] == N_DET_FRAMES
    assert written["cyclist"] == N_DET_FRAMES
    ids, bboxes = read_waymo_results(tmp_path / "results" / "vehicle" / f"{SEGMENT}.npz")
    assert len(ids) == len(bboxes) == N_FRAMES
    assert all(len(i) == 2 for i in ids[:N_DET_FRAMES]) and ids[-1] == []
    assert len({tuple(i) for i in ids[:N_DET_FRAMES]}) == 1  # no identity switch
    # world-frame rows [x, y, z, o, l, w, h, s] close to the truth
    k = ids[10].index(ids[0][0])
    row = bboxes[10][k]
    np.testing.assert_allclose(row[:3], object_world(10, OBJECTS[0][2], OBJECTS[0][3]), atol=0.3)
    np.testing.assert_allclose(row[4:7], OBJECTS[0][4], atol=0.2)
    assert row[7] == pytest.approx(0.9)
    result = tmp_path / "results" / "vehicle" / f"{SEGMENT}.npz"
    # the reference's per-frame object arrays (for pred_bin.py) are there, never read by us
    assert {"ids.npy", "bboxes.npy", "states.npy"} <= set(zipfile.ZipFile(result).namelist())
    with pytest.raises(InputError, match=r"member 'ids'.*pickled object arrays are not read"):
        load_npz(result)
    with load_npz(result, members=FLAT_MEMBERS) as npz:
        assert npz["timestamps"][0] == T0_MICROS
        assert npz["box_states"].dtype.kind == "U" and set(npz["box_states"]) == {"confirmed"}
        assert len(npz["box_velos"]) == len(npz["box_ids"]) == 2 * N_DET_FRAMES
    # the pickled members hold the same boxes as the flat ones (what pred_bin.py reads)
    with np.load(result, allow_pickle=True) as npz:  # our own output, written just above
        assert [list(map(int, r)) for r in npz["ids"]] == ids
        for a, b in zip(npz["bboxes"], bboxes, strict=True):
            np.testing.assert_array_equal(np.asarray(a).reshape(-1, 8), b)


def test_pickled_preprocessing_files_are_refused_with_the_fix(tmp_path: Path) -> None:
    """The ImmortalTracker/MCTrack object arrays are never unpickled: one line naming the file,
    the member and the converter to run on one's own files."""
    root = write_segment(tmp_path / "w", pickled=True)
    with pytest.raises(InputError) as err:
        convert_waymo(root, root / "dets")
    text = str(err.value)
    assert f"ego_info/{SEGMENT}.npz: member 'ego_infos'" in text and "\n" not in text
    assert "bench/waymo_flatten_npz.py" in text
    assert main(["convert", "waymo", "--data-root", str(root), "--detections",
                 str(root / "dets"), "--out", str(tmp_path / "o.json")]) == 2  # fmt: skip
    # with flattened ego info, the pickled detections are refused in turn
    flat = write_segment(tmp_path / "flat")
    (root / "ego_info" / f"{SEGMENT}.npz").unlink()
    (flat / "ego_info" / f"{SEGMENT}.npz").rename(root / "ego_info" / f"{SEGMENT}.npz")
    with pytest.raises(InputError, match=rf"dets/{SEGMENT}\.npz: member 'bboxes'.*flatten"):
        convert_waymo(root, root / "dets")


def test_flat_layout_is_checked(segment: Path) -> None:
    """Malformed pickle-free files: one InputError naming the file and the array."""
    path = segment / "dets" / f"{SEGMENT}.npz"
    good = dict(np.load(path))  # plain arrays only: allow_pickle=False by default
    cases = {
        "no frame_index": ({k: v for k, v in good.items() if k != "frame_index"}, "frame_index"),
        "frame beyond ts_info": ({**good, "frame_index": good["frame_index"] + 99}, "ts_info"),
        "short types": ({**good, "types": good["types"][:3]}, "'types'"),
        "strings as boxes": ({**good, "bboxes": good["bboxes"].astype(str)}, "'bboxes'"),
        "NaN box": ({**good, "bboxes": np.where(good["bboxes"] > 1e9, 0, np.nan)}, "finite"),
        "negative size": ({**good, "bboxes": good["bboxes"] * [1, 1, 1, 1, 1, -1, 1, 1]},
                          r"bboxes row 0: l, w, h = .*: length and width must be > 0"),
        "zero length": ({**good, "bboxes": good["bboxes"] * [1, 1, 1, 1, 0, 1, 1, 1]},
                        r"bboxes row 0: l, w, h = \[0\.0, .*: length and width must be > 0"),
        "per-frame (F, K, 8) boxes": (
            {"bboxes": good["bboxes"][:68].reshape(17, 4, 8), "types": good["types"]},
            "per-frame arrays",
        ),
    }  # fmt: skip
    for name, (arrays, match) in cases.items():
        np.savez_compressed(path, **arrays)
        with pytest.raises(InputError, match=match) as err:
            convert_waymo(segment, segment / "dets")
        assert str(path) in str(err.value), name


def test_a_type_code_that_is_no_waymo_type_is_counted_apart_and_named(
    segment: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Type 9 (Waymo's are 0-4) is no untracked type like a sign (3): it is counted apart and
    warned about with the file's name (it went silently into the skipped types)."""
    path = segment / "dets" / f"{SEGMENT}.npz"
    good = dict(np.load(path))
    types = good["types"].copy()
    sign = int(np.flatnonzero(types == 3)[0])
    types[sign] = 9
    np.savez_compressed(path, **{**good, "types": types})
    with caplog.at_level("WARNING", logger="tracker.io.convert.waymo"):
        conv = convert_waymo(segment, segment / "dets")
    assert conv.unknown_types == {9: 1} and conv.skipped_types == {3: N_DET_FRAMES - 1}
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warned) == 1 and str(path) in warned[0] and "{9: 1}" in warned[0]
    run = tmp_path / "run"
    argv = ["waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    assert main([*argv, "--out", str(run)]) == 0
    summary = json.loads((run / "summary.json").read_text())
    assert summary["unknown_types"] == {"9": 1}
    assert summary["skipped_types"] == {"3": N_DET_FRAMES - 1}


def test_a_score_outside_0_1_names_its_row(segment: Path) -> None:
    """A score beyond [0, 1]: the error names the row, as the other Waymo errors do (it named
    the frame alone)."""
    path = segment / "dets" / f"{SEGMENT}.npz"
    good = dict(np.load(path))
    bboxes = good["bboxes"].copy()
    row = int(np.flatnonzero(good["types"] == 2)[1])  # (a tracked type: signs are dropped first)
    bboxes[row, 7] = 1.5
    np.savez_compressed(path, **{**good, "bboxes": bboxes})
    frame = int(good["frame_index"][row])
    with pytest.raises(InputError) as err:
        convert_waymo(segment, segment / "dets")
    assert str(err.value) == (
        f"{path}: bboxes row {row} (frame {frame}): score 1.5 must be in [0, 1]"
    )


def test_ego_info_poses_and_cameras_are_checked(segment: Path, tmp_path: Path) -> None:
    """A singular or non-rigid ego pose or camera extrinsic, or a camera without a focal length:
    one InputError naming the file and the array entry. A singular one ended mctrack waymo in
    'unexpected error: LinAlgError' (every segment lost); a scaled or transposed one, or a zero
    focal length, gave wrong positions or camera boxes without a word."""
    path = segment / "ego_info" / f"{SEGMENT}.npz"
    good = dict(np.load(path))
    scaled, transposed, zero = (good["ego2global"].copy() for _ in range(3))
    scaled[4, :3, :3] *= 2.0
    transposed[4] = transposed[4].T
    zero[4] = 0.0
    extrinsics, intrinsics = good["cam_extrinsics"].copy(), good["cam_intrinsics"].copy()
    extrinsics[2, 1] = 0.0
    intrinsics[2, 1, :2] = 0.0
    cases = {
        "scaled": ({"ego2global": scaled}, r"ego2global\[4\] is not a rigid transform"),
        "transposed": ({"ego2global": transposed}, r"ego2global\[4\] is not a rigid"),
        "singular": ({"ego2global": zero}, r"ego2global\[4\] is not a rigid"),
        "singular camera": (
            {"cam_extrinsics": extrinsics},
            r"cam_extrinsics\[2, 1\] \(CAM_FRONT_LEFT\) is not a rigid",
        ),
        "no focal length": (
            {"cam_intrinsics": intrinsics},
            r"cam_intrinsics\[2, 1\] \(CAM_FRONT_LEFT\): focal lengths",
        ),
    }
    for name, (arrays, match) in cases.items():
        np.savez_compressed(path, **{**good, **arrays})
        with pytest.raises(InputError, match=match) as err:
            convert_waymo(segment, segment / "dets")
        assert str(path) in str(err.value), name
    # mctrack waymo: the segment fails alone, with that line (not an unexpected error)
    argv = ["waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    assert main([*argv, "--out", str(tmp_path / "run")]) == 2


def test_ground_truth_ids_and_velocities_are_checked(segment: Path, tmp_path: Path) -> None:
    """An object twice in one frame, or a NaN velocity, in the ground truth: one error naming
    the file and the row (mctrack waymo --motion ended in an unexpected error, after tracking:
    'GT track 0 has two samples', or NaN in gt.json). A box beyond the bound a detection's has
    (1e300: finite; tracker.io.bounds) is refused as a detection's, naming its frame too, and a
    velocity beyond the velocity bound (2e4 m/s: was converted, and overflowed downstream at
    1e300) likewise, and a heading beyond the BaseVersion reader's bound (was converted to an
    arbitrary angle)."""
    path = segment / "gt" / f"{SEGMENT}.npz"
    good = dict(np.load(path))
    ids, velos, bboxes = good["ids"].copy(), good["velos"].copy(), good["bboxes"].copy()
    frame0 = np.flatnonzero(good["frame_index"] == 0)
    ids[frame0[1]] = ids[frame0[0]]
    velos[3] = np.nan
    fast = good["velos"].copy()
    fast[7] = [1.5, 2e4]
    bboxes[5, 1] = 1e300
    turned = good["bboxes"].copy()
    turned[6, 3] = -1e300  # (a heading: its float spacing is more than a turn)
    cases = {
        "object twice in a frame": (
            {"ids": ids},
            rf"ids row {frame0[1]}: object '{ids[0]}' is in frame 0 twice",
        ),
        "NaN velocity": ({"velos": velos}, r"velos row 3: must be finite"),
        "velocity beyond the bound": (
            {"velos": fast},
            rf"velos row 7 \(frame {good['frame_index'][7]}\): vx, vy = \[1\.5, 20000\.0\]: "
            r"beyond ±10000 m/s \(faster than anything on or near Earth\)$",
        ),
        "box beyond the bound": (
            {"bboxes": bboxes},
            rf"bboxes row 5 \(frame {good['frame_index'][5]}\): x, y, z = \[.*, 1e\+300, .*\]: "
            r"beyond ±1e\+08 m",
        ),
        "heading beyond the bound": (
            {"bboxes": turned},
            rf"bboxes row 6 \(frame {good['frame_index'][6]}\): heading = -1e\+300: beyond "
            r"±10000 rad \(a heading is within a few turns of zero\)$",
        ),
    }
    argv = ["waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    for name, (arrays, match) in cases.items():
        np.savez_compressed(path, **{**good, **arrays})
        with pytest.raises(InputError, match=match) as err:
            convert_waymo(segment, segment / "dets", gt=segment / "gt")
        assert str(path) in str(err.value), name
        run = ["--gt", str(segment / "gt"), "--motion", "--out", str(tmp_path / "run")]
        assert main([*argv, *run]) == 2, name


def test_ground_truth_without_velos_has_an_unknown_velocity(segment: Path, tmp_path: Path) -> None:
    """GT without ``velos``: velocity unknown (NaN, null in gt.json; it was 0, which the motion
    metrics took for measured standstills as soon as another segment had velos), and --motion
    derives it from the GT positions."""
    path = segment / "gt" / f"{SEGMENT}.npz"
    np.savez_compressed(path, **{k: v for k, v in np.load(path).items() if k != "velos"})
    conv = convert_waymo(segment, segment / "dets", gt=segment / "gt")
    assert conv.gt is not None
    velocities = np.concatenate([g.boxes.velocity for g in conv.gt[SEGMENT]])
    assert len(velocities) and np.isnan(velocities).all()
    run = tmp_path / "run"
    argv = ["waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    assert main([*argv, "--gt", str(segment / "gt"), "--motion", "--out", str(run)]) == 0
    gt = json.loads((run / "gt.json").read_text())[SEGMENT]
    assert {str(b["global_velocity"]) for f in gt for b in f["bboxes"]} == {"None"}
    motion = json.loads((run / "summary.json").read_text())["motion"]
    assert motion["protocol"]["gt_velocity"].startswith("GT world positions")
    kalman = motion["metrics"]["kalman"]["all"]
    assert kalman["n_samples"] > 0 and kalman["n_gt_velocity_unknown"] == 0


def test_waymo_motion_is_printed_and_written_as_kitti_does(
    segment: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """mctrack waymo --motion prints the motion table and writes motion.md with the velocity
    PNG, as mctrack kitti does (the metrics were only in summary.json, and nothing said so)."""
    run = tmp_path / "run"
    argv = ["waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    assert main([*argv, "--gt", str(segment / "gt"), "--motion", "--out", str(run)]) == 0
    printed = capsys.readouterr().out
    kalman = json.loads((run / "summary.json").read_text())["motion"]["metrics"]["kalman"]
    assert "motion (all)" in printed
    assert f"{kalman['all']['vae_deg']:>11.3f}" in printed.split("kalman", 1)[1].splitlines()[0]
    assert (run / "motion.md").read_text().startswith("# Motion metrics")
    assert (run / "motion_velocity.png").stat().st_size > 0


def test_bad_waymo_inputs_name_the_file(segment: Path) -> None:
    (segment / "ts_info" / f"{SEGMENT}.json").unlink()
    with pytest.raises(InputError, match=rf"ts_info/{SEGMENT}\.json: ts_info file not found"):
        convert_waymo(segment, segment / "dets")
    (segment / "ts_info" / f"{SEGMENT}.json").write_text(json.dumps([T0_MICROS, T0_MICROS + 1]))
    with pytest.raises(InputError, match=r"npz: frame_index row 10: frame 2, but ts_info has 2"):
        convert_waymo(segment, segment / "dets")
    with pytest.raises(InputError, match="detections folder not found"):
        convert_waymo(segment, segment / "nope")


def test_waymo_cli(segment: Path, tmp_path: Path) -> None:
    out = tmp_path / "bv.json"
    argv = ["convert", "waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    assert main([*argv, "--gt", str(segment / "gt"), "--gt-out", str(tmp_path / "gt.json"),
                 "--out", str(out)]) == 0  # fmt: skip
    assert len(read_baseversion(out)[SEGMENT]) == N_FRAMES
    run = tmp_path / "run"
    argv = ["waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    assert main([*argv, "--out", str(run)]) == 0
    summary = json.loads((run / "summary.json").read_text())
    assert summary["boxes_written"]["vehicle"] == 2 * N_DET_FRAMES
    assert (run / "results" / "cyclist" / f"{SEGMENT}.npz").is_file()
    assert (run / "tracks.json").is_file()


def test_waymo_cli_records_like_kitti_and_nuscenes(segment: Path, tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    from viz import paths

    run = tmp_path / "run"
    argv = ["waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    assert main([*argv, "--gt", str(segment / "gt"), "--record", "--out", str(run)]) == 0
    rrd = run / "recordings" / f"{SEGMENT}.rrd"
    assert json.loads((run / "summary.json").read_text())["recordings"] == [str(rrd)]
    found = {c.entity_path for c in RrdReader(str(rrd)).stream().to_chunks()}
    assert paths.entity(paths.TRACKS_UPDATED) in found and paths.entity(paths.GT) in found


def test_waymo_run_into_an_earlier_run_replaces_it(segment: Path, tmp_path: Path) -> None:
    """A second run into the same --out leaves only its own outputs (pred_bin.py reads every
    file of results/: a segment left out kept its old results beside the new ones); a run
    refused on its inputs keeps the earlier one, and files of other names stay."""
    for sub, ext in (("ts_info", "json"), ("ego_info", "npz"), ("dets", "npz"), ("gt", "npz")):
        shutil.copy(segment / sub / f"{SEGMENT}.{ext}", segment / sub / f"other.{ext}")
    run = tmp_path / "run"
    argv = ["waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    assert main([*argv, "--gt", str(segment / "gt"), "--motion", "--out", str(run)]) == 0
    (run / "notes.txt").write_text("mine")
    first = sorted(p.relative_to(run).as_posix() for p in run.rglob("*.npz"))
    assert f"results/vehicle/{SEGMENT}.npz" in first and "results/vehicle/other.npz" in first
    assert main([*argv, "--segments", "../other", "--out", str(run)]) == 2  # refused
    assert sorted(p.relative_to(run).as_posix() for p in run.rglob("*.npz")) == first
    assert main([*argv, "--segments", "other", "--out", str(run)]) == 0
    assert sorted(p.relative_to(run).as_posix() for p in run.rglob("*.npz")) == [
        f"results/{kind}/other.npz" for kind in ("cyclist", "pedestrian", "vehicle")
    ]
    assert not (run / "gt.json").exists() and (run / "notes.txt").read_text() == "mine"
    assert not (run / "motion.md").exists() and not (run / "motion_velocity.png").exists()
    assert json.loads((run / "summary.json").read_text())["segments"] == ["other"]


def test_waymo_into_a_run_cut_short_refuses_results_of_other_segments(
    segment: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run killed mid-way leaves its scene parts and results, no summary.json saying whose
    they are: a new run of fewer segments kept the others' results/*/*.npz (pred_bin.py reads
    every file there: a submission mixing two runs). Now they are refused, named, before any
    work; a run of every segment there replaces them."""
    for sub, ext in (("ts_info", "json"), ("ego_info", "npz"), ("dets", "npz"), ("gt", "npz")):
        shutil.copy(segment / sub / f"{SEGMENT}.{ext}", segment / sub / f"other.{ext}")
    run = tmp_path / "run"
    argv = ["waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    assert main([*argv, "--out", str(run)]) == 0
    (run / "summary.json").unlink()  # (what a killed run leaves: deleted at its start)
    (run / ".scenes").mkdir()
    (run / ".scenes" / "000000.json").write_text("{}")
    before = sorted(p.relative_to(run).as_posix() for p in run.rglob("*"))
    capsys.readouterr()
    assert main([*argv, "--segments", SEGMENT, "--out", str(run)]) == 2
    err = capsys.readouterr().err
    assert f"{run / 'results' / 'cyclist' / 'other.npz'} (and 2 more): {run} holds" in err
    assert sorted(p.relative_to(run).as_posix() for p in run.rglob("*")) == before
    assert main([*argv, "--out", str(run)]) == 0
    assert sorted(json.loads((run / "summary.json").read_text())["segments"]) == ["other", SEGMENT]


def test_waymo_into_a_finished_run_refuses_a_result_file_of_no_run(
    segment: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A user's results/<type>/x.npz in a finished run's folder (not of its "segments") is
    kept by design, but pred_bin.py reads every file under results/: it entered the new run's
    submission unsaid. Now the run is refused before any work, naming it (and how many more)."""
    run = tmp_path / "run"
    argv = ["waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    assert main([*argv, "--out", str(run)]) == 0
    for kind in ("vehicle", "cyclist"):
        (run / "results" / kind / "mine.npz").write_bytes(b"mine")
    before = {p.relative_to(run).as_posix(): p.read_bytes() for p in run.rglob("*") if p.is_file()}
    capsys.readouterr()
    assert main([*argv, "--out", str(run)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"mctrack waymo: error: {run / 'results' / 'cyclist' / 'mine.npz'} (and 1 more): a "
        f"result file of neither the run in {run} nor this one, and the submission (pred_bin.py)"
        " reads every file under results/; move or remove them, or give another --out"
    )
    after = {p.relative_to(run).as_posix(): p.read_bytes() for p in run.rglob("*") if p.is_file()}
    assert after == before
    # moved away: the run replaces the earlier one
    for kind in ("vehicle", "cyclist"):
        (run / "results" / kind / "mine.npz").unlink()
    assert main([*argv, "--out", str(run)]) == 0


def test_waymo_stopped_after_its_segments_leaves_no_partial_outputs(
    segment: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C once the segments are tracked (results/<type>/<segment>.npz written, tracks.json
    not yet): pred_bin.py would read those results without the summary.json that marks a
    complete run. Now they go, and the folders the run made for them."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "notes.txt").write_text("mine")

    def interrupted(out: Path, ok: object) -> None:
        assert (out / "results" / "vehicle" / f"{SEGMENT}.npz").is_file()
        raise KeyboardInterrupt

    monkeypatch.setattr("app.scenes.write_tracks", interrupted)
    argv = ["waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    assert main([*argv, "--out", str(run)]) == 130
    assert sorted(p.relative_to(run).as_posix() for p in run.rglob("*")) == ["notes.txt"]


def test_waymo_stopped_after_its_motion_report_leaves_no_motion_md(
    segment: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C once motion.md and its PNG are written (summary.json not yet): they go too."""
    import app.waymo

    run = tmp_path / "run"
    write_motion_metrics = app.waymo.write_motion_metrics

    def interrupted(*args: Any) -> None:
        write_motion_metrics(*args)
        assert (run / "motion.md").is_file() and (run / "motion_velocity.png").is_file()
        raise KeyboardInterrupt

    monkeypatch.setattr(app.waymo, "write_motion_metrics", interrupted)
    argv = ["waymo", "--data-root", str(segment), "--detections", str(segment / "dets")]
    assert main([*argv, "--gt", str(segment / "gt"), "--motion", "--out", str(run)]) == 130
    assert not run.exists() or not any(run.iterdir())


def test_waymo_refuses_inputs_among_its_outputs(
    segment: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--detections a folder of an earlier run's results/ inside --out: the run would delete the
    files it reads (an earlier run's outputs go first); refused before any work, files kept."""
    run = tmp_path / "run"
    detections = run / "results" / "vehicle"
    detections.mkdir(parents=True)
    shutil.copy(segment / "dets" / f"{SEGMENT}.npz", detections)
    (run / "summary.json").write_text('{"command": "waymo"}')  # an earlier run's
    argv = ["waymo", "--data-root", str(segment), "--detections", str(detections)]
    assert main([*argv, "--out", str(run)]) == 2
    err = capsys.readouterr().err
    assert f"--detections holds results/vehicle/{SEGMENT}.npz, a file this run writes" in err
    assert (detections / f"{SEGMENT}.npz").is_file() and (run / "summary.json").is_file()


def test_coordinates_that_overflow_the_transforms_are_named(segment: Path) -> None:
    """A box beyond the bound of every box reader (1e308: tracker.io.bounds), an ego or camera
    translation beyond it (1.7e308 overflowed the pose transforms, 1e300 put the frame's boxes
    there), or a box and an ego pose each within it whose sum is not: one error naming the file
    and the row or entry (was converted with numpy overflow warnings, the box in no camera, or
    NaN poses)."""
    import warnings

    dets, ego = segment / "dets" / f"{SEGMENT}.npz", segment / "ego_info" / f"{SEGMENT}.npz"
    good_dets, good_ego = dict(np.load(dets)), dict(np.load(ego))
    bboxes, poses = good_dets["bboxes"].copy(), good_ego["ego2global"].copy()
    row = int(np.flatnonzero(good_dets["frame_index"] == 3)[1])
    bboxes[row, :3] = 1e308
    poses[2, :3, 3] = 1.7e308
    far_poses = good_ego["ego2global"].copy()
    far_poses[3, :3, 3] = 1e300
    far_camera = good_ego["cam_extrinsics"].copy()
    far_camera[2, 1, :3, 3] = [1.0, 1e300, 2.0]
    # (each within the bound, the box 2e6 m ahead of an ego 9.9e7 m out is not)
    edge_poses, edge_boxes = good_ego["ego2global"].copy(), good_dets["bboxes"].copy()
    edge_poses[3, :3, 3] = [9.9e7, 9.9e7, 0.0]
    first = int(np.flatnonzero(good_dets["frame_index"] == 3)[0])
    edge_boxes[first, :3] = edge_poses[3, :3, :3].T @ [2e6, 2e6, 0.0]
    cases = (
        ({dets: {**good_dets, "bboxes": bboxes}},
         rf"bboxes row {row} \(frame 3\): x, y, z = \[1e\+308, 1e\+308, 1e\+308\]: beyond "
         r"±1e\+08 m", dets),
        ({ego: {**good_ego, "ego2global": poses}},
         r"ego2global\[2\]: translation \[1\.7e\+308, 1\.7e\+308, 1\.7e\+308\]: beyond "
         r"±1e\+08 m \(farther or larger than anything on Earth\)$", ego),
        ({ego: {**good_ego, "ego2global": far_poses}},
         r"ego2global\[3\]: translation \[1e\+300, 1e\+300, 1e\+300\]: beyond ±1e\+08 m", ego),
        ({ego: {**good_ego, "cam_extrinsics": far_camera}},
         r"cam_extrinsics\[2, 1\] \(CAM_FRONT_LEFT\): translation \[1\.0, 1e\+300, 2\.0\]: "
         r"beyond ±1e\+08 m", ego),
        ({dets: {**good_dets, "bboxes": edge_boxes}, ego: {**good_ego, "ego2global": edge_poses}},
         rf"bboxes row {first} \(frame 3\) with ego2global\[3\]: x, y, z = \[101000000\.0, "
         r".* in the world frame: beyond ±1e\+08 m", dets),
    )  # fmt: skip
    for files, match, named in cases:
        for path, arrays in files.items():
            np.savez_compressed(path, **arrays)
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # said once, as an error: no numpy warnings first
            with pytest.raises(InputError, match=match) as err:
                convert_waymo(segment, segment / "dets")
        assert str(err.value).startswith(f"{named}: "), match
        np.savez_compressed(dets, **good_dets)
        np.savez_compressed(ego, **good_ego)
