"""`mctrack`: the command line. Thin: argparse and dispatch; the work lives in tracker/ and viz/."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from tracker.errors import InputError

# subcommand -> (module, help). Each module has add_arguments(parser) and run(args) -> int,
# imported only when used so `mctrack validate` never pays for rerun or trackeval.
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("app.demo", "track the bundled sample sequence and write a recording + summary"),
    "validate": ("app.validate", "check a BaseVersion file and print a summary"),
    "convert": ("app.convert", "convert a dataset's detections and labels to BaseVersion"),
    "track": ("app.track", "run the tracker on a BaseVersion file"),
    "kitti": ("app.kitti", "convert, track and evaluate KITTI tracking sequences"),
    "nuscenes": ("app.nuscenes", "convert, track and evaluate nuScenes (official devkit metrics)"),
    "waymo": ("app.waymo", "convert and track Waymo segments, write the per-segment result npz"),
    "calibrate": (
        "app.calibrate",
        "fit a detector's score calibration profile (raw score -> P(true positive)) on labels",
    ),
    "tune": (
        "app.tune",
        "cross-validated search of one class's settings over detectors (Optuna)",
    ),
    "robustness": (
        "app.robustness",
        "HOTA per class under seeded detection noise (drops, jitter, false positives)",
    ),
    "bench": ("app.bench", "tracker speed benchmark (frames/s, ms/frame, peak memory)"),
    "eval": ("app.eval", "evaluate a tracks file: KITTI static metrics and motion metrics"),
    "view": ("app.view", "run the tracker with the Rerun visual debugger (file, viewer or web)"),
    "shots": ("app.shots", "headless screenshots of a recording at its ID switches and lag"),
    "inspect": ("app.inspect", "open a recording in the viewer at one ID event, focused"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mctrack", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise
            continue  # a subcommand not built yet is absent, not stubbed
        sub_parser = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(sub_parser)
        sub_parser.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return int(args._run(args))
    except InputError as exc:
        print(f"mctrack {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
