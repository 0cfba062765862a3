"""The debug recording, read back from a real .rrd with rerun.chunk.RrdReader.

One recording per session (frames 0-199 of the sample, the reference config, which has ID switches
there), written by the same function `mctrack demo` / `view` use. Every entity path of the
contract must exist; the logged track ids and velocity curves must be the tracker's own output,
and that output must equal a run without observer; the recorded ID switches and fragmentations
must be as many as TrackEval counts on the same frames.
"""

from __future__ import annotations

import atexit
import functools
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest

from tracker.config import load_config
from tracker.io.baseversion import read_baseversion
from tracker.pipeline import run_scene
from viz import paths
from viz.record import RecordResult, record_scene

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"
FRAMES = slice(0, 200)
CONFIG = "kitti_reference"  # the tuned config has no ID switch on this sequence


@functools.cache
def sample_frames() -> tuple[list, list]:
    if not (SAMPLE / "detections.json.gz").is_file():
        pytest.skip(f"sample data missing in {SAMPLE}")
    det = read_baseversion(SAMPLE / "detections.json.gz", fallback_frame_rate_hz=10.0)["0001"]
    gt = read_baseversion(SAMPLE / "gt.json.gz", fallback_frame_rate_hz=10.0)["0001"]
    return det[FRAMES], gt[FRAMES]


@functools.cache
def recording() -> tuple[Path, RecordResult]:
    """(path, RecordResult) of the session's recording (cached: shared by the viz test modules)."""
    det, gt = sample_frames()
    folder = Path(tempfile.mkdtemp(prefix="mctrack-test-viz-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    path = folder / "sample.rrd"
    result = record_scene(
        det,
        load_config(CONFIG),
        gt,
        path,
        labels_dir=SAMPLE / "raw" / "training" / "label_02",
        images={"CAM_FRONT": SAMPLE / "image_02"},
        input_description="test",
        motion_metrics=False,
    )
    return path, result


@pytest.fixture(scope="module")
def rrd() -> Path:
    return recording()[0]


@pytest.fixture(scope="module")
def result() -> RecordResult:
    return recording()[1]


def entity_table(path: Path, entity: str, *, static: bool = False) -> pa.Table:
    from rerun.chunk import RrdReader

    chunks = (
        RrdReader(str(path))
        .stream()
        .filter(content=paths.entity(entity), is_static=static)
        .to_chunks()
    )
    tables = [pa.Table.from_batches([c.to_record_batch()]) for c in chunks]
    assert tables, f"{entity}: nothing recorded"
    table = pa.concat_tables(tables, promote_options="default")
    return table if static else table.sort_by(paths.FRAME)


def entity_paths(path: Path) -> set[str]:
    from rerun.chunk import RrdReader

    return {c.entity_path for c in RrdReader(str(path)).stream().to_chunks()}


def column_at(table: pa.Table, column: str, frame: int) -> list:
    rows = table.filter(pc.equal(table[paths.FRAME], frame))
    values = [v for v in rows[column].to_pylist() if v is not None]
    assert values, f"{column}: no row at frame {frame}"
    return values[-1]


# ---------------------------------------------------------------------------------------------


def test_every_contract_path_exists(rrd: Path, result: RecordResult) -> None:
    cam = "CAM_FRONT"
    some_track = result.track_ids[0]
    series_track = next(
        t for t in result.track_ids if sum(t in o.boxes.track_id for o in result.outputs) >= 3
    )
    expected = [
        paths.DETECTIONS_RAW,
        paths.DETECTIONS_KEPT,
        paths.TRACKS_PREDICTED,
        paths.TRACKS_UPDATED,
        paths.TRACKS_VELOCITY,
        paths.TRAILS,
        paths.EGO,
        paths.EGO_PATH,
        paths.GT,
        paths.MATCHES_BEV,
        paths.UNMATCHED_TRACKS,
        paths.UNMATCHED_DETECTIONS,
        paths.COST_BEV,
        paths.COST_RV,
        paths.camera(cam),
        paths.camera_image(cam),
        paths.camera_detections(cam),
        paths.camera_tracks(cam),
        paths.camera_matches_rv(cam),
        paths.EVENTS,
        paths.EVENTS_LIFECYCLE,
        paths.ID_SWITCH_MARKERS,
        paths.SUMMARY,
        paths.SHOT_INDEX,
        *(paths.track_series(series_track, s) for s in paths.SERIES),
    ]
    present = entity_paths(rrd)
    missing = [p for p in expected if paths.entity(p) not in present]
    assert not missing, missing
    assert some_track in result.track_ids
    # the matched GT's curves exist for some track
    assert any(p.endswith("/" + paths.GT_PREFIX + paths.SPEED) for p in present)


def test_blueprint_is_embedded(rrd: Path) -> None:
    from rerun.chunk import RrdReader

    reader = RrdReader(str(rrd))
    assert len(reader.blueprints()) >= 1
    assert reader.recordings()[0].application_id == paths.APPLICATION_ID


def test_observing_does_not_change_the_output(result: RecordResult) -> None:
    det, _ = sample_frames()
    plain = run_scene(det, load_config(CONFIG)).outputs
    assert len(plain) == len(result.outputs)
    for a, b in zip(plain, result.outputs, strict=True):
        assert a.frame_id == b.frame_id
        assert a.boxes.equals(b.boxes)
        np.testing.assert_array_equal(a.status, b.status)


@pytest.mark.parametrize("frame", [10, 120])
def test_updated_tracks_hold_the_output_ids(rrd: Path, result: RecordResult, frame: int) -> None:
    table = entity_table(rrd, paths.TRACKS_UPDATED)
    labels = column_at(table, "Boxes3D:labels", frame)
    out = next(o for o in result.outputs if o.frame_id == frame)
    assert [int(x) for x in labels] == out.boxes.track_id.tolist()
    centers = np.array(column_at(table, "Boxes3D:centers", frame))
    np.testing.assert_allclose(centers, out.boxes.xyz, rtol=0, atol=1e-4)  # float32


def test_velocity_series_equal_the_output(rrd: Path, result: RecordResult) -> None:
    counts: dict[int, int] = {}
    for o in result.outputs:
        for t in o.boxes.track_id.tolist():
            counts[t] = counts.get(t, 0) + 1
    track = max(counts, key=lambda t: (counts[t], -t))  # the longest track
    rows = [(o.frame_id, o.boxes[o.boxes.track_id == track]) for o in result.outputs]
    rows = [(f, b) for f, b in rows if len(b)]
    expected_frames = [f for f, _ in rows]
    vx = np.array([b.velocity[0, 0] for _, b in rows])
    vy = np.array([b.velocity[0, 1] for _, b in rows])
    for series, values in (
        (paths.VELOCITY_X, vx),
        (paths.VELOCITY_Y, vy),
        (paths.SPEED, np.hypot(vx, vy)),
        (paths.HEADING, np.array([b.yaw[0] for _, b in rows])),
    ):
        table = entity_table(rrd, paths.track_series(track, series))
        assert table[paths.FRAME].to_pylist() == expected_frames
        got = pc.list_flatten(table["Scalars:scalars"]).to_numpy()
        np.testing.assert_allclose(got, values, rtol=1e-12, atol=1e-12)


def test_acceleration_series_for_ca_tracks_only(rrd: Path, tmp_path: Path) -> None:
    """The filtered acceleration is logged per track when its motion model has one (CA, the
    tuned KITTI config); the reference config's CV tracks get no acceleration curve."""
    assert not any(p.endswith("/" + paths.ACCELERATION_X) for p in entity_paths(rrd))
    det, _ = sample_frames()
    out = record_scene(det[:60], load_config("kitti"), None, tmp_path / "ca.rrd")
    track = max(
        {t for o in out.outputs for t in o.boxes.track_id.tolist()},
        key=lambda t: (sum(int((o.boxes.track_id == t).sum()) for o in out.outputs), -t),
    )
    rows = [
        (o.frame_id, o.acceleration[o.boxes.track_id == track][0])
        for o in out.outputs
        if (o.boxes.track_id == track).any()
    ]
    acc = np.array([a for _, a in rows])
    assert np.isfinite(acc).all() and np.abs(acc).max() > 0
    for series, values in ((paths.ACCELERATION_X, acc[:, 0]), (paths.ACCELERATION_Y, acc[:, 1])):
        table = entity_table(tmp_path / "ca.rrd", paths.track_series(track, series))
        assert table[paths.FRAME].to_pylist() == [f for f, _ in rows]
        got = pc.list_flatten(table["Scalars:scalars"]).to_numpy()
        np.testing.assert_allclose(got, values, rtol=1e-12, atol=1e-12)


def test_noise_series_is_the_filters_r(rrd: Path, tmp_path: Path) -> None:
    """A config with ``pose.r_scale`` (the tuned KITTI one) records the position filter's r per
    class and frame, as the tracker's NoiseEstimated events give it: the config's r until the
    detections' noise is estimated, then r_scale x the estimate. The reference config (a fixed
    r) records none."""
    from tracker.categories import category_index
    from tracker.events import ListObserver, NoiseEstimated

    assert not any(p.startswith(paths.entity(paths.NOISE)) for p in entity_paths(rrd))
    det, _ = sample_frames()
    config = load_config("kitti")
    record_scene(det[:60], config, None, tmp_path / "noise.rrd")
    events = ListObserver()
    run_scene(det[:60], config, observer=events)
    car = category_index("car")
    want = np.array([e.r[car] for e in events.of_type(NoiseEstimated)])
    table = entity_table(tmp_path / "noise.rrd", f"{paths.NOISE}/car")
    assert table[paths.FRAME].to_pylist() == [f.frame_id for f in det[:60]]
    got = pc.list_flatten(table["Scalars:scalars"]).to_numpy()
    np.testing.assert_allclose(got, want, rtol=1e-12)
    pose = config.per_category["car"].pose
    assert got[0] == pose.ca.r[0]  # no estimate in the first frame
    assert np.unique(got).size > 3 and (got[-10:] != pose.ca.r[0]).all()


def test_gate_series_is_the_distance_gate_in_effect(tmp_path: Path) -> None:
    """With ``bev.gate_motion_m`` (the tuned KITTI pedestrians) the recording holds the BEV
    distance gate's radius per frame, as the tracker's NoiseEstimated events give it: the
    config's 10 m until the pedestrians' noise is estimated, then sqrt(gate_motion_m² + (4σ)²);
    cars (no motion gate) have no series."""
    from tracker.categories import category_index
    from tracker.events import ListObserver, NoiseEstimated

    det, _ = sample_frames()
    config = load_config("kitti")
    record_scene(det, config, None, tmp_path / "gate.rrd")
    events = ListObserver()
    run_scene(det, config, observer=events)
    ped = category_index("pedestrian")
    want = np.array([e.gate_m[ped] for e in events.of_type(NoiseEstimated)])
    table = entity_table(tmp_path / "gate.rrd", f"{paths.GATE}/pedestrian")
    got = pc.list_flatten(table["Scalars:scalars"]).to_numpy()
    np.testing.assert_allclose(got, want, rtol=1e-12)
    bev = config.per_category["pedestrian"].bev
    assert got[0] == bev.gate_distance_m  # no estimate in the first frame
    assert bev.gate_motion_m < got[-1] < 2 * bev.gate_motion_m  # estimated: about 1 m
    assert not any(
        p.startswith(f"{paths.entity(paths.GATE)}/car") for p in entity_paths(tmp_path / "gate.rrd")
    )


def test_recorded_id_events_equal_trackeval(rrd: Path, result: RecordResult) -> None:
    """The WARN events in the recording are as many as TrackEval's IDSW and Frag."""
    table = entity_table(rrd, paths.EVENTS)
    levels = table["TextLog:level"].to_pylist()
    texts = table["TextLog:text"].to_pylist()
    warn = [t[0] for t, lv in zip(texts, levels, strict=True) if lv and lv[0] == "WARN"]
    # "#K IDSW f<frame> <class> GT<id> T<old>->T<new>: <cause> (evidence)"
    switches = [t for t in warn if t.split(" ")[1] == "IDSW"]
    frags = [t for t in warn if t.split(" ")[1] == "Frag"]
    metrics = result.kitti_metrics  # evaluate_kitti (TrackEval's own counting), same frames
    assert len(switches) == sum(m["IDSW"] for m in metrics.values())
    assert len(frags) == sum(m["Frag"] for m in metrics.values())
    assert len(switches) > 0, "the reference config should switch ids on frames 0-199"
    # and the shot index lists the same frames
    index = entity_table(rrd, paths.SHOT_INDEX, static=True)
    frames = index["id_switch_frames"].to_pylist()[-1]
    assert frames == [e.frame_id for e in result.id_evaluation.id_switches]
    assert sorted({int(t.split(" ")[2][1:]) for t in switches}) == sorted(set(frames))


def test_id_switch_markers_sit_at_the_objects(rrd: Path, result: RecordResult) -> None:
    event = result.id_evaluation.id_switches[0]
    table = entity_table(rrd, paths.ID_SWITCH_MARKERS)
    labels = column_at(table, "Points3D:labels", event.frame_id)
    assert any(f"GT{event.gt_id}:" in label for label in labels)
    _, gt = sample_frames()
    gt_frame = next(f for f in gt if f.frame_id == event.frame_id)
    xyz = gt_frame.boxes.xyz[gt_frame.boxes.track_id == event.gt_id][0]
    positions = np.array(column_at(table, "Points3D:positions", event.frame_id))
    assert np.min(np.linalg.norm(positions[:, :2] - xyz[:2], axis=1)) < 0.01


def test_cost_matrix_rows_and_columns_are_labelled(rrd: Path) -> None:
    """Every row and column of a small matrix is labelled; of a large one every k-th (see
    tests/test_viz.py::test_cost_labels_never_overlap)."""
    labels = entity_table(rrd, f"{paths.COST_BEV}/{paths.COST_LABELS}")
    image = entity_table(rrd, paths.COST_BEV)
    seen = set()
    formats = dict(
        zip(image[paths.FRAME].to_pylist(), image["Image:format"].to_pylist(), strict=True)
    )
    for frame, texts in zip(
        labels[paths.FRAME].to_pylist(), labels["Points2D:labels"].to_pylist(), strict=True
    ):
        if not texts or not formats.get(frame):
            continue
        fmt = formats[frame][0]
        rows = sum(t.startswith("T") and t[1:].isdigit() for t in texts)
        cols = sum(t.startswith("d") and t[1:].isdigit() for t in texts)
        if fmt["height"] <= 6 and fmt["width"] <= 8:
            assert (rows, cols) == (fmt["height"], fmt["width"]), frame
            seen.add("small")
        elif fmt["height"] >= 12:
            assert 0 < rows < fmt["height"] and 0 < cols <= fmt["width"], frame
            seen.add("large")
    assert seen == {"small", "large"}


def test_cost_matrix_extent_frames_the_whole_matrix(rrd: Path) -> None:
    """Rerun frames a 2D view on its points and boxes, not on the image: the box of
    ``cost/bev/extent`` (in the view's background colour) must reach past the last row, or the
    view cuts it in half (tests/test_debugger.py checks the screenshots)."""
    from viz.archetypes import BACKGROUND_RGB, pack_rgb

    extent = entity_table(rrd, f"{paths.COST_BEV}/{paths.COST_EXTENT}")
    image = entity_table(rrd, paths.COST_BEV)
    for frame in (20, 50, 120):
        fmt = column_at(image, "Image:format", frame)[0]
        (cx, cy), (hx, hy) = (
            column_at(extent, "Boxes2D:centers", frame)[0],
            column_at(extent, "Boxes2D:half_sizes", frame)[0],
        )
        eps = 1e-5  # float32
        labels = entity_table(rrd, f"{paths.COST_BEV}/{paths.COST_LABELS}")
        points = np.array(column_at(labels, "Points2D:positions", frame))
        # from the row labels and the note above the column labels to the last column, and
        # room below the last row
        assert cx - hx <= points[:, 0].min() + eps and cx + hx >= fmt["width"] - eps
        assert cy - hy <= points[:, 1].min() + eps and cy + hy >= fmt["height"] + 1.5 - eps
        assert column_at(extent, "Boxes2D:colors", frame) == [pack_rgb(BACKGROUND_RGB)]


#: Rerun's labels in a 2D view, as measured on its screenshots: text of a fixed size in a box
#: ~6 px/character + 13 px wide and ~16 px tall (text and margin), from ~6 px below its point.
LABEL_PX = {"char": 6.0, "pad": 13.0, "height": 16.0, "below": 6.0}
#: The smallest cost view (the focused layout's, 1920x1080 viewer): plot area, px.
SMALL_COST_VIEW_PX = (700.0, 240.0)


def _label_boxes(positions: np.ndarray, labels: list[str], extent: tuple) -> np.ndarray:
    """(x0, y0, x1, y1) px of each label in the small cost view, which Rerun frames on the
    points and boxes (the extent box and the labels' points)."""
    (cx, cy), (hx, hy) = extent
    lo = np.minimum(positions.min(axis=0), [cx - hx, cy - hy])
    hi = np.maximum(positions.max(axis=0), [cx + hx, cy + hy])
    width, height = SMALL_COST_VIEW_PX
    px = min(width / (hi[0] - lo[0]), height / (hi[1] - lo[1]))
    w = LABEL_PX["char"] * np.array([len(t) for t in labels]) + LABEL_PX["pad"]
    x, y = positions[:, 0] * px, positions[:, 1] * px + LABEL_PX["below"]
    return np.column_stack([x - w / 2, y, x + w / 2, y + LABEL_PX["height"]])


def _overlaps(boxes: np.ndarray, labels: list[str]) -> list[tuple[str, str]]:
    found = []
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            a, b = boxes[i], boxes[j]
            dx = min(a[2], b[2]) - max(a[0], b[0])
            dy = min(a[3], b[3]) - max(a[1], b[1])
            if dx > 0.5 and dy > 0.5:
                found.append((labels[i], labels[j]))
    return found


@pytest.mark.parametrize(("rows", "cols"), [(3, 4), (8, 6), (12, 10), (20, 18), (40, 9), (6, 30)])
def test_cost_labels_never_overlap(rows: int, cols: int) -> None:
    """A matrix of 12 or more rows had a label per row, one row (~8 px in the focused layout's
    small view) apart for ~16 px of text: they ran into each other. The labels the builders
    lay out (rows, staggered columns, values of every feasible cell, the note) must not
    overlap at that view's scale, which follows from the extent box; a small matrix keeps
    every row and column label."""
    from tracker.events import CostComputed, Matched, Stage
    from viz.observer import _build_cost_extent, _build_cost_labels, _CostPart

    rng = np.random.default_rng(rows * 100 + cols)
    cost = rng.uniform(0.0, 1.0, (rows + 3, cols))
    cost[-3:] = np.inf  # rows without a comparable pair: left out, the note says so
    cost[0, 0] = 0.79  # accepted, the dearest feasible value around: drawn first all the same
    tracks = np.arange(100, 100 + rows + 3) * 7
    event = CostComputed(Stage.BEV, cost, tracks, np.arange(cols) + 3, np.full(rows + 3, 0.8))
    matched = Matched(
        Stage.BEV, tracks[:2], np.array([3, 4]), cost[:2, :2].diagonal(), tracks[:0], tracks[:0]
    )
    part = _CostPart(event, matched)
    fields, _, _ = _build_cost_labels([part])
    ext, _, _ = _build_cost_extent([part])
    labels = list(fields["labels"])
    boxes = _label_boxes(
        np.asarray(fields["positions"], np.float64),
        labels,
        (ext["centers"][0], ext["half_sizes"][0]),
    )
    assert not _overlaps(boxes, labels)
    row_labels = [t for t in labels if t.startswith("T")]
    col_labels = [t for t in labels if t.startswith("d")]
    assert row_labels[0] == f"T{tracks[0]}" and col_labels[0] == "d3"
    assert "+3 tracks without a feasible pair" in labels
    if rows <= 8 and cols <= 6:
        assert len(row_labels) == rows and len(col_labels) == cols
    # thinned no more than needed: the next row label is less than two labels' height away
    tops = np.sort(boxes[[t.startswith("T") for t in labels], 1])
    assert len(row_labels) == rows or (np.diff(tops) < 2 * LABEL_PX["height"]).all()
    values = [t for t in labels if t[0].isdigit()]
    assert values
    if cols <= 12:  # (beyond, only each row's cheapest value is drawn)
        assert "0.79" in values


def test_all_tracks_view_names_every_curve_it_shows(rrd: Path) -> None:
    """The "all tracks" view shows every curve under tracks/ (its contents are the whole
    subtree), but was named "speed [m/s], heading [rad]" over vx, vy, ax and ay as well."""
    from rerun.chunk import RrdReader

    from viz.layout import VIEW_ALL_TRACKS
    from viz.paths import SERIES

    prefix = paths.entity(paths.TRACKS) + "/"
    entities = {
        str(c.entity_path)
        for c in RrdReader(str(rrd)).stream().filter(content=prefix + "**").to_chunks()
    }
    kinds = {
        e.rsplit("/", 1)[1].removeprefix(paths.GT_PREFIX) for e in entities if e.count("/") == 3
    }
    short = {"speed": "speed", "velocity_x": "vx", "velocity_y": "vy", "heading": "heading"}
    short |= {"acceleration_x": "ax", "acceleration_y": "ay"}
    # (ax, ay: constant-acceleration categories only, none with this config)
    assert set(SERIES) <= kinds <= set(short)  # a new curve: name it in VIEW_ALL_TRACKS too
    title = VIEW_ALL_TRACKS.split(":", 1)[1]
    assert all(f" {name}" in title for name in short.values())


def test_lifecycle_events_are_logged(rrd: Path, result: RecordResult) -> None:
    table = entity_table(rrd, paths.EVENTS_LIFECYCLE)
    texts = [t[0] for t in table["TextLog:text"].to_pylist() if t]
    levels = {lv[0] for lv in table["TextLog:level"].to_pylist() if lv}
    assert levels <= {"DEBUG", "INFO"}
    born = [t for t in texts if t.startswith("born: ")]
    assert sum(len(t.split(", ")) for t in born) == result.counts["tracks_born"]
    assert any(t.startswith("lost: ") for t in texts)


def test_dropped_detections_say_why(rrd: Path) -> None:
    table = entity_table(rrd, paths.DETECTIONS_RAW)
    labels = [x for row in table["Boxes3D:labels"].to_pylist() if row for x in row]
    assert any("dropped: score" in x for x in labels)


def test_camera_image_only_at_its_frames(rrd: Path) -> None:
    table = entity_table(rrd, paths.camera_image("CAM_FRONT"))
    opacity = {
        f: o[0]
        for f, o in zip(
            table[paths.FRAME].to_pylist(), table["EncodedImage:opacity"].to_pylist(), strict=True
        )
        if o
    }
    assert {f for f, o in opacity.items() if o == 1.0} == {10, 15, 20}
    assert opacity[11] == 0.0  # hidden again afterwards, not left behind later boxes


def test_summary_lists_the_switches(rrd: Path, result: RecordResult) -> None:
    table = entity_table(rrd, paths.SUMMARY, static=True)
    text = table["TextDocument:text"].to_pylist()[-1][0]
    assert "## ID switches" in text and "## Config (resolved)" in text
    first = result.id_evaluation.id_switches[0]
    k = result.id_evaluation.events.index(first)
    cause = result.causes[k].cause.value
    assert f"| {k} | {first.frame_id} | IDSW | car | {first.gt_id} |" in text
    assert f"T{first.old_track_id} -> T{first.new_track_id} | {cause} |" in text
    assert "mctrack inspect" in text and "### Causes" in text
    assert "motion metrics: not available" in text  # motion_metrics=False here


def test_recorded_gt_wireframes_are_the_projection(rrd: Path) -> None:
    from tracker.camera import box_wireframes_image
    from viz.projection import drawable_segments

    _, gt = sample_frames()
    frame = gt[10]
    cam = frame.cameras[0]
    seg = box_wireframes_image(frame.boxes, cam)
    expected, _ = drawable_segments(seg, np.tile([cam.width_px, cam.height_px], (len(seg), 1)))
    table = entity_table(rrd, f"{paths.camera(cam.name)}/gt")
    strips = np.array(column_at(table, "LineStrips2D:strips", frame.frame_id))
    np.testing.assert_allclose(strips, expected, atol=1e-2)


@pytest.mark.parametrize("with_gt", [False, True])
def test_synthetic_scene_without_labels(tmp_path: Path, with_gt: bool) -> None:
    """No KITTI labels, no ego pose: the recording still works (BEV-IoU ID switches with GT)."""
    from tracker.io.synthetic import synthetic_scene

    det, gt = synthetic_scene(num_objects=6, num_frames=40, seed=3)
    config = load_config("kitti", overrides={"categories": ["car", "pedestrian"]})
    path = tmp_path / "synthetic.rrd"
    result = record_scene(det, config, gt if with_gt else None, path, motion_metrics=False)
    present = entity_paths(path)
    for p in (paths.TRACKS_UPDATED, paths.COST_BEV, paths.camera_tracks("CAM_FRONT")):
        assert paths.entity(p) in present
    assert (paths.entity(paths.GT) in present) == with_gt
    assert paths.entity(paths.EGO) not in present  # synthetic frames have no ego pose
    if with_gt:
        assert result.id_evaluation is not None and "BEV IoU" in result.id_evaluation.method
    else:
        assert result.id_evaluation is None and result.lag is None


def test_the_recordings_summary_names_it_from_any_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`mctrack demo` and `kitti --record` record to a relative path; the summary document's
    `mctrack inspect` line named it so, which works only from the folder the run was in."""
    from tracker.config import load_config
    from tracker.eval.id_switches import IdEvaluation
    from viz.record import RecordResult, summary_markdown

    monkeypatch.chdir(tmp_path)
    result = RecordResult("0001", Path("out") / "demo.rrd", [], 0.0, 0.0)
    result.id_evaluation = IdEvaluation("x", (), (), {})
    text = summary_markdown(result, load_config("kitti"), "")
    assert f"`mctrack inspect {tmp_path / 'out' / 'demo.rrd'} --event K`" in text
