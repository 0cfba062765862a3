"""The default blueprint embedded in every recording: a layout for debugging a tracker run.

Left: the BEV / 3D scene (following the ego) over the camera views. Right: the two cost
matrices, the velocity curves, and the events log next to the summary. The time panel starts
paused on the ``frame`` timeline, so a recording opens on a still picture.
"""

from __future__ import annotations

from collections.abc import Sequence

import rerun.blueprint as rrb

from viz import paths

# view names (``mctrack shots`` finds the views by these prefixes)
VIEW_BEV = "BEV / 3D"
VIEW_CAMERA = "camera "
VIEW_COST_BEV = "cost BEV"
VIEW_COST_RV = "cost RV"
VIEW_SPEED_LAG = "speed vs GT"
VIEW_ID_EVENTS = "ID switches"

#: Frames either side of the cursor shown by the "all tracks" time series.
SERIES_WINDOW_FRAMES = 60
#: The BEV eye in the ego frame (metres): behind and above the car, looking ahead of it.
BEV_EYE_POSITION_M = (-16.0, 0.0, 26.0)
BEV_EYE_TARGET_M = (16.0, 0.0, 0.0)


def _speed_view(track_ids: Sequence[int], name: str) -> rrb.TimeSeriesView:
    contents = [
        paths.entity(paths.track_series(t, s))
        for t in track_ids
        for s in (paths.SPEED, paths.GT_PREFIX + paths.SPEED)
    ]
    return rrb.TimeSeriesView(origin=paths.entity(paths.TRACKS), contents=contents, name=name)


def _xy_view(track_ids: Sequence[int], name: str) -> rrb.TimeSeriesView:
    series = (paths.VELOCITY_X, paths.VELOCITY_Y)
    contents = [
        paths.entity(paths.track_series(t, p + s))
        for t in track_ids
        for s in series
        for p in ("", paths.GT_PREFIX)
    ]
    return rrb.TimeSeriesView(origin=paths.entity(paths.TRACKS), contents=contents, name=name)


def _acceleration_view(track_ids: Sequence[int], name: str) -> rrb.TimeSeriesView:
    contents = [
        paths.entity(paths.track_series(t, s))
        for t in track_ids
        for s in (paths.ACCELERATION_X, paths.ACCELERATION_Y)
    ]
    return rrb.TimeSeriesView(origin=paths.entity(paths.TRACKS), contents=contents, name=name)


def _heading_view(track_ids: Sequence[int], name: str) -> rrb.TimeSeriesView:
    contents = [
        paths.entity(paths.track_series(t, p + paths.HEADING))
        for t in track_ids
        for p in ("", paths.GT_PREFIX)
    ]
    return rrb.TimeSeriesView(origin=paths.entity(paths.TRACKS), contents=contents, name=name)


def debug_blueprint(
    cameras: Sequence[tuple[str, int, int]],
    *,
    lag_track_ids: Sequence[int] = (),
    switch_track_ids: Sequence[int] = (),
) -> rrb.Blueprint:
    """The debugging layout.

    Parameters
    ----------
    cameras : (name, width_px, height_px) of each camera: one 2D view each, framed on the
        image (tabs beyond three cameras).
    lag_track_ids : tracks whose speed / velocity / heading curves (with their matched GT's) get
        their own views: the largest velocity lag. Known only after the run.
    switch_track_ids : tracks of the first ID switch, compared in one speed view.
    """
    # Ego-centric: the view's origin is the ego frame (z up, x = direction of travel), so the
    # eye follows the car at a fixed offset; tracking an entity instead keeps the eye as far
    # away as the whole drive is long.
    scene = rrb.Spatial3DView(
        origin=paths.entity(paths.EGO),
        contents=[
            paths.entity(paths.WORLD) + "/**",
            paths.entity(paths.ID_SWITCH_MARKERS) + "/**",
        ],
        name=VIEW_BEV,
        eye_controls=rrb.EyeControls3D(
            position=BEV_EYE_POSITION_M, look_target=BEV_EYE_TARGET_M, eye_up=(0.0, 0.0, 1.0)
        ),
    )
    cams = [
        rrb.Spatial2DView(
            origin=paths.entity(paths.camera(name)),
            name=f"{VIEW_CAMERA}{name}",
            visual_bounds=rrb.VisualBounds2D(x_range=[0, width], y_range=[0, height]),
        )
        for name, width, height in cameras
    ]
    if not cams:
        camera_area: rrb.Container | rrb.View | None = None
    elif len(cams) <= 3:
        camera_area = rrb.Horizontal(*cams) if len(cams) > 1 else cams[0]
    else:
        camera_area = rrb.Tabs(*cams)
    left = rrb.Vertical(scene, camera_area, row_shares=[3, 2]) if camera_area else scene

    costs = rrb.Tabs(
        rrb.Spatial2DView(
            origin=paths.entity(paths.COST_BEV), name=f"{VIEW_COST_BEV}: tracks (rows) x detections"
        ),
        rrb.Spatial2DView(
            origin=paths.entity(paths.COST_RV),
            name=f"{VIEW_COST_RV} (image plane): tracks x detections",
        ),
        active_tab=0,
    )
    all_tracks = rrb.TimeSeriesView(
        origin=paths.entity(paths.TRACKS),
        name="all tracks (±60 frames)",
        time_ranges=rrb.VisibleTimeRange(
            paths.FRAME,
            start=rrb.TimeRangeBoundary.cursor_relative(seq=-SERIES_WINDOW_FRAMES),
            end=rrb.TimeRangeBoundary.cursor_relative(seq=SERIES_WINDOW_FRAMES),
        ),
    )
    series: list[rrb.View] = []
    if lag_track_ids:
        label = ", ".join(f"T{t}" for t in lag_track_ids)
        series += [
            _speed_view(lag_track_ids, f"{VIEW_SPEED_LAG}: {label} (largest lag)"),
            _xy_view(lag_track_ids, f"vx, vy vs GT: {label}"),
            _heading_view(lag_track_ids, f"heading vs GT: {label}"),
            _acceleration_view(lag_track_ids, f"ax, ay: {label}"),
        ]
    if switch_track_ids:
        label = " / ".join(f"T{t}" for t in switch_track_ids)
        series.append(_speed_view(switch_track_ids, f"speed: {label} (first ID switch)"))
    series.append(all_tracks)
    velocity = rrb.Tabs(*series, active_tab=0)
    text = rrb.Tabs(
        rrb.TextLogView(
            origin=paths.entity(paths.EVENTS),
            contents=["$origin"],
            name=f"{VIEW_ID_EVENTS}, fragmentations",
            rows=rrb.archetypes.TextLogRows(filter_by_log_level=["WARN", "ERROR"]),
        ),
        rrb.TextLogView(
            origin=paths.entity(paths.EVENTS),
            name="all events",
            rows=rrb.archetypes.TextLogRows(filter_by_log_level=["INFO", "WARN", "ERROR"]),
        ),
        rrb.TextDocumentView(origin=paths.entity(paths.SUMMARY), name="summary"),
        active_tab=0,
    )
    right = rrb.Vertical(costs, velocity, text, row_shares=[5, 4, 4])
    return rrb.Blueprint(
        rrb.Horizontal(left, right, column_shares=[3, 2]),
        # collapsed: the timeline bar without the stream tree, the views get the room
        rrb.TimePanel(timeline=paths.FRAME, play_state="paused", state="collapsed"),
        rrb.SelectionPanel(expanded=False),
        rrb.BlueprintPanel(expanded=False),
        collapse_panels=False,
    )
