"""`mctrack waymo`: convert ImmortalTracker-style Waymo files, track, and write the per-segment
result ``.npz`` files (ImmortalTracker / MCTrack convention) plus the tracks file.

The official Waymo metrics need the ``pred.bin`` protobuf, made from these files by the
reference's ``pred_bin.py`` (TensorFlow + waymo-open-dataset): docs/nuscenes_waymo.md."""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app import scenes
from app.common import (
    outputs_removed_on_failure,
    print_motion,
    refuse_inputs_among_outputs,
    remove_earlier_outputs,
    write_motion_metrics,
)
from app.inputs import add_mode_argument
from app.outputs import (
    holds_a_run,
    outputs_at_stake,
    outputs_of,
    outputs_replaced_by,
    refuse_foreign_results,
)
from app.scenes import SceneRecord
from tracker.config import TrackerConfig, config_to_dict, load_config
from tracker.errors import InputError
from tracker.eval.fates import combine_fates
from tracker.frame import Frame
from tracker.io.fileio import (
    check_output_folder,
    refuse_case_collisions,
    write_bytes_atomic,
    write_text_atomic,
)
from tracker.io.waymo_writer import RESULT_TYPES
from tracker.io.writers import tracks_scene_json


def _csv(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data-root", required=True, help="folder with ego_info/ and ts_info/")
    parser.add_argument("--detections", required=True, help="folder of <segment>.npz detections")
    parser.add_argument("--gt", default=None, help="folder of <segment>.npz ground truth (ids)")
    parser.add_argument("--segments", type=_csv, default=None, help="segment names (default all)")
    parser.add_argument("--config", default="waymo", help="waymo or a TOML path")
    add_mode_argument(parser)
    parser.add_argument("--motion", action="store_true", help="motion metrics (needs --gt)")
    parser.add_argument(
        "--record",
        action="store_true",
        help="also write a Rerun recording per segment to OUT/recordings/<segment>.rrd",
    )
    parser.add_argument("--out", required=True, help="output folder")
    scenes.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    check_output_folder(args.out)  # before any work
    summary = run_waymo(
        data_root=Path(args.data_root),
        detections=Path(args.detections),
        gt=Path(args.gt) if args.gt else None,
        segments=args.segments,
        config_name=args.config,
        mode=args.mode,
        motion=args.motion,
        record=args.record,
        out=Path(args.out),
        parallel=scenes.from_args(args),
    )
    failed = summary["failed"]
    names = [*summary["segments"], *failed]  # (its "segments" are those tracked)
    head = scenes.tracked_head(failed, names, "segment")
    if head:
        print(
            f"{head}, {summary['frames']} frames, "
            f"{summary['tracker_fps'] or '-'} frames/s -> {summary['results']} "
            f"{summary['boxes_written']}"
        )
    if failed:
        note = "results written for the others alone" if summary["segments"] else "no results"
        print(scenes.failed_run_line(failed, names, "segment", note))
    print_motion(summary.get("motion"))  # (as `mctrack kitti`: the table; motion.md beside)
    return scenes.print_failures("waymo", failed)


@dataclass(frozen=True, slots=True)
class WaymoSceneJob:
    """One Waymo segment as a task: convert it (by path), track it, write its result files."""

    data_root: Path
    detections: Path
    gt: Path | None
    config: TrackerConfig
    out: Path
    keep: bool  # send the frames and outputs back (the motion metrics need them)
    record: bool = False  # also a Rerun recording, OUT/recordings/<segment>.rrd

    def process(self, index: int, scene: str, frames: list[Frame] | None) -> SceneRecord:
        from tracker.io.convert.waymo import convert_waymo
        from tracker.io.waymo_writer import write_waymo_results

        conv = convert_waymo(self.data_root, self.detections, gt=self.gt, segments=[scene])
        frames = conv.detections[scene]
        gt_frames = conv.gt[scene] if conv.gt is not None else None
        info: dict[str, Any] = {
            "skipped_types": dict(conv.skipped_types),
            "unknown_types": dict(conv.unknown_types),
        }
        result = scenes.track_or_record(frames, gt_frames, self.config, self.out, scene,
                                        record=self.record, info=info)  # fmt: skip
        written = write_waymo_results(self.out / "results", {scene: (frames, result.outputs)})
        write_bytes_atomic(
            scenes.part_path(self.out, index, "json"),
            tracks_scene_json(scene, frames, result.outputs),
        )
        info["written"] = written
        return SceneRecord(
            index,
            scene,
            frames=len(frames),
            tracker_seconds=result.tracker_seconds,
            info=info,
            kept=(frames, gt_frames, result.outputs) if self.keep else None,
        )


def run_waymo(
    *,
    data_root: Path,
    detections: Path,
    out: Path,
    gt: Path | None = None,
    segments: list[str] | None = None,
    config_name: str | Path = "waymo",
    mode: str | None = None,
    motion: bool = False,
    record: bool = False,
    quiet: bool = False,
    parallel: scenes.Parallelism = scenes.SEQUENTIAL,
) -> dict[str, Any]:
    """The end-to-end Waymo job; returns (and writes) ``out/summary.json``.

    Each segment is one task (:mod:`app.scenes`); a segment with bad input fails alone.
    """
    if motion and gt is None:
        raise InputError("--motion needs --gt (the ground-truth npz folder)")
    config = load_config(config_name, overrides={"mode": mode} if mode else None)
    from tracker.io.convert.waymo import segment_names

    names = segment_names(data_root, detections, segments)
    # (files per segment: results/<type>/<segment>.npz)
    refuse_case_collisions(names, "--segments" if segments else detections, "segments", ".npz")
    # of its segments: in the folder of a run cut short, another results/*/*.npz (or
    # recording) is refused, not kept to mix into the submission pred_bin.py reads
    inputs = {"--data-root": data_root, "--detections": detections, "--gt": gt}
    at_stake = outputs_at_stake("waymo", out, names, record=record)
    # (in a finished run's folder a user's results/<type>/x.npz stays, but pred_bin.py would
    # put it in this run's submission)
    refuse_foreign_results(out, at_stake)
    refuse_inputs_among_outputs(out, at_stake, inputs, outputs_of("waymo", names, record=record))
    # a refused run keeps the earlier one; else its files (of any command) go: pred_bin.py reads
    # every file of results/, and a segment left out or failing now would keep its old results
    # (of results/, the files of the segments its summary lists: a file of anyone's stays)
    if holds_a_run(out):
        remove_earlier_outputs(out, outputs_replaced_by("waymo", out, names, record=record))
    # from here on the run writes: one stopped (Ctrl-C, an error) removes what it wrote, so
    # OUT never holds results/ without the summary.json that marks a complete run
    with outputs_removed_on_failure(out, outputs_of("waymo")):
        job = WaymoSceneJob(data_root, detections, gt, config, out, keep=motion, record=record)
        t0 = time.perf_counter()
        records = scenes.run_scenes(job, names, parallel=parallel, quiet=quiet)
        wall_secs = time.perf_counter() - t0
        ok = [r for r in records if r.error is None]
        scenes.write_tracks(out, ok)
        written = dict.fromkeys(RESULT_TYPES, 0)
        skipped: Counter[int] = Counter()
        unknown: Counter[int] = Counter()
        for r in ok:
            written.update({k: written[k] + v for k, v in r.info["written"].items()})
            skipped.update(r.info["skipped_types"])
            unknown.update(r.info["unknown_types"])
        frames = sum(r.frames for r in ok)
        seconds = sum(r.tracker_seconds for r in ok)
        summary: dict[str, Any] = {
            "command": "waymo",  # (marks its folder a run's: app.outputs.holds_a_run)
            "dataset": "waymo",
            "segments": [r.scene for r in ok],
            "frames": frames,
            "results": str(out / "results"),
            "boxes_written": written,
            "tracker_seconds": round(seconds, 4),
            "tracker_fps": round(frames / seconds, 1) if seconds > 0 else None,
            "skipped_types": {str(k): v for k, v in sorted(skipped.items())},
            # (codes that are no Waymo type: dropped, each file warned about)
            "unknown_types": {str(k): v for k, v in sorted(unknown.items())},
            **scenes.summary_fields(records, parallel, wall_secs),
            "detection_fates": combine_fates([r.info["fates"] for r in records if r.error is None]),
            "config": config_to_dict(config),
        }
        recordings = [r.info["recording"] for r in ok if "recording" in r.info]
        if recordings:
            summary["recordings"] = recordings
        if motion and gt is not None:
            from tracker.io.baseversion import write_baseversion

            det_scenes = {r.scene: r.kept[0] for r in ok}
            gt_scenes = {r.scene: r.kept[1] for r in ok}
            write_baseversion(out / "gt.json", gt_scenes)
            summary["motion"] = write_motion_metrics(
                det_scenes,
                gt_scenes,
                {r.scene: r.kept[2] for r in ok},
                ["car", "pedestrian", "cyclist"],
                out,
            )
        write_text_atomic(out / "summary.json", [json.dumps(summary, indent=2, allow_nan=False)])
    return summary
