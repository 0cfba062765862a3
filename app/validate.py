"""`mctrack validate FILE`: check a BaseVersion file, print a summary or the first error."""

from __future__ import annotations

import argparse
import json

from tracker.io.baseversion import LoadReport, read_baseversion, summarize


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="BaseVersion JSON file")
    parser.add_argument(
        "--frame-rate",
        type=float,
        default=None,
        help="frame rate used for frames whose timestamp is null (official KITTI files)",
    )
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")


def run(args: argparse.Namespace) -> int:
    report = LoadReport()
    scenes = read_baseversion(args.file, fallback_frame_rate_hz=args.frame_rate, report=report)
    summary = summarize(scenes, report)
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    print(f"{args.file}: OK")
    print(f"  scenes: {summary['scenes']}, frames: {summary['frames']}, boxes: {summary['boxes']}")
    for name, count in summary["boxes_per_category"].items():
        print(f"    {name:<16}{count:>8}")
    print(f"  time span: {summary['time_span_secs']:.1f} s")
    for name, count in summary.get("skipped_unknown_categories", {}).items():
        print(f"  skipped (unknown category): {name} x{count}")
    for name, file_name in summary.get("scene_names_escaped_in_file_names", {}).items():
        print(f"  warning: scene {name!a} is written to files as {file_name!r}")
    return 0
