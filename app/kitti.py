"""`mctrack kitti`: convert, track, write KITTI results, evaluate with TrackEval, summarise."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tqdm import tqdm

from app.common import peak_rss_mb
from app.inputs import (
    NO_POSES_NOTE,
    add_detector_argument,
    add_kitti_root_argument,
    check_kitti_root,
    default_kitti_root,
)
from tracker.calibration import calibrate_frames, resolve_profile
from tracker.config import BUILTIN, ScoreSource, TrackerConfig, config_to_dict, load_config
from tracker.frame import Frame
from tracker.io.convert.kitti import VALIDATION_SEQS
from tracker.io.fileio import write_text_atomic
from tracker.io.writers import write_kitti_sequence, write_tracks_file

if TYPE_CHECKING:
    from tracker.pipeline import SceneResult


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_kitti_root_argument(parser)
    add_detector_argument(parser)
    parser.add_argument(
        "--seqs",
        default=",".join(VALIDATION_SEQS),
        help="comma-separated sequences (default: the 11 validation sequences)",
    )
    parser.add_argument(
        "--labels",
        default=None,
        metavar="DIR",
        help="label_02 folder for evaluation (default: <root>/training/label_02)",
    )
    parser.add_argument(
        "--classes",
        default="car,pedestrian,cyclist",
        help="comma-separated classes to track and evaluate",
    )
    parser.add_argument(
        "--config", default="kitti", help="built-in config name (kitti, ...) or a TOML file"
    )
    parser.add_argument(
        "--mode",
        choices=["online", "offline"],
        default=None,
        help="tracking mode (default: the config's); offline with a built-in config uses "
        "<config>_offline",
    )
    parser.add_argument(
        "--poses",
        default="orbslam3",
        help="ego poses: orbslam3 (<root>/training/pose_orbslam3), none (no ego motion: "
        "velocities relative to the ego vehicle) or a folder of <seq>.txt",
    )
    parser.add_argument(
        "--profile",
        default=None,
        help="score calibration profile (TOML from `mctrack calibrate`); default: the one shipped "
        "for --detector, if any (configs with scores = 'as_given' use none)",
    )
    parser.add_argument("--no-eval", action="store_true", help="skip the evaluation")
    parser.add_argument(
        "--motion",
        action="store_true",
        help="also compute the motion metrics (summary.json 'motion', motion.md, PNG)",
    )
    parser.add_argument(
        "--record",
        action="store_true",
        help="also write a Rerun recording per sequence to OUT/recordings/<seq>.rrd",
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")


def run(args: argparse.Namespace) -> int:
    root = args.kitti_root or default_kitti_root()
    seqs = [s.strip() for s in args.seqs.split(",") if s.strip()]
    poses = None if args.poses == "none" else args.poses
    check_kitti_root(root, seqs=seqs, poses=poses, detector=args.detector)
    if poses is None:
        print(NO_POSES_NOTE, file=sys.stderr)
    out = Path(args.out)
    summary = run_kitti(
        kitti_root=root,
        seqs=seqs,
        classes=[c.strip() for c in args.classes.split(",") if c.strip()],
        config_name=args.config,
        mode=args.mode,
        detector=args.detector,
        profile=Path(args.profile) if args.profile else None,
        labels=Path(args.labels) if args.labels else None,
        poses=poses,
        evaluate=not args.no_eval,
        motion=args.motion,
        record=out / "recordings" if args.record else None,
        out=out,
    )
    _print_summary(summary)
    return 0


def run_kitti(
    *,
    kitti_root: Path,
    seqs: list[str],
    classes: list[str],
    config_name: str | Path = "kitti",
    mode: str | None = None,
    detector: str = "pointrcnn",
    profile: Path | None = None,
    labels: Path | None = None,
    poses: str | None = "orbslam3",
    evaluate: bool = True,
    motion: bool = False,
    record: Path | None = None,
    out: Path,
    config_overrides: dict[str, Any] | None = None,
    quiet: bool = False,
) -> dict[str, Any]:
    """The end-to-end KITTI job; returns (and writes) ``out/summary.json``.

    With ``motion`` the labels are converted too and the motion metrics
    (:func:`tracker.eval.motion_eval.evaluate_motion`) go to ``summary["motion"]``,
    ``out/motion.md`` and ``out/motion_velocity.png``.
    """
    from tracker.io.convert.kitti import convert_kitti
    from tracker.pipeline import run_scene  # scipy: imported when running, not for --help

    overrides = dict(config_overrides or {})
    overrides["categories"] = classes
    if mode == "offline" and f"{config_name}_offline" in BUILTIN:
        config_name = f"{config_name}_offline"  # the built-in offline settings
    if mode:
        overrides["mode"] = mode
    config = load_config(config_name, overrides=overrides)
    t0 = time.perf_counter()
    detections, gt = convert_kitti(
        kitti_root,
        seqs=seqs,
        detector=detector,
        poses=poses,
        classes=classes,
        with_gt=motion or record is not None,
    )
    detections, calibration = apply_score_source(detections, config, detector, profile)
    convert_secs = time.perf_counter() - t0

    results: dict[str, SceneResult] = {}
    total_frames = sum(len(f) for f in detections.values())
    with tqdm(total=total_frames, unit="frame", disable=quiet or None, file=sys.stderr) as bar:
        for seq, frames in detections.items():
            bar.set_description(f"seq {seq}")
            results[seq] = run_scene(frames, config)
            bar.update(len(frames))
    tracker_secs = sum(r.tracker_seconds for r in results.values())
    label_dir = labels or kitti_root / "training" / "label_02"
    if record is not None:  # outside the timed tracker region
        from viz.record import record_scene

        for seq, frames in detections.items():
            labels_ok = label_dir if (label_dir / f"{seq}.txt").is_file() else None
            record_scene(
                frames,
                config,
                (gt or {}).get(seq),
                record / f"{seq}.rrd",
                labels_dir=labels_ok,
                motion_metrics=False,
            )

    data_dir = out / "data"
    for seq, frames in detections.items():
        write_kitti_sequence(data_dir / f"{seq}.txt", results[seq].outputs, frames)
    write_tracks_file(
        out / "tracks.json", {s: (detections[s], results[s].outputs) for s in detections}
    )

    summary: dict[str, Any] = {
        "dataset": "kitti",
        "detector": detector,
        "sequences": list(detections),
        "mode": config.mode.value,
        "classes": classes,
        "frames": total_frames,
        "tracker_seconds": round(tracker_secs, 4),
        "tracker_fps": round(total_frames / tracker_secs, 1) if tracker_secs > 0 else None,
        "score_calibration": calibration,
        "convert_seconds": round(convert_secs, 3),
        "peak_rss_mb": peak_rss_mb(),
        "config": config_to_dict(config),
    }
    if evaluate:
        missing = [s for s in detections if not (label_dir / f"{s}.txt").is_file()]
        if missing:
            summary["evaluation"] = f"skipped: no labels for {missing} in {label_dir}"
        else:
            from tracker.eval.kitti import absent_classes, evaluate_kitti

            lengths = {s: len(detections[s]) for s in detections}
            metrics = evaluate_kitti(
                label_dir=label_dir, result_dir=data_dir, seq_lengths=lengths, classes=classes
            )
            absent = absent_classes(metrics)
            summary["metrics"] = {c: m for c, m in metrics.items() if c not in absent}
            if absent:
                summary["metrics_absent"] = {
                    c: f"no ground-truth {c} in these sequences; {metrics[c]['FP']} tracked "
                    "boxes, all false positives"
                    for c in absent
                }
            summary["evaluator"] = "trackeval 1.3.0, KITTI 2D box protocol (HOTA, CLEAR, Identity)"
    if motion:
        summary["motion"] = _motion(detections, gt, results, classes, out)
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "summary.json", [json.dumps(summary, indent=2)])
    return summary


def apply_score_source(
    detections: dict[str, list[Frame]],
    config: TrackerConfig,
    detector: str,
    profile: Path | None,
) -> tuple[dict[str, list[Frame]], str]:
    """Scores in the units the config's thresholds expect, and a note of what was used."""
    if config.scores is ScoreSource.AS_GIVEN:
        return detections, "none (scores as converted; the config asks for scores = 'as_given')"
    found = resolve_profile(detector, profile)
    every = [f for frames in detections.values() for f in frames]
    calibrated = calibrate_frames(every, found)
    out, i = {}, 0
    for seq, frames in detections.items():
        out[seq], i = calibrated[i : i + len(frames)], i + len(frames)
    if found is None:
        return out, f"none found for {detector!r}: fallback sigmoid(raw) or raw probability"
    return out, f"profile {profile or detector + ' (shipped)'}"


def _motion(
    detections: dict[str, Any],
    gt: dict[str, Any] | None,
    results: dict[str, SceneResult],
    classes: list[str],
    out: Path,
) -> dict[str, Any] | str:
    """Motion metrics of the run, and ``out/motion.md`` with the velocity-curve PNG."""
    from tracker.eval.motion_eval import MOTION_PLOT, evaluate_motion, motion_report_lines

    missing = sorted(s for s in detections if gt is None or s not in gt)
    if gt is None or missing:
        return f"skipped: no labels for {missing}"
    motion = evaluate_motion(
        detections,
        gt,
        {s: r.outputs for s, r in results.items()},
        classes=classes,
        plot_path=out / MOTION_PLOT,
    )
    write_text_atomic(
        out / "motion.md", ["\n".join(["# Motion metrics", "", *motion_report_lines(motion)])]
    )
    return motion


def _print_summary(summary: dict[str, Any]) -> None:
    print(
        f"frames {summary['frames']}  tracker {summary['tracker_seconds']:.2f} s  "
        f"{summary['tracker_fps']} frames/s  peak RSS {summary['peak_rss_mb']} MB"
    )
    metrics = summary.get("metrics")
    if isinstance(metrics, dict):
        cols = ["HOTA", "DetA", "AssA", "MOTA", "IDF1", "IDSW", "FP", "FN", "Frag"]
        print(f"{'class':<12}" + "".join(f"{c:>9}" for c in cols))
        for cls, m in metrics.items():
            print(f"{cls:<12}" + "".join(f"{m[c]:>9}" for c in cols))
        for cls, why in summary.get("metrics_absent", {}).items():
            print(f"{cls:<12}  absent: {why}")
    elif "evaluation" in summary:
        print(summary["evaluation"])
    motion = summary.get("motion")
    if isinstance(motion, dict):
        cols = ["vae_deg", "vne_mps", "vir_ratio", "vse_mps", "vde_secs", "n_samples"]
        print(f"{'motion (all)':<14}" + "".join(f"{c:>11}" for c in cols))
        for est, rows in motion["metrics"].items():
            row = rows["all"]
            print(f"{est:<14}" + "".join(_cell(row[c]) for c in cols))
    elif isinstance(motion, str):
        print(f"motion: {motion}")


def _cell(value: float | int | None) -> str:
    if value is None:
        return f"{'n/a':>11}"
    return f"{value:>11.3f}" if isinstance(value, float) else f"{value:>11}"
