"""One recording per sequence holding two runs side by side (``mctrack compare --record``).

Two 3D views, A on the left and B on the right, each with the ground truth (grey) and its own
run's tracks (A blue, B orange, labelled ``A T12`` / ``B T7``): one recording, so the time
cursor moves both views together, which two recordings opened side by side would not. The
fixed (green) and introduced (red) events are markers at the GT object in the view of the run
that has the event, rows of a text log (click one to jump to its frame) and a table in the
summary document.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from tracker.frame import Frame
from tracker.io.fileio import finish_temp
from viz import paths
from viz.archetypes import boxes3d_fields, solid
from viz.record import partial_path

RGB_A = (80, 140, 255)
RGB_B = (255, 150, 40)
RGB_GT = (150, 150, 150)
RGB_FIXED = (60, 200, 90)
RGB_INTRODUCED = (240, 60, 60)
RGB_KEPT = (230, 200, 60)

A_TRACKS = "world/a/tracks"
B_TRACKS = "world/b/tracks"
A_MARKERS = "world/a/events"
B_MARKERS = "world/b/events"
EVENTS = "events"
SUMMARY = "summary"


def compare_blueprint(name_a: str, name_b: str) -> rrb.Blueprint:
    """A | B 3D views over the event log and summary."""

    def view(side: str, name: str) -> rrb.Spatial3DView:
        return rrb.Spatial3DView(
            origin="/world",
            contents=["/world/gt/**", f"/world/{side}/**"],
            name=f"{side.upper()}: {name}",
        )

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(view("a", name_a), view("b", name_b)),
            rrb.Horizontal(
                rrb.TextLogView(origin=f"/{EVENTS}", name="fixed / introduced"),
                rrb.TextDocumentView(origin=f"/{SUMMARY}", name="summary"),
                column_shares=[3, 2],
            ),
            row_shares=[3, 1],
        ),
        rrb.TimePanel(timeline=paths.FRAME, play_state="paused", expanded=True),
        rrb.SelectionPanel(expanded=False),
        rrb.BlueprintPanel(expanded=False),
        collapse_panels=False,
    )


def _by_frame(frames: Sequence[Frame] | None) -> dict[int, Frame]:
    return {f.frame_id: f for f in frames or ()}


def _gt_xyz(gt: Mapping[int, Frame], frame_id: int, gt_id: int) -> np.ndarray | None:
    f = gt.get(frame_id)
    if f is None:
        return None
    hit = np.flatnonzero(f.boxes.track_id == gt_id)
    return f.boxes.xyz[hit[0]] if len(hit) else None


def record_comparison(
    path: str | Path,
    sequence: str,
    frames_a: Sequence[Frame],
    frames_b: Sequence[Frame],
    gt_frames: Sequence[Frame] | None,
    pairs: Sequence[Mapping[str, Any]],
    *,
    names: tuple[str, str] = ("A", "B"),
    summary_markdown: str = "",
) -> Path:
    """Write ``path`` (complete or absent). ``frames_a`` / ``frames_b``: each run's tracks
    (boxes with ``track_id``) per frame; ``pairs``: this sequence's matched events
    (:func:`tracker.eval.compare.match_events`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = partial_path(path)
    rec = rr.RecordingStream(paths.APPLICATION_ID, recording_id=f"compare-{sequence}")
    rec.save(str(partial), default_blueprint=compare_blueprint(*names))
    rec.send_recording_name(f"compare {sequence}: {names[0]} | {names[1]}")
    rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(SUMMARY, rr.TextDocument(summary_markdown, media_type="text/markdown"), static=True)
    a, b, gt = _by_frame(frames_a), _by_frame(frames_b), _by_frame(gt_frames)
    markers: dict[int, list[tuple[str, Mapping[str, Any], str]]] = {}
    for p in pairs:
        if p["status"] == "kept":
            continue  # markers and log rows only for what changed
        e = p["a"] if p["status"] == "fixed" else p["b"]
        side = "a" if p["status"] == "fixed" else "b"
        markers.setdefault(int(e["frame"]), []).append((side, e, p["status"]))
    for f in sorted(set(a) | set(b) | set(gt) | set(markers)):
        rec.set_time(paths.FRAME, sequence=f)
        for entity, frame, rgb, prefix in (
            ("world/gt", gt.get(f), RGB_GT, "GT"),
            (A_TRACKS, a.get(f), RGB_A, "A T"),
            (B_TRACKS, b.get(f), RGB_B, "B T"),
        ):
            if frame is None:
                continue
            boxes = frame.boxes
            labels = [f"{prefix}{int(t)}" for t in boxes.track_id]
            fields = boxes3d_fields(
                boxes, colors=solid(rgb, len(boxes)), labels=labels, radius=0.03
            )
            rec.log(entity, rr.Boxes3D(**fields, fill_mode="majorwireframe"))
        at = markers.get(f, [])
        for side, entity in (("a", A_MARKERS), ("b", B_MARKERS)):
            mine = [(e, s) for sd, e, s in at if sd == side]
            xyz = [_gt_xyz(gt, f, int(e["gt_id"])) for e, _ in mine]
            shown = [(x, e, s) for x, (e, s) in zip(xyz, mine, strict=True) if x is not None]
            if shown:
                rec.log(
                    entity,
                    rr.Points3D(
                        np.stack([x for x, _, _ in shown]),
                        radii=0.6,
                        colors=[RGB_FIXED if s == "fixed" else RGB_INTRODUCED for *_, s in shown],
                        labels=[f"{s}: {e['kind']} GT{e['gt_id']}" for _, e, s in shown],
                    ),
                )
            else:
                rec.log(entity, rr.Clear(recursive=False))
        for _side, e, status in at:
            cause = f" ({e['cause']})" if e.get("cause") else ""
            rec.log(
                EVENTS,
                rr.TextLog(
                    f"{status}: {e['kind']} frame {e['frame']} {e['class']} GT{e['gt_id']} "
                    f"T{e['old_track']}->T{e['new_track']}{cause}",
                    level="INFO" if status == "fixed" else "WARN",
                ),
            )
    rec.flush()
    rec.disconnect()
    finish_temp(partial, path)
    return path
