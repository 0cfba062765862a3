"""`mctrack demo`: track the bundled KITTI sequence 0001 and write a debug recording.

Prints a short summary (tracks, ID switches, HOTA/MOTA for car by TrackEval on the sample's
labels) and how to open ``DIR/demo.rrd``, which holds the ground truth, the ID-switch events and
the velocity curves.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from tracker.errors import InputError
from tracker.io.fileio import check_output_folder

SAMPLE_DIR = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default=".", help="folder for demo.rrd (default: here)")
    parser.add_argument("--frames", default=None, help="frame range A:B (default: all 447)")
    parser.add_argument("--sample", default=str(SAMPLE_DIR), help=argparse.SUPPRESS)


def run(args: argparse.Namespace) -> int:
    from app.track import parse_frame_range
    from tracker.calibration import calibrate_frames, find_profile
    from tracker.config import load_config
    from tracker.eval.kitti import absent_classes
    from tracker.io.baseversion import read_baseversion
    from viz.record import record_scene

    sample = Path(args.sample)
    detections, gt_file = sample / "detections.json.gz", sample / "gt.json.gz"
    labels, images = sample / "raw" / "training" / "label_02", sample / "image_02"
    if not detections.is_file() or not gt_file.is_file():
        raise InputError(
            f"sample data not found in {sample} (detections.json.gz, gt.json.gz); see "
            "sample_data/README.md to regenerate it"
        )
    check_output_folder(args.out)  # before any work
    config = load_config("kitti")
    window = parse_frame_range(args.frames)
    frames = read_baseversion(detections, fallback_frame_rate_hz=config.frame_rate_hz)["0001"]
    gt = read_baseversion(gt_file, fallback_frame_rate_hz=config.frame_rate_hz)["0001"]
    if not frames[window]:
        raise InputError(f"--frames {args.frames}: the sample has frames 0:{len(frames)}")
    frames, gt = frames[window], gt[window]
    frames = calibrate_frames(frames, find_profile("pointrcnn"))  # the sample is PointRCNN's
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "demo.rrd"
    description = (
        f"- detections: `{detections}` (PointRCNN), frames {frames[0].frame_id}.."
        f"{frames[-1].frame_id}\n- ground truth: `{gt_file}`\n- labels: `{labels}`\n"
        f"- images: `{images}` (frames 10, 15, 20)\n- config: `kitti`"
    )
    result = record_scene(
        frames,
        config,
        gt,
        path,
        labels_dir=labels,
        images={frames[0].cameras[0].name: images},
        input_description=description,
    )
    print(f"MCTrack demo: KITTI tracking sequence 0001, {len(frames)} frames")
    print(f"  tracks: {len(result.track_ids)}")
    ev = result.id_evaluation
    if ev is not None:
        car = ev.counts.get("car", {})
        switches = ev.of_kind(type(ev.events[0].kind).ID_SWITCH) if ev.events else []
        frames_list = ", ".join(str(e.frame_id) for e in switches[:8])
        more = " ..." if len(switches) > 8 else ""
        print(
            f"  ID switches (car): {car.get('IDSW', 0)}, fragmentations: {car.get('Frag', 0)}"
            + (f"  at frames {frames_list}{more}" if switches else "")
        )
    metrics = result.kitti_metrics or {}
    if "car" in metrics and "car" in absent_classes(metrics):  # (as the recording says it)
        print("  car (TrackEval, KITTI 2D): no labelled car in these frames, not scored")
    elif "car" in metrics:
        m = metrics["car"]
        print(
            f"  car (TrackEval, KITTI 2D): HOTA {m['HOTA']:.2f}  MOTA {m['MOTA']:.2f}  "
            f"IDF1 {m['IDF1']:.2f}"
        )
    if result.lag is not None:
        lag = result.lag
        print(
            f"  largest velocity lag: frame {lag.frame_id}, T{lag.track_id} "
            f"{lag.track_speed_mps:.1f} m/s vs GT {lag.gt_speed_mps:.1f} m/s"
        )
    print(f"wrote {path}")
    print(f"open it with:  rerun {path}")
    return 0
