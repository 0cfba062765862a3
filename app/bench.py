"""`mctrack bench`: tracker speed (frames/s, ms/frame) and peak memory.

1. The 11 KITTI validation sequences, PointRCNN detections, all three classes (tracker only:
   conversion and writing are outside the timed region).
2. Synthetic dense scenes with 50 and 200 objects per frame.

Each case runs ``--repeat`` times and the best run is kept: on a shared machine the slower runs
measure the neighbours. The machine's load average is printed with the results. The compiled
geometry kernel is loaded when the tracker is built, before the timer starts (the first run of
a checkout compiles it once).
"""

from __future__ import annotations

import argparse
import json
import os
from typing import Any

from app.common import peak_rss_mb
from app.inputs import (
    add_kitti_root_argument,
    check_kitti_root,
    default_kitti_root,
    positive_int,
)
from tracker.calibration import calibrate_frames, find_profile
from tracker.config import ScoreSource, load_config
from tracker.io.fileio import check_output_file, write_text_atomic
from tracker.io.synthetic import synthetic_scene


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_kitti_root_argument(parser)
    parser.add_argument(
        "--config", default="kitti", help="built-in config name (kitti, ...) or a TOML file"
    )
    parser.add_argument(
        "--repeat", type=positive_int, default=5, help="runs per case; the best is kept"
    )
    parser.add_argument(
        "--frames", type=positive_int, default=200, help="frames per synthetic scene"
    )
    parser.add_argument("--json", default=None, help="also write the results to this file")


def run(args: argparse.Namespace) -> int:
    from tracker.io.convert.kitti import VALIDATION_SEQS
    from tracker.pipeline import run_scene  # scipy: imported when running, not for --help

    if args.json:  # before the benchmark: a bad --json fails now, not after minutes
        check_output_file(args.json, "--json")
    results: dict[str, Any] = {"load_average_1min": round(os.getloadavg()[0], 2)}
    print(
        f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} (1 min); "
        f"best of {args.repeat} runs per case"
    )
    root = args.kitti_root or default_kitti_root()
    if args.kitti_root is not None:  # a path the user gave must exist; the default may not
        check_kitti_root(root, seqs=VALIDATION_SEQS)
    if root.is_dir():
        from tracker.io.convert.kitti import convert_kitti

        config = load_config(
            args.config, overrides={"categories": ["car", "pedestrian", "cyclist"]}
        )
        scenes, _ = convert_kitti(root, seqs=VALIDATION_SEQS, with_gt=False)
        if config.scores is ScoreSource.PROFILE:  # the units the thresholds are in
            profile = find_profile("pointrcnn")
            scenes = {s: calibrate_frames(f, profile) for s, f in scenes.items()}
        frames = sum(len(f) for f in scenes.values())
        best = min(
            sum(run_scene(f, config).tracker_seconds for f in scenes.values())
            for _ in range(args.repeat)
        )
        results["kitti_val"] = {
            "frames": frames,
            "seconds": round(best, 3),
            "frames_per_sec": round(frames / best, 1),
            "ms_per_frame": round(1000 * best / frames, 3),
        }
        print(
            f"KITTI val (11 seqs, car+ped+cyc): {frames} frames in {best:.3f} s -> "
            f"{frames / best:.0f} frames/s ({1000 * best / frames:.3f} ms/frame)"
        )
    else:
        print(f"KITTI val: skipped ({root} not found)")

    config = load_config(args.config, overrides={"categories": ["car", "pedestrian"]})
    for n in (50, 200):
        dets, _ = synthetic_scene(num_objects=n, num_frames=args.frames, seed=n)
        best = min(run_scene(dets, config).tracker_seconds for _ in range(args.repeat))
        ms = 1000 * best / len(dets)
        results[f"synthetic_{n}"] = {
            "objects": n,
            "frames": len(dets),
            "frames_per_sec": round(1000 / ms, 1),
            "ms_per_frame": round(ms, 3),
        }
        print(
            f"synthetic {n} objects/frame: {ms:.2f} ms/frame ({1000 / ms:.0f} frames/s, "
            f"{len(dets)} frames)"
        )
    results["peak_rss_mb"] = peak_rss_mb()
    print(f"peak RSS: {results['peak_rss_mb']} MB")
    if args.json:
        write_text_atomic(args.json, [json.dumps(results, indent=2)])
    return 0
