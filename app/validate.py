"""`mctrack validate FILE`: check a BaseVersion file; print a summary, or every error (up to
--max-errors) with their count."""

from __future__ import annotations

import argparse
import json
import sys

from app.inputs import positive_int
from app.track import require_frames
from tracker.errors import InputError
from tracker.io.baseversion import summarize, validate_baseversion


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="BaseVersion JSON file")
    parser.add_argument(
        "--frame-rate",
        type=float,
        default=None,
        help="frame rate used for frames whose timestamp is null (official KITTI files) "
        "(default: none: such frames get no time, NaN)",
    )
    parser.add_argument(
        "--max-errors", type=positive_int, default=50, help="errors listed at most (all counted)"
    )
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")


def run(args: argparse.Namespace) -> int:
    result = validate_baseversion(
        args.file, max_errors=args.max_errors, fallback_frame_rate_hz=args.frame_rate
    )
    if result.error_count == 1:  # the usual case: one line, as every other command's errors
        raise InputError(result.errors[0])
    if not result.ok:
        for message in result.errors:
            print(f"mctrack validate: error: {message}", file=sys.stderr)
        shown = len(result.errors)
        more = f" ({shown} shown)" if shown < result.error_count else ""
        print(f"mctrack validate: {args.file}: {result.error_count} errors{more}", file=sys.stderr)
        return 2
    # well-formed but empty: mctrack track and view refuse it, so "OK" would mislead
    require_frames(result.scenes, args.file, "track")
    summary = summarize(result.scenes, result.report)
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
