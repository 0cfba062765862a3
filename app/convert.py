"""``mctrack convert <dataset>``: raw benchmark files → BaseVersion JSON.

Datasets: ``kitti``, ``nuscenes`` (detection results + metadata tables, needs the devkit) and
``waymo`` (ImmortalTracker-style npz detections + ego_info/ts_info); docs/nuscenes_waymo.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from app.inputs import (
    IMAGE_DETECTOR_HELP,
    NO_POSES_NOTE,
    add_kitti_root_argument,
    check_image_detector,
    check_kitti_root,
    class_list,
    default_kitti_root,
    sequence_list,
    unit_interval,
)
from tracker.errors import InputError
from tracker.frame import Frame
from tracker.io.fileio import check_output_file, check_output_folder


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
    add_kitti_root_argument(kitti)
    kitti.add_argument(
        "--split",
        default="training",
        choices=["training", "testing"],
        help="which half of the kit (testing has no labels)",
    )
    kitti.add_argument(
        "--seqs", type=sequence_list, default=None, help="e.g. 0001,0006 (default: all)"
    )
    kitti.add_argument("--detector", default="pointrcnn", help="folder under detections/")
    kitti.add_argument(
        "--detections", type=Path, default=None, help="detections folder (overrides --detector)"
    )
    kitti.add_argument(
        "--image-detector",
        default=None,
        metavar="NAME",
        help=f"{IMAGE_DETECTOR_HELP}; track with image_boxes = auto to write them",
    )
    kitti.add_argument(
        "--detections-layout",
        default="auto",
        choices=["auto", "ab3dmot", "kitti_tracking", "kitti_object"],
        help="ab3dmot: <seq>.txt (CSV) or <Class>/<seq>.txt; kitti_tracking: <seq>.txt in the "
        "label format + score; kitti_object: <seq>/<frame>.txt; auto: whichever exists",
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
        "--classes",
        type=class_list,
        default=["car", "pedestrian", "cyclist"],
        help="detection classes",
    )
    kitti.add_argument("--no-gt", action="store_true", help="skip label_02 ground truth")
    kitti.add_argument("--gzip", action="store_true", help="write .json.gz (about 5x smaller)")
    kitti.add_argument("--out", type=Path, required=True, help="output folder")
    _add_nuscenes(datasets)
    _add_waymo(datasets)


def _add_nuscenes(datasets: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    nusc = datasets.add_parser(
        "nuscenes",
        help="nuScenes detection results (submission JSON) + metadata tables (needs the devkit)",
        description="Write OUT (BaseVersion detections with ego poses and the six cameras) and, "
        "with --gt-out, the split's ground truth. docs/nuscenes_waymo.md",
    )
    nusc.add_argument("--dataroot", type=Path, required=True, help="holds <version>/ and maps/")
    nusc.add_argument(
        "--version", default="v1.0-trainval", help="v1.0-trainval, v1.0-mini or v1.0-test"
    )
    nusc.add_argument("--detections", type=Path, required=True, help="detection results JSON")
    nusc.add_argument(
        "--split", default="val", help="val, mini_val, test, ... or a custom split (splits.json)"
    )
    nusc.add_argument(
        "--score-min",
        type=unit_interval,
        default=0.0,
        help="drop detections scoring below this, in [0, 1], counted (smaller files; the "
        "tracker filters anyway) (default: 0: keep all)",
    )
    nusc.add_argument("--gt-out", type=Path, default=None, help="also write the GT BaseVersion")
    nusc.add_argument("--out", type=Path, required=True, help="output FILE.json (or .json.gz)")


def _add_waymo(datasets: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    waymo = datasets.add_parser(
        "waymo",
        help="Waymo: ImmortalTracker-style <segment>.npz detections + ego_info/ts_info",
        description="Write OUT (BaseVersion in the world frame, with the five cameras). "
        "docs/nuscenes_waymo.md",
    )
    waymo.add_argument(
        "--data-root", type=Path, required=True, help="folder with ego_info/ and ts_info/"
    )
    waymo.add_argument(
        "--detections", type=Path, required=True, help="folder of <segment>.npz detections"
    )
    waymo.add_argument("--gt", type=Path, default=None, help="folder of <segment>.npz GT (ids)")
    waymo.add_argument("--segments", type=_csv, default=None, help="segment names (default all)")
    waymo.add_argument("--gt-out", type=Path, default=None, help="write the GT BaseVersion here")
    waymo.add_argument("--out", type=Path, required=True, help="output FILE.json (or .json.gz)")


def _summary(name: str, scenes: dict[str, list[Frame]]) -> str:
    frames = sum(len(f) for f in scenes.values())
    boxes = sum(len(frame.boxes) for f in scenes.values() for frame in f)
    return f"{name}: {len(scenes)} sequences, {frames} frames, {boxes} boxes"


def _run_kitti(args: argparse.Namespace) -> int:
    from tracker.io.baseversion import write_baseversion
    from tracker.io.convert.kitti import convert_kitti

    start = time.perf_counter()
    root = args.kitti_root or default_kitti_root()
    poses = None if str(args.poses).lower() == "none" else args.poses
    if args.detections is not None and not args.detections.is_dir():
        raise InputError(f"{args.detections}: --detections folder not found")
    check_kitti_root(
        root,
        split=args.split,
        seqs=args.seqs,
        poses=poses,
        detector=None if args.detections else args.detector,
    )
    check_image_detector(
        root, args.image_detector, args.split, classes=args.classes, seqs=args.seqs
    )
    if poses is None:
        print(NO_POSES_NOTE, file=sys.stderr)
    detections, gt = convert_kitti(
        root,
        split=args.split,
        seqs=args.seqs,
        detector=args.detector,
        detections_dir=args.detections,
        detections_layout=args.detections_layout,
        poses=poses,
        pose_format=args.pose_format,
        classes=args.classes,
        with_gt=not args.no_gt,
        image_detector=args.image_detector,
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


def _run_nuscenes(args: argparse.Namespace) -> int:
    from tracker.io.baseversion import write_baseversion
    from tracker.io.convert.nuscenes import convert_nuscenes

    start = time.perf_counter()
    conv = convert_nuscenes(
        args.dataroot,
        version=args.version,
        detections=args.detections,
        split=args.split,
        with_gt=args.gt_out is not None,
        score_min=args.score_min,
    )
    write_baseversion(args.out, conv.detections)
    print(_summary("detections", conv.detections), "->", args.out)
    if conv.gt is not None:
        write_baseversion(args.gt_out, conv.gt)
        print(_summary("gt", conv.gt), "->", args.gt_out)
    print(f"done in {time.perf_counter() - start:.2f} s")
    return 0


def _run_waymo(args: argparse.Namespace) -> int:
    from tracker.io.baseversion import write_baseversion
    from tracker.io.convert.waymo import convert_waymo

    if args.gt_out is not None and args.gt is None:
        raise InputError("--gt-out needs --gt (the ground-truth npz folder)")
    start = time.perf_counter()
    conv = convert_waymo(args.data_root, args.detections, gt=args.gt, segments=args.segments)
    write_baseversion(args.out, conv.detections)
    print(_summary("detections", conv.detections), "->", args.out)
    if conv.skipped_types:
        print(f"skipped untracked Waymo types: {dict(sorted(conv.skipped_types.items()))}")
    if conv.gt is not None and args.gt_out is not None:
        write_baseversion(args.gt_out, conv.gt)
        print(_summary("gt", conv.gt), "->", args.gt_out)
    print(f"done in {time.perf_counter() - start:.2f} s")
    return 0


def run(args: argparse.Namespace) -> int:
    """Run ``mctrack convert``; bad or missing input raises (the CLI prints one line, exit 2)."""
    # the output is checked before the (long) conversion
    if args.dataset == "kitti":
        check_output_folder(args.out)
    else:
        check_output_file(args.out)
        if getattr(args, "gt_out", None) is not None:
            check_output_file(args.gt_out, "--gt-out")
    runners = {"kitti": _run_kitti, "nuscenes": _run_nuscenes, "waymo": _run_waymo}
    return runners[args.dataset](args)
