"""`mctrack nuscenes`: convert, track, write the nuScenes tracking submission, evaluate it with
the official devkit (AMOTA, AMOTP, MOTA, IDS, recall), and summarise. docs/nuscenes_waymo.md"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from tqdm import tqdm

from app.common import peak_rss_mb
from app.inputs import recording_path
from tracker.config import TrackingMode, config_to_dict, load_config
from tracker.errors import InputError
from tracker.events import TrackOutput
from tracker.frame import Frame
from tracker.io.fileio import write_text_atomic


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataroot", required=True, help="nuScenes root (holds <version>/)")
    parser.add_argument("--version", default="v1.0-trainval", help="v1.0-trainval/-mini/-test")
    parser.add_argument("--split", default="val", help="val, mini_val, test or a custom split")
    parser.add_argument("--detections", required=True, help="detection results JSON")
    parser.add_argument("--config", default="nuscenes", help="nuscenes or a TOML path")
    parser.add_argument(
        "--mode",
        choices=["online", "offline"],
        default=None,
        help="tracking mode (default: the config's)",
    )
    parser.add_argument(
        "--scenes",
        default=None,
        help="comma-separated scene names (default: the whole split; a subset is not evaluated, "
        "the official evaluation needs every sample of the split)",
    )
    parser.add_argument("--score-min", type=float, default=0.0, help="drop detections below this")
    parser.add_argument("--no-eval", action="store_true", help="skip the official evaluation")
    parser.add_argument(
        "--motion", action="store_true", help="also the motion metrics (needs the annotations)"
    )
    parser.add_argument(
        "--record",
        action="store_true",
        help="write a Rerun debug recording per scene to OUT/recordings/<scene>.rrd "
        "(viz.record.record_scene; needs rerun-sdk)",
    )
    parser.add_argument("--out", required=True, help="output folder")


def run(args: argparse.Namespace) -> int:
    summary = run_nuscenes(
        dataroot=Path(args.dataroot),
        version=args.version,
        split=args.split,
        detections=Path(args.detections),
        config_name=args.config,
        mode=args.mode,
        scenes=[s.strip() for s in args.scenes.split(",") if s.strip()] if args.scenes else None,
        score_min=args.score_min,
        evaluate=not args.no_eval,
        motion=args.motion,
        record=args.record,
        out=Path(args.out),
    )
    _print_summary(summary)
    return 0


def run_nuscenes(
    *,
    dataroot: Path,
    version: str,
    split: str,
    detections: Path,
    out: Path,
    config_name: str | Path = "nuscenes",
    mode: str | None = None,
    scenes: list[str] | None = None,
    score_min: float = 0.0,
    evaluate: bool = True,
    motion: bool = False,
    record: bool = False,
    quiet: bool = False,
) -> dict[str, Any]:
    """The end-to-end nuScenes job; returns (and writes) ``out/summary.json``.

    Writes ``out/results.json`` (the tracking submission, checked with the devkit's loader),
    ``out/tracks.json`` (the tracks file, for ``mctrack eval`` / ``mctrack view``), with
    ``motion`` also ``out/gt.json``, ``out/motion.md`` and the velocity PNG, and with ``record``
    one ``.rrd`` per scene in ``out/recordings/``.
    """
    from tracker.eval.nuscenes import evaluate_nuscenes, load_results_with_devkit
    from tracker.io.convert.nuscenes import convert_nuscenes, load_nuscenes
    from tracker.io.nuscenes_writer import write_nuscenes_results
    from tracker.io.writers import write_tracks_file
    from tracker.pipeline import run_scene

    config = load_config(config_name, overrides={"mode": mode} if mode else None)
    has_gt = not version.endswith("test")
    want_gt = has_gt and (motion or record)
    t0 = time.perf_counter()
    nusc = load_nuscenes(dataroot, version)
    conv = convert_nuscenes(
        dataroot,
        version=version,
        detections=detections,
        split=split,
        with_gt=want_gt,
        score_min=score_min,
        nusc=nusc,
    )
    del nusc  # several GB on v1.0-trainval; the evaluation loads its own copy
    det_scenes = conv.detections
    if scenes:
        missing = [s for s in scenes if s not in det_scenes]
        if missing:
            raise InputError(f"--scenes: not in split {split!r}: {missing}")
        det_scenes = {s: det_scenes[s] for s in scenes}
    convert_secs = time.perf_counter() - t0

    outputs: dict[str, list[TrackOutput]] = {}
    tracker_secs = 0.0
    recordings: list[str] = []
    total_frames = sum(len(f) for f in det_scenes.values())
    with tqdm(total=total_frames, unit="frame", disable=quiet or None, file=sys.stderr) as bar:
        for name, frames in det_scenes.items():
            bar.set_description(name)
            if record:
                from viz.record import record_scene

                gt_frames = conv.gt.get(name) if conv.gt else None
                path = recording_path(out, name)
                result = record_scene(frames, config, gt_frames, path)
                outputs[name], seconds = result.outputs, result.tracker_seconds
                recordings.append(str(path))
            else:
                scene_result = run_scene(frames, config)
                outputs[name], seconds = scene_result.outputs, scene_result.tracker_seconds
            tracker_secs += seconds
            bar.update(len(frames))

    results = {s: (det_scenes[s], outputs[s]) for s in det_scenes}
    coasting_score = None if config.mode is TrackingMode.OFFLINE else 0.0
    out.mkdir(parents=True, exist_ok=True)
    results_path = out / "results.json"
    n_boxes = write_nuscenes_results(
        results_path, results, meta=conv.meta, coasting_score=coasting_score
    )
    load_results_with_devkit(results_path)  # the devkit's own format check
    write_tracks_file(out / "tracks.json", results)

    summary: dict[str, Any] = {
        "dataset": "nuscenes",
        "version": version,
        "split": split,
        "detections": str(detections),
        "scenes": list(det_scenes),
        "frames": total_frames,
        "boxes_written": n_boxes,
        "results": str(results_path),
        "mode": config.mode.value,
        "tracker_seconds": round(tracker_secs, 4),
        "tracker_fps": round(total_frames / tracker_secs, 1) if tracker_secs > 0 else None,
        "convert_seconds": round(convert_secs, 3),
        "peak_rss_mb": peak_rss_mb(),
        "skipped_detections": dict(sorted(conv.skipped_detections.items())),
        "config": config_to_dict(config),
    }
    if recordings:
        summary["recordings"] = recordings
    if not evaluate:
        summary["evaluation"] = "skipped (--no-eval)"
    elif not has_gt:
        summary["evaluation"] = "skipped: the test split has no public annotations (submit it)"
    elif scenes:
        summary["evaluation"] = "skipped: --scenes selects part of the split"
    else:
        summary["metrics"] = evaluate_nuscenes(
            results_path, dataroot=dataroot, version=version, split=split, out_dir=out / "eval"
        )
    if motion:
        summary["motion"] = _motion(det_scenes, conv.gt, outputs, config.categories, out)
    write_text_atomic(out / "summary.json", [json.dumps(summary, indent=2, allow_nan=False)])
    return summary


def _motion(
    det_scenes: dict[str, list[Frame]],
    gt: dict[str, list[Frame]] | None,
    outputs: dict[str, list[TrackOutput]],
    classes: tuple[str, ...],
    out: Path,
) -> dict[str, Any] | str:
    from tracker.eval.motion_eval import MOTION_PLOT, evaluate_motion, motion_report_lines
    from tracker.io.baseversion import write_baseversion
    from tracker.io.fileio import write_text_atomic

    if gt is None:
        return "skipped: no annotations (test split)"
    gt = {s: gt[s] for s in det_scenes}
    write_baseversion(out / "gt.json", gt)
    result = evaluate_motion(
        det_scenes, gt, outputs, classes=list(classes), plot_path=out / MOTION_PLOT
    )
    write_text_atomic(
        out / "motion.md", ["\n".join(["# Motion metrics", "", *motion_report_lines(result)])]
    )
    return result


def _print_summary(summary: dict[str, Any]) -> None:
    print(
        f"{len(summary['scenes'])} scenes, {summary['frames']} frames, tracker "
        f"{summary['tracker_seconds']:.2f} s ({summary['tracker_fps']} frames/s), "
        f"{summary['boxes_written']} boxes -> {summary['results']}"
    )
    metrics = summary.get("metrics")
    if isinstance(metrics, dict):
        cols = ["amota", "amotp", "recall", "mota", "ids"]
        print(f"{'class':<12}" + "".join(f"{c.upper():>9}" for c in cols))
        rows = [("overall", metrics["overall"]), *metrics["per_class"].items()]
        for name, m in rows:
            cells = "".join(f"{'n/a':>9}" if m.get(c) is None else f"{m[c]:>9.3f}" for c in cols)
            print(f"{name:<12}{cells}")
    elif "evaluation" in summary:
        print(summary["evaluation"])
    if isinstance(summary.get("motion"), str):
        print(f"motion: {summary['motion']}")
    elif "motion" in summary:
        print("motion metrics: see motion.md")
