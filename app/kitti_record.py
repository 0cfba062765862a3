"""`mctrack kitti --record DIR`: one debug recording per sequence, and the causes of the run's
ID switches and fragmentations (``DIR/causes.md``, ``summary.json`` "causes").

:func:`record_sequence` runs inside each sequence's task (:class:`app.kitti.KittiSceneJob`): it
tracks the sequence once, with the recording's observers, hands the outputs to the task (which
writes the KITTI result file), evaluates that file once (TrackEval's metrics and the ID events
from one loading; the run's combined metrics are made from these) and finishes the recording;
:func:`recording_summary` gathers the tasks' results into the summary.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tracker.config import TrackerConfig
from tracker.events import TrackOutput
from tracker.frame import Frame
from tracker.io.fileio import path_in, write_text_atomic

if TYPE_CHECKING:
    from viz.record import RecordResult

LOG = logging.getLogger(__name__)


def record_sequence(
    frames: Sequence[Frame],
    gt_frames: Sequence[Frame] | None,
    config: TrackerConfig,
    record_dir: Path,
    kitti_root: Path,
    label_dir: Path,
    result_file: Path,
    on_tracked: Callable[[list[TrackOutput]], None],
) -> tuple[RecordResult, dict[str, Any]]:
    """Track and record one sequence (its camera images too, where ``image_02/<seq>`` exists).

    The sequence is tracked once, with the recording's observers; ``on_tracked`` gets the
    outputs right after tracking (the task writes ``result_file`` there), and the recording's
    TrackEval evaluation of that file (metrics and ID events from one loading) comes back in
    the result for the run's combined metrics. Returns the result and plain data for the
    task's ``info``: "recording" (path), "recording_seconds" (per phase) and, with labels,
    "causes" ({class: {"IDSW"|"Frag": {cause: n}}})."""
    from tracker.eval.id_causes import cause_counts
    from viz.record import record_scene

    seq = frames[0].scene if frames else ""
    has_labels = path_in(label_dir, seq, ".txt").is_file()
    cameras = frames[0].cameras if frames else ()
    image_dir = path_in(kitti_root / "training" / "image_02", seq, "")
    images = {cameras[0].name: image_dir} if cameras and image_dir.is_dir() else None
    path = path_in(record_dir, seq, ".rrd")
    r = record_scene(
        frames,
        config,
        gt_frames,
        path,
        labels_dir=label_dir if has_labels else None,
        images=images,
        input_description=f"KITTI tracking sequence {seq} ({kitti_root})",
        motion_metrics=False,
        result_file=result_file,
        on_tracked=on_tracked,
    )
    info: dict[str, Any] = {"recording": str(path), "recording_seconds": dict(r.seconds)}
    if r.skipped_images:  # (a file that cannot be read or decoded: the observer left it out)
        info["skipped_images"] = list(r.skipped_images)
    if r.id_evaluation is not None:  # {} when evaluated without an event
        info["causes"] = cause_counts(r.causes)
    return r, info


def recording_summary(
    records: Sequence[Any], config: TrackerConfig, record_dir: Path
) -> dict[str, Any]:
    """Summary keys "recordings", "recording_seconds" (summed per phase), with labels "causes"
    (per sequence), "causes_other_share" and "causes_markdown" (``record_dir/causes.md``, the
    table of :func:`tracker.eval.id_causes.cause_table_markdown`) and, when a camera image
    could not be read or decoded, "recording_skipped_images" ({sequence: [the file and why]}:
    recorded without it, each also a warning)."""
    from tracker.eval.id_causes import cause_table_markdown, other_share

    recordings = {r.scene: r.info["recording"] for r in records if "recording" in r.info}
    skipped = {r.scene: r.info["skipped_images"] for r in records if "skipped_images" in r.info}
    for seq, lines in skipped.items():
        for line in lines:
            LOG.warning("recording %s: without %s", seq, line)
    seconds: Counter[str] = Counter()
    for r in records:
        seconds.update(r.info.get("recording_seconds", {}))
    evaluated = [r.scene for r in records if "causes" in r.info]
    causes = {r.scene: r.info["causes"] for r in records if r.info.get("causes")}
    # the header names every evaluated sequence: one without events is not left out unsaid
    quiet = [s for s in evaluated if s not in causes]
    no_event = f" ({', '.join(quiet)}: no event)" if quiet else ""
    out: dict[str, Any] = {
        "recordings": recordings,
        "recording_seconds": {k: round(v, 2) for k, v in sorted(seconds.items())},
    }
    if skipped:
        out["recording_skipped_images"] = skipped
    if causes:
        md = record_dir / "causes.md"
        lines = [
            "# Causes of ID switches and fragmentations",
            "",
            f"Sequences {', '.join(evaluated)}{no_event}; classes {', '.join(config.categories)}; "
            "events counted by TrackEval's CLEAR (KITTI 2D-box protocol); causes from "
            "tracker/eval/id_causes.py.",
            "",
            *cause_table_markdown(causes),
            "",
            f'Share of "other": {other_share(causes):.1%}.',
            "",
        ]
        write_text_atomic(md, ["\n".join(lines)])
        out["causes"] = causes
        out["causes_other_share"] = round(other_share(causes), 4)
        out["causes_markdown"] = str(md)
    return out
