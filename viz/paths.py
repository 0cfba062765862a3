"""Every entity path and timeline of a recording, defined once: the contract with users and tests.

Paths are written without a leading slash, as ``rr.log`` takes them; a reader of the ``.rrd``
sees them with one (``/world/gt``): use :func:`entity` to compare.
"""

from __future__ import annotations

from typing import Final

APPLICATION_ID: Final = "mctrack_studio"

# timelines
FRAME: Final = "frame"  # sequence: the dataset's frame id
TIME: Final = "time"  # the frame's time (duration since the scene's t=0, or a timestamp)

# 3D world (z up)
WORLD: Final = "world"
DETECTIONS_RAW: Final = "world/detections/raw"  # every input detection; dropped ones say why
DETECTIONS_KEPT: Final = "world/detections/kept"  # after category/score/NMS filtering
TRACKS_PREDICTED: Final = "world/tracks/predicted"  # every live track predicted to the frame
TRACKS_UPDATED: Final = "world/tracks/updated"  # the tracker's output (label = track id)
TRACKS_VELOCITY: Final = "world/tracks/velocity"  # output velocity arrows
TRAILS: Final = "world/trails"  # recent output positions per track
EGO: Final = "world/ego"  # ego pose: Transform3D (z-up, heading = direction of travel) + axes
EGO_PATH: Final = "world/ego_path"  # the whole ego path (static, written at the end; not below
# world/ego, whose children move with the ego)
GT: Final = "world/gt"  # ground-truth boxes (label = GT id)
MATCHES_BEV: Final = "world/matches/bev"  # predicted track -> matched detection, coloured by cost
UNMATCHED_TRACKS: Final = "world/matches/bev/unmatched_tracks"
UNMATCHED_DETECTIONS: Final = "world/matches/bev/unmatched_detections"

# cost matrices (heat map images, rows tracks x columns detections)
COST: Final = "cost"
COST_BEV: Final = "cost/bev"
COST_RV: Final = "cost/rv"
COST_LABELS: Final = "labels"  # child: row ids "T<track>", column ids "d<row>", cell values
COST_MATCHED: Final = "matched"  # child: outlines of the accepted pairs
COST_EXTENT: Final = "extent"  # child: a box in the view's background colour around the matrix

# cameras: the Pinhole is logged at cameras/<name>, so all children share its image plane
CAMERAS: Final = "cameras"

# time series and events
TRACKS: Final = "tracks"
SPEED: Final = "speed"
VELOCITY_X: Final = "velocity_x"
VELOCITY_Y: Final = "velocity_y"
HEADING: Final = "heading"
ACCELERATION_X: Final = "acceleration_x"  # filtered, CA tracks only (no GT counterpart)
ACCELERATION_Y: Final = "acceleration_y"
GT_PREFIX: Final = "gt_"  # tracks/<id>/gt_speed ... : the matched GT's curve
SERIES: Final = (SPEED, VELOCITY_X, VELOCITY_Y, HEADING)
# event_gt/<gt id>/speed: the speed of each ID event's GT object over all its frames, one curve
# (the old and new tracks' tracks/<id>/gt_speed are two pieces of it, one per track)
EVENT_GT: Final = "event_gt"
# noise/<class>: the position filter's measurement variance r (m², x and y), which follows the
# detections' estimated centre noise with pose.r_scale (tracker/noise.py)
NOISE: Final = "noise"
# gate/<class>: the radius of the BEV distance gate in effect (m), which widens with the same
# estimate where bev.gate_motion_m asks (tracker.mctracker: a pair farther apart is not scored)
GATE: Final = "gate"
EVENTS: Final = "events"  # TextLog (WARN): ID switches and fragmentations against the GT
# Lifecycle lines (born, lost, re-acquired, deleted) go one level down: mixed with the WARN rows
# in one entity, the 0.41 viewer showed the last lifecycle row with a WARN level.
EVENTS_LIFECYCLE: Final = "events/lifecycle"
ID_SWITCH_MARKERS: Final = "events/id_switches"  # Points3D at the objects concerned
FOCUS: Final = "focus"  # focus/e<K>/{paths,boxes,explain}: static, per ID event (focused view)
SUMMARY: Final = "summary"  # static TextDocument
SHOT_INDEX: Final = "summary/index"  # static AnyValues: frames worth a screenshot


def camera(name: str) -> str:
    return f"{CAMERAS}/{name}"


def camera_image(name: str) -> str:
    return f"{CAMERAS}/{name}/image"


def camera_detections(name: str) -> str:
    return f"{CAMERAS}/{name}/detections"


def camera_tracks(name: str) -> str:
    return f"{CAMERAS}/{name}/tracks"


def camera_matches_rv(name: str) -> str:
    return f"{CAMERAS}/{name}/matches/rv"


def track_series(track_id: int, series: str) -> str:
    """``tracks/<id>/<series>``; series is one of :data:`SERIES` or ``gt_`` + one of them."""
    return f"{TRACKS}/{track_id}/{series}"


def event_gt_series(gt_id: int, series: str = SPEED) -> str:
    """``event_gt/<gt id>/<series>``: an ID event's GT object's own curve."""
    return f"{EVENT_GT}/{gt_id}/{series}"


def entity(path: str) -> str:
    """The path as a recording reader spells it (leading slash)."""
    return path if path.startswith("/") else f"/{path}"
