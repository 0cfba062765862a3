"""`mctrack validate FILE`: check a BaseVersion file; print a summary, or every error (up to
--max-errors) with their count. With --json, either goes to stdout as JSON (the errors as
``{"file", "ok": false, "error_count", "errors"}``; the text lines still go to stderr, exit 2)."""

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
    parser.add_argument(
        "--json",
        action="store_true",
        help="print the summary, or the errors (exit status 2), as JSON on stdout",
    )


def run(args: argparse.Namespace) -> int:
    result = validate_baseversion(
        args.file, max_errors=args.max_errors, fallback_frame_rate_hz=args.frame_rate
    )
    if not result.ok and args.json:  # a script reading stdout gets the errors, not nothing
        _print_errors_json(args.file, result.errors, result.error_count)
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
    try:
        require_frames(result.scenes, args.file, "track")
    except InputError as exc:
        if args.json:
            _print_errors_json(args.file, [str(exc)], 1)
        raise
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


def _print_errors_json(file: str, errors: list[str], count: int) -> None:
    """The errors as JSON on stdout: the first ``len(errors)`` messages of ``count``."""
    print(json.dumps({"file": file, "ok": False, "error_count": count, "errors": errors}, indent=2))
