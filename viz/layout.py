"""The default blueprint embedded in every recording: a layout for debugging a tracker run.

Left: the BEV / 3D scene (following the ego) over the camera views. Right: the two cost
matrices, the velocity curves, and the events log next to the summary. The time panel starts
paused on the ``frame`` timeline, so a recording opens on a still picture.
"""

from __future__ import annotations

from collections.abc import Sequence

import rerun.blueprint as rrb

from viz import paths
from viz.archetypes import BACKGROUND_RGB

# view names (``mctrack shots`` finds the views by these prefixes)
VIEW_BEV = "BEV / 3D"
VIEW_CAMERA = "camera "
VIEW_COST_BEV = "cost BEV"
VIEW_COST_RV = "cost RV"
VIEW_SPEED_LAG = "speed vs GT"
VIEW_ID_EVENTS = "ID switches"
#: Frames either side of the cursor shown by the "all tracks" time series.
SERIES_WINDOW_FRAMES = 60
#: Every curve of every track (and its GT's) shares this view, so its name lists them all.
VIEW_ALL_TRACKS = (
    "all tracks: speed, vx, vy [m/s], ax, ay [m/s²], heading [rad]"
    f" (±{SERIES_WINDOW_FRAMES} frames)"
)

#: The cost views' background: the colour of the unseen box that frames each matrix
#: (``cost/*/extent``), whatever the viewer's theme.
_COST_BACKGROUND = rrb.Background(kind="SolidColor", color=BACKGROUND_RGB)
#: The BEV eye in the ego frame (metres): behind and above the car, looking ahead of it.
BEV_EYE_POSITION_M = (-16.0, 0.0, 26.0)
BEV_EYE_TARGET_M = (16.0, 0.0, 0.0)


def _speed_view(
    track_ids: Sequence[int],
    name: str,
    speed_max_mps: float | None = None,
    gt_id: int | None = None,
) -> rrb.TimeSeriesView:
    """The tracks' speed with their matched GT's (``tracks/<id>/gt_speed``), or, for an ID
    event's tracks (``gt_id``), with that one GT object's curve (``event_gt/<id>/speed``): both
    tracks matched it, so their GT curves were two pieces of it, drawn as two curves."""
    own = [paths.entity(paths.track_series(t, paths.SPEED)) for t in track_ids]
    if gt_id is None:
        gt_speed = paths.GT_PREFIX + paths.SPEED
        gts = [paths.entity(paths.track_series(t, gt_speed)) for t in track_ids]
    else:
        gts = [paths.entity(paths.event_gt_series(gt_id))]
    contents = [*own, *gts]
    axis = rrb.ScalarAxis(range=(0.0, speed_max_mps)) if speed_max_mps else None
    return rrb.TimeSeriesView(
        origin=paths.entity(paths.TRACKS), contents=contents, name=name, axis_y=axis
    )


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
    switch_gt_id: int | None = None,
    lag_speed_max_mps: float | None = None,
    noise_view: bool = False,
    gate_view: bool = False,
) -> rrb.Blueprint:
    """The debugging layout.

    Parameters
    ----------
    cameras : (name, width_px, height_px) of each camera: one 2D view each, framed on the
        image (tabs beyond three cameras).
    lag_track_ids : tracks whose speed / velocity / heading curves (with their matched GT's) get
        their own views: the largest velocity lag. Known only after the run.
    switch_track_ids : tracks of the first ID switch, compared in one speed view.
    switch_gt_id : its GT object, whose speed that view shows once (None: each track's GT).
    lag_speed_max_mps : top of the lag speed view's y axis (m/s; None: fit all data).
    noise_view : a view of the position filter's r per class over time (a config with
        ``pose.r_scale``: r follows the detections' estimated noise).
    gate_view : a view of the BEV distance gate's radius per class over time (a config with
        ``bev.gate_motion_m``: the gate widens with the same estimate).
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
            origin=paths.entity(paths.COST_BEV),
            name=f"{VIEW_COST_BEV}: tracks (rows) x detections",
            background=_COST_BACKGROUND,
        ),
        rrb.Spatial2DView(
            origin=paths.entity(paths.COST_RV),
            name=f"{VIEW_COST_RV} (image plane): tracks x detections",
            background=_COST_BACKGROUND,
        ),
        active_tab=0,
    )
    all_tracks = rrb.TimeSeriesView(
        origin=paths.entity(paths.TRACKS),
        name=VIEW_ALL_TRACKS,
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
            _speed_view(
                lag_track_ids, f"{VIEW_SPEED_LAG} [m/s]: {label} (largest lag)", lag_speed_max_mps
            ),
            _xy_view(lag_track_ids, f"vx, vy vs GT [m/s]: {label}"),
            _heading_view(lag_track_ids, f"heading vs GT [rad]: {label}"),
            _acceleration_view(lag_track_ids, f"ax, ay [m/s²]: {label}"),
        ]
    if switch_track_ids:
        label = " / ".join(f"T{t}" for t in switch_track_ids)
        series.append(
            _speed_view(
                switch_track_ids, f"speed [m/s]: {label} (first ID switch)", gt_id=switch_gt_id
            )
        )
    series.append(all_tracks)
    if noise_view:
        series.append(
            rrb.TimeSeriesView(
                origin=paths.entity(paths.NOISE),
                name="position r [m²] per class (from the detections' noise)",
            )
        )
    if gate_view:
        series.append(
            rrb.TimeSeriesView(
                origin=paths.entity(paths.GATE),
                name="BEV distance gate [m] per class (widens with the detections' noise)",
            )
        )
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
    return _paused(rrb.Horizontal(left, right, column_shares=[3, 2]))


def _paused(root: rrb.Container) -> rrb.Blueprint:
    """A blueprint paused on the frame timeline, panels collapsed (the views get the room)."""
    return rrb.Blueprint(
        root,
        rrb.TimePanel(timeline=paths.FRAME, play_state="paused", state="collapsed"),
        rrb.SelectionPanel(expanded=False),
        rrb.BlueprintPanel(expanded=False),
        collapse_panels=False,
    )


#: The focused view's eye relative to the event (metres, world z up): behind-left and above,
#: close enough that a pedestrian's box is legible, far enough for both trails.
FOCUS_EYE_OFFSET_M = (-6.0, -6.0, 11.0)
VIEW_FOCUS = "focus "
VIEW_EXPLAIN = "event"
#: Everything not part of the event is drawn in this colour in the focused view.
DIM_RGB = (70, 70, 78)


def focus_eye(target_xyz: Sequence[float]) -> rrb.EyeControls3D:
    """Eye looking at ``target_xyz`` from :data:`FOCUS_EYE_OFFSET_M` (z up)."""
    target = [float(v) for v in target_xyz]
    position = [t + o for t, o in zip(target, FOCUS_EYE_OFFSET_M, strict=True)]
    return rrb.EyeControls3D(position=position, look_target=target, eye_up=(0.0, 0.0, 1.0))


def focus_blueprint(
    cameras: Sequence[tuple[str, int, int]],
    *,
    event_index: int,
    target_xyz: Sequence[float],
    track_ids: Sequence[int],
    gt_id: int | None = None,
) -> rrb.Blueprint:
    """One ID event, focused: a world-frame 3D view centred on the event with the old/new tracks'
    trails, the GT path and their three boxes bright (``focus/e<K>``) and everything else dimmed,
    the camera, the BEV cost matrix, the event's explanation (cause, evidence, the cost rows of
    both tracks at the deciding frame) and both tracks' speed against their GT."""
    focus = f"{paths.FOCUS}/e{event_index}"
    dim = {
        paths.entity(p): _dim_boxes()
        for p in (
            paths.TRACKS_UPDATED,
            paths.TRACKS_PREDICTED,
            paths.GT,
            paths.DETECTIONS_RAW,
            paths.DETECTIONS_KEPT,
        )
    }
    scene = rrb.Spatial3DView(
        origin=paths.entity(paths.WORLD),
        contents=[
            paths.entity(paths.WORLD) + "/**",
            "- " + paths.entity(paths.TRACKS_VELOCITY),
            "- " + paths.entity(paths.MATCHES_BEV) + "/**",
            paths.entity(focus) + "/**",
            paths.entity(paths.ID_SWITCH_MARKERS),
        ],
        name=f"{VIEW_FOCUS}#{event_index}",
        eye_controls=focus_eye(target_xyz),
        overrides=dim,
    )
    cams = [
        rrb.Spatial2DView(
            origin=paths.entity(paths.camera(name)),
            name=f"{VIEW_CAMERA}{name}",
            visual_bounds=rrb.VisualBounds2D(x_range=[0, width], y_range=[0, height]),
        )
        for name, width, height in cameras[:1]
    ]
    left = rrb.Vertical(scene, *cams, row_shares=[3, 2]) if cams else scene
    ids = [t for t in track_ids if t >= 0]
    right = rrb.Vertical(
        rrb.TextDocumentView(origin=paths.entity(f"{focus}/explain"), name=VIEW_EXPLAIN),
        rrb.Spatial2DView(
            origin=paths.entity(paths.COST_BEV),
            name=f"{VIEW_COST_BEV}: tracks (rows) x detections",
            background=_COST_BACKGROUND,
        ),
        _speed_view(
            ids,
            "speed [m/s]: "
            + " / ".join(f"T{t}" for t in ids)
            + (f" and GT {gt_id}" if gt_id is not None else ""),
            gt_id=gt_id,
        ),
        row_shares=[5, 3, 2],
    )
    return _paused(rrb.Horizontal(left, right, column_shares=[3, 2]))


def _dim_boxes() -> object:
    import rerun as rr

    return rr.Boxes3D.from_fields(colors=[DIM_RGB], show_labels=False)
