"""The debugger's explanation of ID events: ego heading, lag finder, focused view, shots, inspect,
images and causes on real KITTI (0016, the validation sequence with the most pedestrian IDSW)."""

from __future__ import annotations

import functools
import math
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from tests.cli_output import without_kernel_lines
from tests.test_viz import column_at, entity_table, recording
from tracker.eval.id_causes import Cause
from viz import layout, paths
from viz.observer import ego_yaw
from viz.record import (
    LAG_MIN_SAMPLES,
    LAG_WARMUP_SAMPLES,
    find_velocity_lag,
)
from viz.shots import (
    PlannedShot,
    image_variance,
    plan_shots,
    read_shot_index,
    renderer_available,
    take_shots,
)

#: A conservative field of view for "inside the view" (Rerun's 3D default is wider).
VERTICAL_FOV_DEG = 45.0
ASPECT = 1.5


def _in_view(eye: dict[str, np.ndarray], point: np.ndarray) -> bool:
    """Does ``point`` project inside a pinhole at ``eye['position']`` looking at its target?"""
    p, t, up = eye["position"], eye["look_target"], eye["eye_up"]
    f = (t - p) / np.linalg.norm(t - p)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    d = point - p
    z = d @ f
    if z <= 0:
        return False
    tan_v = math.tan(math.radians(VERTICAL_FOV_DEG / 2))
    return abs(d @ r / z) < tan_v * ASPECT and abs(d @ u / z) < tan_v


def _eye(target: np.ndarray) -> dict[str, np.ndarray]:
    """The focused view's eye, as the blueprint gets it (:func:`viz.layout.focus_eye`)."""
    eye = layout.focus_eye(target)
    return {
        "position": np.array(eye.position.as_arrow_array().to_pylist()[0]),
        "look_target": np.array(eye.look_target.as_arrow_array().to_pylist()[0]),
        "eye_up": np.array(eye.eye_up.as_arrow_array().to_pylist()[0]),
    }


# ---------------------------------------------------------------------------------------------
# ego heading


def _pose(yaw: float, *, camera_axes: bool) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    forward, left = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
    up = np.array([0.0, 0.0, 1.0])
    pose = np.eye(4)
    # camera axes: x right, y down, z forward; vehicle axes: x forward, y left, z up
    pose[:3, :3] = np.column_stack([-left, -up, forward] if camera_axes else [forward, left, up])
    pose[:3, 3] = [5.0, -2.0, 1.6]
    return pose


@pytest.mark.parametrize("camera_axes", [True, False], ids=["kitti-camera", "vehicle"])
@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5, math.pi / 2])
def test_ego_yaw_is_the_poses_heading(yaw: float, camera_axes: bool) -> None:
    poses = np.stack([_pose(yaw, camera_axes=camera_axes)] * 3)  # parked: never moves
    assert np.allclose(np.cos(ego_yaw(poses) - yaw), 1.0)


# ---------------------------------------------------------------------------------------------
# lag finder


def _samples(
    track_speed: np.ndarray, gt_speed: np.ndarray, *, track_id: int = 3, gt_id: int = 7
) -> tuple:
    n = len(gt_speed)
    t = np.arange(n) * 0.1
    x = np.cumsum(gt_speed) * 0.1  # moving along x
    return (
        np.arange(n) + LAG_WARMUP_SAMPLES,
        t,
        np.full(n, track_id),
        np.full(n, gt_id),
        track_speed,
        np.column_stack([gt_speed, np.zeros(n)]),
        np.column_stack([x, np.zeros(n)]),
    )


def test_lag_finder_returns_nothing_on_pure_noise() -> None:
    rng = np.random.default_rng(0)
    n = 120
    for scale in (0.05, 0.3, 1.0):
        gt = 5.0 + rng.normal(0, scale, n)
        trk = 5.0 + rng.normal(0, scale, n)
        assert find_velocity_lag([_samples(trk, gt)]) is None, scale


def test_lag_finder_finds_the_delay_of_a_delayed_copy() -> None:
    n = 100
    t = np.arange(n)
    gt = 2.0 + 6.0 / (1.0 + np.exp(-(t - 50) / 4.0))  # accelerates from 2 to 8 m/s
    delay = 6  # samples = 0.6 s
    trk = np.r_[np.full(delay, gt[0]), gt[:-delay]]
    lag = find_velocity_lag([_samples(trk, gt)])
    assert lag is not None
    assert lag.delay_secs == pytest.approx(0.6)
    assert lag.track_id == 3 and lag.gt_id == 7
    assert 45 <= lag.frame_id - LAG_WARMUP_SAMPLES <= 55  # where the GT speed changes fastest
    assert lag.mean_gap_after_mps < 0.2 * lag.mean_gap_before_mps
    # a second pair without any speed change is never "the largest lag", however noisy
    noisy = np.full(n, 5.0) + np.random.default_rng(1).normal(0, 0.5, n)
    flat = _samples(noisy, np.full(n, 5.0), track_id=4, gt_id=8)
    assert find_velocity_lag([flat, _samples(trk, gt)]).track_id == 3
    assert (
        find_velocity_lag([_samples(trk[: LAG_MIN_SAMPLES - 1], gt[: LAG_MIN_SAMPLES - 1])]) is None
    )


# ---------------------------------------------------------------------------------------------
# focused view, shots, inspect (on the shared sample recording)


def test_focused_eye_sees_the_event_and_markers() -> None:
    path, result = recording()
    index = read_shot_index(path)
    assert len(index.event_frames) == len(result.id_evaluation.events)
    assert [Cause(c) for c in index.event_causes] == [c.cause for c in result.causes]
    switches = [k for k, kind in enumerate(index.event_kinds) if kind == 0]
    assert switches
    for k in switches:
        target = np.array(index.event_xyz_m[k])
        eye = _eye(target)
        assert _in_view(eye, target)
        assert _in_view(eye, target + np.array([0.0, 0.0, 2.0]))  # the marker above it
        # the marker in the recording is where the focused view looks
        table = entity_table(path, paths.ID_SWITCH_MARKERS)
        positions = np.array(column_at(table, "Points3D:positions", index.event_frames[k]))
        assert (
            np.min(np.linalg.norm(positions - (target + np.array([0.0, 0.0, 2.0])), axis=1)) < 1e-3
        )


def test_inspect_prints_the_url_and_the_event(capsys: pytest.CaptureFixture[str]) -> None:
    path, result = recording()
    k = next(i for i, e in enumerate(result.id_evaluation.events) if e.kind.value == "id_switch")
    e = result.id_evaluation.events[k]
    assert main(["inspect", str(path), "--event", str(k), "--print"]) == 0
    out = capsys.readouterr().out
    assert f"event #{k}: ID switch at frame {e.frame_id}" in out
    assert f"T{e.old_track_id} -> T{e.new_track_id} ({result.causes[k].cause.value})" in out
    assert f"recording: {path.resolve().as_uri()}\n" in out  # no #when: 0.41 ignores it
    assert main(["inspect", str(path), "--event", "100000", "--print"]) == 2


def test_inspect_list_prints_each_event_without_a_display(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``inspect REC --list``: one line per event --event opens (sequence, #K, frame, kind,
    tracks), by frame; no viewer, no display. A run folder lists each of its recordings."""
    from viz import rerun_process

    def spawn(*args: object, **kwargs: object) -> None:
        raise AssertionError("no viewer for --list")

    monkeypatch.setattr(rerun_process, "start_rerun", spawn)
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(name, raising=False)
    path, result = recording()
    events = result.id_evaluation.events
    assert main(["inspect", str(path), "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(events) > 5
    order = sorted(range(len(events)), key=lambda k: (events[k].frame_id, k))
    for line, k in zip(lines, order, strict=True):
        e = events[k]
        kind = "ID switch" if e.kind.value == "id_switch" else "fragmentation"
        assert line.split() == [
            "0001",
            f"#{k}",
            "frame",
            str(e.frame_id),
            *kind.split(),
            f"T{e.old_track_id}",
            "->",
            f"T{e.new_track_id}",
            "(GT",
            f"{e.gt_id})",
        ]
    # a run folder: its recordings/ (here two sequences), by sequence then frame
    run = tmp_path / "run"
    (run / "recordings").mkdir(parents=True)
    shutil.copy(path, run / "recordings" / "0001.rrd")
    empty = _tiny_recording(run / "recordings" / "0000.rrd")
    assert main(["inspect", str(run), "--list"]) == 0
    captured = capsys.readouterr()
    assert captured.out.splitlines() == lines
    assert f"{empty}: no ID events (ID switches or fragmentations) recorded" in captured.err
    assert main(["inspect", str(tmp_path), "--list"]) == 2  # no recordings there
    assert "no recordings (.rrd)" in capsys.readouterr().err
    with pytest.raises(SystemExit) as usage:  # one or the other
        main(["inspect", str(path), "--list", "--event", "1"])
    assert usage.value.code == 2


def _tiny_recording(path: Path) -> Path:
    """A recording without ID events (nor ground truth): a few frames of the sample."""
    from tests.test_viz import sample_frames
    from tracker.config import load_config
    from viz.record import record_scene

    det, _ = sample_frames()
    record_scene(det[:3], load_config("kitti"), None, path, motion_metrics=False)
    return path


def test_inspect_without_a_display_says_so_and_names_shots(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without DISPLAY / WAYLAND_DISPLAY (SSH, CI) the viewer's window cannot open: inspect
    says so in one line with the shots command for the same moment, instead of spawning a
    viewer that fails with "transport error" after 6 s."""
    from app.common import EXIT_VIEWER_FAILED
    from app.inspect import missing_display

    assert missing_display({}, "linux")
    assert not missing_display({"DISPLAY": ":0"}, "linux")
    assert not missing_display({"WAYLAND_DISPLAY": "wayland-0"}, "linux")
    assert not missing_display({}, "darwin") and not missing_display({}, "win32")

    _without_a_display(monkeypatch)
    path, _ = recording()
    for what, where in ((["--event", "1"], "--event 1"), (["--frame", "15"], "--frame 15")):
        assert main(["inspect", str(path), *what]) == EXIT_VIEWER_FAILED
        err = capsys.readouterr().err
        assert err == (
            "mctrack inspect: no display for the viewer's window (DISPLAY and WAYLAND_DISPLAY "
            f"are unset); on a machine without one, picture the moment with: mctrack shots "
            f"{path} {where} --out shots/\n"
        )


def _without_a_display(monkeypatch: pytest.MonkeyPatch) -> None:
    """A Linux machine without DISPLAY / WAYLAND_DISPLAY, where starting a viewer fails the
    test (the command must refuse before)."""
    from viz import rerun_process

    def spawn(*args: object, **kwargs: object) -> None:
        raise AssertionError("no viewer without a display")

    monkeypatch.setattr(rerun_process, "start_rerun", spawn)
    monkeypatch.setattr("sys.platform", "linux")
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(name, raising=False)


def test_view_spawn_without_a_display_is_refused_before_any_work(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``mctrack view INPUT --spawn`` without a display: the viewer died on winit's error and
    the run then hung with no word (the recording's flush waits for a viewer that never came)."""
    from app.common import EXIT_VIEWER_FAILED
    from tests.test_viz import SAMPLE

    _without_a_display(monkeypatch)
    det = SAMPLE / "detections.json.gz"
    code = main(["view", str(det), "--frames", "0:5", "--spawn"])
    assert code == EXIT_VIEWER_FAILED  # as inspect
    assert without_kernel_lines(capsys.readouterr().err) == (
        "mctrack view: error: --spawn: no display for the viewer's window (DISPLAY and "
        "WAYLAND_DISPLAY are unset); record to a file (--save OUT.rrd, then mctrack shots "
        "OUT.rrd --out shots/) or serve a web viewer (--serve-web)\n"
    )


def test_inspect_refuses_a_frame_the_recording_does_not_have(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A --frame outside the recording (or a recording without frames, or not an .rrd at all)
    is a one-line error naming the frames there are, not a viewer opened on an empty scene."""
    import rerun as rr

    path, _ = recording()  # frames 0-199
    assert main(["inspect", str(path), "--frame", "199", "--print"]) == 0
    assert capsys.readouterr().out.startswith("frame 199\n")
    assert main(["inspect", str(path), "--print"]) == 0
    assert capsys.readouterr().out.startswith("frame 0\n")
    for frame in ("200", "-1"):
        assert main(["inspect", str(path), "--frame", frame, "--print"]) == 2
        err = capsys.readouterr().err
        assert err == (
            f"mctrack inspect: error: {path}: --frame {frame}: the recording has frames 0..199\n"
        )
    frameless = tmp_path / "static.rrd"
    rec = rr.RecordingStream(paths.APPLICATION_ID, recording_id="static-only")
    rec.save(frameless)
    rec.log(paths.SUMMARY, rr.TextDocument("nothing tracked"), static=True)
    rec.flush()
    rec.disconnect()
    assert main(["inspect", str(frameless), "--print"]) == 2
    assert capsys.readouterr().err == (
        f"mctrack inspect: error: {frameless}: the recording has no frames\n"
    )
    assert main(["inspect", str(frameless), "--event", "0", "--print"]) == 2
    assert capsys.readouterr().err == (
        f"mctrack inspect: error: {frameless}: --event 0: the recording has no ID events "
        "(ID switches or fragmentations)\n"
    )
    other = tmp_path / "tracks.json"
    other.write_text("{}")
    for what in (["--frame", "3"], ["--event", "0"]):
        assert main(["inspect", str(other), *what, "--print"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"mctrack inspect: error: {other}: not a readable Rerun recording")
        assert err.count("\n") == 1


def test_a_truncated_recording_is_one_line_without_rerun_warning(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
    recwarn: pytest.WarningsRecorder,
) -> None:
    """A recording cut short (a copy stopped mid-way): inspect and shots end in the one-line
    error alone; Rerun's RerunWarning ("RRD file has no footer/manifest ...", a Python warning
    block with its source line) went before it, and is now in the debug log (-v)."""
    import logging

    from rerun.error_utils import RerunWarning

    path, _ = recording()
    cut = tmp_path / "trunc.rrd"
    cut.write_bytes(path.read_bytes()[:200_000])
    commands = (["inspect", "--list"], ["inspect", "--frame", "3", "--print"], ["shots"])
    for command, *options in commands:
        out = ["--out", str(tmp_path / "shots")] if command == "shots" else []
        with caplog.at_level(logging.DEBUG, logger="mctrack"):
            assert main([command, str(cut), *options, *out]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"mctrack {command}: error: {cut}: not a readable Rerun recording")
        assert err.count("\n") == 1, err
        assert not [w for w in recwarn if issubclass(w.category, RerunWarning)]
        assert "no footer/manifest" in caplog.text
        caplog.clear()


def _planned_shots(monkeypatch: pytest.MonkeyPatch) -> list[PlannedShot]:
    """The shots `mctrack shots` plans, collected instead of taken (no viewer)."""
    from viz import shots

    planned: list[PlannedShot] = []

    def take_shots(recording: Path, out: str, *, plan: list[PlannedShot], **kw: object) -> list:
        planned.extend(plan)
        return []

    monkeypatch.setattr(shots, "take_shots", take_shots)
    return planned


def test_shots_refuses_a_frame_the_recording_does_not_have(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """shots --frame outside the recording is inspect's one-line error, before any viewer (it
    was a screenshot of an empty scene at that frame, or 'cannot render' without a driver)."""
    path, _ = recording()  # frames 0-199
    planned = _planned_shots(monkeypatch)
    out = str(tmp_path / "shots")
    assert main(["shots", str(path), "--frame", "199", "--out", out]) == 0
    assert planned == [PlannedShot(199, "frame")]
    for frame in ("200", "-1"):
        assert main(["shots", str(path), "--frame", frame, "--out", out]) == 2
        err = capsys.readouterr().err
        assert err == (
            f"mctrack shots: error: {path}: --frame {frame}: the recording has frames 0..199\n"
        )
    assert planned == [PlannedShot(199, "frame")] and not (tmp_path / "shots").exists()


def test_shots_max_events_0_takes_the_lag_shot_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """docs/debugger.md's ``mctrack shots ref.rrd --max-events 0`` (the lag shot only) was
    refused as a usage error (--max-events took integers >= 1 only)."""
    import dataclasses

    from viz import shots

    path, _ = recording()
    index = read_shot_index(path)
    assert index.lag_frame is not None and index.event_frames
    planned = _planned_shots(monkeypatch)
    out = str(tmp_path / "shots")
    assert main(["shots", str(path), "--max-events", "0", "--out", out]) == 0
    assert planned == [PlannedShot(index.lag_frame, "lag")]
    with pytest.raises(SystemExit) as usage:  # argparse: a usage error
        main(["shots", str(path), "--max-events", "-1", "--out", out])
    assert usage.value.code == 2
    assert "--max-events: expected an integer >= 0, got '-1'" in capsys.readouterr().err
    # events, but no lag: says what is missing (not "no ID switches ... recorded")
    no_lag = dataclasses.replace(index, lag_frame=None, lag_track_id=None)
    monkeypatch.setattr(shots, "read_shot_index", lambda _: no_lag)
    assert main(["shots", str(path), "--max-events", "0", "--out", out]) == 0
    assert capsys.readouterr().out == (
        f"{path}: no velocity lag recorded; nothing to capture (--max-events 0)\n"
    )
    assert planned == [PlannedShot(index.lag_frame, "lag")]


def test_shots_lists_each_png_with_a_readable_caption(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The list of PNGs said "(frame at frame 15: viewer)" and "(event #3 id_switch at ...)"."""
    from viz import shots

    path, _ = recording()
    made = [
        shots.Shot(tmp_path / "a.png", 15, "frame", "viewer"),
        shots.Shot(tmp_path / "b.png", 80, "id_switch", "event", 3),
        shots.Shot(tmp_path / "c.png", 81, "fragmentation", "focus #4", 4),
        shots.Shot(tmp_path / "d.png", 410, "lag", "speed vs GT"),
    ]
    monkeypatch.setattr(shots, "take_shots", lambda *a, **kw: made)
    assert main(["shots", str(path), "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().out.splitlines() == [
        f"{tmp_path / 'a.png'}  (frame 15: viewer)",
        f"{tmp_path / 'b.png'}  (event #3 ID switch at frame 80: event)",
        f"{tmp_path / 'c.png'}  (event #4 fragmentation at frame 81: focus #4)",
        f"{tmp_path / 'd.png'}  (largest velocity lag at frame 410: speed vs GT)",
    ]


def test_inspect_lands_on_the_event_frame_in_a_real_viewer(tmp_path: Path) -> None:
    """``mctrack inspect``'s viewer driving on Rerun's headless native viewer: the viewer's own
    time cursor (read back with ViewerClient.get_state) is on the event's frame and the
    focused layout is shown; for --frame, on that frame in the default layout."""

    from app.inspect import drive_viewer, inspect_target
    from viz.shots import headless_viewer, renderer_available

    ok, why = renderer_available()
    if not ok:
        pytest.skip(f"no software renderer: {why}")
    path, result = recording()
    k = next(i for i, e in enumerate(result.id_evaluation.events) if e.frame_id > 0)
    frame = result.id_evaluation.events[k].frame_id
    with headless_viewer() as client:
        assert drive_viewer(client, path, inspect_target(path, k, None), tmp_path) == frame
        state = client.get_state()
        cursor = [(r.current_timeline, r.current_time) for r in state.recordings]
        assert (paths.FRAME, frame) in cursor
        assert any(v.name.startswith(layout.VIEW_FOCUS) for v in state.views)
        target = inspect_target(path, None, 7)
        assert drive_viewer(client, path, target, tmp_path) == 7


def test_focused_blueprint_of_an_event_targets_it(monkeypatch: pytest.MonkeyPatch) -> None:
    from viz import shots

    path, _ = recording()
    index = read_shot_index(path)
    seen = {}
    monkeypatch.setattr(layout, "focus_blueprint", lambda cams, **kw: seen.update(kw, cams=cams))
    shots.focus_blueprint_for(path, index, 0)
    assert seen["event_index"] == 0
    assert seen["target_xyz"] == index.event_xyz_m[0]
    assert seen["track_ids"] == (index.event_old_track_ids[0], index.event_new_track_ids[0])
    assert seen["cams"] == [("CAM_FRONT", 1242, 375)]
    assert seen["gt_id"] == index.event_gt_ids[0]


def _speed_views(blueprint: object) -> list:
    """The TimeSeriesViews of a blueprint whose name starts with "speed [m/s]: T"."""
    import rerun.blueprint as rrb

    found, todo = [], [blueprint.root_container]  # type: ignore[attr-defined]
    while todo:
        item = todo.pop()
        if isinstance(item, rrb.TimeSeriesView):
            if str(item.name).startswith("speed [m/s]: T"):
                found.append(item)
        else:
            todo += list(getattr(item, "contents", []) or [])
    return found


def test_event_speed_view_draws_the_gt_curve_once() -> None:
    """Both tracks of an ID switch matched the one GT object: the event's speed view (focused
    layout, and the default layout's first-switch view) drew its curve twice, as each track's
    matched-GT curve. Now it draws the GT object's own curve (event_gt/<id>/speed), which holds
    both tracks' pieces."""
    from viz import shots

    path, result = recording()
    index = read_shot_index(path)
    k = index.event_kinds.index(0)  # an ID switch
    old, new, gt = (
        index.event_old_track_ids[k],
        index.event_new_track_ids[k],
        index.event_gt_ids[k],
    )
    views = _speed_views(shots.focus_blueprint_for(path, index, k))
    first = result.id_evaluation.id_switches[0]
    views += _speed_views(
        layout.debug_blueprint(
            [], switch_track_ids=[first.old_track_id, first.new_track_id], switch_gt_id=first.gt_id
        )
    )
    assert len(views) == 2
    for view, (a, b, g) in zip(
        views, [(old, new, gt), (first.old_track_id, first.new_track_id, first.gt_id)], strict=True
    ):
        contents = [str(c) for c in view.contents]
        assert [c for c in contents if "gt" in c] == [paths.entity(paths.event_gt_series(g))]
        assert {paths.entity(paths.track_series(t, paths.SPEED)) for t in (a, b)} <= set(contents)
    # the one curve holds the pieces the two tracks' matched-GT curves had
    curve = entity_table(path, paths.event_gt_series(gt))
    speed = dict(
        zip(curve[paths.FRAME].to_pylist(), curve["Scalars:scalars"].to_pylist(), strict=True)
    )
    assert curve["SeriesLines:names"].to_pylist()[0] == [f"GT {gt} speed"]
    pieces = 0
    for t in (old, new):
        piece = entity_table(path, paths.track_series(t, paths.GT_PREFIX + paths.SPEED))
        at_event_gt = [
            (f, v)
            for f, v in zip(
                piece[paths.FRAME].to_pylist(), piece["Scalars:scalars"].to_pylist(), strict=True
            )
            if f in speed and speed[f] == v
        ]
        pieces += len(at_event_gt) > 0
    assert pieces == 2


def test_shot_plans() -> None:
    path, result = recording()
    index = read_shot_index(path)
    assert index.image_frames == [10, 15, 20]
    # --frame: the nearest frame with an image within 3 frames, else the frame itself
    assert plan_shots(index, frame=13) == [PlannedShot(15, "frame")]
    assert plan_shots(index, frame=40) == [PlannedShot(40, "frame")]
    assert len(plan_shots(index, events="all")) == len(result.id_evaluation.events)
    k = index.event_kinds.index(0)
    assert plan_shots(index, events=[k]) == [
        PlannedShot(index.event_shot_frames[k], "id_switch", k)
    ]
    with pytest.raises(IndexError):
        plan_shots(index, events=[len(index.event_frames)])


def test_shots_of_an_event_and_a_frame(tmp_path: Path) -> None:
    ok, why = renderer_available()
    if not ok:
        pytest.skip(f"no software renderer: {why}")
    path, _ = recording()
    index = read_shot_index(path)
    k, k2 = [i for i, kind in enumerate(index.event_kinds) if kind == 0][:2]
    frame = index.event_shot_frames[k]
    plan = [*plan_shots(index, events=[k, k2]), *plan_shots(index, frame=15)]
    shots = take_shots(path, tmp_path, plan=plan, settle_secs=1.0)
    names = {s.path.name for s in shots}
    # each event in its own focused layout (not the previous event's)
    frame2 = index.event_shot_frames[k2]
    second = next(s for s in shots if s.path.name == f"event{k2}_f{frame2:04d}_focus.png")
    assert second.view == f"{layout.VIEW_FOCUS}#{k2}"
    for view in ("viewer", "focus", "event", "camera", "cost_bev"):
        assert f"event{k}_f{frame:04d}_{view}.png" in names
    for view in ("viewer", "bev_3d", "camera", "cost_bev"):
        assert f"frame_f0015_{view}.png" in names
    focus = next(s for s in shots if s.path.name == f"event{k}_f{frame:04d}_focus.png")
    assert focus.view == f"{layout.VIEW_FOCUS}#{k}"
    for s in shots:
        assert image_variance(s.path) > 20.0, s.path
    # the cost views frame the whole matrix: nothing drawn along their bottom edge (the last
    # row was cut in half: Rerun frames a 2D view on its points and boxes, not on the image)
    from PIL import Image

    for name in (f"event{k}_f{frame:04d}_cost_bev.png", "frame_f0015_cost_bev.png"):
        with Image.open(tmp_path / name) as im:
            rgb = np.asarray(im.convert("RGB"))
        assert (rgb[-6:] == rgb[-1, 0]).all(), name


# ---------------------------------------------------------------------------------------------
# real KITTI: 0016 pedestrians through `mctrack kitti --record`


@functools.cache
def _kitti_0016(kitti_root: Path) -> tuple[Path, dict]:
    from app.kitti import run_kitti

    out = Path(tempfile.mkdtemp(prefix="mctrack-test-0016-"))
    summary = run_kitti(
        kitti_root=kitti_root,
        seqs=["0016"],
        classes=["pedestrian"],
        record=out / "rec",
        out=out,
        quiet=True,
    )
    return out, summary


@pytest.fixture(scope="module")
def kitti_0016(kitti_root: Path):
    out, summary = _kitti_0016(kitti_root)
    yield out, summary
    shutil.rmtree(out, ignore_errors=True)


def test_kitti_record_logs_images_where_image_02_exists(kitti_0016) -> None:
    _, summary = kitti_0016
    rrd = Path(summary["recordings"]["0016"])
    table = entity_table(rrd, paths.camera_image("CAM_FRONT"))
    shown = [
        f
        for f, blob in zip(
            table[paths.FRAME].to_pylist(),
            table["EncodedImage:blob"].to_pylist(),
            strict=True,
        )
        if blob
    ]
    assert shown == [2, 7, 12]  # training/image_02/0016/0000{02,07,12}.png


def test_kitti_record_parked_ego_faces_the_poses_heading(kitti_0016, kitti_root: Path) -> None:
    from tracker.io.convert.kitti import convert_kitti

    _, summary = kitti_0016
    rrd = Path(summary["recordings"]["0016"])
    frames = convert_kitti(kitti_root, seqs=["0016"], classes=["pedestrian"])[0]["0016"]
    table = entity_table(rrd, paths.EGO)
    rows = [
        (f, q[0])
        for f, q in zip(
            table[paths.FRAME].to_pylist(), table["Transform3D:quaternion"].to_pylist(), strict=True
        )
        if q  # the axes rows of the same entity carry no rotation
    ]
    q = np.array([r for _, r in sorted(rows)])
    yaw_rec = 2 * np.arctan2(q[:, 2], q[:, 3])
    yaw_pose = ego_yaw(np.stack([f.world_from_ego for f in frames]))
    assert len(yaw_rec) == len(frames) == 209
    assert np.allclose(np.cos(yaw_rec - yaw_pose), 1.0, atol=1e-6)
    # the ego barely moves in 0016, and its heading is not the -90 deg of a camera's x axis
    assert abs(np.degrees(np.median(yaw_pose)) + 90.0) > 45.0


def test_kitti_0016_pedestrian_switches_explained_and_in_view(kitti_0016) -> None:
    out, summary = kitti_0016
    per = summary["per_sequence"]["0016"]["pedestrian"]
    assert per == {k: summary["metrics"]["pedestrian"][k] for k in ("IDSW", "Frag")}
    causes = summary["causes"]["0016"]["pedestrian"]
    assert sum(causes["IDSW"].values()) == per["IDSW"] > 0
    assert sum(causes["Frag"].values()) == per["Frag"]
    assert causes["IDSW"]["other"] == 0
    index = read_shot_index(summary["recordings"]["0016"])
    switches = [k for k, kind in enumerate(index.event_kinds) if kind == 0]
    assert len(switches) == per["IDSW"]
    for k in switches:
        target = np.array(index.event_xyz_m[k])
        assert np.isfinite(target).all()
        assert _in_view(_eye(target), target + np.array([0.0, 0.0, 2.0]))
        assert index.event_causes[k] != "other"
    assert (out / "rec" / "causes.md").is_file()


def test_causes_md_names_the_sequences_without_events(tmp_path: Path) -> None:
    """causes.md's header listed only the sequences with an event, so a run of all 11
    validation sequences read as a run of 10 (0010 has none); a sequence recorded without
    labels (no evaluation) is not named."""
    from types import SimpleNamespace

    from app.kitti_record import recording_summary
    from tracker.config import load_config

    counts = {"car": {"IDSW": {c.value: 0 for c in Cause}, "Frag": {c.value: 0 for c in Cause}}}
    counts["car"]["Frag"]["missed_no_detection"] = 2
    records = [
        SimpleNamespace(scene="0001", info={"recording": "0001.rrd", "causes": counts}),
        SimpleNamespace(scene="0010", info={"recording": "0010.rrd", "causes": {}}),
        SimpleNamespace(scene="0020", info={"recording": "0020.rrd"}),  # no labels
    ]
    config = load_config("kitti")
    summary = recording_summary(records, config, tmp_path)
    assert summary["causes"] == {"0001": counts}  # summary.json as before
    header = (tmp_path / "causes.md").read_text().splitlines()[2]
    assert header.startswith(
        f"Sequences 0001, 0010 (0010: no event); classes {', '.join(config.categories)}; "
    )


def test_fragmentation_cost_table_lists_its_track_once() -> None:
    """A fragmentation back to the same track has one cost row, labelled "old = new"; an ID
    switch has the old and the new track's rows."""
    from tracker.boxes import Boxes
    from tracker.eval.id_causes import FrameStages, StageLog
    from tracker.eval.id_switches import IdEvent, IdEventKind
    from tracker.events import CostComputed, Stage
    from tracker.frame import Frame
    from viz.record import explain_markdown

    stages = StageLog()
    cost = np.array([[0.3, np.inf, 1.9], [np.inf, 0.8, np.inf], [2.5, np.inf, 0.2]])
    stages.frames[40] = FrameStages(
        Frame(scene="s", frame_id=40, timestamp_secs=4.0, boxes=Boxes.empty()),
        bev=CostComputed(
            Stage.BEV, cost, np.array([5, 6, 7]), np.array([0, 1, 2]), np.array([1.0, 1.0, 1.2])
        ),
    )

    def event(kind: IdEventKind, old: int, new: int) -> IdEvent:
        return IdEvent(kind, 40, "pedestrian", 9, old, new, 0.7, 31)

    frag = explain_markdown(3, event(IdEventKind.FRAGMENTATION, 5, 5), None, stages)
    rows = [ln for ln in frag.splitlines() if ln.startswith("| T")]
    assert rows == ["| T5 | old = new | 1.00 | 0.30 | 1.90 |"]
    assert "| track | role | gate | d0 | d2 |" in frag
    switch = explain_markdown(4, event(IdEventKind.ID_SWITCH, 5, 7), None, stages)
    rows = [ln for ln in switch.splitlines() if ln.startswith("| T")]
    assert rows == ["| T5 | old | 1.00 | 0.30 | 1.90 |", "| T7 | new | 1.20 | 2.50 | 0.20 |"]
    lone = explain_markdown(5, event(IdEventKind.FRAGMENTATION, 6, 6), None, stages)
    assert "| T6 | old = new | 1.00 | 0.80 |" in lone
    gone = explain_markdown(6, event(IdEventKind.FRAGMENTATION, 8, 8), None, stages)
    assert "the track had no comparable detection" in gone


class _Exited:
    """A rerun process that exited at once (status 2), as on a refused option."""

    pid = -1
    returncode = 2

    def poll(self) -> int:
        return 2


@pytest.mark.parametrize("sink", ["--spawn", "--serve-web"])
def test_view_viewer_not_started_exits_as_inspect_and_shots_do(
    sink: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A viewer or server that does not start is the environment, not the input: view exited
    with 2 (bad input) there, inspect and shots with 4; now all with EXIT_VIEWER_FAILED."""
    import app.inspect
    import app.shots
    from app.common import EXIT_VIEWER_FAILED
    from tests.test_viz import SAMPLE
    from viz import rerun_process

    assert EXIT_VIEWER_FAILED == app.inspect.EXIT_VIEWER_FAILED == app.shots.EXIT_VIEWER_FAILED
    monkeypatch.setattr(rerun_process, "start_rerun", lambda *a, **k: _Exited())
    monkeypatch.setattr(rerun_process, "port_open", lambda *a: False)
    monkeypatch.setenv("DISPLAY", ":mctrack-test")
    det = SAMPLE / "detections.json.gz"
    assert main(["view", str(det), "--frames", "0:5", sink]) == EXIT_VIEWER_FAILED == 4
    err = capsys.readouterr().err.splitlines()[-1]
    what = "the viewer" if sink == "--spawn" else "the server"
    assert err == (
        f"mctrack view: error: {sink}: {what} did not start on 127.0.0.1: the rerun viewer "
        "exited (status 2)"
    )


def test_report_serve_viewer_not_started_is_a_viewer_failure(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """report --serve's web viewer that exits: exit 4 as the other viewers (it was a
    RuntimeError, reported as a bug, exit 1)."""
    from app.cli import EXIT_VIEWER_FAILED, error_message
    from app.serve import report_server
    from tracker.errors import ViewerError
    from viz import rerun_process

    monkeypatch.setattr(rerun_process, "start_rerun", lambda *a, **k: _Exited())
    with pytest.raises(ViewerError) as failed, report_server(tmp_path, {}):
        pass
    assert error_message(failed.value) == (
        "the rerun web viewer exited (status 2)",
        EXIT_VIEWER_FAILED,
    )


@pytest.mark.parametrize("sink", [[], ["--save", "x.rrd"]])
def test_view_host_without_a_viewer_is_refused(
    sink: list[str],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """--host with --save (or the default file) was ignored without a word: refused before any
    work, nothing written."""
    from tests.test_viz import SAMPLE

    monkeypatch.chdir(tmp_path)  # (the default file's folder)

    det = SAMPLE / "detections.json.gz"
    out = tmp_path / "x.rrd"
    sink = [sink[0], str(out)] if sink else sink
    assert main(["view", str(det), "--frames", "0:5", *sink, "--host", "0.0.0.0"]) == 2
    assert capsys.readouterr().err == (
        "mctrack view: error: --host 0.0.0.0: only with --spawn or --serve-web (the viewer's "
        "address); without them view records to a file\n"
    )
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("given", "refused"),
    [
        (["--grpc-port", "9001"], "--grpc-port 9001: only with --spawn or --serve-web (the "
         "viewer's port); without them view records to a file"),
        (["--save", "x.rrd", "--grpc-port", "9001"], "--grpc-port 9001: only with --spawn or "
         "--serve-web (the viewer's port); without them view records to a file"),
        (["--save", "x.rrd", "--web-port", "9002"], "--web-port 9002: only with --serve-web (its "
         "web page); without it view records to a file"),
        (["--spawn", "--web-port", "9002"], "--web-port 9002: only with --serve-web (its web "
         "page); --spawn's viewer has none"),
    ],
)  # fmt: skip
def test_view_ports_without_their_viewer_are_refused(
    given: list[str],
    refused: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """--grpc-port and --web-port where no server uses them (--save or the default file; the
    native viewer of --spawn has no web page) were ignored without a word: refused before any
    work, as --host is; nothing written, no viewer started."""
    from tests.test_viz import SAMPLE
    from viz import rerun_process

    monkeypatch.chdir(tmp_path)  # (the default file's folder)
    monkeypatch.setattr(rerun_process, "start_rerun", lambda *a, **k: pytest.fail("started"))
    monkeypatch.setenv("DISPLAY", ":mctrack-test")
    det = SAMPLE / "detections.json.gz"
    assert main(["view", str(det), "--frames", "0:5", *given]) == 2
    assert capsys.readouterr().err == f"mctrack view: error: {refused}\n"
    assert not list(tmp_path.iterdir())


def test_view_help_says_which_sink_each_viewer_option_goes_with(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit):
        main(["view", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "(default 9090; only with --serve-web)" in out
    assert "(default 9876; only with --spawn or --serve-web)" in out
    assert "(default 127.0.0.1; only with --spawn or --serve-web)" in out


def test_inspect_list_with_print_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    """--print beside --list was ignored without a word."""
    path, _ = recording()
    assert main(["inspect", str(path), "--list", "--print"]) == 2
    assert capsys.readouterr().err == (
        "mctrack inspect: error: --print and --list: give one (--list starts no viewer either)\n"
    )


def test_inspect_help_first_line_names_list(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["inspect", "--help"])
    out = capsys.readouterr().out
    described = out.split("\n\n")[1]  # (after the usage lines)
    assert described.startswith("mctrack inspect REC [--event K | --frame F | --list]:")


def _recorded_results(monkeypatch: pytest.MonkeyPatch) -> list:
    """Every RecordResult that ``record_scene`` returns from here on (view and demo import it
    when they run)."""
    import viz.record

    results: list = []
    real = viz.record.record_scene

    def kept(*args: object, **kwargs: object) -> object:
        results.append(real(*args, **kwargs))
        return results[-1]

    monkeypatch.setattr(viz.record, "record_scene", kept)
    return results


def _track_ids_per_frame(outputs: list) -> list[tuple[int, list[int]]]:
    return [(o.frame_id, sorted(int(t) for t in o.boxes.track_id)) for o in outputs]


@pytest.mark.parametrize("profile", ["pointrcnn", "self", None])
def test_view_tracks_what_track_tracks_with_the_same_profile(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
    profile: str | None,
) -> None:
    """`view INPUT --profile P` tracks, frame by frame, what `track INPUT --profile P` writes,
    and without --profile both warn alike that the scores are used as given: view had no
    --profile and tracked the raw scores without a word (205 tracks on the sample, car 4 ID
    switches, where the demo and `kitti --seqs 0001` have 118 and none)."""
    import json
    import logging

    from tests.test_viz import SAMPLE

    det, given = str(SAMPLE / "detections.json.gz"), ["--profile", profile] if profile else []
    recorded = _recorded_results(monkeypatch)
    with caplog.at_level(logging.WARNING):
        view = ["view", det, "--frames", "0:150", "--no-motion", "--save", str(tmp_path / "v.rrd")]
        assert main([*view, *given]) == 0
    view_log = caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert main(["track", det, "--frames", "0:150", "--out", str(tmp_path), *given]) == 0
    tracked = json.loads((tmp_path / "tracks.json").read_text())["0001"]
    written = [(f["frame_id"], sorted(b["track_id"] for b in f["bboxes"])) for f in tracked]
    assert _track_ids_per_frame(recorded[0].outputs) == written
    warning = "no --profile: detection_score is used as given"
    assert (warning in view_log) is (warning in caplog.text) is (profile is None)


def test_view_with_the_samples_profile_records_the_demos_tracks_and_id_switches(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The docs' `view` of the sample with --profile pointrcnn (the sample's detector) records
    the demo's tracks and ID switches (frames 0-149: 67 tracks, car 0 ID switches; without the
    profile 109 tracks, car 1 ID switch)."""
    from tests.test_viz import SAMPLE

    recorded = _recorded_results(monkeypatch)
    frames = ["--frames", "0:150"]
    assert main(["demo", "--out", str(tmp_path), *frames]) == 0
    view = ["view", str(SAMPLE / "detections.json.gz"), "--gt", str(SAMPLE / "gt.json.gz")]
    labels = ["--labels", str(SAMPLE / "raw" / "training" / "label_02")]
    save = ["--no-motion", "--save", str(tmp_path / "v.rrd")]
    assert main([*view, *labels, *frames, *save, "--profile", "pointrcnn"]) == 0
    demo, viewed = recorded
    assert _track_ids_per_frame(viewed.outputs) == _track_ids_per_frame(demo.outputs)
    assert demo.id_evaluation is not None and viewed.id_evaluation is not None
    assert viewed.id_evaluation.counts == demo.id_evaluation.counts
    printed = capsys.readouterr().out
    assert "  tracks: 67\n  ID switches (car): 0, fragmentations: 1" in printed
    assert "scene 0001: 150 frames, 67 tracks, car: 0 ID switches, 1 fragmentations" in printed


def test_track_and_view_take_profile_none_as_the_given_scores_without_the_warning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """`--profile none` is what `kitti` and `robustness` accept for "no calibration"; `track`
    and `view` took it for a file name ("none: no such profile file"). It tracks what no
    --profile tracks, the user's choice said by the option rather than warned about."""
    import json
    import logging

    from tests.test_viz import SAMPLE

    det = str(SAMPLE / "detections.json.gz")
    recorded = _recorded_results(monkeypatch)
    written = {}
    for name, given in (("default", []), ("none", ["--profile", "none"])):
        caplog.clear()
        out = tmp_path / name
        with caplog.at_level(logging.WARNING):
            assert main(["track", det, "--frames", "0:60", "--out", str(out), *given]) == 0
            save = ["--no-motion", "--save", str(tmp_path / f"{name}.rrd")]
            assert main(["view", det, "--frames", "0:60", *save, *given]) == 0
        assert ("no --profile" in caplog.text) is (name == "default")
        tracks = json.loads((out / "tracks.json").read_text())["0001"]
        written[name] = [
            (f["frame_id"], sorted(b["track_id"] for b in f["bboxes"])) for f in tracks
        ]
    assert written["none"] == written["default"] and written["none"]
    assert _track_ids_per_frame(recorded[0].outputs) == written["default"]
    assert _track_ids_per_frame(recorded[1].outputs) == written["none"]
