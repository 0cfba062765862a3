"""`mctrack kitti --record DIR`: one debug recording per sequence, and the causes of the run's
ID switches and fragmentations (``DIR/causes.md``, ``summary.json`` "causes").

Runs after the timed tracking and the evaluation of :func:`app.kitti.run_kitti`, so each
recording reuses that run's KITTI result file and per-sequence TrackEval metrics instead of
computing them again (see docs/debugger.md, "Recording time").
"""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from tqdm import tqdm

from tracker.config import TrackerConfig
from tracker.events import Event, FrameStarted
from tracker.frame import Frame
from tracker.io.fileio import write_text_atomic


def record_sequences(
    detections: Mapping[str, Sequence[Frame]],
    gt: Mapping[str, Sequence[Frame]] | None,
    config: TrackerConfig,
    record_dir: Path,
    kitti_root: Path,
    label_dir: Path,
    data_dir: Path,
    metrics_per_seq: Mapping[str, dict[str, dict[str, float]]],
    quiet: bool = False,
) -> dict[str, Any]:
    """Record every sequence; returns the summary keys "recordings", "recording_seconds" and,
    with labels, "causes" ({seq: {class: {"IDSW"|"Frag": {cause: n}}}}) and "causes_markdown"."""
    from tracker.eval.id_causes import cause_counts, cause_table_markdown, other_share
    from viz.record import record_scene

    recordings: dict[str, str] = {}
    causes: dict[str, Any] = {}
    seconds: Counter[str] = Counter()
    total = sum(len(f) for f in detections.values())
    with tqdm(
        total=total, unit="frame", desc="recording", disable=quiet or None, file=sys.stderr
    ) as bar:

        def progress(event: Event) -> None:
            if isinstance(event, FrameStarted):
                bar.update(1)

        for seq, frames in detections.items():
            bar.set_description(f"record {seq}")
            has_labels = (label_dir / f"{seq}.txt").is_file()
            cameras = frames[0].cameras if frames else ()
            image_dir = kitti_root / "training" / "image_02" / seq
            images = {cameras[0].name: image_dir} if cameras and image_dir.is_dir() else None
            result_file = data_dir / f"{seq}.txt"
            path = record_dir / f"{seq}.rrd"
            r = record_scene(
                frames,
                config,
                (gt or {}).get(seq),
                path,
                labels_dir=label_dir if has_labels else None,
                images=images,
                input_description=f"KITTI tracking sequence {seq} ({kitti_root})",
                motion_metrics=False,
                kitti_metrics=metrics_per_seq.get(seq),
                result_file=result_file if result_file.is_file() else None,
                progress=progress,
            )
            recordings[seq] = str(path)
            if r.id_evaluation is not None and r.causes:
                causes[seq] = cause_counts(r.causes)
            seconds.update(r.seconds)
    out: dict[str, Any] = {
        "recordings": recordings,
        "recording_seconds": {k: round(v, 2) for k, v in sorted(seconds.items())},
    }
    if causes:
        md = record_dir / "causes.md"
        lines = [
            "# Causes of ID switches and fragmentations",
            "",
            f"Sequences {', '.join(causes)}; classes {', '.join(config.categories)}; events "
            "counted by TrackEval's CLEAR (KITTI 2D-box protocol); causes from "
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
