"""`mctrack waymo`: convert ImmortalTracker-style Waymo files, track, and write the per-segment
result ``.npz`` files (ImmortalTracker / MCTrack convention) plus the tracks file.

The official Waymo metrics need the ``pred.bin`` protobuf, made from these files by the
reference's ``pred_bin.py`` (TensorFlow + waymo-open-dataset): docs/nuscenes_waymo.md."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from tqdm import tqdm

from app.inputs import recording_path
from tracker.config import config_to_dict, load_config
from tracker.events import TrackOutput
from tracker.io.fileio import write_text_atomic


def _csv(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data-root", required=True, help="folder with ego_info/ and ts_info/")
    parser.add_argument("--detections", required=True, help="folder of <segment>.npz detections")
    parser.add_argument("--gt", default=None, help="folder of <segment>.npz ground truth (ids)")
    parser.add_argument("--segments", type=_csv, default=None, help="segment names (default all)")
    parser.add_argument("--config", default="waymo", help="waymo or a TOML path")
    parser.add_argument(
        "--mode",
        choices=["online", "offline"],
        default=None,
        help="tracking mode (default: the config's)",
    )
    parser.add_argument("--motion", action="store_true", help="motion metrics (needs --gt)")
    parser.add_argument(
        "--record",
        action="store_true",
        help="also write a Rerun recording per segment to OUT/recordings/<segment>.rrd",
    )
    parser.add_argument("--out", required=True, help="output folder")


def run(args: argparse.Namespace) -> int:
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
    )
    print(
        f"{len(summary['segments'])} segments, {summary['frames']} frames, "
        f"{summary['tracker_fps']} frames/s -> {summary['results']} {summary['boxes_written']}"
    )
    return 0


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
) -> dict[str, Any]:
    """The end-to-end Waymo job; returns (and writes) ``out/summary.json``; with ``record``
    also one Rerun recording per segment in ``out/recordings/``."""
    from tracker.errors import InputError
    from tracker.io.convert.waymo import convert_waymo
    from tracker.io.waymo_writer import write_waymo_results
    from tracker.io.writers import write_tracks_file
    from tracker.pipeline import run_scene

    if motion and gt is None:
        raise InputError("--motion needs --gt (the ground-truth npz folder)")
    config = load_config(config_name, overrides={"mode": mode} if mode else None)
    conv = convert_waymo(data_root, detections, gt=gt, segments=segments)
    outputs: dict[str, list[TrackOutput]] = {}
    seconds = 0.0
    frames = sum(len(f) for f in conv.detections.values())
    recordings: list[str] = []
    with tqdm(total=frames, unit="frame", disable=quiet or None, file=sys.stderr) as bar:
        for name, scene_frames in conv.detections.items():
            if record:
                from viz.record import record_scene

                path = recording_path(out, name)
                gt_frames = conv.gt.get(name) if conv.gt else None
                result = record_scene(scene_frames, config, gt_frames, path)
                recordings.append(str(path))
            else:
                result = run_scene(scene_frames, config)
            outputs[name], seconds = result.outputs, seconds + result.tracker_seconds
            bar.update(len(scene_frames))
    results = {s: (conv.detections[s], outputs[s]) for s in conv.detections}
    written = write_waymo_results(out / "results", results)
    write_tracks_file(out / "tracks.json", results)
    summary: dict[str, Any] = {
        "dataset": "waymo",
        "segments": list(conv.detections),
        "frames": frames,
        "results": str(out / "results"),
        "boxes_written": written,
        "tracker_seconds": round(seconds, 4),
        "tracker_fps": round(frames / seconds, 1) if seconds > 0 else None,
        "skipped_types": {str(k): v for k, v in sorted(conv.skipped_types.items())},
        "config": config_to_dict(config),
    }
    if recordings:
        summary["recordings"] = recordings
    if motion and conv.gt is not None:
        from tracker.eval.motion_eval import evaluate_motion
        from tracker.io.baseversion import write_baseversion

        write_baseversion(out / "gt.json", conv.gt)
        summary["motion"] = evaluate_motion(
            conv.detections, conv.gt, outputs, classes=["car", "pedestrian", "cyclist"]
        )
    write_text_atomic(out / "summary.json", [json.dumps(summary, indent=2, allow_nan=False)])
    return summary
