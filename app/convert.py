"""``mctrack convert <dataset>``: raw benchmark files → BaseVersion JSON.

Only ``kitti`` exists so far; ``nuscenes`` and ``waymo`` get their own sub-subcommands here.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from tracker.errors import InputError
from tracker.frame import Frame


def _csv(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the dataset sub-subcommands to the ``convert`` parser."""
    datasets = parser.add_subparsers(dest="dataset", required=True, metavar="DATASET")
    kitti = datasets.add_parser(
        "kitti",
        help="KITTI tracking (labels, AB3DMOT/KITTI-object detections, ORB-SLAM3 or oxts poses)",
        description="Write OUT/detections.json and OUT/gt.json (when labels exist).",
    )
    kitti.add_argument("--kitti-root", type=Path, required=True, help="the kitti/tracking folder")
    kitti.add_argument("--split", default="training", choices=["training", "testing"])
    kitti.add_argument("--seqs", type=_csv, default=None, help="e.g. 0001,0006 (default: all)")
    kitti.add_argument("--detector", default="pointrcnn", help="folder under detections/")
    kitti.add_argument(
        "--detections", type=Path, default=None, help="detections folder (overrides --detector)"
    )
    kitti.add_argument(
        "--detections-layout", default="auto", choices=["auto", "ab3dmot", "kitti_object"]
    )
    kitti.add_argument(
        "--poses",
        default="orbslam3",
        help="'orbslam3' (the kit's <split>/pose_orbslam3), 'none', or a folder of <seq>.txt",
    )
    kitti.add_argument(
        "--pose-format",
        default="camera",
        choices=["camera", "lidar"],
        help="pose files in a folder: camera-2 poses (ORB-SLAM3) or velodyne→world (oxts)",
    )
    kitti.add_argument(
        "--classes", type=_csv, default=["car", "pedestrian", "cyclist"], help="detection classes"
    )
    kitti.add_argument("--no-gt", action="store_true", help="skip label_02 ground truth")
    kitti.add_argument("--gzip", action="store_true", help="write .json.gz (about 5x smaller)")
    kitti.add_argument("--out", type=Path, required=True, help="output folder")


def _summary(name: str, scenes: dict[str, list[Frame]]) -> str:
    frames = sum(len(f) for f in scenes.values())
    boxes = sum(len(frame.boxes) for f in scenes.values() for frame in f)
    return f"{name}: {len(scenes)} sequences, {frames} frames, {boxes} boxes"


def _run_kitti(args: argparse.Namespace) -> int:
    from tracker.baseversion import write_baseversion
    from tracker.convert.kitti import convert_kitti

    start = time.perf_counter()
    poses = None if str(args.poses).lower() == "none" else args.poses
    detections, gt = convert_kitti(
        args.kitti_root,
        split=args.split,
        seqs=args.seqs,
        detector=args.detector,
        detections_dir=args.detections,
        detections_layout=args.detections_layout,
        poses=poses,
        pose_format=args.pose_format,
        classes=args.classes,
        with_gt=not args.no_gt,
    )
    converted = time.perf_counter()
    args.out.mkdir(parents=True, exist_ok=True)
    suffix = ".json.gz" if args.gzip else ".json"
    write_baseversion(args.out / f"detections{suffix}", detections)
    print(_summary("detections", detections), "->", args.out / f"detections{suffix}")
    if gt is not None:
        write_baseversion(args.out / f"gt{suffix}", gt)
        print(_summary("gt", gt), "->", args.out / f"gt{suffix}")
    done = time.perf_counter()
    print(f"converted in {converted - start:.2f} s, written in {done - converted:.2f} s")
    return 0


def run(args: argparse.Namespace) -> int:
    """Run ``mctrack convert``; returns the exit code (2 for bad or missing input)."""
    try:
        if args.dataset == "kitti":
            return _run_kitti(args)
    except (InputError, FileNotFoundError) as exc:
        print(f"mctrack convert {args.dataset}: error: {exc}", file=sys.stderr)
        return 2
    print(f"mctrack convert: unknown dataset {args.dataset!r}", file=sys.stderr)
    return 2
