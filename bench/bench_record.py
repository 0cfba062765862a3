"""Recording overhead and memory of the Rerun debug recording (issue #5 figures).

1. KITTI tracking sequence 0001 (the bundled sample: PointRCNN detections, 447 frames), ms per
   frame of the tracker alone vs the tracker with the full debug recording streamed to a file
   (``--save``), without and with ground truth. "Recording" is everything ``record_scene`` does
   except the evaluation (TrackEval, motion metrics), which is analysis and timed separately.
   Best of ``--repeat`` runs, wall clock.
2. Memory: a 10,000-frame synthetic scene (20 objects) recorded to a file; resident memory
   (RSS) after 1,000 and 10,000 frames, for the tracker alone and with the recording, each in a
   fresh process so the numbers do not contaminate each other.

Usage: ``python bench/bench_record.py [--repeat 3] [--frames 10000] [--json out.json]``
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SAMPLE = ROOT / "sample_data" / "kitti-0001"
RSS_AT = (1_000, 5_000, 10_000)


def _rss_mb() -> float:
    """Current resident memory (not the peak), from /proc."""
    with open("/proc/self/statm") as fh:
        pages = int(fh.read().split()[1])
    return pages * resource.getpagesize() / 2**20


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def kitti_overhead(repeat: int) -> dict[str, Any]:
    from tracker.config import load_config
    from tracker.io.baseversion import read_baseversion
    from tracker.io.fileio import work_folder
    from tracker.pipeline import run_scene
    from viz.record import record_scene

    config = load_config("kitti")
    frames = read_baseversion(SAMPLE / "detections.json.gz", fallback_frame_rate_hz=10.0)["0001"]
    gt = read_baseversion(SAMPLE / "gt.json.gz", fallback_frame_rate_hz=10.0)["0001"]
    labels = SAMPLE / "raw" / "training" / "label_02"
    n = len(frames)
    run_scene(frames, config)  # warm-up (imports, caches)
    variants = {
        "record": {},
        "record_with_gt": {"gt_frames": gt, "labels_dir": labels},
    }
    # interleaved, best of each: the machine is shared, a slow spell should not hit one variant
    track_s = track_cpu = float("inf")
    best: dict[str, Any] = {}
    cpu: dict[str, float] = {}
    with work_folder("benchrecord") as tmp:
        for i in range(repeat):
            c0 = time.process_time()
            track_s = min(track_s, _timed(lambda: run_scene(frames, config)))
            track_cpu = min(track_cpu, time.process_time() - c0)
            for name, kwargs in variants.items():
                path = Path(tmp) / f"{name}_{i}.rrd"
                result = record_scene(
                    frames,
                    config,
                    path=path,
                    images={"CAM_FRONT": SAMPLE / "image_02"},
                    **kwargs,
                )
                if name not in best or result.recording_seconds < best[name][0].recording_seconds:
                    best[name] = (result, path.stat().st_size / 2**20)
                c = result.cpu_seconds
                cpu[name] = min(cpu.get(name, float("inf")), c["track"] + c["flush"] + c["post"])
    out: dict[str, Any] = {
        "frames": n,
        "tracking_ms_per_frame": 1000 * track_s / n,
        "tracking_cpu_ms_per_frame": 1000 * track_cpu / n,
    }
    for name, (result, size_mb) in best.items():
        out[name] = {
            "ms_per_frame": 1000 * result.recording_seconds / n,
            "overhead_ms_per_frame": 1000 * (result.recording_seconds - track_s) / n,
            "during_run_overhead_ms_per_frame": 1000
            * (result.seconds["track"] + result.seconds["flush"] - track_s)
            / n,
            "after_run_ms_per_frame": 1000 * result.seconds["post"] / n,
            "cpu_ms_per_frame": 1000 * cpu[name] / n,
            "cpu_overhead_ms_per_frame": 1000 * (cpu[name] - track_cpu) / n,
            "evaluation_s": result.seconds["evaluate"],
            "file_mb": size_mb,
        }
    out["peak_rss_mb"] = _peak_rss_mb()
    return out


def _timed(fn: Any) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def memory_child(mode: str, num_frames: int) -> dict[str, Any]:
    """One fresh process: track (and record) the synthetic scene, RSS at fixed frames."""
    import rerun as rr  # imported in both modes so the baseline carries the library too

    from tracker.config import load_config
    from tracker.io.fileio import work_folder
    from tracker.io.synthetic import synthetic_scene
    from tracker.pipeline import run_scene

    del rr
    frames, _ = synthetic_scene(num_objects=20, num_frames=num_frames)
    config = load_config("kitti", overrides={"categories": ["car", "pedestrian"]})
    rss: dict[int, float] = {}
    start_rss = _rss_mb()

    class Probe:
        def __init__(self, inner: Any = None) -> None:
            self.inner, self.count = inner, 0

        def __call__(self, event: Any) -> None:
            if self.inner is not None:
                self.inner(event)
            if type(event).__name__ == "FrameFinished":
                self.count += 1
                if self.count in RSS_AT:
                    rss[self.count] = _rss_mb()

    start = time.perf_counter()
    if mode == "track":
        run_scene(frames, config, observer=Probe())
    else:
        from viz.observer import RerunObserver
        from viz.record import new_recording

        with work_folder("benchrecord") as tmp:
            rec = new_recording("synthetic", path=Path(tmp) / "long.rrd")
            observer = RerunObserver(rec)
            run_scene(frames, config, observer=Probe(observer))
            observer.flush()
            rec.flush()
            rec.disconnect()
            size = (Path(tmp) / "long.rrd").stat().st_size / 2**20
    secs = time.perf_counter() - start
    result = {"mode": mode, "start_rss_mb": start_rss, "rss_mb": rss, "seconds": secs}
    if mode != "track":
        result["file_mb"] = size
    result["peak_rss_mb"] = _peak_rss_mb()
    return result


def memory(num_frames: int) -> dict[str, Any]:
    out = {}
    for mode in ("track", "record"):
        proc = subprocess.run(
            [sys.executable, __file__, "--memory-child", mode, "--frames", str(num_frames)],
            capture_output=True,
            text=True,
            check=True,
        )
        out[mode] = json.loads(proc.stdout.strip().splitlines()[-1])
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--frames", type=int, default=10_000, help="synthetic scene length")
    parser.add_argument("--json", default=None)
    parser.add_argument("--skip-memory", action="store_true")
    parser.add_argument("--memory-child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.memory_child:
        print(json.dumps(memory_child(args.memory_child, args.frames)))
        return 0

    results: dict[str, Any] = {"kitti_0001": kitti_overhead(args.repeat)}
    k = results["kitti_0001"]
    print(f"KITTI 0001 ({k['frames']} frames), best of {args.repeat}, wall clock:")
    print(
        f"  tracking only                  {k['tracking_ms_per_frame']:6.2f} ms/frame"
        f"  (CPU {k['tracking_cpu_ms_per_frame']:.2f})"
    )
    for name, label in (("record", "+ recording (--save)"), ("record_with_gt", "+ recording, GT")):
        r = k[name]
        print(
            f"  {label:<30} {r['ms_per_frame']:6.2f} ms/frame  overhead "
            f"{r['overhead_ms_per_frame']:5.2f} ms/frame (during run "
            f"{r['during_run_overhead_ms_per_frame']:.2f}, after {r['after_run_ms_per_frame']:.2f})"
            f"  file {r['file_mb']:.1f} MB; CPU {r['cpu_ms_per_frame']:.2f} ms/frame, overhead "
            f"{r['cpu_overhead_ms_per_frame']:.2f} (all threads)"
            + (f"  [+ evaluation {r['evaluation_s']:.1f} s]" if name == "record_with_gt" else "")
        )
    print(f"  peak RSS {k['peak_rss_mb']:.0f} MB")
    if not args.skip_memory:
        results["memory"] = mem = memory(args.frames)
        print(f"synthetic scene, 20 objects, {args.frames} frames: RSS (MB) after N frames")
        for mode, label in (("track", "tracking only"), ("record", "with recording")):
            m = mem[mode]
            at = "  ".join(f"{n:>6}: {v:6.0f}" for n, v in sorted(m["rss_mb"].items()))
            extra = f"  file {m['file_mb']:.0f} MB" if "file_mb" in m else ""
            print(
                f"  {label:<16} start {m['start_rss_mb']:5.0f}  {at}  ({m['seconds']:.0f} s){extra}"
            )
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
