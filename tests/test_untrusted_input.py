"""Untrusted input (issue #15): no code execution, no writes outside --out, a clean one-line
error for every malformed file, and every detection accounted for."""

from __future__ import annotations

import dataclasses
import gzip
import io
import json
import logging
import os
import pickle
import time
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.cli import main
from tracker.config import load_config
from tracker.errors import InputError
from tracker.eval.fates import FateCounter
from tracker.io.baseversion import frame_to_dict, read_baseversion, validate_baseversion
from tracker.io.fileio import (
    load_npz,
    path_in,
    remove_stale_temps,
    safe_filename,
    write_bytes_atomic,
)
from tracker.io.waymo_writer import read_waymo_results
from tracker.pipeline import run_scene

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001" / "detections.json.gz"

CAM = {
    "image_shape": [1242, 375],
    "camera2image": [[721.5, 0, 609.6, 44.9], [0, 721.5, 172.9, 0.2], [0, 0, 1, 0.003]],
    "global2camera": [[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]],
}


def box(**edit: Any) -> dict[str, Any]:
    b = {
        "category": "car",
        "detection_score": 0.9,
        "global_xyz": [10.0, 0.0, 0.8],
        "lwh": [3.9, 1.6, 1.5],
        "global_yaw": 0.0,
    }
    b.update(edit)
    return b


def frame(frame_id: int = 0, boxes: list[Any] | None = None, **edit: Any) -> dict[str, Any]:
    f = {
        "frame_id": frame_id,
        "timestamp": frame_id * 100_000,
        "cur_sample_token": None,
        "transform_matrix": {"cameras_transform_matrix": {"CAM_FRONT": CAM}},
        "bboxes": [box()] if boxes is None else boxes,
    }
    f.update(edit)
    return f


def write_text(tmp_path: Path, text: str | bytes, name: str = "in.json") -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8", "surrogatepass") if isinstance(text, str) else text)
    return path


# ---------------------------------------------------------------------------------------------
# no code execution from npz


class _Payload:
    """Unpickling this creates ``marker`` (open(marker, "w")): harmless proof of execution."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, ...]:
        return (open, (self.marker, "w"))


def _malicious_npz(path: Path, marker: Path) -> None:
    arr = np.empty(1, dtype=object)
    arr[0] = _Payload(str(marker))
    buffer = io.BytesIO()
    np.save(buffer, arr, allow_pickle=True)
    with zipfile.ZipFile(path, "w") as zf:
        for name in ("ids", "bboxes", "box_ids"):  # box_ids: a member our result reader reads
            zf.writestr(f"{name}.npy", buffer.getvalue())


def test_malicious_npz_runs_no_code(tmp_path: Path) -> None:
    bad, marker = tmp_path / "bad.npz", tmp_path / "PWNED"
    _malicious_npz(bad, marker)
    for load in (load_npz, read_waymo_results):
        with pytest.raises(InputError, match=r"bad\.npz: member '\w+'.*pickled object arrays"):
            load(bad)
    assert not marker.exists()
    # the payload is real: numpy's own loader with pickle enabled runs it
    with np.load(bad, allow_pickle=True) as npz:
        npz["ids"]
    assert marker.exists()


def test_object_arrays_are_refused_plain_arrays_load(tmp_path: Path) -> None:
    """Even a harmless object array (lists, arrays) is never unpickled; the error says how to
    convert one's own files. Plain and fixed-width string arrays load."""
    ragged = np.empty(2, dtype=object)
    ragged[0], ragged[1] = [1, 2], np.zeros((1, 8))
    path = tmp_path / "ragged.npz"
    np.savez_compressed(path, ts=np.arange(3, dtype=np.int64), ids=ragged)
    with pytest.raises(InputError) as err:
        load_npz(path, "detections")
    assert str(err.value).startswith(f"{path}: member 'ids' of the detections file: pickled")
    assert "bench/waymo_flatten_npz.py" in str(err.value)
    ok = tmp_path / "ok.npz"
    np.savez_compressed(ok, ts=np.arange(3, dtype=np.int64), ids=np.array(["a", "bc"]))
    npz = load_npz(ok)
    np.testing.assert_array_equal(npz["ts"], [0, 1, 2])
    assert npz["ids"].dtype == np.dtype("<U2") and list(npz["ids"]) == ["a", "bc"]
    (tmp_path / "junk.npz").write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(InputError, match=r"junk\.npz"):
        load_npz(tmp_path / "junk.npz")


def _set_declared_sizes(path: Path, size: int) -> None:
    """Make every member of a (stored, small) zip declare ``size`` uncompressed bytes, in the
    local headers and the central directory, as a crafted bomb would."""
    data = bytearray(path.read_bytes())
    for signature, offset in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
        at = data.find(signature)
        while at >= 0:
            data[at + offset : at + offset + 4] = size.to_bytes(4, "little")
            at = data.find(signature, at + 4)
    path.write_bytes(bytes(data))


def test_npz_bombs_are_refused_before_decompressing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An npz is a zip: the members' declared sizes and the arrays' headers are checked against
    the cap (MCTRACK_MAX_INPUT_BYTES, default 4 GiB) before any member is decompressed."""
    # a real bomb: 64 MiB of zeros in a 65 KB file, under a 16 MiB cap
    bomb = tmp_path / "bomb.npz"
    np.savez_compressed(bomb, a=np.zeros(8 * 2**20))
    assert bomb.stat().st_size < 100_000
    monkeypatch.setenv("MCTRACK_MAX_INPUT_BYTES", str(16 * 2**20))
    with pytest.raises(InputError, match=r"bomb\.npz: npz members declare 67108992 bytes, over"):
        load_npz(bomb)
    assert load_npz(bomb, max_bytes=2**27)["a"].shape == (8 * 2**20,)  # a cap that fits
    monkeypatch.delenv("MCTRACK_MAX_INPUT_BYTES")
    # a crafted one: two tiny members that each declare ~4 GiB (8 GiB over the default cap)
    crafted = tmp_path / "crafted.npz"
    np.savez(crafted, a=np.zeros(1), b=np.zeros(1))
    _set_declared_sizes(crafted, 2**32 - 2)
    with pytest.raises(InputError, match=r"crafted\.npz: npz members declare 8589934588 bytes"):
        load_npz(crafted)


def _npz_with_header(path: Path, shape: tuple[int, ...], payload: bytes) -> None:
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f8", "fortran_order": False, "shape": shape}
    )
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("bboxes.npy", header.getvalue() + payload)


def test_npz_headers_that_lie_are_refused(tmp_path: Path) -> None:
    """A header claiming more (or fewer) items than its member holds, or a terabyte array in a
    few bytes: refused by the header check, naming the file and the member; numpy would
    allocate the claimed array first."""
    lies = {
        "more.npz": ((1000,), np.zeros(10).tobytes(), r"header says \(1000,\) float64 .* 208"),
        "fewer.npz": ((2,), np.zeros(10).tobytes(), r"header says \(2,\) float64"),
        "huge.npz": ((10**6, 10**6), b"\0" * 80, r"declares 8000000000000 bytes"),
        "overflow.npz": ((2**40, 2**40, 2**40), b"", r"declares \d{30,} bytes"),
    }
    for name, (shape, payload, match) in lies.items():
        path = tmp_path / name
        _npz_with_header(path, shape, payload)
        with pytest.raises(InputError, match=rf"{name}: member 'bboxes'.*{match}"):
            load_npz(path)
    # the honest twin loads
    _npz_with_header(tmp_path / "honest.npz", (10,), np.arange(10.0).tobytes())
    np.testing.assert_array_equal(load_npz(tmp_path / "honest.npz")["bboxes"], np.arange(10.0))


# ---------------------------------------------------------------------------------------------
# names from input data stay in the output folder

HOSTILE_NAMES = [
    "../../x",
    "/abs/x",
    "..",
    ".",
    "a/b",
    "a\\b",
    "C:\\x",
    ".hidden",
    "%2F",
    "%",
    "é/../..",
    "x" * 300,
    "~",
    "con",
    " ../x",
]


@pytest.mark.parametrize("name", HOSTILE_NAMES)
def test_hostile_names_stay_in_the_folder(tmp_path: Path, name: str) -> None:
    path = path_in(tmp_path, name, ".txt")
    assert path.parent == tmp_path
    assert path.resolve().parent == tmp_path.resolve()
    assert not path.name.startswith(".") and len(path.name.encode()) <= 255


def test_safe_filename_is_injective_and_keeps_safe_names() -> None:
    names = {*HOSTILE_NAMES, "0001", "scene-0103", "a%2Fb", "a%2fb", "\ud800", "\x00", ""}
    assert len({safe_filename(n) for n in names}) == len(names)
    assert safe_filename("0001") == "0001" and safe_filename("scene-0103") == "scene-0103"


@pytest.mark.parametrize(
    ("name", "problem"),
    [("a\x00b", "control"), ("\ud800", "surrogate"), ("", "empty"), ("a\nb", "control")],
)
def test_unusable_scene_names_are_refused(tmp_path: Path, name: str, problem: str) -> None:
    text = json.dumps({name: [frame()]})  # json escapes them: \u0000, \ud800
    path = write_text(tmp_path, text)
    with pytest.raises(InputError, match=problem):
        read_baseversion(path)
    result = validate_baseversion(path)
    assert result.error_count == 1 and problem in result.errors[0]


def test_track_writes_hostile_scene_names_inside_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    names = ["../../escaped", "/tmp/abs_escape_15", "a/b", ".."]
    path = write_text(tmp_path, json.dumps({n: [frame(0), frame(1)] for n in names}))
    out = tmp_path / "deep" / "out"
    assert main(["track", str(path), "--out", str(out), "--kitti-results"]) == 0
    written = sorted(p for p in tmp_path.rglob("*") if p.is_file() and p != path)
    assert written and all(out in p.parents for p in written)
    assert len(list((out / "data").iterdir())) == len(names)
    assert not Path("/tmp/abs_escape_15.txt").exists()
    assert main(["validate", str(path)]) == 0
    assert "scene '../../escaped' is written to files as '%2E.%2F..%2Fescaped'" in (
        capsys.readouterr().out
    )
    summary = json.loads((out / "summary.json").read_text())
    assert {o["path"] for o in summary["outputs"]} == {
        p.relative_to(out).as_posix() for p in written if p.name != "summary.json"
    }


# ---------------------------------------------------------------------------------------------
# decompression cap, strict JSON


def test_gzip_bomb_is_refused_by_the_cap(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    text = json.dumps({"s": [frame(0)]}) + " " * 3_000_000  # 3 MB of padding, ~3 KB gzipped
    path = write_text(tmp_path, gzip.compress(text.encode()), "bomb.json.gz")
    assert path.stat().st_size < 20_000
    monkeypatch.setenv("MCTRACK_MAX_INPUT_BYTES", "1000000")
    with pytest.raises(InputError, match=r"bomb\.json\.gz: decompresses to more than 1000000"):
        read_baseversion(path)
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "MCTRACK_MAX_INPUT_BYTES" in err
    monkeypatch.setenv("MCTRACK_MAX_INPUT_BYTES", "5000000")
    assert len(read_baseversion(path)["s"]) == 1  # under the cap: read


def _corrupt_deflate() -> bytes:
    data = bytearray(gzip.compress(json.dumps({"s": [frame(0)] * 50}).encode()))
    data[30:60] = b"\xff" * 30
    return bytes(data)


def _far_pose(x: float, scale: float = 1.0) -> list[list[float]]:
    """A 4x4 pose translated by x along x (``scale``: its rotation part scaled)."""
    pose = np.eye(4)
    pose[:3, :3] *= scale
    pose[0, 3] = x
    return pose.tolist()


def _cameras(**poses: Any) -> dict[str, Any]:
    """A transform_matrix whose CAM_FRONT takes its extrinsics from ``poses`` (the frame's
    ``global2*`` and the camera's ``*2camera``), not from a global2camera."""
    camera = {k: v for k, v in CAM.items() if k != "global2camera"}
    camera |= {k: v for k, v in poses.items() if k.endswith("2camera")}
    frame_poses = {k: v for k, v in poses.items() if not k.endswith("2camera")}
    return {**frame_poses, "cameras_transform_matrix": {"CAM_FRONT": camera}}


def _posed(transform_matrix: dict[str, Any]) -> str:
    """A file of one frame with this ``transform_matrix``."""
    return json.dumps({"s": [frame(transform_matrix=transform_matrix)]})


def _box_text(x: str) -> str:
    return json.dumps(box(global_xyz=[0, 0, 0])).replace("[0, 0, 0]", f"[{x}, 0, 0]")


# the reproducers (1-9) and the schema's other refusals
MALFORMED: list[tuple[str, str | bytes, str]] = [
    ("deep nesting", '{"s":' + "[" * 100_000 + "]" * 100_000 + "}", "nested too deeply"),
    ("corrupt deflate", _corrupt_deflate(), "corrupt gzip"),
    (
        "singular global2ego",
        json.dumps({"s": [frame(transform_matrix={"global2ego": [[0] * 4] * 4})]}),
        "global2ego' is singular",
    ),
    (
        "track_id Infinity",
        json.dumps({"s": [frame(boxes=[box(track_id=float("inf"))])]}),
        "track_id",
    ),
    ("track_id 2^63", json.dumps({"s": [frame(boxes=[box(track_id=2**63)])]}), "track_id"),
    ("400-digit coordinate", '{"s":[{"frame_id":0,"bboxes":[{"x":' + "9" * 400 + "}]}]}", "digits"),
    ("5000-digit integer", '{"s":[{"frame_id":' + "1" * 5000 + ',"bboxes":[]}]}', "digits"),
    (
        "400-digit timestamp",
        '{"s":[{"frame_id":0,"timestamp":' + "9" * 400 + ',"bboxes":[]}]}',
        "digits",
    ),
    ("timestamp beyond 2^53", json.dumps({"s": [frame(timestamp=10**18)]}), "timestamp"),
    ("frame_id -1e308", '{"s":[{"frame_id":-1e308,"bboxes":[]}]}', "frame_id"),
    (
        "NaN in transform_matrix",
        '{"s":[{"frame_id":0,"transform_matrix":{"x":NaN},"bboxes":[]}]}',
        "transform_matrix.x",
    ),
    ("duplicate scene", '{"s":[], "s":[]}', "duplicate key 's'"),
    ("string in lwh", json.dumps({"s": [frame(boxes=[box(lwh=["2.5", 1, 1])])]}), "lwh"),
    ("bool in lwh", json.dumps({"s": [frame(boxes=[box(lwh=[2.5, False, True])])]}), "lwh"),
    ("float frame_id", json.dumps({"s": [frame(frame_id=1.0)]}), "frame_id"),
    ("string frame_id", json.dumps({"s": [frame(frame_id="1")]}), "frame_id"),
    ("token not a string", json.dumps({"s": [frame(cur_sample_token=5)]}), "cur_sample_token"),
    ("zero length", json.dumps({"s": [frame(boxes=[box(lwh=[0, 1.6, 1.5])])]}), "lwh"),
    ("zero width", json.dumps({"s": [frame(boxes=[box(lwh=[3.9, 0.0, 1.5])])]}), "lwh"),
    ("category not a string", json.dumps({"s": [frame(boxes=[box(category=3)])]}), "category"),
    ("score true", json.dumps({"s": [frame(boxes=[box(detection_score=True)])]}), "score"),
    ("not UTF-8", b'{"s\xff": []}', "UTF-8"),
    ("1e400 coordinate", '{"s":[{"frame_id":0,"bboxes":[' + _box_text("1e400") + "]}]}", "xyz"),
    # finite, but beyond any place on Earth: its squares overflowed downstream
    (
        "1e300 coordinate",
        json.dumps({"s": [frame(boxes=[box(), box(global_xyz=[1e300, 0, 0.8])])]}),
        "frame index 0, box 1: field 'global_xyz' = [1e+300, 0.0, 0.8]: beyond ±1e+08 m",
    ),
    (
        "1e300 size",
        json.dumps({"s": [frame(boxes=[box(lwh=[3.9, 1.6, 1e300])])]}),
        "box 0: field 'lwh' = [3.9, 1.6, 1e+300]: beyond ±1e+08 m",
    ),
    # a velocity (detection or ground truth) at 1e300 m/s: finite, but it overflowed downstream
    (
        "1e300 velocity",
        json.dumps({"s": [frame(boxes=[box(), box(global_velocity=[0.5, 1e300])])]}),
        "box 1: field 'global_velocity' = [0.5, 1e+300]: beyond ±10000 m/s (faster than",
    ),
    # a pose at 1e300 m: the ego (ranges, score calibration) or a camera (projections) there
    (
        "1e300 global2ego",
        _posed({"global2ego": _far_pose(1e300)}),
        "frame index 0: field 'global2ego' has translation [1e+300, 0.0, 0.0]: beyond ±1e+08 m",
    ),
    (
        "nearly singular global2ego",  # (its inverse: the ego 2^31 m out)
        _posed({"global2ego": _far_pose(1.0, scale=2**-31)}),
        "field 'global2ego' puts the ego at [-2147483648.0, ",
    ),
    (
        "1e300 global2camera",
        _posed(_cameras(global2camera=_far_pose(-2e8))),
        "field 'transform_matrix.cameras_transform_matrix.CAM_FRONT.global2camera' has "
        "translation [-200000000.0, 0.0, 0.0]: beyond ±1e+08 m",
    ),
    (
        "1e300 global2lidar",
        _posed(_cameras(global2lidar=_far_pose(1e300), lidar2camera=_far_pose(0.0))),
        "field 'global2lidar' has translation [1e+300, 0.0, 0.0]: beyond ±1e+08 m",
    ),
    (
        "a chain beyond the bound",  # (each pose within it)
        _posed(_cameras(global2ego=_far_pose(9e7), ego2camera=_far_pose(9e7))),
        "field 'transform_matrix.cameras_transform_matrix.CAM_FRONT': camera_from_world has "
        "translation [180000000.0, 0.0, 0.0]: beyond ±1e+08 m",
    ),
]


def test_the_box_bound_per_row() -> None:
    """tracker.io.bounds.beyond_bound: per row of (N, k) or (N,), inf beyond, NaN not (refused as
    not finite elsewhere, or an unknown velocity), no rows no error (a frame without boxes, an
    empty label file); the velocity bound is a bound of its own."""
    from tracker.io.bounds import MAX_BOX_METRES, MAX_SPEED_MPS, beyond_bound

    rows = np.array([[0.0, -MAX_BOX_METRES], [1.0, -2e8], [np.inf, 0.0], [np.nan, 0.0]])
    assert beyond_bound(rows).tolist() == [False, True, True, False]
    assert beyond_bound(rows[:, 1]).tolist() == [False, True, False, False]
    assert beyond_bound(np.zeros((0, 3))).shape == beyond_bound(np.zeros(0)).shape == (0,)
    # velocities: their own bound (NaN: unknown, not beyond)
    speeds = np.array([[MAX_SPEED_MPS, -MAX_SPEED_MPS], [0.0, 1.5e4], [np.nan, np.nan]])
    assert beyond_bound(speeds, MAX_SPEED_MPS).tolist() == [False, True, False]


@pytest.mark.parametrize(("case", "text", "expected"), MALFORMED, ids=[c[0] for c in MALFORMED])
def test_malformed_input_is_one_clean_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str, text: str | bytes, expected: str
) -> None:
    name = "in.json.gz" if case == "corrupt deflate" else "in.json"
    path = write_text(tmp_path, text, name)
    with pytest.raises(InputError) as info:
        read_baseversion(path)
    assert str(path) in str(info.value) and expected in str(info.value)
    assert not validate_baseversion(path).ok
    assert main(["validate", str(path)]) == 2
    assert main(["track", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 2 and "Traceback" not in err  # one line per command
    assert not (tmp_path / "out" / "tracks.json").exists()


def test_validate_collects_every_error_up_to_the_cap(tmp_path: Path) -> None:
    frames = [frame(i, boxes=[box(lwh=[0, 1, 1]), box(), box(global_yaw="x")]) for i in range(30)]
    path = write_text(tmp_path, json.dumps({"s": frames, "t": 5}))
    result = validate_baseversion(path, max_errors=10)
    assert result.error_count == 61  # two bad boxes in each of 30 frames, and scene t
    assert len(result.errors) == 10
    assert "frame index 0, box 0: field 'lwh'" in result.errors[0]
    assert "frame index 0, box 2: field 'global_yaw'" in result.errors[1]


def test_frames_losing_their_camera_model_track_and_write(tmp_path: Path) -> None:
    """Found by the slow property suite: a coasting track keeps the camera index of the frame it
    was last matched in; a later frame without camera models must still be written."""
    path = write_text(tmp_path, json.dumps({"s": [frame(0, transform_matrix=None)]}))
    plain = read_baseversion(path)["s"][0]
    assert not plain.cameras
    coasting = dataclasses.replace(plain, boxes=plain.boxes.replace(camera=np.array([0])))
    assert frame_to_dict(coasting)["bboxes"][0]["bbox_image"]["camera_type"] is None


# ---------------------------------------------------------------------------------------------
# --out checked before any work


def test_bad_out_fails_before_any_work(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("x")
    for out in (a_file, a_file / "sub"):
        assert main(["track", str(SAMPLE), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(out) in err
    assert a_file.read_text() == "x"


def test_kitti_results_without_camera_is_refused_before_tracking(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_text(tmp_path, json.dumps({"s": [frame(0, transform_matrix=None)]}))
    assert main(["track", str(path), "--out", str(tmp_path / "o"), "--kitti-results"]) == 2
    assert "CAM_FRONT camera model" in capsys.readouterr().err
    assert not (tmp_path / "o" / "tracks.json").exists()


# ---------------------------------------------------------------------------------------------
# partial outputs


def test_stranded_temp_of_a_dead_run_is_removed(tmp_path: Path) -> None:
    dead_pid = 2**22 + 12345  # above the default pid_max: no such process
    stranded = tmp_path / f".tracks.json.{dead_pid}.abc123.tmp"
    stranded.write_bytes(b"half a file")
    live = tmp_path / f".tracks.json.{os.getpid()}.def456.tmp"
    live.write_bytes(b"being written")
    write_bytes_atomic(tmp_path / "x.json", b"{}")
    assert not stranded.exists() and live.exists()
    assert remove_stale_temps(tmp_path, older_than_secs=-1) == 0  # a live run's temp stays
    assert sorted(p.name for p in tmp_path.iterdir()) == [live.name, "x.json"]


def test_an_old_temp_of_a_live_run_is_kept_and_one_without_a_pid_goes(tmp_path: Path) -> None:
    # mctrack view holds each finished recording under its temporary name until the last
    # scene is recorded: a run over an hour must not lose its first scene's recording
    long_ago = time.time() - 2 * 3600
    held = tmp_path / f".0001.rrd.{os.getpid()}.abc12345.tmp"
    held.write_bytes(b"a finished recording")
    no_pid = tmp_path / ".0001.rrd.tmp"  # not one of our names: only its age tells
    no_pid.write_bytes(b"?")
    fresh = tmp_path / ".0002.rrd.tmp"
    fresh.write_bytes(b"?")
    for p in (held, no_pid):
        os.utime(p, (long_ago, long_ago))
    write_bytes_atomic(tmp_path / "x.json", b"{}")  # removes the stale temps of its folder
    assert held.read_bytes() == b"a finished recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == [held.name, fresh.name, "x.json"]


# ---------------------------------------------------------------------------------------------
# every detection has exactly one fate


@pytest.mark.parametrize("config_name", ["kitti", "kitti_offline", "kitti_reference"])
def test_every_detection_has_one_fate(config_name: str) -> None:
    config = load_config(config_name)
    scenes = read_baseversion(SAMPLE, fallback_frame_rate_hz=config.frame_rate_hz)
    frames = scenes["0001"][:150]
    fates = FateCounter(rv_gate_consumes=config.rv_reference)
    observed = run_scene(frames, config, observer=fates)
    plain = run_scene(frames, config)
    summary = fates.summary()
    n_input = sum(len(f.boxes) for f in frames)
    assert summary["detections"] == n_input
    assert sum(summary["per_fate"].values()) == n_input
    per_class = summary["per_fate_and_class"]
    assert sum(n for d in per_class.values() for n in d.values()) == n_input
    assert all(
        per_class[f] and sum(per_class[f].values()) == n
        for f, n in summary["per_fate"].items()
        if n
    )
    # the fates agree with the tracker's output: born = new track ids, matched rows are output
    ids = {int(t) for o in plain.outputs for t in o.boxes.track_id}
    if config.mode.value == "online":
        assert summary["per_fate"]["born"] >= len(ids)
    matched = summary["per_fate"]["matched_bev"] + summary["per_fate"]["matched_rv"]
    assert matched > 0 and summary["per_fate"]["born"] > 0
    # counting changes nothing
    for a, b in zip(observed.outputs, plain.outputs, strict=True):
        np.testing.assert_array_equal(a.boxes.track_id, b.boxes.track_id)
        np.testing.assert_array_equal(a.boxes.xyz, b.boxes.xyz)


def test_track_prints_and_stores_the_fates(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="tracker.pipeline")
    out = tmp_path / "o"
    args = ["track", str(SAMPLE), "--out", str(out), "--frames", "0:100"]
    assert main([*args, "--config", "kitti_offline"]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    fates = summary["detection_fates"]
    assert f"detections {fates['detections']}: " in printed
    assert sum(fates["per_fate"].values()) == fates["detections"] == fates["input_boxes"]
    removed = summary["offline_removed"]
    assert removed["tracks"] > 0 and f"removed {removed['tracks']} tracks" in printed
    assert "offline post-processing removed" in caplog.text
    assert summary["complete"] and summary["outputs"][0]["path"] == "tracks.json"
    assert summary["outputs"][0]["bytes"] == (out / "tracks.json").stat().st_size


def test_pickle_is_not_used_on_input_paths() -> None:
    root = Path(__file__).resolve().parents[1]
    for py in [*root.glob("tracker/**/*.py"), *root.glob("app/*.py")]:
        text = py.read_text()
        assert "allow_pickle=True" not in text, py
        assert "pickle.load(" not in text and "pickle.loads(" not in text, py
    assert pickle  # the test module itself builds the malicious payload


def test_view_save_renames_a_complete_recording(tmp_path: Path) -> None:
    pytest.importorskip("rerun")
    path = tmp_path / "rec" / "x.rrd"
    args = ["view", str(SAMPLE), "--frames", "0:5", "--save", str(path), "--no-motion"]
    assert main(args) == 0
    assert [p.name for p in path.parent.iterdir()] == ["x.rrd"]  # no temporary file left
    assert path.stat().st_size > 10_000


def test_path_in_takes_a_linked_file_and_refuses_a_name_that_leaves(tmp_path: Path) -> None:
    from tracker.io.fileio import path_in

    (tmp_path / "elsewhere.txt").write_text("x")
    (tmp_path / "labels").mkdir()
    (tmp_path / "labels" / "0006.txt").symlink_to(tmp_path / "elsewhere.txt")
    assert path_in(tmp_path / "labels", "0006", ".txt").read_text() == "x"
    for name in ("../0006", "..", "a/b"):
        assert path_in(tmp_path / "labels", name, ".txt").parent == tmp_path / "labels"
