"""The BaseVersion loader's contract, property-tested (issue #15).

For any document (valid ones, valid ones with one hostile edit, and corrupted bytes):

* ``read_baseversion`` returns or raises an ``InputError`` naming the file, never another
  exception;
* ``validate_baseversion`` never raises, and accepts exactly what ``read_baseversion`` accepts;
* what is accepted, the tracker processes to the end and the writers write (tracks file, KITTI
  results when the frames have a camera model): ``validate`` OK means ``track`` succeeds.

A fast subset runs by default; ``pytest -m slow tests/test_loader_properties.py`` runs 10,000
hostile cases (5,000 edited documents, 5,000 corrupted files; docs/reliability.md).
"""

from __future__ import annotations

import copy
import gzip
import json
import math
import random
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from tracker.config import load_config
from tracker.errors import InputError
from tracker.eval.fates import FateCounter
from tracker.frame import Frame
from tracker.io.baseversion import read_baseversion, validate_baseversion
from tracker.io.writers import write_kitti_sequence, write_tracks_file
from tracker.mctracker import MCTracker
from tracker.pipeline import SceneResult

FAST = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow], database=None
)
# 5,000 cases of each of the two hostile kinds: 10,000 in the slow run
SLOW = settings(
    max_examples=5_000, deadline=None, suppress_health_check=list(HealthCheck), database=None
)
CONFIG = load_config("kitti")
CATEGORIES = ["car", "pedestrian", "cyclist", "van", "bicycle", "traffic_cone", "Tram"]
CAM = {
    "image_shape": [1242, 375],
    "camera2image": [[721.5, 0, 609.6, 44.9], [0, 721.5, 172.9, 0.2], [0, 0, 1, 0.003]],
    "global2camera": [[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]],
}

finite = st.floats(-200, 200, allow_nan=False, allow_infinity=False)
positive = st.floats(0.05, 20, allow_nan=False)


@st.composite
def boxes(draw: st.DrawFn) -> dict[str, Any]:
    b: dict[str, Any] = {
        "category": draw(st.sampled_from(CATEGORIES)),
        "detection_score": draw(st.floats(0, 1)),
        "global_xyz": [draw(finite), draw(finite), draw(st.floats(-3, 3))],
        "lwh": [draw(positive), draw(positive), draw(positive)],
        "global_yaw": draw(st.floats(-10, 10)),
    }
    if draw(st.booleans()):
        b["global_velocity"] = [draw(st.floats(-30, 30)), draw(st.floats(-30, 30))]
    if draw(st.booleans()):
        x1, y1 = draw(st.floats(0, 1200)), draw(st.floats(0, 370))
        b["bbox_image"] = {
            "camera_type": draw(st.sampled_from(["CAM_FRONT", None, "CAM_OTHER"])),
            "x1y1x2y2": [x1, y1, x1 + draw(positive), y1 + draw(positive)],
        }
    if draw(st.booleans()):
        b["track_id"] = draw(st.integers(0, 10_000))
    if draw(st.booleans()):
        b["detection_score_raw"] = draw(st.floats(-20, 20))
    return b


@st.composite
def documents(draw: st.DrawFn) -> dict[str, Any]:
    doc: dict[str, Any] = {}
    names = draw(
        st.lists(
            st.sampled_from(["0001", "scene-0103", "a/b", "..", "x y", "é"]),
            min_size=1,
            max_size=2,
            unique=True,
        )
    )
    for name in names:
        n_frames = draw(st.integers(1, 3))
        start = draw(st.integers(0, 5))
        with_camera = draw(st.booleans())
        frames = []
        for i in range(n_frames):
            frame: dict[str, Any] = {
                "frame_id": start + i,
                "timestamp": draw(st.sampled_from([None, (start + i) * 100_000])),
                "cur_sample_token": draw(st.sampled_from([None, "tok"])),
                # CAM_OTHER: a camera listed without a model (its boxes get no camera); without
                # a camera list, a box's camera_type is not checked
                "transform_matrix": {
                    "cameras_transform_matrix": {"CAM_FRONT": CAM, "CAM_OTHER": {}}
                }
                if with_camera
                else None,
                "bboxes": draw(st.lists(boxes(), max_size=3)),
            }
            frames.append(frame)
        doc[name] = frames
    return doc


def _random_document(seed: int) -> dict[str, Any]:
    """A valid document from a seed: the same shapes as ``documents()``, built without
    hypothesis' per-value draws (ten times faster), for the hostile strategies below."""
    rng = random.Random(seed)
    doc: dict[str, Any] = {}
    for name in rng.sample(["0001", "scene-0103", "a/b", "..", "x y", "é"], rng.randint(1, 2)):
        start, with_camera = rng.randint(0, 5), rng.random() < 0.5
        frames = []
        for i in range(rng.randint(1, 3)):
            bboxes = []
            for _ in range(rng.randint(0, 3)):
                b: dict[str, Any] = {
                    "category": rng.choice(CATEGORIES),
                    "detection_score": rng.random(),
                    "global_xyz": [rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-3, 3)],
                    "lwh": [rng.uniform(0.05, 20) for _ in range(3)],
                    "global_yaw": rng.uniform(-10, 10),
                }
                if rng.random() < 0.5:
                    b["global_velocity"] = [rng.uniform(-30, 30), rng.uniform(-30, 30)]
                if rng.random() < 0.5:
                    x1, y1 = rng.uniform(0, 1200), rng.uniform(0, 370)
                    b["bbox_image"] = {
                        "camera_type": rng.choice(["CAM_FRONT", None, "CAM_OTHER"]),
                        "x1y1x2y2": [x1, y1, x1 + rng.uniform(1, 50), y1 + rng.uniform(1, 50)],
                    }
                if rng.random() < 0.5:
                    b["track_id"] = rng.randint(0, 10_000)
                bboxes.append(b)
            frames.append(
                {
                    "frame_id": start + i,
                    "timestamp": rng.choice([None, (start + i) * 100_000]),
                    "cur_sample_token": rng.choice([None, "tok"]),
                    # a copy: the edits below change documents in place
                    "transform_matrix": {
                        "cameras_transform_matrix": {
                            "CAM_FRONT": copy.deepcopy(CAM),
                            "CAM_OTHER": {},
                        }
                    }
                    if with_camera
                    else None,
                    "bboxes": bboxes,
                }
            )
        doc[name] = frames
    return doc


seeded_documents = st.builds(_random_document, st.integers(0, 2**32))


HOSTILE_TEXT = ["", "\x00", "\ud800", "../../x", "/abs", "NaN", "1e999", "🚗", "a" * 300]
json_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.sampled_from([0, -1, 2**53 + 1, 2**63, -(2**63) - 1]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e308, -1e308, 5e-324, 1.5]),
    st.text(max_size=8),
    st.sampled_from(HOSTILE_TEXT),
)
json_values = st.recursive(
    json_scalars,
    lambda children: st.one_of(
        st.lists(children, max_size=5), st.dictionaries(st.text(max_size=5), children, max_size=4)
    ),
    max_leaves=12,
)


def _locations(value: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [path]
    if isinstance(value, dict):
        for k, v in value.items():
            out += _locations(v, (*path, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            out += _locations(v, (*path, i))
    return out


@st.composite
def edited_documents(draw: st.DrawFn) -> dict[str, Any]:
    """A valid document with one hostile edit at any location (replace, delete, add)."""
    doc = draw(seeded_documents)  # a fresh object per draw: edited in place
    for _ in range(draw(st.integers(1, 2))):
        locations = _locations(doc)[1:]
        if not locations:  # the first edit emptied the document
            break
        where = draw(st.sampled_from(locations))
        parent: Any = doc
        for key in where[:-1]:
            parent = parent[key]
        key = where[-1]
        action = draw(st.sampled_from(["replace", "replace", "delete", "add", "numeric"]))
        if action == "replace":
            parent[key] = draw(json_values)
        elif action == "delete":
            del parent[key]
        elif action == "add" and isinstance(parent, dict):
            parent[draw(st.sampled_from([*HOSTILE_TEXT, "track_id", "status", "x"]))] = draw(
                json_values
            )
        elif action == "numeric" and isinstance(parent[key], int | float):
            parent[key] = draw(
                st.sampled_from([math.nan, math.inf, -math.inf, 0, -1, 2**64, 1e300, True, "1"])
            )
    return doc


def _dump(doc: dict[str, Any]) -> bytes:
    return json.dumps(doc).encode("utf-8", "surrogatepass")


@st.composite
def corrupted_bytes(draw: st.DrawFn) -> tuple[bytes, bool]:
    """(file bytes, gzip?): a valid document's text with byte-level damage."""
    raw = _dump(draw(seeded_documents))
    kind = draw(
        st.sampled_from(
            ["truncate", "insert", "flip", "nest", "bigint", "dupkey", "gz-corrupt", "gz-trunc"]
        )
    )
    pos = draw(st.integers(0, len(raw)))
    if kind == "truncate":
        raw = raw[:pos]
    elif kind == "insert":
        raw = raw[:pos] + draw(st.binary(min_size=1, max_size=4)) + raw[pos:]
    elif kind == "flip" and raw:
        i = min(pos, len(raw) - 1)
        raw = raw[:i] + bytes([raw[i] ^ draw(st.integers(1, 255))]) + raw[i + 1 :]
    elif kind == "nest":
        depth = draw(st.sampled_from([50, 900, 5000, 200_000]))
        raw = b'{"s":' + b"[" * depth + b"]" * depth + b"}"
    elif kind == "bigint":
        digits = draw(st.sampled_from([20, 400, 5000]))
        raw = raw.replace(b'"frame_id": ', b'"frame_id": ' + b"9" * digits, 1)
    elif kind == "dupkey":
        raw = raw.replace(b'"bboxes": ', b'"bboxes": [], "bboxes": ', 1)
    gz = kind.startswith("gz")
    if gz:
        raw = gzip.compress(raw, mtime=0)
        i = min(max(pos, 12), len(raw) - 1)
        if kind == "gz-corrupt":
            raw = raw[:i] + bytes([raw[i] ^ 0x5A]) + raw[i + 1 :]
        else:
            raw = raw[:i]
    return raw, gz


_TRACKER: list[MCTracker] = []


def _run(frames: list[Frame], fates: FateCounter) -> SceneResult:
    """run_scene's loop with one reused tracker (building one costs more than tracking here)."""
    if not _TRACKER:
        _TRACKER.append(MCTracker(CONFIG))
    tracker = _TRACKER[0]
    tracker.reset()
    tracker.observer = fates
    return SceneResult("", [tracker.step(f) for f in frames], 0.0)


def check_contract(raw: bytes, gz: bool = False) -> bool:
    """The loader's contract on one file; returns whether the file was accepted."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / ("in.json.gz" if gz else "in.json")
        path.write_bytes(raw)
        result = validate_baseversion(path, max_errors=5, fallback_frame_rate_hz=10.0)
        assert result.error_count >= len(result.errors)
        assert all(str(path) in e for e in result.errors)
        try:
            scenes = read_baseversion(path, fallback_frame_rate_hz=10.0)
        except InputError as exc:
            assert str(path) in str(exc)
            assert not result.ok, "validate accepted a file read_baseversion refuses"
            assert str(exc) == result.errors[0]  # the same first error
            event("refused with an InputError")
            return False
        assert result.ok, f"validate refused a readable file: {result.errors}"
        # accepted: the tracker and the writers get to the end
        out = Path(tmp) / "out"
        fates = FateCounter()
        results = {s: _run(f, fates) for s, f in scenes.items()}
        write_tracks_file(out / "tracks.json", {s: (scenes[s], results[s].outputs) for s in scenes})
        for s, frames in scenes.items():
            if all(f.camera_index("CAM_FRONT") >= 0 for f in frames):
                write_kitti_sequence(out / "data" / "x.txt", results[s].outputs, frames)
        total = sum(len(f.boxes) for fr in scenes.values() for f in fr)
        assert sum(fates.summary()["per_fate"].values()) == total
        read_baseversion(out / "tracks.json")  # the output is valid input
        event("accepted, tracked and written")
        return True


@FAST
@given(documents())
def test_valid_documents_are_accepted_and_tracked(doc: dict[str, Any]) -> None:
    assert check_contract(_dump(doc))


@FAST
@given(edited_documents())
def test_edited_documents_give_input_errors_only(doc: dict[str, Any]) -> None:
    check_contract(_dump(doc))


@FAST
@given(corrupted_bytes())
def test_corrupted_bytes_give_input_errors_only(case: tuple[bytes, bool]) -> None:
    check_contract(*case)


@pytest.mark.slow
@SLOW
@given(edited_documents())
def test_slow_edited_documents(doc: dict[str, Any]) -> None:
    check_contract(_dump(doc))


@pytest.mark.slow
@SLOW
@given(corrupted_bytes())
def test_slow_corrupted_bytes(case: tuple[bytes, bool]) -> None:
    check_contract(*case)
